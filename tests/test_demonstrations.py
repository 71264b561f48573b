"""Sampling the greedy expert and the empirical statistics of eq. (5)."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError


def test_sample_shapes_dtypes_and_greedy_expert(rng, grid4):
    R = rng.standard_normal((3, 16, 4))
    demos = fo.sample_demonstrations(grid4, R, 7, 5, rng)
    assert isinstance(demos, list) and len(demos) == 3
    _, pol = fo.optimal_q(grid4, R)
    for i, d in enumerate(demos):
        assert d.shape == (7, 5, 2) and d.dtype == np.int64
        states, actions = d[..., 0], d[..., 1]
        assert states.min() >= 0 and states.max() < 16
        np.testing.assert_array_equal(actions, pol[i][states])
        # every step follows a transition of positive probability
        P = grid4.transitions
        assert np.all(P[states[:, :-1], actions[:, :-1], states[:, 1:]] > 0)


def test_single_reward_gives_one_task(rng, grid4):
    demos = fo.sample_demonstrations(grid4, rng.standard_normal((16, 4)), 2, 3, rng)
    assert len(demos) == 1 and demos[0].shape == (2, 3, 2)


def test_same_seed_same_demos(grid4):
    R = np.random.default_rng(1).standard_normal((2, 16, 4))
    a = fo.sample_demonstrations(grid4, R, 4, 6, 123)
    b = fo.sample_demonstrations(grid4, R, 4, 6, np.random.default_rng(123))
    c = fo.sample_demonstrations(grid4, R, 4, 6, 124)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert any(not np.array_equal(x, z) for x, z in zip(a, c))


def test_starts_are_uniform_and_dynamics_followed(rng, grid3):
    R = rng.standard_normal((9, 4))
    n = 9000
    demos = fo.sample_demonstrations(grid3, R, n, 2, rng)[0]
    counts = np.bincount(demos[:, 0, 0], minlength=9)
    expected = n / 9
    # chi-square with 8 dof: P(X > 26.1) = 0.001
    assert np.sum((counts - expected) ** 2 / expected) < 26.1
    # empirical next-state distribution of state 4 matches P
    s4 = demos[:, 0, 0] == 4
    a4 = demos[s4, 0, 1][0]
    freq = np.bincount(demos[s4, 1, 0], minlength=9) / s4.sum()
    np.testing.assert_allclose(freq, grid3.transitions[4, a4], atol=0.06)


def test_empirical_statistics_hand_computed(grid3):
    episodes = np.array([[[0, 1], [3, 3], [4, 3]], [[0, 3], [1, 1], [4, 3]]])
    mu, pi = fo.empirical_statistics(grid3, [episodes])
    assert mu.shape == (1, 9) and pi.shape == (1, 9, 4)
    np.testing.assert_allclose(mu[0], [2 / 6, 1 / 6, 0, 1 / 6, 2 / 6, 0, 0, 0, 0])
    np.testing.assert_allclose(pi[0, 0], [0, 0.5, 0, 0.5])
    np.testing.assert_allclose(pi[0, 4], [0, 0, 0, 1])
    np.testing.assert_allclose(pi[0, 1], [0, 1, 0, 0])
    for s in (2, 5, 6, 7, 8):  # unvisited
        np.testing.assert_array_equal(pi[0, s], 0.0)


def test_empirical_statistics_ragged_and_float_integral_episodes(grid3):
    task = [np.array([[0, 1], [3, 3]]), [[4, 2]], np.array([[4.0, 2.0], [3.0, 0.0], [0.0, 1.0]])]
    mu, pi = fo.empirical_statistics(grid3, [task, np.array([[[8, 0]]])])
    np.testing.assert_allclose(mu[0, [0, 3, 4]], [2 / 6, 2 / 6, 2 / 6])
    np.testing.assert_allclose(pi[0, 3], [0.5, 0, 0, 0.5])
    np.testing.assert_allclose(mu[1], np.eye(9)[8])


def test_empirical_statistics_properties(rng, grid4):
    demos = fo.sample_demonstrations(grid4, rng.standard_normal((5, 16, 4)), 3, 4, rng)
    mu, pi = fo.empirical_statistics(grid4, demos)
    np.testing.assert_allclose(mu.sum(axis=1), 1.0)
    visited = mu > 0
    np.testing.assert_allclose(pi.sum(axis=2)[visited], 1.0)
    np.testing.assert_array_equal(pi[~visited], 0.0)
    # a 4-d array (n, m, L, 2) is accepted as n tasks
    mu4, pi4 = fo.empirical_statistics(grid4, np.stack(demos))
    np.testing.assert_array_equal(mu4, mu)
    np.testing.assert_array_equal(pi4, pi)


# --- validation -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "demos, fragment",
    [
        ([np.array([[[9, 0]]])], r"task 0, episode 0, step 0: state 9 is out of range \[0, 9\)"),
        ([np.array([[[0, 0]]]), np.array([[[0, 0], [-1, 0]]])], r"task 1, episode 0, step 1: state -1 is out of range"),
        ([np.array([[[0, 0]], [[0, 4]]])], r"task 0, episode 1, step 0: action 4 is out of range \[0, 4\)"),
        ([np.array([[[0, -2]]])], r"action -2 is out of range"),
        ([np.zeros((2, 3, 3), dtype=int)], r"task 0 must be an int array of shape \(m, L, 2\).*got an array of shape \(2, 3, 3\) and dtype int64"),
        ([np.zeros((2, 0, 2), dtype=int)], r"task 0, episode 0 must have shape \(L, 2\) with L >= 1; got \(0, 2\)"),
        ([[]], r"demonstrations of task 0 are empty"),
        ([np.zeros((0, 3, 2), dtype=int)], r"demonstrations of task 0 are empty"),
        ([], r"demos_per_task is empty"),
        ([np.array([[[0.5, 1.0]]])], r"task 0, episode 0, step 0: state 0.5 is not an integer"),
        ([[[["a", "b"]]]], r"task 0, episode 0, step 0: state 'a' is not an integer \(the pairs have dtype <U1\)"),
        ([np.zeros(5, dtype=int)], r"must be an int array of shape \(m, L, 2\).*got an array of shape \(5,\) and dtype int64"),
        ([3], r"got int 3$"),
        (np.zeros((2, 3, 2), dtype=int), r"got an array of shape \(2, 3, 2\), the layout of one task's episodes"),
        ("demos", r"demos_per_task must be a list with one entry per task .*; got str"),
    ],
)
def test_bad_demonstrations(grid3, demos, fragment):
    with pytest.raises(ValidationError, match=fragment):
        fo.empirical_statistics(grid3, demos)


def test_3d_array_as_demos_per_task_is_rejected_by_learners(rng, grid3):
    demos = fo.sample_demonstrations(grid3, rng.standard_normal((9, 4)), 2, 3, rng)[0]  # (m, L, 2)
    with pytest.raises(ValidationError, match=r"got an array of shape \(2, 3, 2\)"):
        fo.GradIRL(max_iter=1).fit(grid3, demos)
    with pytest.raises(ValidationError, match=r"got an array of shape \(2, 3, 2\)"):
        fo.FactIRL(n_primitives=2, max_iter=1).fit(grid3, demos)


@pytest.mark.parametrize(
    "kwargs, fragment",
    [
        (dict(n_demos=0, length=3), r"n_demos must be an integer >= 1; got 0"),
        (dict(n_demos=2.0, length=3), r"n_demos must be an integer >= \d; got 2\.0"),
        (dict(n_demos=2, length=-1), r"length must be an integer >= 1; got -1"),
        (dict(n_demos=2, length=True), r"length must be an integer >= 1; got True"),
    ],
)
def test_bad_sampling_arguments(rng, grid3, kwargs, fragment):
    with pytest.raises(ValidationError, match=fragment):
        fo.sample_demonstrations(grid3, np.zeros((9, 4)), rng=rng, **kwargs)


def test_bad_rng_and_rewards(grid3):
    with pytest.raises(ValidationError, match="rng must be a numpy Generator.*got str"):
        fo.sample_demonstrations(grid3, np.zeros((9, 4)), 1, 1, rng="seed")
    with pytest.raises(ValidationError, match=r"rewards must have shape .*got \(8, 4\)"):
        fo.sample_demonstrations(grid3, np.zeros((8, 4)), 1, 1, rng=0)


# --- start states and final states -----------------------------------------------------------


def _reference_sampler(mdp, R, n_demos, length, rng):
    """The sampler as it was before start states existed (dense dynamics, uniform starts)."""
    _, policy = fo.optimal_q(mdp, R)
    P = mdp.transitions.reshape(mdp.n_states * mdp.n_actions, mdp.n_states)
    cum = np.cumsum(P, axis=1)
    n, S, A = R.shape
    out = np.empty((n, n_demos, length, 2), dtype=np.int64)
    states = rng.integers(0, S, size=(n, n_demos))
    for t in range(length):
        actions = policy[np.arange(n)[:, None], states]
        out[:, :, t, 0], out[:, :, t, 1] = states, actions
        u = rng.random((n, n_demos, 1))
        states = np.minimum((u > cum[states * A + actions]).sum(axis=2), S - 1)
    return [out[i] for i in range(n)], states


def test_default_sampling_is_unchanged_and_equals_an_explicit_uniform_start(rng, grid4):
    R = rng.standard_normal((3, 16, 4))
    expected, expected_final = _reference_sampler(grid4, R, 6, 9, np.random.default_rng(7))
    default = fo.sample_demonstrations(grid4, R, 6, 9, rng=7)
    uniform = fo.sample_demonstrations(grid4, R, 6, 9, rng=7, start=np.full(16, 1 / 16))
    per_task = fo.sample_demonstrations(grid4, R, 6, 9, rng=7, start=np.full((3, 16), 1 / 16))
    demos, final = fo.sample_demonstrations(grid4, R, 6, 9, rng=7, return_final_states=True)
    for i in range(3):
        for got in (default, uniform, per_task, demos):
            np.testing.assert_array_equal(got[i], expected[i])
    np.testing.assert_array_equal(final, expected_final)
    assert final.shape == (3, 6) and final.dtype == np.int64


def test_final_states_follow_the_dynamics(rng, grid3):
    R = rng.standard_normal((2, 9, 4))
    demos, final = fo.sample_demonstrations(grid3, R, 400, 3, rng=rng, return_final_states=True)
    P = grid3.transitions
    for i in range(2):
        last = demos[i][:, -1]
        assert np.all(P[last[:, 0], last[:, 1], final[i]] > 0)
    # with one step, the final state of episodes from state 4 is distributed as P(. | 4, a)
    d1, f1 = fo.sample_demonstrations(grid3, R[0], 4000, 1, rng=rng, start=4, return_final_states=True)
    a = d1[0][0, 0, 1]
    np.testing.assert_allclose(np.bincount(f1[0], minlength=9) / 4000, P[4, a], atol=0.03)


def test_start_state_index(rng, grid3):
    demos = fo.sample_demonstrations(grid3, rng.standard_normal((2, 9, 4)), 5, 3, rng=rng, start=6)
    for d in demos:
        np.testing.assert_array_equal(d[:, 0, 0], 6)


def test_start_distribution_is_followed_and_zero_states_never_drawn(rng, grid3):
    p = np.array([0.5, 0.0, 0.2, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0])
    n = 9000
    starts = fo.sample_demonstrations(grid3, rng.standard_normal((9, 4)), n, 1, rng=rng, start=p)[0][:, 0, 0]
    counts = np.bincount(starts, minlength=9)
    assert np.all(counts[p == 0] == 0)
    expected = n * p[p > 0]
    # chi-square with 2 dof: P(X > 13.8) = 0.001
    assert np.sum((counts[p > 0] - expected) ** 2 / expected) < 13.8


def test_start_distribution_per_task(rng, grid3):
    starts = np.zeros((3, 9))
    starts[0, 8] = 1.0
    starts[1, [0, 1]] = 0.5
    starts[2, 2] = 1.0
    demos = fo.sample_demonstrations(grid3, rng.standard_normal((3, 9)), 200, 2, rng=rng, start=starts)
    np.testing.assert_array_equal(demos[0][:, 0, 0], 8)
    assert set(demos[1][:, 0, 0].tolist()) == {0, 1}
    np.testing.assert_array_equal(demos[2][:, 0, 0], 2)


def test_a_cdf_ending_below_one_never_picks_a_zero_probability_state(grid3, monkeypatch):
    p = np.zeros(9)
    p[[1, 3]] = [0.5, 0.5 - 1e-10]  # sums to 1 within the tolerance

    class Top:  # a generator whose uniform draws are at the very top of [0, 1)
        def __init__(self):
            self.rng = np.random.default_rng(0)

        def random(self, size):
            return np.full(size, 1.0 - 2.0**-53)

        def integers(self, *args, **kwargs):
            return self.rng.integers(*args, **kwargs)

    import factirl_opt.tasks.demonstrations as demonstrations

    monkeypatch.setattr(demonstrations, "as_rng", lambda rng: Top())
    demos = fo.sample_demonstrations(grid3, np.zeros((9, 4)), 3, 1, start=p)
    np.testing.assert_array_equal(demos[0][:, 0, 0], 3)


@pytest.mark.parametrize(
    "kwargs, fragment",
    [
        (dict(start=9), r"start must be an integer >= 0 and <= 8; got 9"),
        (dict(start=np.full((3, 9), 1 / 9)), r"one per task of shape \(n, S\) = \(2, 9\); got ndarray of shape \(3, 9\)"),
        (dict(start=np.eye(9)[0] * 0.5), r"start probabilities must sum to 1 .*start sums to 0.5"),
        (dict(return_final_states=1), r"return_final_states must be True or False; got 1"),
    ],
)
def test_bad_start_and_final_state_arguments(rng, grid3, kwargs, fragment):
    with pytest.raises(ValidationError, match=fragment):
        fo.sample_demonstrations(grid3, np.zeros((2, 9, 4)), 1, 1, rng=rng, **kwargs)


# --- the row-CDF cache -----------------------------------------------------------------------


def test_row_cdfs_cached_outside_the_mdp_and_freed_with_it(rng):
    import gc
    import weakref

    from factirl_opt.tasks.demonstrations import _ROW_CDFS, row_cdfs

    mdp = fo.GridWorld(size=3, gamma=0.9)
    fo.sample_demonstrations(mdp, rng.standard_normal((9, 4)), 2, 2, rng=rng)
    assert "_row_cdfs" not in vars(mdp)
    assert mdp in _ROW_CDFS and row_cdfs(mdp) is row_cdfs(mdp)
    cum, succ = row_cdfs(mdp)
    assert not cum.flags.writeable and not succ.flags.writeable
    alive = weakref.ref(mdp)
    del mdp
    gc.collect()
    assert alive() is None  # the cache does not keep its MDP alive
    assert all(key is not None for key in _ROW_CDFS.keys())


def test_sampling_from_threads_matches_sequential(rng):
    from concurrent.futures import ThreadPoolExecutor

    import scipy.sparse as sp

    dense = fo.GridWorld(size=5, gamma=0.9)
    sparse = fo.TabularMDP(sp.csr_matrix(dense.transitions.reshape(100, 25)), gamma=0.9)
    R = rng.standard_normal((3, 25, 4))
    expected = fo.sample_demonstrations(dense, R, 4, 6, rng=11)

    def run(k):
        mdp = (dense, sparse)[k % 2]
        return fo.sample_demonstrations(mdp, R, 4, 6, rng=11)

    with ThreadPoolExecutor(4) as pool:
        results = list(pool.map(run, range(16)))
    for got in results:
        for x, y in zip(got, expected):
            np.testing.assert_array_equal(x, y)


# -- tasks in many environments ----------------------------------------------------------------
def _envs(rng):
    other = fo.TabularMDP(rng.dirichlet(np.ones(7), size=(7, 4)), 0.85)
    g3, g4 = fo.GridWorld(3), fo.GridWorld(4)
    mdps = [g3, g4, g3, other]
    rewards = [rng.standard_normal((9, 4)), rng.standard_normal(16), rng.standard_normal((9, 4)), rng.standard_normal((7, 4))]
    return mdps, rewards


def test_per_task_mdps_sample_as_one_call_per_environment(rng):
    mdps, rewards = _envs(rng)
    demos, final = fo.sample_demonstrations(mdps, rewards, 3, 5, rng=7, return_final_states=True)
    assert isinstance(demos, list) and [d.shape for d in demos] == [(3, 5, 2)] * 4 and final.shape == (4, 3)
    # the same draws as one call per distinct MDP, in order of first appearance, from one generator
    gen = np.random.default_rng(7)
    groups = [(mdps[0], [0, 2]), (mdps[1], [1]), (mdps[3], [3])]
    for mdp, idx in groups:
        R = [np.repeat(rewards[i][:, None], 4, axis=1) if rewards[i].ndim == 1 else rewards[i] for i in idx]
        ref, ref_final = fo.sample_demonstrations(mdp, np.stack(R), 3, 5, rng=gen, return_final_states=True)
        for j, i in enumerate(idx):
            np.testing.assert_array_equal(demos[i], ref[j])
            np.testing.assert_array_equal(final[i], ref_final[j])
    # states stay in each task's own MDP, and the expert is greedy on its own Q*
    _, policies = fo.optimal_q(mdps, rewards)
    for d, mdp, pol in zip(demos, mdps, policies):
        assert d[..., 0].max() < mdp.n_states
        np.testing.assert_array_equal(d[..., 1], pol[d[..., 0]])
    plain = fo.sample_demonstrations(mdps, rewards, 3, 5, rng=7)
    for a, b in zip(plain, demos):
        np.testing.assert_array_equal(a, b)


def test_one_shared_mdp_object_samples_bit_identically(rng, grid4):
    R = rng.standard_normal((4, 16, 4))
    ref, ref_final = fo.sample_demonstrations(grid4, R, 3, 6, rng=11, return_final_states=True)
    got, final = fo.sample_demonstrations([grid4] * 4, list(R), 3, 6, rng=11, return_final_states=True)
    np.testing.assert_array_equal(final, ref_final)
    for a, b in zip(got, ref):
        np.testing.assert_array_equal(a, b)


def test_per_task_start_states(rng):
    mdps, rewards = _envs(rng)
    starts = [np.eye(m.n_states)[m.n_states - 1] for m in mdps]
    demos = fo.sample_demonstrations(mdps, rewards, 2, 3, rng=0, start=starts)
    assert [int(d[0, 0, 0]) for d in demos] == [8, 15, 8, 6]
    assert all(np.all(d[:, 0, 0] == 2) for d in fo.sample_demonstrations(mdps, rewards, 2, 3, rng=0, start=np.int64(2)))
    with pytest.raises(ValidationError, match=r"start describes 3 tasks but 4 MDPs"):
        fo.sample_demonstrations(mdps, rewards, 2, 3, rng=0, start=starts[:3])
    with pytest.raises(ValidationError, match=r"tasks \[0, 2\] \(one MDP, S = 9; .*\): start must be an integer >= 0 and <= 8"):
        fo.sample_demonstrations(mdps, rewards, 2, 3, rng=0, start=12)


def test_per_task_mdps_errors(rng):
    mdps, rewards = _envs(rng)
    with pytest.raises(ValidationError, match=r"rewards describes 3 tasks but 4 MDPs"):
        fo.sample_demonstrations(mdps, rewards[:3], 2, 3)
    with pytest.raises(ValidationError, match=r"rewards\[3\] \(task 3, S = 7\) must have shape \(S, A\) = \(7, 4\)"):
        fo.sample_demonstrations(mdps, [*rewards[:3], np.zeros((9, 4))], 2, 3)
    five = fo.TabularMDP(rng.dirichlet(np.ones(7), size=(7, 5)), 0.85)
    with pytest.raises(ValidationError, match=r"task 3 has 5, task 0 has 4"):
        fo.sample_demonstrations([*mdps[:3], five], [*rewards[:3], np.zeros((7, 5))], 2, 3)
    with pytest.raises(ValidationError, match=r"n_demos"):
        fo.sample_demonstrations(mdps, rewards, 0, 3)
    with pytest.raises(ValidationError, match=r"return_final_states must be True or False"):
        fo.sample_demonstrations(mdps, rewards, 2, 3, return_final_states=1)

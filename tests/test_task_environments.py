"""Tasks in many environments at the public functions: scores, planning, sampling, feature rewards."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError

SCORERS = {
    "score": lambda m, t, l: fo.score(m, t, l),
    "deviation": lambda m, t, l: fo.deviation(m, t, l),
    "optimal_score": lambda m, t, l: fo.optimal_score(m, t),
    "soft_deviation": lambda m, t, l: fo.soft_deviation(m, t, l, beta=2.0),
}


@pytest.fixture
def envs(rng):
    """Three environments with 4 actions: 9, 16 and 7 states (the last with random dynamics)."""
    other = fo.TabularMDP(rng.dirichlet(np.ones(7), size=(7, 4)), 0.85)
    return fo.GridWorld(3), fo.GridWorld(4), other


@pytest.fixture
def mixed(rng, envs):
    """Five tasks on the three environments, in interleaved order, with mixed reward layouts."""
    g3, g4, other = envs
    mdps = [g3, g4, g3, other, g4]
    true = [rng.standard_normal((9, 4)), rng.standard_normal(16), rng.standard_normal((9, 4)),
            rng.standard_normal((7, 4)), rng.standard_normal((16, 4))]
    learnt = [rng.standard_normal((m.n_states, 4)) for m in mdps]
    return mdps, true, learnt


def _full(mdp, r):
    r = np.asarray(r, dtype=float)
    return np.repeat(r[:, None], mdp.n_actions, axis=1) if r.ndim == 1 else r


@pytest.mark.parametrize("name", list(SCORERS))
def test_scores_equal_the_per_environment_calls(mixed, name):
    mdps, true, learnt = mixed
    f = SCORERS[name]
    got = f(mdps, true, learnt)
    assert isinstance(got, np.ndarray) and got.shape == (5,)
    # one call per distinct MDP on its tasks (what the grouping does): exactly equal
    for mdp in {id(m): m for m in mdps}.values():
        idx = [i for i, m in enumerate(mdps) if m is mdp]
        ref = f(mdp, np.stack([_full(mdp, true[i]) for i in idx]), np.stack([learnt[i] for i in idx]))
        np.testing.assert_array_equal(got[idx], ref)
    # one task at a time
    for i, mdp in enumerate(mdps):
        assert got[i] == pytest.approx(f(mdp, true[i], learnt[i]), rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("name", list(SCORERS))
def test_one_shared_mdp_object_is_bit_identical(rng, grid4, name):
    true, learnt = rng.standard_normal((6, 16, 4)), rng.standard_normal((6, 16, 4))
    f = SCORERS[name]
    ref = f(grid4, true, learnt)
    np.testing.assert_array_equal(f([grid4] * 6, true, learnt), ref)
    np.testing.assert_array_equal(f(tuple([grid4] * 6), list(true), list(learnt)), ref)


def test_state_rewards_per_task_are_repeated_over_actions(mixed):
    mdps, true, learnt = mixed
    full = [_full(m, r) for m, r in zip(mdps, true)]
    np.testing.assert_array_equal(fo.deviation(mdps, true, learnt), fo.deviation(mdps, full, learnt))


def test_equal_sizes_take_a_stacked_array(rng):
    a, b = fo.GridWorld(3), fo.GridWorld(3, p_success=0.9)
    true, learnt = rng.standard_normal((3, 9, 4)), rng.standard_normal((3, 9))
    got = fo.score([a, b, a], true, learnt)
    np.testing.assert_array_equal(got[[0, 2]], fo.score(a, true[[0, 2]], learnt[[0, 2]]))
    assert got[1] == fo.score(b, true[1:2], learnt[1:2])[0]


def test_rewards_must_fit_each_task(mixed, envs, rng):
    mdps, true, learnt = mixed
    with pytest.raises(ValidationError, match=r"true_rewards describes 4 tasks but 5 MDPs were given"):
        fo.score(mdps, true[:4], learnt)
    with pytest.raises(ValidationError, match=r"learnt_rewards\[1\] \(task 1, S = 16\) must have shape \(S, A\) = \(16, 4\)"):
        fo.deviation(mdps, true, [learnt[0], learnt[0], *learnt[2:]])
    with pytest.raises(ValidationError, match=r"true_rewards\[1\] \(task 1, S = 16\) must have shape"):
        fo.optimal_score(mdps, np.zeros((5, 9, 4)))  # a stacked array while the sizes differ
    with pytest.raises(ValidationError, match=r"learnt_rewards\[0\] \(task 0, S = 9\) must be one reward of shape \(S_i, A\)"):
        fo.score(mdps, true, [np.zeros((2, 9)), *learnt[1:]])
    with pytest.raises(ValidationError, match=r"learnt_rewards\[0\] \(task 0, S = 9\) must be one reward"):
        fo.score(mdps, true, [np.zeros((1, 9, 4)), *learnt[1:]])
    with pytest.raises(ValidationError, match=r"learnt_rewards must be a list of one array per task"):
        fo.score(mdps, true, 3.0)
    with pytest.raises(ValidationError, match=r"true_rewards must hold one entry per task \(5\); got a 0-d array"):
        fo.score(mdps, np.array(1.0), learnt)
    with pytest.raises(ValidationError, match=r"true_rewards\[2\] \(task 2, S = 9\) must be finite"):
        fo.soft_deviation(mdps, [*true[:2], np.full((9, 4), np.nan), *true[3:]], learnt)


def test_environments_are_checked(mixed, rng):
    mdps, true, learnt = mixed
    five = fo.TabularMDP(rng.dirichlet(np.ones(9), size=(9, 5)), 0.9)
    with pytest.raises(ValidationError, match=r"same number of actions: task 2 has 5, task 0 has 4"):
        fo.deviation([mdps[0], mdps[1], five, mdps[3], mdps[4]], true, learnt)
    with pytest.raises(ValidationError, match=r"mdps\[1\] \(task 1\) must be a TabularMDP; got str"):
        fo.score([mdps[0], "grid"], true[:2], learnt[:2])
    with pytest.raises(ValidationError, match=r"non-empty sequence of TabularMDP"):
        fo.optimal_score([], [])


def test_errors_of_one_group_name_its_tasks(mixed):
    mdps, true, learnt = mixed
    with pytest.raises(ValidationError, match=r"tasks \[0, 2\] \(one MDP, S = 9; .*\): start must be an integer >= 0 and <= 8; got 12"):
        fo.soft_deviation(mdps, true, learnt, start=12)
    with pytest.raises(ValidationError, match=r"beta"):
        fo.soft_deviation(mdps, true, learnt, beta=-1.0)


def test_soft_deviation_per_task_start(mixed):
    mdps, true, learnt = mixed
    starts = [np.eye(m.n_states)[1] for m in mdps]
    got = fo.soft_deviation(mdps, true, learnt, start=starts)
    np.testing.assert_allclose(got, fo.soft_deviation(mdps, true, learnt, start=1), rtol=0, atol=1e-12)
    for i, m in enumerate(mdps):
        assert got[i] == pytest.approx(fo.soft_deviation(m, true[i], learnt[i], start=starts[i]), abs=1e-12)
    with pytest.raises(ValidationError, match=r"start describes 2 tasks but 5 MDPs"):
        fo.soft_deviation(mdps, true, learnt, start=starts[:2])


# -- feature_rewards ---------------------------------------------------------------------------
def test_feature_rewards_shared_and_per_task(rng, envs):
    g3, g4, _ = envs
    Phi, W = rng.random((9, 3)), rng.standard_normal((2, 3))
    state = fo.feature_rewards(Phi, W)
    np.testing.assert_allclose(state, W @ Phi.T, rtol=0, atol=1e-14)
    full = fo.feature_rewards(Phi, W, g3)
    assert full.shape == (2, 9, 4)
    np.testing.assert_array_equal(full, np.repeat(state[:, :, None], 4, axis=2))
    # state-action features (S*A, p), per task, mixed sizes: a list
    Fs = [rng.random((9 * 4, 3)), rng.random((16, 3))]
    out = fo.feature_rewards(Fs, W, [g3, g4])
    assert isinstance(out, list) and [r.shape for r in out] == [(9, 4), (16, 4)]
    np.testing.assert_allclose(out[0], (Fs[0] @ W[0]).reshape(9, 4), rtol=0, atol=1e-14)
    np.testing.assert_allclose(out[1], np.repeat((Fs[1] @ W[1])[:, None], 4, axis=1), rtol=0, atol=1e-14)
    ragged = fo.feature_rewards([Phi, rng.random((16, 3))], W)
    assert isinstance(ragged, list) and [r.shape for r in ragged] == [(9,), (16,)]


def test_feature_rewards_score_a_reward_on_new_environments(rng):
    maps = fo.objectworld.objectworld_maps(3, size=6, rng=0)
    new = fo.objectworld.fresh_maps(maps, rng=1)
    W = rng.standard_normal((3, new.features[0].shape[1]))
    true = fo.feature_rewards(new.features, W, new.mdps)
    assert np.all(fo.deviation(new.mdps, true, fo.feature_rewards(new.features, W)) == 0.0)
    assert np.all(fo.deviation(new.mdps, true, fo.feature_rewards(new.features, -W, new.mdps)) > 0)


def test_feature_rewards_errors(rng, envs):
    g3, g4, _ = envs
    Phi = rng.random((9, 3))
    with pytest.raises(ValidationError, match=r"weights must be a 2-d array; got shape \(3,\)"):
        fo.feature_rewards(Phi, np.ones(3))
    with pytest.raises(ValidationError, match=r"weights must have shape \(2, 3, ...\); got \(2, 4\)"):
        fo.feature_rewards(Phi, np.ones((2, 4)))
    with pytest.raises(ValidationError, match=r"got 3 feature matrices for 2 tasks"):
        fo.feature_rewards([Phi, Phi, Phi], np.ones((2, 3)))
    with pytest.raises(ValidationError, match=r"features of task 1 must have S = 16 or S\*A = 64 rows \(its MDP\); got \(9, 3\)"):
        fo.feature_rewards([Phi, Phi], np.ones((2, 3)), [g3, g4])
    with pytest.raises(ValidationError, match=r"same number of columns p: task 1 has 2, task 0 has 3"):
        fo.feature_rewards([Phi, Phi[:, :2]], np.ones((2, 3)))
    with pytest.raises(ValidationError, match=r"got 1 MDPs for 2 tasks"):
        fo.feature_rewards(Phi, np.ones((2, 3)), [g3])
    with pytest.raises(ValidationError, match=r"features must be one \(S, p\) or \(S\*A, p\) matrix"):
        fo.feature_rewards(None, np.ones((2, 3)))
    with pytest.raises(ValidationError, match=r"features must be a 2-d array"):
        fo.feature_rewards(np.ones(4), np.ones((2, 3)))

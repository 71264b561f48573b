"""Demonstrations as lists of episodes of different lengths, through statistics and learners."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError

N_TASKS, K = 4, 2


@pytest.fixture(scope="module")
def setting():
    mdp = fo.GridWorld(size=4)
    rng = np.random.default_rng(7)
    D = fo.random_dictionary(mdp.n_params, K, rng=rng)
    H = fo.random_coefficients(N_TASKS, K, rng=rng)
    rewards = fo.task_rewards(D, H, mdp.n_states, mdp.n_actions)
    demos = fo.sample_demonstrations(mdp, rewards, n_demos=3, length=8, rng=rng)
    return mdp, rewards, demos


def _ragged(demos, rng):
    """Each task's (m, L, 2) steps cut into episodes of random, different lengths."""
    out = []
    for task in demos:
        steps = task.reshape(-1, 2)
        cuts = np.sort(rng.choice(np.arange(1, len(steps)), size=3, replace=False))
        out.append(np.split(steps, cuts))
    return out


def _fact(**kw):
    return fo.FactIRL(n_primitives=K, max_iter=4, inner_steps=3, flat_max_iter=10, transfer_max_iter=10, rng=0, **kw)


def test_statistics_of_ragged_episodes_by_hand():
    mdp = fo.GridWorld(size=3)
    task = [np.array([[0, 1], [3, 1], [6, 3]]), [[0, 2]], ((0, 1), (7, 0))]  # lengths 3, 1, 2; array, lists, tuples
    mu, pi = fo.empirical_statistics(mdp, [task])
    expected_mu = np.zeros(9)
    expected_mu[[0, 3, 6, 7]] = [3, 1, 1, 1]
    np.testing.assert_array_equal(mu[0], expected_mu / 6)
    np.testing.assert_allclose(pi[0, 0], [0, 2 / 3, 1 / 3, 0])
    np.testing.assert_array_equal(pi[0, 6], [0, 0, 0, 1])
    np.testing.assert_array_equal(pi[0, 1], 0)  # unvisited


def test_equal_length_lists_match_arrays_bit_for_bit(setting):
    mdp, _, demos = setting
    as_lists = [[ep.tolist() for ep in task] for task in demos]  # plain Python lists of episodes
    flat_a = fo.GradIRL(max_iter=15).fit(mdp, demos)
    flat_l = fo.GradIRL(max_iter=15).fit(mdp, as_lists)
    np.testing.assert_array_equal(flat_a.weights_, flat_l.weights_)
    np.testing.assert_array_equal(flat_a.loss_, flat_l.loss_)
    fact_a = _fact().fit(mdp, demos)
    fact_l = _fact().fit(mdp, as_lists)
    np.testing.assert_array_equal(fact_a.dictionary_, fact_l.dictionary_)
    np.testing.assert_array_equal(fact_a.coefficients_, fact_l.coefficients_)
    np.testing.assert_array_equal(fact_a.transfer(mdp, demos[:2]), fact_a.transfer(mdp, as_lists[:2]))


def test_ragged_fit_and_transfer_equal_concatenated_steps(setting):
    """Only the steps matter (eq. 5): ragged episodes fit exactly like the same steps as one episode."""
    mdp, rewards, demos = setting
    ragged = _ragged(demos, np.random.default_rng(3))
    assert any(len({len(ep) for ep in task}) > 1 for task in ragged)
    concatenated = [task.reshape(1, -1, 2) for task in demos]

    flat_r = fo.GradIRL(max_iter=15).fit(mdp, ragged)
    flat_c = fo.GradIRL(max_iter=15).fit(mdp, concatenated)
    np.testing.assert_array_equal(flat_r.rewards_, flat_c.rewards_)
    assert flat_r.loss_history_[-1] < flat_r.loss_history_[0]

    fact_r = _fact().fit(mdp, ragged)
    fact_c = _fact().fit(mdp, concatenated)
    np.testing.assert_array_equal(fact_r.rewards_, fact_c.rewards_)
    assert fo.deviation(mdp, rewards, fact_r.rewards_).shape == (N_TASKS,)

    h_r = fact_r.transfer(mdp, ragged[:2])
    h_c = fact_r.transfer(mdp, concatenated[:2])
    assert h_r.shape == (2, K)
    np.testing.assert_array_equal(h_r, h_c)
    assert fact_r.transfer_loss_history_[-1] < fact_r.transfer_loss_history_[0]


def test_tasks_may_mix_forms(setting):
    mdp, _, demos = setting
    mixed = [demos[0], list(demos[1]), [demos[2][0]], [ep[:5] for ep in demos[3]] + [demos[3][0][5:]]]
    same = [demos[0], demos[1], demos[2][:1], demos[3]]
    mu_m, pi_m = fo.empirical_statistics(mdp, mixed)
    mu_s, pi_s = fo.empirical_statistics(mdp, same)
    np.testing.assert_array_equal(mu_m[:3], mu_s[:3])
    np.testing.assert_array_equal(pi_m[:3], pi_s[:3])
    # task 3 drops three steps of its later episodes; counts differ, shapes agree
    assert mu_m.shape == (4, 16) and not np.array_equal(mu_m[3], mu_s[3])
    model = fo.GradIRL(max_iter=5).fit(mdp, mixed)
    assert model.rewards_.shape == (4, 16, 4)


def test_integral_floats_are_accepted():
    mdp = fo.GridWorld(size=3)
    ints = [[np.array([[0, 1], [3, 2]]), np.array([[4, 0]])]]
    floats = [[np.array([[0.0, 1.0], [3.0, 2.0]]), [[4.0, 0.0]]]]
    for a, b in zip(fo.empirical_statistics(mdp, ints), fo.empirical_statistics(mdp, floats)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    "demos, match",
    [
        ([], "demos_per_task is empty"),
        ({0: [[0, 1]]}, "demos_per_task must be a list"),
        ([[]], "demonstrations of task 0 are empty"),
        ([None], "demonstrations of task 0 must be an int array"),
        ([np.zeros((2, 3, 2, 1), dtype=int)], "demonstrations of task 0 must be an int array"),
        ([[np.zeros((3, 2), int)], [np.zeros((3, 3), int)]], r"task 1, episode 0 must have shape \(L, 2\).*\(3, 3\)"),
        ([[np.zeros((2, 2), int), np.zeros((0, 2), int)]], r"task 0, episode 1 must have shape .*got \(0, 2\)"),
        ([[[0, 1]]], r"demos_per_task\[0\] is a single episode \(a list of \(state, action\) pairs\)"),
        ([[[[0, 1], [2]]]], r"task 0, episode 0 must be an array of \(state, action\) pairs"),
        ([[np.array([[0.5, 1.0]])]], r"task 0, episode 0, step 0: state 0.5 is not an integer"),
        ([[np.array([[0, 1], [np.nan, 1.0]])]], r"task 0, episode 0, step 1: state nan is not an integer"),
        ([[np.array([[True, False]])]], r"state True is not an integer \(the pairs have dtype bool\)"),
        ([[np.array([[0, 1]]), np.array([[16, 0]])]], r"task 0, episode 1, step 0: state 16 is out of range \[0, 16\)"),
        ([[np.array([[0, 4]])]], r"action 4 is out of range \[0, 4\)"),
        ([[np.array([[-1, 0]])]], r"state -1 is out of range"),
    ],
)
def test_bad_episodes_give_clear_errors(demos, match):
    mdp = fo.GridWorld(size=4)
    with pytest.raises(ValidationError, match=match):
        fo.empirical_statistics(mdp, demos)
    with pytest.raises(ValidationError, match=match):
        fo.GradIRL(max_iter=1).fit(mdp, demos)


def test_bad_episodes_in_transfer(setting):
    mdp, _, demos = setting
    model = _fact().fit(mdp, demos)
    with pytest.raises(ValidationError, match=r"demonstrations of task 0, episode 1"):
        model.transfer(mdp, [[demos[0][0], demos[0][1][:, :1]]])

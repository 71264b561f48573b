"""Boundary checks: the reward layouts of check_rewards and the start states of check_start."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt._validation import check_rewards, check_start
from factirl_opt.exceptions import ValidationError


def _square_mdp(rng, S=3):
    """An MDP with as many actions as states (A == S): the case where (S, A) and (n, S) coincide."""
    P = rng.random((S, S, S)) + 0.1
    return fo.TabularMDP(P / P.sum(axis=2, keepdims=True), gamma=0.9)


# --- check_rewards: the four layouts ---------------------------------------------------------


def test_state_rewards_are_repeated_over_actions(rng, grid3):
    r = rng.standard_normal((2, 9))
    R, single = check_rewards(grid3, r)
    assert R.shape == (2, 9, 4) and not single
    np.testing.assert_array_equal(R, np.repeat(r[:, :, None], 4, axis=2))
    R1, single1 = check_rewards(grid3, r[0])
    assert single1 and R1.shape == (1, 9, 4)
    np.testing.assert_array_equal(R1[0], np.repeat(r[0][:, None], 4, axis=1))
    R1[0, 0, 0] = 99.0  # a new array: the caller's rewards are not touched
    assert r[0, 0] != 99.0


def test_state_action_layouts_unchanged(rng, grid3):
    R3 = rng.standard_normal((2, 9, 4))
    out, single = check_rewards(grid3, R3)
    assert not single
    np.testing.assert_array_equal(out, R3)
    out, single = check_rewards(grid3, R3[0])
    assert single and out.shape == (1, 9, 4)


def test_square_mdp_reads_an_s_by_s_array_as_one_state_action_reward(rng):
    """With A == S, (S, S) is one (S, A) reward (never S state rewards); other 2-d shapes are state rewards."""
    mdp = _square_mdp(rng)
    square = rng.standard_normal((3, 3))
    R, single = check_rewards(mdp, square)
    assert single
    np.testing.assert_array_equal(R[0], square)
    # n != S state rewards over S == A actions: unambiguous
    r = rng.standard_normal((2, 3))
    R, single = check_rewards(mdp, r)
    assert not single
    np.testing.assert_array_equal(R, np.repeat(r[:, :, None], 3, axis=2))
    # n == S state rewards are passed explicitly repeated, as documented
    R, single = check_rewards(mdp, fo.objectworld.state_action_rewards(square, 3))
    assert not single and R.shape == (3, 3, 3)
    np.testing.assert_array_equal(R[:, :, 1], square)


def test_many_tasks_of_state_rewards_when_n_equals_s(rng, grid3):
    """n == S is unambiguous while A != S: (9, 9) on a 9-state, 4-action grid is 9 state rewards."""
    r = rng.standard_normal((9, 9))
    R, single = check_rewards(grid3, r)
    assert R.shape == (9, 9, 4) and not single


@pytest.mark.parametrize("shape", [(8,), (10,), (2, 8), (9, 3), (9, 5), (2, 9, 3), (1, 2, 9, 4), ()])
def test_bad_reward_shapes_name_all_layouts(grid3, shape):
    with pytest.raises(ValidationError) as info:
        check_rewards(grid3, np.zeros(shape), "true_rewards")
    msg = str(info.value)
    assert msg.startswith("true_rewards must have shape (S, A) = (9, 4) or (n, 9, 4); got " + str(shape))
    assert "state rewards of shape (S,) = (9,) or (n, S) = (n, 9) are accepted too" in msg


def test_state_rewards_checked_for_overflow_and_finiteness(grid3):
    with pytest.raises(ValidationError, match=r"rewards reach 1e\+300"):
        check_rewards(grid3, np.full(9, 1e300))
    r = np.zeros(9)
    r[4] = np.nan
    with pytest.raises(ValidationError, match=r"rewards must be finite; found nan at index \(4,\)"):
        check_rewards(grid3, r)


# --- every public function that takes rewards ------------------------------------------------


def _same(a, b):
    if isinstance(a, tuple):
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)
    elif isinstance(a, list):
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)
    else:
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    "call",
    [
        lambda m, R: fo.optimal_q(m, R),
        lambda m, R: fo.value_iteration(m, R, tol=1e-10),
        lambda m, R: fo.policy_evaluation(m, R, np.zeros(m.n_states, dtype=int) if R.ndim < 2 or R.shape == (m.n_states, m.n_actions) else np.zeros((len(R), m.n_states), dtype=int)),
        lambda m, R: fo.optimal_score(m, R),
        lambda m, R: fo.score(m, R, R),
        lambda m, R: fo.deviation(m, R, -R),
        lambda m, R: fo.sample_demonstrations(m, R, 3, 4, rng=5),
    ],
    ids=["optimal_q", "value_iteration", "policy_evaluation", "optimal_score", "score", "deviation", "sample_demonstrations"],
)
def test_public_functions_take_state_rewards(rng, grid3, call):
    r = rng.standard_normal((2, 9))
    _same(call(grid3, r), call(grid3, np.repeat(r[:, :, None], 4, axis=2)))
    _same(call(grid3, r[1]), call(grid3, np.repeat(r[1][:, None], 4, axis=1)))


def test_multitask_rewards_go_straight_into_deviation_and_sampling():
    world = fo.objectworld.make_objectworld(size=5, rng=0)
    mdp = world.mdp()
    r, _, _ = fo.objectworld.multitask_rewards(world, 3, rng=1)  # (n, S) state rewards
    R = fo.objectworld.state_action_rewards(r)
    np.testing.assert_array_equal(fo.deviation(mdp, r, r), 0.0)
    np.testing.assert_allclose(fo.deviation(mdp, r, R[::-1]), fo.deviation(mdp, R, R[::-1]), rtol=0, atol=0)
    _same(fo.sample_demonstrations(mdp, r, 2, 3, rng=0), fo.sample_demonstrations(mdp, R, 2, 3, rng=0))


def test_mixed_layouts_in_score_must_count_the_same_tasks(rng, grid3):
    with pytest.raises(ValidationError, match=r"same number of tasks; got 2 true \(shape \(2, 9\)\) and 1 learnt \(shape \(9, 4\)\)"):
        fo.score(grid3, np.zeros((2, 9)), np.zeros((9, 4)))
    assert isinstance(fo.score(grid3, np.zeros(9), np.zeros((9, 4))), float)


# --- check_start -----------------------------------------------------------------------------


def test_check_start_forms():
    assert check_start(None, 2, 4) is None
    assert check_start(3, 2, 4) == 3 and isinstance(check_start(np.int64(3), 2, 4), int)
    p = check_start([0.5, 0.5, 0, 0], 2, 4)
    assert p.shape == (2, 4) and p.dtype == np.float64
    np.testing.assert_array_equal(p[1], [0.5, 0.5, 0, 0])
    rows = np.array([[1.0, 0, 0, 0], [0, 0, 0, 1.0]])
    np.testing.assert_array_equal(check_start(rows, 2, 4), rows)


@pytest.mark.parametrize(
    "start, fragment",
    [
        (4, r"start must be an integer >= 0 and <= 3; got 4"),
        (-1, r"start must be an integer >= 0 and <= 3; got -1"),
        (True, r"start must be an integer >= 0 and <= 3; got True"),
        (1.0, r"start must be None, a state index in \[0, 4\).*got float of shape \(\)"),
        ([0.5, 0.5], r"distribution over the states of shape \(S,\) = \(4,\) or one per task of shape \(n, S\) = \(2, 4\); got list of shape \(2,\)"),
        (np.full((3, 4), 0.25), r"got ndarray of shape \(3, 4\)"),
        ([0.5, 0.6, -0.1, 0.0], r"start must hold nonnegative probabilities; start has -0.1 at state 2"),
        ([[1, 0, 0, 0], [0, 0.5, 0.4, 0]], r"start probabilities must sum to 1 \(within 1e-09\); start\[1\] sums to 0.9"),
        ([0.25, 0.25, 0.25, np.nan], r"start must be finite; found nan at index \(3,\)"),
        ("uniform", r"start must be a real numeric array"),
    ],
)
def test_check_start_errors(start, fragment):
    with pytest.raises(ValidationError, match=fragment):
        check_start(start, 2, 4)


# --- policies and statistics name the bad entry -----------------------------------------------


def test_policy_messages_name_the_entry(grid3):
    from factirl_opt._validation import check_policy, check_statistics, check_stochastic_policy

    pol = np.zeros((2, 9), dtype=int)
    pol[1, 5] = 7
    with pytest.raises(ValidationError, match=r"policy must hold integer actions in \[0, 4\); got 7 for task 1, state 5"):
        check_policy(grid3, pol, 2)
    with pytest.raises(ValidationError, match=r"integer actions in \[0, 4\); got an array of dtype float64"):
        check_policy(grid3, np.zeros(9), 1)
    pi = np.full((2, 9, 4), 0.25)
    pi[1, 3] = [0.5, 0.5, 0.5, -0.5]
    with pytest.raises(ValidationError, match=r"must be nonnegative; pi\(a=3\|s=3\) of task 1 is -0\.5"):
        check_stochastic_policy(grid3, pi, 2)
    pi[1, 3] = [0.5, 0.5, 0.5, 0.0]
    with pytest.raises(ValidationError, match=r"must sum to 1; task 1, state 3 sums to 1\.5"):
        check_stochastic_policy(grid3, pi, 2)
    mu = np.full((1, 9), 1 / 9)
    pi_hat = np.full((1, 9, 4), 0.25)
    mu[0, 2], mu[0, 3] = -1 / 9, 3 / 9
    with pytest.raises(ValidationError, match=r"mu_hat must be nonnegative; found -0\.11\d* at index \(0, 2\) \(task 0\)"):
        check_statistics(grid3, mu, pi_hat)
    pi_hat[0, 4] = [1.25, -0.25, 0, 0]
    with pytest.raises(ValidationError, match=r"pi_hat must be nonnegative; found -0\.25 at index \(0, 4, 1\)"):
        check_statistics(grid3, np.full((1, 9), 1 / 9), pi_hat)


@pytest.mark.parametrize("params, error, message", [
    (lambda: dict(transfer_max_iter=-1), ValidationError, r"^transfer_max_iter must be an integer >= 0; got -1"),
    (lambda: dict(transfer_max_iter="5"), ValidationError, r"^transfer_max_iter must be an integer >= 0; got '5'"),
    (lambda: dict(start=fo.Start(init="random", flat_max_iter=-1)), ValidationError,
     r"^start__flat_max_iter must be an integer >= 0; got -1"),
    (lambda: dict(solver="nope"), fo.exceptions.UnknownSolverError, r"unknown solver 'nope'"),
    (lambda: dict(solver=fo.SolverSettings(flat_solver="nope"), start=fo.Start(init="random")),
     fo.exceptions.UnknownSolverError, r"^unknown solver 'nope' for SolverSettings.flat_solver; available"),
    (lambda: dict(solver=fo.SolverSettings(flat_solver=3)), ValidationError,
     r"^flat_solver must be a registered solver name or a solvers.StepSolver; got 3"),
    (lambda: dict(solver=fo.SolverSettings(d_solver="nope")), fo.exceptions.UnknownSolverError,
     r"^unknown solver 'nope' for SolverSettings.d_solver; available: .*armijo"),
    (lambda: dict(solver=fo.SolverSettings(d_solver="armijo", d_solver_options=[1])), ValidationError,
     r"^d_solver_options must be a dict"),
])
def test_fit_checks_every_parameter_naming_it(params, error, message):
    """Parameters that only one path reads are checked by ``fit`` whatever its path (or when their
    group is made), naming the parameter (a bad transfer_max_iter was accepted, and refused later by
    transfer naming max_iter; a bad flat_solver or d_solver was refused as "solver must be a
    registered name", or not at all)."""
    mdp = fo.GridWorld(size=3)
    rng = np.random.default_rng(0)
    demos = fo.sample_demonstrations(mdp, rng.normal(size=(4, 9, 4)), 3, 5, rng=rng)
    with pytest.raises(error, match=message):
        fo.FactIRL(2, max_iter=1, **params()).fit(mdp, demos)

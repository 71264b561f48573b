"""Exact planning: Q* by policy iteration vs value iteration, policy evaluation, Boltzmann."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt import planning
from factirl_opt.exceptions import FactIRLError, ValidationError

PLANNERS = fo.available_planners()
BETA = 5.0
EPS = 1e-6


@pytest.fixture(params=["grid", "random"])
def mdp(request, grid4, random_mdp):
    return grid4 if request.param == "grid" else random_mdp


def test_optimal_q_single_matches_value_iteration(rng, mdp):
    R = rng.standard_normal((mdp.n_states, mdp.n_actions))
    Q, pol = fo.optimal_q(mdp, R)
    Q_vi = fo.value_iteration(mdp, R, tol=1e-13)
    assert Q.shape == R.shape and pol.shape == (mdp.n_states,)
    assert np.max(np.abs(Q - Q_vi)) < 1e-9
    np.testing.assert_array_equal(pol, np.argmax(Q, axis=1))
    # Bellman optimality: Q = R + gamma P max_a Q
    np.testing.assert_allclose(Q, R + mdp.gamma * mdp.transitions @ Q.max(axis=1), atol=1e-12)


def test_optimal_q_batched_matches_value_iteration_and_single(rng, mdp):
    R = rng.standard_normal((5, mdp.n_states, mdp.n_actions))
    Q, pol = fo.optimal_q(mdp, R)
    assert Q.shape == R.shape and pol.shape == (5, mdp.n_states) and pol.dtype == np.intp
    assert np.max(np.abs(Q - fo.value_iteration(mdp, R, tol=1e-13))) < 1e-9
    for i in range(5):
        Qi, _ = fo.optimal_q(mdp, R[i])
        np.testing.assert_allclose(Qi, Q[i], atol=1e-12)


@pytest.mark.parametrize("start", ["right", "wrong", "random"])
def test_warm_start_is_exact_from_any_policy(rng, mdp, start):
    R = rng.standard_normal((3, mdp.n_states, mdp.n_actions))
    Q_ref, pol_ref = fo.optimal_q(mdp, R)
    warm = {
        "right": pol_ref,
        "wrong": np.argmin(Q_ref, axis=2),
        "random": rng.integers(0, mdp.n_actions, size=(3, mdp.n_states)),
    }[start]
    Q, pol = fo.optimal_q(mdp, R, policy=warm)
    assert np.max(np.abs(Q - Q_ref)) < 1e-10
    np.testing.assert_array_equal(np.take_along_axis(Q, pol[..., None], 2)[..., 0], Q.max(axis=2))
    # single reward with a single (S,) warm start
    Q1, _ = fo.optimal_q(mdp, R[0], policy=warm[0])
    assert np.max(np.abs(Q1 - Q_ref[0])) < 1e-10


def test_optimal_q_ties_do_not_cycle(grid4):
    R = np.zeros((grid4.n_states, grid4.n_actions))  # every policy is optimal
    Q, pol = fo.optimal_q(grid4, R, policy=np.full(grid4.n_states, 2))
    np.testing.assert_array_equal(Q, 0.0)
    np.testing.assert_array_equal(pol, 2)  # ties keep the current action


def test_policy_evaluation_matches_direct_solve(rng, mdp):
    S = mdp.n_states
    R = rng.standard_normal((2, S, mdp.n_actions))
    policy = rng.integers(0, mdp.n_actions, size=(2, S))
    V = fo.policy_evaluation(mdp, R, policy)
    for i in range(2):
        P_pi = np.array([mdp.transitions[s, policy[i, s]] for s in range(S)])
        R_pi = np.array([R[i, s, policy[i, s]] for s in range(S)])
        np.testing.assert_allclose(V[i], np.linalg.solve(np.eye(S) - mdp.gamma * P_pi, R_pi), rtol=1e-12, atol=1e-12)
    V0 = fo.policy_evaluation(mdp, R[0], policy[0])
    assert V0.shape == (S,)
    np.testing.assert_allclose(V0, V[0], atol=1e-13)


def test_policy_evaluation_of_greedy_policy_is_v_star(rng, mdp):
    R = rng.standard_normal((mdp.n_states, mdp.n_actions))
    Q, pol = fo.optimal_q(mdp, R)
    np.testing.assert_allclose(fo.policy_evaluation(mdp, R, pol), Q.max(axis=1), atol=1e-12)


def test_boltzmann_matches_softmax_and_sums_to_one(rng):
    Q = rng.standard_normal((3, 5, 4))
    pi = fo.boltzmann_policy(Q, 2.5)
    e = np.exp(2.5 * Q)
    np.testing.assert_allclose(pi, e / e.sum(axis=-1, keepdims=True), rtol=1e-13)
    np.testing.assert_allclose(pi.sum(axis=-1), 1.0, atol=1e-15)


def test_boltzmann_is_stable_for_huge_beta_q():
    """beta * Q up to 1e16: a naive exp overflows beyond ~709."""
    Q = np.array([[1e10, -1e10, 0.5e10, 0.0], [1e5, 1e5, -1e5, 1e5 - 1e-3]])
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        pi = fo.boltzmann_policy(Q, 1e6)
    assert np.all(np.isfinite(pi))
    np.testing.assert_allclose(pi.sum(axis=-1), 1.0)
    np.testing.assert_allclose(pi[0], [1, 0, 0, 0])
    np.testing.assert_allclose(pi[1], [0.5, 0.5, 0, 0])  # exact ties share the mass


@pytest.mark.parametrize("beta", [0.0, -1.0, np.nan, np.inf])
def test_boltzmann_bad_beta(beta):
    with pytest.raises(ValidationError, match=r"beta must be a finite number > 0; got " + repr(float(beta))):
        fo.boltzmann_policy(np.zeros((2, 2)), beta)


def test_boltzmann_needs_an_action_axis():
    with pytest.raises(ValidationError, match=r"action axis; got shape \(\)"):
        fo.boltzmann_policy(3.0, 1.0)


# --- validation -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "shape, fragment",
    [((16, 3), r"got \(16, 3\)"), ((15,), r"got \(15,\)"), ((2, 15, 4), r"got \(2, 15, 4\)"), ((1, 2, 16, 4), r"got \(1, 2, 16, 4\)")],
)
def test_bad_reward_shapes(grid4, shape, fragment):
    with pytest.raises(ValidationError, match=r"rewards must have shape \(S, A\) = \(16, 4\) or \(n, 16, 4\); " + fragment):
        fo.optimal_q(grid4, np.zeros(shape))


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nonfinite_rewards(grid4, bad):
    R = np.zeros((16, 4))
    R[3, 1] = bad
    with pytest.raises(ValidationError, match=rf"rewards must be finite; found {bad!r}"):
        fo.optimal_q(grid4, R)


def test_non_numeric_rewards(grid4):
    with pytest.raises(ValidationError, match="rewards must be a real numeric array"):
        fo.optimal_q(grid4, [["a"] * 4] * 16)


@pytest.mark.parametrize(
    "policy, fragment",
    [
        (np.zeros(15, dtype=int), r"policy must have shape \(1, 16\).*got \(15,\)"),
        (np.zeros((2, 16), dtype=int), r"policy must have shape \(1, 16\).*got \(2, 16\)"),
        (np.full(16, 4), r"integer actions in \[0, 4\); got"),
        (np.full(16, -1), r"integer actions in \[0, 4\); got"),
        (np.zeros(16), r"integer actions in \[0, 4\); got"),
    ],
)
def test_bad_policies(grid4, policy, fragment):
    with pytest.raises(ValidationError, match=fragment):
        fo.optimal_q(grid4, np.zeros((16, 4)), policy=policy)
    with pytest.raises(ValidationError, match=fragment):
        fo.policy_evaluation(grid4, np.zeros((16, 4)), policy)


def test_policy_evaluation_needs_a_policy(grid4):
    with pytest.raises(ValidationError, match="policy must be given"):
        fo.policy_evaluation(grid4, np.zeros((16, 4)), None)


def test_not_an_mdp():
    with pytest.raises(ValidationError, match="mdp must be a TabularMDP; got ndarray"):
        fo.optimal_q(np.zeros((2, 2, 2)), np.zeros((2, 2)))


# --- every planner against the dense route (models of tests/planning/conftest.py) ----------------


@pytest.mark.parametrize("name", PLANNERS)
def test_q_star_matches_dense_route_and_value_iteration(twins, name, assert_rel):
    sparse_mdp, dense_mdp = twins
    R = np.random.default_rng(1).standard_normal((4, sparse_mdp.n_states, sparse_mdp.n_actions))
    Q_ref, pol_ref = fo.optimal_q(dense_mdp, R, planner="dense")
    Q, pol = fo.optimal_q(sparse_mdp, R, planner=name)
    assert_rel(Q, Q_ref)
    np.testing.assert_array_equal(pol, pol_ref)
    assert_rel(Q, fo.value_iteration(sparse_mdp, R, tol=1e-13, planner=name))
    # warm start from a wrong policy, single task
    Q1, _ = fo.optimal_q(sparse_mdp, R[0], policy=np.argmin(Q_ref[0], axis=1), planner=name)
    assert_rel(Q1, Q_ref[0])


@pytest.mark.parametrize("name", PLANNERS)
def test_policy_values_deterministic_and_stochastic(twins, name, assert_rel):
    sparse_mdp, dense_mdp = twins
    rng = np.random.default_rng(2)
    S, A = sparse_mdp.n_states, sparse_mdp.n_actions
    R = rng.standard_normal((3, S, A))
    det = rng.integers(0, A, size=(3, S))
    stoch = rng.dirichlet(np.ones(A), size=(3, S))
    for policy in (det, stoch):
        V_ref = fo.policy_evaluation(dense_mdp, R, policy, planner="dense")
        assert_rel(fo.policy_evaluation(sparse_mdp, R, policy, planner=name), V_ref)
        # the Bellman equation itself: V = R_pi + gamma P_pi V
        w = stoch if policy is stoch else np.eye(A)[det]
        P3 = dense_mdp.transitions
        np.testing.assert_allclose(V_ref, np.einsum("nsa,nsa->ns", w, R) + dense_mdp.gamma * np.einsum("nsa,sat,nt->ns", w, P3, V_ref),
                                   rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", PLANNERS)
def test_loss_and_gradient_match_dense_route(twins, name, make_statistics, assert_rel):
    sparse_mdp, dense_mdp = twins
    rng = np.random.default_rng(3)
    mu, pi_hat = make_statistics(rng, sparse_mdp, 4)
    R = rng.standard_normal((4, sparse_mdp.n_states, sparse_mdp.n_actions))
    L_ref, G_ref = fo.policy_matching_loss(dense_mdp, R, mu, pi_hat, BETA, planner="dense")
    L, G = fo.policy_matching_loss(sparse_mdp, R, mu, pi_hat, BETA, planner=name)
    assert_rel(L, L_ref)
    assert_rel(G, G_ref)
    # warm at nearby rewards (the sparse planner's cache and low-rank updates), then back
    _, pol = fo.optimal_q(sparse_mdp, R, planner=name)
    for R2 in (R + 1e-2 * rng.standard_normal(R.shape), R):
        L_ref, G_ref = fo.policy_matching_loss(dense_mdp, R2, mu, pi_hat, BETA, planner="dense")
        L, G = fo.policy_matching_loss(sparse_mdp, R2, mu, pi_hat, BETA, policy=pol, planner=name)
        assert_rel(L, L_ref)
        assert_rel(G, G_ref)


def test_grid_loss_gradient_and_score_match_dense_route(make_statistics, assert_rel):
    grid = fo.GridWorld(8)
    dense = fo.TabularMDP(grid.transitions, grid.gamma)
    rng = np.random.default_rng(4)
    mu, pi_hat = make_statistics(rng, grid, 3)
    R = rng.standard_normal((3, grid.n_states, 4))
    L_ref, G_ref = fo.policy_matching_loss(dense, R, mu, pi_hat, BETA, planner="dense")
    R_hat = R + 0.3 * rng.standard_normal(R.shape)
    dev_ref = fo.deviation(dense, R, R_hat, planner="dense")
    for name in PLANNERS:
        L, G = fo.policy_matching_loss(grid, R, mu, pi_hat, BETA, planner=name)
        assert_rel(L, L_ref)
        assert_rel(G, G_ref)
        assert_rel(fo.deviation(grid, R, R_hat, planner=name), dev_ref)


@pytest.mark.parametrize("name", ["sparse-lu", "dense"])
def test_gradient_matches_finite_differences_on_sparse_model(twins, name, make_statistics, tie_free_rewards):
    sparse_mdp, _ = twins
    rng = np.random.default_rng(5)
    mu, pi_hat = make_statistics(rng, sparse_mdp, 1)
    R = tie_free_rewards(rng, sparse_mdp, (sparse_mdp.n_states, sparse_mdp.n_actions))
    _, G = fo.policy_matching_loss(sparse_mdp, R, mu[0], pi_hat[0], BETA, planner=name)
    coords = [tuple(c) for c in rng.integers(0, R.shape, size=(12, 2))]
    for idx in coords:
        Rp, Rm = R.copy(), R.copy()
        Rp[idx] += EPS
        Rm[idx] -= EPS
        fd = (fo.policy_matching_loss(sparse_mdp, Rp, mu[0], pi_hat[0], BETA, planner=name)[0][0]
              - fo.policy_matching_loss(sparse_mdp, Rm, mu[0], pi_hat[0], BETA, planner=name)[0][0]) / (2 * EPS)
        assert abs(G[0][idx] - fd) <= 1e-6 * max(1.0, float(np.max(np.abs(G))))


@pytest.mark.parametrize("name", PLANNERS)
@pytest.mark.parametrize("kind", ["deterministic", "stochastic"])
def test_adjoint_is_the_transpose_of_tangent(twins, name, kind):
    sparse_mdp, _ = twins
    rng = np.random.default_rng(6)
    n, S, A = 3, sparse_mdp.n_states, sparse_mdp.n_actions
    pl = planning.get_planner(sparse_mdp, name)
    policy = rng.integers(0, A, size=(n, S)) if kind == "deterministic" else rng.dirichlet(np.ones(A), size=(n, S))
    system = pl.system(policy)
    dR, G = rng.standard_normal((n, S, A)), rng.standard_normal((n, S, A))
    lhs = np.sum(planning.tangent(pl, system, policy, dR) * G, axis=(1, 2))
    rhs = np.sum(dR * planning.adjoint(pl, system, policy, G), axis=(1, 2))
    np.testing.assert_allclose(lhs, rhs, rtol=1e-11)
    # k directions at once equal k single directions
    dRk = rng.standard_normal((n, S, A, 2))
    dQk = planning.tangent(pl, system, policy, dRk)
    for j in range(2):
        np.testing.assert_allclose(dQk[..., j], planning.tangent(pl, system, policy, dRk[..., j]), rtol=1e-12, atol=1e-12)


def test_value_iteration_raises_when_it_does_not_converge(grid3):
    slow = fo.GridWorld(3, gamma=0.9999)
    with pytest.raises(FactIRLError, match=r"value iteration did not reach tol=1e-12 in 50 sweeps"):
        fo.value_iteration(slow, np.ones((9, 4)), max_iter=50)


def test_policy_iteration_sweep_limit(twins):
    sparse_mdp, _ = twins
    R = np.random.default_rng(11).standard_normal((2, sparse_mdp.n_states, sparse_mdp.n_actions))
    Q, pol = fo.optimal_q(sparse_mdp, R, planner="dense")
    with pytest.raises(FactIRLError, match="policy iteration did not converge in 1 sweeps"):
        fo.optimal_q(sparse_mdp, R, policy=np.argmin(Q, axis=2), max_iter=1, planner="dense")


def test_planners_agree_to_rounding_at_the_same_rewards(make_statistics, tie_free_rewards):
    """What does not depend on the planner: Q*, the greedy policy (no ties), loss and gradient."""
    grid = fo.GridWorld(13)
    rng = np.random.default_rng(7)
    R = tie_free_rewards(rng, grid, (4, grid.n_states, 4))
    mu, pi_hat = make_statistics(rng, grid, 4)
    (Qd, pd), (Qs, ps) = (fo.optimal_q(grid, R, planner=name) for name in ("dense", "sparse-lu"))
    np.testing.assert_array_equal(pd, ps)
    np.testing.assert_allclose(Qs, Qd, rtol=0, atol=1e-13 * np.abs(Qd).max())
    (Ld, Gd), (Ls, Gs) = (fo.policy_matching_loss(grid, R, mu, pi_hat, BETA, planner=name) for name in ("dense", "sparse-lu"))
    np.testing.assert_allclose(Ls, Ld, rtol=1e-13)
    np.testing.assert_allclose(Gs, Gd, rtol=0, atol=1e-13 * np.abs(Gd).max())


# -- tasks in many environments ----------------------------------------------------------------
def test_optimal_q_per_task_mdps(rng, grid3, grid4, random_mdp):
    other = fo.TabularMDP(rng.dirichlet(np.ones(6), size=(6, 4)), 0.8)
    mdps = [grid3, grid4, other, grid3]
    R = [rng.standard_normal((m.n_states, 4)) for m in mdps]
    Q, pol = fo.optimal_q(mdps, R)
    assert isinstance(Q, list) and [q.shape for q in Q] == [(9, 4), (16, 4), (6, 4), (9, 4)]
    assert [p.shape for p in pol] == [(9,), (16,), (6,), (9,)]
    Q3, pol3 = fo.optimal_q(grid3, np.stack([R[0], R[3]]))
    np.testing.assert_array_equal(np.stack([Q[0], Q[3]]), Q3)
    np.testing.assert_array_equal(np.stack([pol[0], pol[3]]), pol3)
    for i, mdp in enumerate(mdps):
        Qi, pi = fo.optimal_q(mdp, R[i])
        np.testing.assert_allclose(Q[i], Qi, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(pol[i], pi)
    # warm start per task: the same Q*
    Qw, _ = fo.optimal_q(mdps, R, policy=[np.zeros(m.n_states, dtype=int) for m in mdps])
    for a, b in zip(Qw, Q):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    with pytest.raises(ValidationError, match=r"policy describes 2 tasks but 4 MDPs"):
        fo.optimal_q(mdps, R, policy=[np.zeros(9, dtype=int)] * 2)
    with pytest.raises(ValidationError, match=r"rewards\[2\] \(task 2, S = 6\) must have shape"):
        fo.optimal_q(mdps, [R[0], R[1], R[0], R[3]])
    with pytest.raises(ValidationError, match=r"task 1 has 3, task 0 has 4"):
        fo.optimal_q([grid3, random_mdp], [R[0], np.zeros((6, 3))])


def test_optimal_q_shared_or_equal_sized_mdps_are_stacked(rng, grid4):
    R = rng.standard_normal((3, 16, 4))
    Q, pol = fo.optimal_q(grid4, R)
    Qs, pols = fo.optimal_q([grid4] * 3, R)
    np.testing.assert_array_equal(Qs, Q)
    np.testing.assert_array_equal(pols, pol)
    twin = fo.GridWorld(4, p_success=0.9)
    Qt, polt = fo.optimal_q([grid4, twin, grid4], R)
    assert isinstance(Qt, np.ndarray) and Qt.shape == (3, 16, 4) and polt.shape == (3, 16)
    np.testing.assert_array_equal(Qt[1], fo.optimal_q(twin, R[1:2])[0][0])

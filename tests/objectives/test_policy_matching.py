"""Eq. (5) loss and its gradients: adjoint vs central finite differences vs the eq. (9) routes.

Every check is made at rewards whose greedy policy has no near-ties (gap > 1e-3, see the
``tie_free_rewards`` fixture), so Q* is differentiable there and a central difference with
step 1e-6 stays on one policy.
"""

import numpy as np
from helpers import central_difference, greedy_gap, rel_err
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError
from factirl_opt.objectives import PolicyMatchingObjective, dq_dtheta
from factirl_opt.objectives.problems import dictionary_problem, weights_problem


EPS = 1e-6
BETA = 5.0
ROUTES = ["fixed_point", "direct"]




@pytest.fixture(params=["grid", "random"])
def mdp(request, grid3, random_mdp):
    return grid3 if request.param == "grid" else random_mdp


# --- loss -----------------------------------------------------------------------------------


def test_loss_matches_definition(rng, mdp, make_statistics):
    mu, pi_hat = make_statistics(rng, mdp, 3)
    R = rng.standard_normal((3, mdp.n_states, mdp.n_actions))
    loss, grad = fo.policy_matching_loss(mdp, R, mu, pi_hat, BETA)
    Q, _ = fo.optimal_q(mdp, R)
    z = np.exp(BETA * Q)
    pi = z / z.sum(axis=2, keepdims=True)
    expected = np.array([sum(mu[i, s] * np.sum((pi[i, s] - pi_hat[i, s]) ** 2) for s in range(mdp.n_states)) for i in range(3)])
    np.testing.assert_allclose(loss, expected, rtol=1e-12)
    assert loss.shape == (3,) and grad.shape == R.shape


def test_loss_is_zero_when_statistics_match_the_boltzmann_policy(rng, mdp):
    R = rng.standard_normal((mdp.n_states, mdp.n_actions))
    Q, _ = fo.optimal_q(mdp, R)
    pi = fo.boltzmann_policy(Q, BETA)
    mu = np.full(mdp.n_states, 1.0 / mdp.n_states)
    loss, grad = fo.policy_matching_loss(mdp, R, mu, pi, BETA)
    assert loss[0] < 1e-28
    assert np.max(np.abs(grad)) < 1e-12


def test_batched_equals_single(rng, mdp, make_statistics):
    mu, pi_hat = make_statistics(rng, mdp, 4)
    R = rng.standard_normal((4, mdp.n_states, mdp.n_actions))
    loss, grad = fo.policy_matching_loss(mdp, R, mu, pi_hat, BETA)
    for i in range(4):
        li, gi = fo.policy_matching_loss(mdp, R[i], mu[i], pi_hat[i], BETA)
        np.testing.assert_allclose(li[0], loss[i], rtol=1e-13)
        np.testing.assert_allclose(gi[0], grad[i], rtol=1e-10, atol=1e-15)


def test_warm_start_policy_does_not_change_the_result(rng, mdp, make_statistics):
    mu, pi_hat = make_statistics(rng, mdp, 2)
    R = rng.standard_normal((2, mdp.n_states, mdp.n_actions))
    loss, grad = fo.policy_matching_loss(mdp, R, mu, pi_hat, BETA)
    wrong = np.argmin(R, axis=2)
    loss_w, grad_w = fo.policy_matching_loss(mdp, R, mu, pi_hat, BETA, policy=wrong)
    np.testing.assert_allclose(loss_w, loss, rtol=1e-12)
    np.testing.assert_allclose(grad_w, grad, rtol=1e-9, atol=1e-14)


# --- tabular gradient -----------------------------------------------------------------------


def test_tabular_gradient_matches_finite_differences(rng, mdp, make_statistics, tie_free_rewards):
    mu, pi_hat = make_statistics(rng, mdp, 2)
    R = tie_free_rewards(rng, mdp, (2, mdp.n_states, mdp.n_actions))
    _, grad = fo.policy_matching_loss(mdp, R, mu, pi_hat, BETA)
    for i in range(2):
        fd = central_difference(lambda r: fo.policy_matching_loss(mdp, r, mu[i], pi_hat[i], BETA)[0][0], R[i])
        assert rel_err(grad[i], fd) < 1e-5


@pytest.mark.parametrize("route", ROUTES)
def test_tabular_gradient_matches_eq9_reference(rng, mdp, make_statistics, tie_free_rewards, route):
    mu, pi_hat = make_statistics(rng, mdp, 3)
    R = tie_free_rewards(rng, mdp, (3, mdp.n_states, mdp.n_actions))
    loss, grad = fo.policy_matching_loss(mdp, R, mu, pi_hat, BETA)
    loss_ref, grad_ref = fo.objectives.policy_matching_grad_reference(mdp, R, mu, pi_hat, BETA, route=route)
    np.testing.assert_allclose(loss_ref, loss, rtol=1e-13)
    assert grad_ref.shape == (3, mdp.n_params)
    assert np.max(np.abs(grad.reshape(3, -1) - grad_ref)) < 1e-8


def test_gradient_includes_the_beta_factor(rng, grid3, make_statistics, tie_free_rewards):
    """Eq. (8) leaves out beta; the true gradient scales with it (checked against FD at beta=20)."""
    mu, pi_hat = make_statistics(rng, grid3, 1)
    R = 0.2 * tie_free_rewards(rng, grid3, (grid3.n_states, grid3.n_actions))
    _, grad = fo.policy_matching_loss(grid3, R, mu, pi_hat, 20.0)
    fd = central_difference(lambda r: fo.policy_matching_loss(grid3, r, mu, pi_hat, 20.0)[0][0], R)
    assert rel_err(grad[0], fd) < 1e-5


def test_dq_dtheta_routes_agree_and_match_finite_differences(rng, grid3, tie_free_rewards):
    R = tie_free_rewards(rng, grid3, (grid3.n_states, grid3.n_actions))
    _, pol = fo.optimal_q(grid3, R)
    phi_fp = dq_dtheta(grid3, pol, route="fixed_point")
    phi_dir = dq_dtheta(grid3, pol, route="direct")
    assert phi_fp.shape == (grid3.n_params, grid3.n_params)
    assert np.max(np.abs(phi_fp - phi_dir)) < 1e-10
    j = int(rng.integers(grid3.n_params))
    e = np.zeros(grid3.n_params)
    e[j] = EPS
    Qp, _ = fo.optimal_q(grid3, R + e.reshape(R.shape))
    Qm, _ = fo.optimal_q(grid3, R - e.reshape(R.shape))
    np.testing.assert_allclose(phi_dir[:, j], ((Qp - Qm) / (2 * EPS)).ravel(), atol=1e-7)
    with pytest.raises(ValidationError, match="route"):
        dq_dtheta(grid3, pol, route="sideways")
    with pytest.raises(ValidationError, match=r"features must have shape"):
        dq_dtheta(grid3, pol, features=np.ones((5, 2)))


# --- feature weights, dictionary, coefficients (through the step problems) ------------------


def _objective(rng, mdp, make_statistics, n):
    mu, pi_hat = make_statistics(rng, mdp, n)
    return PolicyMatchingObjective(mdp, mu, pi_hat, BETA), mu, pi_hat


def _tie_free_factors(rng, mdp, n, k):
    """Random factors (F (S*A, k), W (n, k)) whose rewards W F^T have no greedy near-ties."""
    for _ in range(200):
        D = rng.standard_normal((mdp.n_params, k))
        H = rng.standard_normal((n, k))
        if greedy_gap(mdp, (H @ D.T).reshape(n, mdp.n_states, mdp.n_actions)) > 1e-3:
            return D, H
    raise RuntimeError("no tie-free factors found")


def test_feature_weight_gradient(rng, mdp, make_statistics, tie_free_rewards):
    k, n = 3, 2
    F, w = _tie_free_factors(rng, mdp, n, k)
    obj, mu, pi_hat = _objective(rng, mdp, make_statistics, n)
    problem = weights_problem(obj, F)
    rows = np.arange(n)
    loss, grad = problem.loss_and_grad(w, rows)
    assert grad.shape == (n, k)
    for i in range(n):
        fd = central_difference(lambda wi: problem.loss_and_grad(wi[None], rows[i : i + 1])[0][0], w[i])
        assert rel_err(grad[i], fd) < 1e-5
    R = (w @ F.T).reshape(n, mdp.n_states, mdp.n_actions)
    # dJ/dw = F^T dJ/dR
    _, y = fo.policy_matching_loss(mdp, R, mu, pi_hat, BETA)
    np.testing.assert_allclose(grad, y.reshape(n, -1) @ F, rtol=1e-12, atol=1e-15)
    for route in ROUTES:
        loss_ref, grad_ref = fo.objectives.policy_matching_grad_reference(mdp, R, mu, pi_hat, BETA, features=F, route=route)
        np.testing.assert_allclose(loss_ref, loss, rtol=1e-13)
        assert np.max(np.abs(grad_ref - grad)) < 1e-8


def test_dictionary_gradient(rng, mdp, make_statistics):
    """dJ/dD = sum_i y_i h_i^T (eq. 11) vs FD on the total loss and vs eq. (9) + chain rule."""
    n, k = 3, 2
    D, H = _tie_free_factors(rng, mdp, n, k)
    obj, mu, pi_hat = _objective(rng, mdp, make_statistics, n)
    problem = dictionary_problem(obj, H)
    loss, grad = problem.loss_and_grad(D.reshape(1, -1), np.arange(1))
    assert loss.shape == (1,) and grad.shape == (1, mdp.n_params * k)
    fd = central_difference(lambda x: problem.loss_and_grad(x[None], np.arange(1))[0][0], D.ravel())
    assert rel_err(grad[0], fd) < 1e-5
    R = (H @ D.T).reshape(n, mdp.n_states, mdp.n_actions)
    for route in ROUTES:
        loss_ref, y_ref = fo.objectives.policy_matching_grad_reference(mdp, R, mu, pi_hat, BETA, route=route)
        np.testing.assert_allclose(loss[0], loss_ref.sum(), rtol=1e-13)
        chain = sum(np.outer(y_ref[i], H[i]) for i in range(n))  # (S*A, k)
        assert np.max(np.abs(grad[0] - chain.ravel())) < 1e-8


def test_coefficient_gradient(rng, mdp, make_statistics):
    """dJ/dh_i = D^T y_i (eq. 12) vs FD and vs eq. (9) with features D."""
    n, k = 3, 2
    D, H = _tie_free_factors(rng, mdp, n, k)
    obj, mu, pi_hat = _objective(rng, mdp, make_statistics, n)
    problem = weights_problem(obj, D)
    rows = np.arange(n)
    loss, grad = problem.loss_and_grad(H, rows)
    fd = central_difference(lambda h: problem.loss_and_grad(h, rows)[0].sum(), H)
    assert rel_err(grad, fd) < 1e-5
    R = (H @ D.T).reshape(n, mdp.n_states, mdp.n_actions)
    for route in ROUTES:
        _, g_feat = fo.objectives.policy_matching_grad_reference(mdp, R, mu, pi_hat, BETA, features=D, route=route)
        _, y_ref = fo.objectives.policy_matching_grad_reference(mdp, R, mu, pi_hat, BETA, route=route)
        assert np.max(np.abs(grad - g_feat)) < 1e-8
        assert np.max(np.abs(grad - y_ref @ D)) < 1e-8


def test_tabular_weights_problem_matches_loss(rng, grid3, make_statistics):
    obj, mu, pi_hat = _objective(rng, grid3, make_statistics, 2)
    problem = weights_problem(obj)
    x = rng.standard_normal((2, grid3.n_params))
    loss, grad = problem.loss_and_grad(x, np.arange(2))
    l2, g2 = fo.policy_matching_loss(grid3, x.reshape(2, grid3.n_states, grid3.n_actions), mu, pi_hat, BETA)
    np.testing.assert_allclose(loss, l2, rtol=1e-13)
    np.testing.assert_allclose(grad, g2.reshape(2, -1), rtol=1e-10, atol=1e-15)


# --- Gauss-Newton residuals and Jacobian ----------------------------------------------------


def test_residual_jacobian_matches_finite_differences(rng, mdp, make_statistics):
    n, k = 2, 3
    F, W = _tie_free_factors(rng, mdp, n, k)
    mu, pi_hat = make_statistics(rng, mdp, n)
    S, A = mdp.n_states, mdp.n_actions
    R = (W @ F.T).reshape(n, S, A)
    loss, r, J = fo.objectives.residual_jacobian(mdp, R, mu, pi_hat, BETA, F)
    assert r.shape == (n, S * A) and J.shape == (n, S * A, k)
    np.testing.assert_allclose(loss, np.sum(r * r, axis=1), rtol=1e-12)
    np.testing.assert_allclose(loss, fo.policy_matching_loss(mdp, R, mu, pi_hat, BETA)[0], rtol=1e-13)

    def res(i, w):
        return fo.objectives.residual_jacobian(mdp, (F @ w).reshape(1, S, A), mu[i], pi_hat[i], BETA, F)[1][0]

    for i in range(n):
        fd = np.column_stack([
            (res(i, W[i] + EPS * e) - res(i, W[i] - EPS * e)) / (2 * EPS) for e in np.eye(k)
        ])
        assert rel_err(J[i], fd) < 1e-5
    # Gauss-Newton identity: gradient of ||r||^2 is 2 J^T r
    problem = weights_problem(PolicyMatchingObjective(mdp, mu, pi_hat, BETA), F)
    _, grad = problem.loss_and_grad(W, np.arange(n))
    np.testing.assert_allclose(grad, 2 * np.einsum("nmk,nm->nk", J, r), rtol=1e-9, atol=1e-14)


def test_residual_jacobian_through_weights_problem(rng, grid3, make_statistics):
    n, k = 2, 2
    F, W = _tie_free_factors(rng, grid3, n, k)
    obj, mu, pi_hat = _objective(rng, grid3, make_statistics, n)
    problem = weights_problem(obj, F)
    loss, r, J = problem.residual_jacobian(W, np.arange(n))
    R = (W @ F.T).reshape(n, grid3.n_states, grid3.n_actions)
    l2, r2, J2 = fo.objectives.residual_jacobian(grid3, R, mu, pi_hat, BETA, F)
    np.testing.assert_allclose(loss, l2, rtol=1e-13)
    np.testing.assert_allclose(J, J2, rtol=1e-12, atol=1e-15)


def _few_visited(rng, mdp, make_statistics, n, visited):
    """Statistics of tasks that visit ``visited`` states each (one short demonstration)."""
    mu, pi_hat = make_statistics(rng, mdp, n)
    for i in range(n):
        off = rng.permutation(mdp.n_states)[visited:]
        mu[i, off] = 0.0
        pi_hat[i, off] = 0.0
    return mu / mu.sum(axis=1, keepdims=True), pi_hat


@pytest.mark.parametrize("planner", ["dense", "sparse-lu"])
def test_reverse_jacobian_is_the_forward_one_and_matches_finite_differences(rng, grid3, make_statistics, planner):
    """Reverse mode (one adjoint right-hand side per residual row of a visited state) builds the
    Jacobian of forward mode (p tangent right-hand sides); auto takes it when those rows are fewer than p."""
    n, k = 3, 13  # 2 visited states x 4 actions = 8 rows < 13 parameters
    F, W = _tie_free_factors(rng, grid3, n, k)
    mu, pi_hat = _few_visited(rng, grid3, make_statistics, n, 2)
    S, A = grid3.n_states, grid3.n_actions
    R = (W @ F.T).reshape(n, S, A)
    out = {mode: fo.objectives.residual_jacobian(grid3, R, mu, pi_hat, BETA, F, planner=planner, mode=mode)
           for mode in ("forward", "reverse", "auto")}
    J = out["reverse"][2]
    assert J.shape == (n, S * A, k) and np.any(J != 0)
    np.testing.assert_allclose(J, out["forward"][2], rtol=0, atol=1e-12 * np.max(np.abs(J)))
    np.testing.assert_array_equal(out["auto"][2], J)
    np.testing.assert_array_equal(J.reshape(n, S, A, k)[mu == 0], 0.0)  # unvisited states' rows

    def res(i, w):
        return fo.objectives.residual_jacobian(grid3, (F @ w).reshape(1, S, A), mu[i], pi_hat[i], BETA, F, mode="reverse")[1][0]

    for i in range(n):
        fd = np.column_stack([(res(i, W[i] + EPS * e) - res(i, W[i] - EPS * e)) / (2 * EPS) for e in np.eye(k)])
        assert rel_err(J[i], fd) < 1e-5


@pytest.mark.parametrize("mode, transposed", [("forward", False), ("reverse", True), ("auto", True)])
def test_objective_builds_its_jacobian_in_its_mode(rng, grid3, make_statistics, mode, transposed):
    """The objective's ``jacobian_mode``: reverse mode solves transposed systems (the adjoint), forward mode
    forward ones; both give one Jacobian."""
    from factirl_opt.planning import CountingPlanner, get_planner

    n, k = 2, 13
    F, W = _tie_free_factors(rng, grid3, n, k)
    mu, pi_hat = _few_visited(rng, grid3, make_statistics, n, 2)
    counter = CountingPlanner(get_planner(grid3))
    obj = PolicyMatchingObjective(grid3, mu, pi_hat, BETA, planner=counter)
    with fo.objectives.jacobian_mode(mode):
        loss, r, J = weights_problem(obj, F).residual_jacobian(W, np.arange(n))
    assert (counter.n_transpose > 0) == transposed
    own = PolicyMatchingObjective(grid3, mu, pi_hat, BETA, planner=CountingPlanner(get_planner(grid3)))
    own.jacobian_mode = mode  # an objective's own mode wins over the block's
    with fo.objectives.jacobian_mode("reverse" if mode == "forward" else "forward"):
        weights_problem(own, F).residual_jacobian(W, np.arange(n))
    assert (own.planner.n_transpose > 0) == transposed
    R = (W @ F.T).reshape(n, grid3.n_states, grid3.n_actions)
    np.testing.assert_allclose(J, fo.objectives.residual_jacobian(grid3, R, mu, pi_hat, BETA, F, mode="forward")[2],
                               rtol=0, atol=1e-12 * np.max(np.abs(J)))


def test_bad_jacobian_mode_is_refused(grid3):
    with pytest.raises(ValidationError, match="jacobian mode must be one of 'auto', 'forward', 'reverse'; got 'adjoint'"):
        fo.objectives.residual_jacobian(grid3, np.zeros((1, 9, 4)), np.full(9, 1 / 9), np.full((9, 4), 0.25), BETA,
                                        np.ones((36, 2)), mode="adjoint")
    with pytest.raises(ValidationError, match="got None"):
        with fo.objectives.jacobian_mode(None):
            pass


# --- the objective's cache and evaluation count -------------------------------------------


def test_objective_counts_evaluations_and_caches_repeats(rng, grid3, make_statistics):
    obj, mu, pi_hat = _objective(rng, grid3, make_statistics, 2)
    R = rng.standard_normal((2, grid3.n_states, grid3.n_actions))
    first = obj.loss_and_grad(R)
    assert obj.n_evaluations == 1
    again = obj.loss_and_grad(R.copy())
    assert obj.n_evaluations == 1  # served from the cache
    np.testing.assert_array_equal(again[0], first[0])
    np.testing.assert_array_equal(again[1], first[1])
    obj.loss_and_grad(R[1:] + 1.0, rows=np.array([1]))
    assert obj.n_evaluations == 2
    assert isinstance(obj.n_evaluations, int)


# --- validation -----------------------------------------------------------------------------


@pytest.mark.parametrize("beta", [0.0, -1.0, np.inf, np.nan, "hot"])
def test_bad_beta(rng, grid3, make_statistics, beta):
    mu, pi_hat = make_statistics(rng, grid3, 1)
    R = np.zeros((grid3.n_states, grid3.n_actions))
    with pytest.raises(ValidationError, match=rf"beta must be a finite number > 0; got {beta!r}".replace("(", r"\(")):
        fo.policy_matching_loss(grid3, R, mu, pi_hat, beta)


@pytest.mark.parametrize(
    "mu_shape, pi_shape, fragment",
    [
        ((3, 8), (3, 9, 4), r"mu_hat must have shape \(n, 9\); got \(3, 8\)"),
        ((3, 9), (3, 9, 3), r"pi_hat must have shape \(3, 9, 4\).*got \(3, 9, 3\)"),
        ((2, 9), (2, 9, 4), r"describe 2 tasks but rewards describe 3"),
        ((3, 9, 1), (3, 9, 4), r"mu_hat must have shape \(n, 9\); got \(3, 9, 1\)"),
    ],
)
def test_bad_statistics_shapes(grid3, mu_shape, pi_shape, fragment):
    R = np.zeros((3, 9, 4))
    with pytest.raises(ValidationError, match=fragment):
        fo.policy_matching_loss(grid3, R, np.full(mu_shape, 1 / 9), np.full(pi_shape, 0.25), BETA)


@pytest.mark.parametrize("bad, fragment", [(np.nan, "must be finite"), (-0.1, "must be nonnegative")])
def test_bad_statistics_values(grid3, bad, fragment):
    mu = np.full((1, 9), 1 / 9)
    mu[0, 2] = bad
    with pytest.raises(ValidationError, match=fragment):
        fo.policy_matching_loss(grid3, np.zeros((9, 4)), mu, np.full((1, 9, 4), 0.25), BETA)


def test_bad_reward_shape_for_loss(grid3):
    with pytest.raises(ValidationError, match=r"rewards must have shape .*got \(9, 3\)"):
        fo.policy_matching_loss(grid3, np.zeros((9, 3)), np.full(9, 1 / 9), np.full((9, 4), 0.25), BETA)


def test_bad_features_for_residual_jacobian(grid3):
    with pytest.raises(ValidationError, match=r"features must have shape \(S\*A = 36, p\) with p >= 1; got \(35, 2\)"):
        fo.objectives.residual_jacobian(grid3, np.zeros((1, 9, 4)), np.full(9, 1 / 9), np.full((9, 4), 0.25), BETA, np.ones((35, 2)))

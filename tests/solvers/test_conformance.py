"""Conformance suite run over every registered step solver.

Exact references: on a linear least-squares problem ``r_i(h) = A_i h - y_i`` the Gauss-Newton
model is exact, so the first step of a GN solver must equal the damped subproblem's exact
solution: closed form (unconstrained), ``scipy.optimize.nnls`` (nonneg), and an enumeration of
all sign patterns (sparse). Every solver, GN or not, must keep its constraint after every
step and never increase its objective across an accepted step, on the linear problem, on a
nonlinear least squares ``r_i = exp(A_i h) - y_i`` and on the real eq. (5) H-step and D-step
problems. The matrix-free products of the D-step problem (what ``gn-cg`` sees) are checked
against an explicitly formed Jacobian and against finite differences through Q*.
"""

import itertools

import numpy as np
import pytest
from scipy.optimize import nnls

import factirl_opt as fo
import solvers
from factirl_opt.objectives import PolicyMatchingObjective
from factirl_opt.objectives.problems import dictionary_problem, weights_problem
from solvers.gauss_newton import reduce_least_squares

from helpers import greedy_gap

from solver_problems import ALL, GN, K, M, N, exact_step, exp_problem, feasible, least_squares_problem, linear_problem, sparse_reference  # noqa: F401


@pytest.mark.parametrize("interface", ["cvxpy", "direct"])
@pytest.mark.parametrize("name", GN)
def test_gn_step_matches_exact_reference(name, interface, rng):
    problem, A, y = linear_problem(rng)
    solver = solvers.get_solver(name, interface=interface, alpha=0.3, damping=0.05)
    x0 = solver.project(rng.standard_normal((N, K)))
    state = solver.init_state(problem, x0)
    lam = state.lam.copy()
    ref = exact_step(A, y, x0, lam, solver.constraint, solver.alpha)
    # the QP step itself, on the reduced data
    R, b = reduce_least_squares(state.jacobian, state.residual, x0, lam)
    z = solver.solve_subproblems(R, b, x0)
    np.testing.assert_allclose(z, ref, atol=1e-6, rtol=0)
    # one whole LM step: the model is exact on a linear problem, so every row is accepted
    x1, state, progressed = solver.update(problem, x0, state)
    assert progressed
    np.testing.assert_allclose(x1, ref, atol=1e-6, rtol=0)
    np.testing.assert_allclose(state.lam, lam * solver.lam_down)
    if solver.constraint == "nonneg":
        assert np.min(x1) >= -1e-8
        assert np.any(ref == 0.0), "the reference should have active constraints"
    if solver.constraint == "sparse":
        assert np.sum(np.abs(x1) < 1e-9) == np.sum(ref == 0.0) > 0


@pytest.mark.parametrize("name", ALL)
def test_linear_problem_monotone_and_feasible(name, rng):
    problem, A, y = linear_problem(rng)
    solver = solvers.get_solver(name)
    x0 = rng.standard_normal((N, K))
    seen = []

    def objective(x):
        r = np.einsum("nmk,nk->nm", A, x) - y
        return np.sum(r * r, axis=1) + solver.penalty(x)

    x = solver.project(x0)
    state = solver.init_state(problem, x)
    np.testing.assert_allclose(state.loss, objective(x), rtol=1e-12)
    for _ in range(8):
        x_new, state, _ = solver.update(problem, x, state)
        assert feasible(solver, x_new)
        before, after = objective(x), objective(x_new)
        assert np.all(after <= before + 1e-12), "a step increased a row's objective"
        np.testing.assert_allclose(state.loss, after, rtol=1e-10, atol=1e-12)
        seen.append(after.sum())
        x = x_new
    assert seen[-1] < objective(solver.project(x0)).sum()


@pytest.mark.parametrize("name", ALL)
def test_nonlinear_problem_monotone(name, rng):
    problem, A, y = exp_problem(rng)
    solver = solvers.get_solver(name)
    x0 = solver.project(0.3 * rng.standard_normal((N, K)))
    res = solver.run(problem, x0, 15)
    hist = np.array(res.loss_history)
    assert np.all(np.diff(hist) <= 1e-12 * hist[0]), hist
    assert hist[-1] < (0.5 if solver.constraint == "none" else 1.0) * hist[0]
    assert np.all(np.isfinite(res.coefficients)) and feasible(solver, res.coefficients)
    rows = np.arange(N)
    np.testing.assert_allclose(res.loss, problem.residual_jacobian(res.coefficients, rows)[0] + solver.penalty(res.coefficients), rtol=1e-12)
    assert res.n_evaluations >= res.iterations


@pytest.mark.parametrize("name", ALL)
def test_irl_h_step_monotone_and_feasible(name, rng, grid4):
    """The real H-step problem (eq. 5 with a fixed dictionary) on a 4x4 grid."""
    k = 3
    D = fo.random_dictionary(grid4.n_params, k, rng)
    H = fo.random_coefficients(5, k, kind="nonneg", rng=rng)
    demos = fo.sample_demonstrations(grid4, fo.task_rewards(D, H, 16, 4), 2, 6, rng)
    mu, pi_hat = fo.empirical_statistics(grid4, demos)
    problem = weights_problem(PolicyMatchingObjective(grid4, mu, pi_hat, 5.0), D)
    solver = solvers.get_solver(name)
    x0 = 0.3 * np.abs(rng.standard_normal((5, k)))
    if solver.needs_linearization and problem.linearize is None:
        with pytest.raises(solvers.SolverOptionError, match="needs problem.linearize"):
            solver.run(problem, x0, 10)
        return
    res = solver.run(problem, x0, 10)
    hist = np.array(res.loss_history)
    assert np.all(np.diff(hist) <= 1e-12), hist
    assert hist[-1] < hist[0]
    assert feasible(solver, res.coefficients)
    assert res.coefficients.shape == (5, k) and res.status in ("converged", "max_iter", "stalled")
    assert res.n_evaluations >= res.iterations


@pytest.mark.parametrize("name", [n for n in GN if n.endswith("-sparse")])
def test_sparse_zeros_grow_with_alpha(name, rng):
    problem, A, y = linear_problem(rng)
    zeros = []
    for alpha in (0.0, 1.0, 10.0, 1e4):
        res = solvers.get_solver(name, alpha=alpha).run(problem, np.zeros((N, K)), 15)
        zeros.append(int(np.sum(res.coefficients == 0.0)))
    assert zeros == sorted(zeros) and zeros[0] == 0 and zeros[-1] == N * K, zeros


@pytest.mark.parametrize("name", GN)
def test_gn_step_tiny_jacobian_no_fallback(name, rng):
    """Near a fit the Jacobian is tiny (saturated softmax); the step must stay exact and the
    QP solvers must not report inaccurate solutions (each task's QP is rescaled)."""
    import warnings

    problem, A, y = linear_problem(rng)
    A *= 1e-5
    y *= 1e-5
    solver = solvers.get_solver(name, alpha=0.3e-10, damping=0.05)
    x0 = solver.project(rng.standard_normal((N, K)))
    state = solver.init_state(problem, x0)
    ref = exact_step(A, y, x0, state.lam.copy(), solver.constraint, solver.alpha)
    with warnings.catch_warnings():
        warnings.simplefilter("error", solvers.QPFallbackWarning)
        x1, state, _ = solver.update(problem, x0, state)
    np.testing.assert_allclose(x1, ref, atol=1e-6, rtol=0)


# --- the IRL dictionary (D-step) problem -------------------------------------------------------

#: unconstrained solvers: the D-step has no constraint
D_STEP = [name for name in ALL if solvers.get_solver(name).constraint == "none" and not name.startswith("gn-qp-")]


def _dictionary_setting(rng, mdp, n=3, k=2, features=None, unit_norm=False):
    """A D-step problem on ``mdp`` (demonstrations of random factorial rewards) and a point
    ``vec(D)`` whose rewards have no greedy near-tie (so Q* is differentiable around it)."""
    p = mdp.n_params if features is None else features.shape[1]
    F = np.eye(mdp.n_params) if features is None else features
    D_true, H_true = rng.standard_normal((p, k)), rng.standard_normal((n, k))
    demos = fo.sample_demonstrations(mdp, fo.task_rewards(F @ D_true, H_true, mdp.n_states, mdp.n_actions), 3, 6, rng)
    mu, pi_hat = fo.empirical_statistics(mdp, demos)
    H = H_true + 0.3 * rng.standard_normal((n, k))
    for _ in range(200):
        D = rng.standard_normal((p, k))
        if greedy_gap(mdp, fo.task_rewards(F @ D, H, mdp.n_states, mdp.n_actions)) > 1e-3:
            break
    obj = PolicyMatchingObjective(mdp, mu, pi_hat, 2.0)
    return dictionary_problem(obj, H, features, unit_norm=unit_norm), D.reshape(1, -1)


@pytest.mark.parametrize("variant", ["tabular", "features", "unit-norm"])
def test_dictionary_products_match_an_explicit_jacobian(variant, rng, grid3):
    """J formed column by column from jvp (one batched forward solve per column); vjp must be
    its transpose, and the gradient 2 J^T r, to 1e-10."""
    Phi = rng.standard_normal((grid3.n_params, 5)) if variant == "features" else None
    problem, x = _dictionary_setting(rng, grid3, features=Phi, unit_norm=variant == "unit-norm")
    lin = problem.linearize(x, np.arange(1))
    P = problem.n_params
    J = np.stack([lin.jvp(np.eye(P)[j][None])[0] for j in range(P)], axis=1)  # (m, P)
    assert J.shape == (lin.residual.shape[1], P) and np.linalg.norm(J) > 0
    U = rng.standard_normal((4, lin.residual.shape[1]))
    for u in U:
        np.testing.assert_allclose(lin.vjp(u[None])[0], J.T @ u, rtol=0, atol=1e-10 * np.linalg.norm(J) * np.linalg.norm(u))
    _, grad = problem.loss_and_grad(x, np.arange(1))
    np.testing.assert_allclose(grad[0], 2.0 * J.T @ lin.residual[0], rtol=0, atol=1e-10 * np.linalg.norm(grad))
    np.testing.assert_allclose(lin.loss, np.sum(lin.residual**2), rtol=1e-13)


@pytest.mark.parametrize("variant", ["tabular", "features", "unit-norm"])
def test_dictionary_jvp_matches_finite_differences_through_q_star(variant, rng, grid3):
    """``J v`` vs the central difference of the residual along ``v``: Q* is re-planned at each
    perturbed dictionary (the greedy policy does not change within eps)."""
    Phi = rng.standard_normal((grid3.n_params, 5)) if variant == "features" else None
    problem, x = _dictionary_setting(rng, grid3, features=Phi, unit_norm=variant == "unit-norm")
    rows, eps = np.arange(1), 1e-6
    lin = problem.linearize(x, rows)
    for _ in range(3):
        v = rng.standard_normal(x.shape)
        fd = (problem.linearize(x + eps * v, rows).residual - problem.linearize(x - eps * v, rows).residual) / (2 * eps)
        jv = lin.jvp(v)
        assert np.linalg.norm(jv - fd) <= 1e-6 * np.linalg.norm(fd)


@pytest.mark.parametrize("alternating", [False, True])
@pytest.mark.parametrize("name", D_STEP)
def test_irl_d_step_never_increases_the_loss(name, alternating, rng, grid4):
    """Each D-step solver (and its alternating form, which FactIRL's fit uses) on the real
    eq. (10) problem over vec(D): the loss history never rises and matches the true loss."""
    problem, x0 = _dictionary_setting(rng, grid4, n=5, k=3)
    solver = solvers.get_solver(name)
    solver = solver.for_alternating() if alternating else solver
    res = solver.run(problem, x0, 8)
    hist = np.array(res.loss_history)
    assert np.all(np.diff(hist) <= 0.0), hist
    assert hist[-1] < hist[0] and res.coefficients.shape == x0.shape
    np.testing.assert_allclose(res.loss, problem.loss_and_grad(res.coefficients, np.arange(1))[0], rtol=1e-12)

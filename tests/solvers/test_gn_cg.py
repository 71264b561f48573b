"""The matrix-free Gauss-Newton solver (gn-cg): CG against the explicitly formed normal
equations, consistency of the products, Levenberg-Marquardt steps, and its requirements."""

import numpy as np
import pytest

import solvers
from solvers.gn_cg import cg_normal_equations

from solver_problems import K, N, exact_step, exp_problem, least_squares_problem, linear_problem


def _explicit(A, r, lam):
    """``(A^T A + lam I)^{-1} (-A^T r)`` of every row, formed explicitly."""
    k = A.shape[2]
    M = np.einsum("nmi,nmj->nij", A, A) + lam[:, None, None] * np.eye(k)
    return np.linalg.solve(M, -np.einsum("nmk,nm->nk", A, r)[..., None])[..., 0]


@pytest.mark.parametrize("m, k", [(9, 4), (60, 30)])
def test_cg_matches_the_explicit_normal_equations(m, k):
    rng = np.random.default_rng(0)
    A = rng.standard_normal((5, m, k))
    r = rng.standard_normal((5, m))
    lam = np.array([1e-3, 1e-1, 1.0, 10.0, 0.5]) * m
    grad = np.einsum("nmk,nm->nk", A, r)
    delta, its, broken = cg_normal_equations(
        lambda V: np.einsum("nmk,nk->nm", A, V), lambda U: np.einsum("nmk,nm->nk", A, U), grad, lam, 10 * k, 1e-14
    )
    ref = _explicit(A, r, lam)
    np.testing.assert_allclose(delta, ref, rtol=0, atol=1e-10 * np.max(np.abs(ref)))
    assert broken == 0 and np.all(its >= 1)


def test_cg_is_truncated_and_counts_products():
    rng = np.random.default_rng(1)
    A = rng.standard_normal((3, 40, 20))
    r = rng.standard_normal((3, 40))
    calls = {"jvp": 0, "vjp": 0}

    def jvp(V):
        calls["jvp"] += 1
        return np.einsum("nmk,nk->nm", A, V)

    def vjp(U):
        calls["vjp"] += 1
        return np.einsum("nmk,nm->nk", A, U)

    grad = vjp(r)
    calls["vjp"] = 0
    lam = np.full(3, 1e-6)
    delta, its, _ = cg_normal_equations(jvp, vjp, grad, lam, 3, 0.0)
    assert calls == {"jvp": 3, "vjp": 3} and np.all(its == 3)
    # truncated CG from zero is a descent direction that decreases the damped model
    model = lambda d: np.sum((r + np.einsum("nmk,nk->nm", A, d)) ** 2, axis=1) + lam * np.sum(d * d, axis=1)
    assert np.all(np.einsum("nk,nk->n", grad, delta) < 0) and np.all(model(delta) < model(np.zeros_like(delta)))


def test_jvp_vjp_consistency(rng):
    """<J v, u> = <v, J^T u> row by row for the test problems' linearisations."""
    for make in (linear_problem, exp_problem):
        problem, A, y = make(rng)
        x = 0.3 * rng.standard_normal((N, K))
        rows = np.arange(N)
        lin = problem.linearize(x, rows)
        V, U = rng.standard_normal((N, K)), rng.standard_normal((N, lin.residual.shape[1]))
        np.testing.assert_allclose(np.einsum("nm,nm->n", lin.jvp(V), U), np.einsum("nk,nk->n", V, lin.vjp(U)), rtol=1e-12)
        np.testing.assert_allclose(lin.loss, np.sum(lin.residual**2, axis=1))


def test_first_step_is_the_exact_damped_step_on_a_linear_problem(rng):
    problem, A, y = linear_problem(rng)
    solver = solvers.get_solver("gn-cg", cg_max_iter=50, cg_tol=1e-14, damping=0.05)
    x0 = rng.standard_normal((N, K))
    state = solver.init_state(problem, x0)
    lam = state.lam.copy()
    ref = exact_step(A, y, x0, lam, "none", 0.0)
    x1, state, progressed = solver.update(problem, x0, state)
    assert progressed
    np.testing.assert_allclose(x1, ref, atol=1e-10)
    np.testing.assert_allclose(state.lam, lam * solver.lam_down)
    # the initial damping is relative to the Rayleigh quotient of J^T J along the gradient
    g = np.einsum("nmk,nm->nk", A, np.einsum("nmk,nk->nm", A, x0) - y)
    Jg = np.einsum("nmk,nk->nm", A, g)
    np.testing.assert_allclose(lam, 0.05 * np.sum(Jg**2, axis=1) / np.sum(g**2, axis=1))


def test_levenberg_marquardt_on_a_nonlinear_problem(rng):
    problem, A, y = exp_problem(rng)
    solver = solvers.get_solver("gn-cg")
    res = solver.run(problem, np.zeros((N, K)), 25, tol=0.0)
    assert res.n_evaluations == problem.n_evaluations() > res.iterations  # one linearize per trial (+ the start)
    hist = np.array(res.loss_history)
    assert np.all(np.diff(hist) <= 0)
    reachable = np.arange(N) < N // 2  # rows whose targets have an exact fit
    assert np.all(res.loss[reachable] < 1e-12)
    armijo = solvers.get_solver("armijo").run(problem, np.zeros((N, K)), 25, tol=0.0)
    assert hist[-1] < armijo.loss_history[-1]
    # products counted: per step at most cg_max_iter jvp (+1 at the start for the scale)
    st = res.state
    assert st.n_jvp >= st.cg_iterations and st.n_jvp <= 1 + res.iterations * (solver.max_retries + 1) * solver.cg_max_iter
    assert st.n_vjp >= res.iterations


def test_rows_from_different_linearisations_give_the_right_products(rng):
    """After steps where only some rows were accepted, the products of every row still use
    that row's own (latest) linearisation."""
    problem, A, y = exp_problem(rng)
    solver = solvers.get_solver("gn-cg", damping=1e-6)
    x = np.zeros((N, K))
    state = solver.init_state(problem, x)
    pieces = set()
    for _ in range(6):
        x, state, _ = solver.update(problem, x, state)
        pieces.add(len([p for p in state.lin.pieces if p is not None]))
        V = rng.standard_normal((N, K))
        J = np.exp(np.einsum("nmk,nk->nm", A, x))[:, :, None] * A
        np.testing.assert_allclose(state.lin.jvp(V, np.arange(N), A.shape[1]), np.einsum("nmk,nk->nm", J, V), rtol=1e-10)
        np.testing.assert_allclose(state.grad, np.einsum("nmk,nm->nk", J, state.residual), rtol=1e-10, atol=1e-12)
    assert max(pieces) > 1  # the case did occur


def test_needs_a_linearization(rng):
    problem, _, _ = linear_problem(rng)
    bare = solvers.StepProblem(problem.loss_and_grad, problem.n_evaluations, N, K, residual_jacobian=problem.residual_jacobian)
    with pytest.raises(solvers.SolverOptionError, match=r"solver 'gn-cg' needs problem.linearize"):
        solvers.get_solver("gn-cg").run(bare, np.zeros((N, K)), 2)
    assert solvers.get_solver("gn-cg").needs_linearization and not solvers.get_solver("armijo").needs_linearization


def test_bad_linearizations_are_reported(rng):
    problem, A, y = linear_problem(rng)

    def not_one(x, rows):
        return problem.residual_jacobian(x, rows)

    def bad_shape(x, rows):
        lin = problem.linearize(x, rows)
        return solvers.Linearization(lin.loss, lin.residual, jvp=lin.jvp, vjp=lambda U: lin.vjp(U)[:, :2])

    for linearize, fragment in ((not_one, "must return a Linearization"), (bad_shape, r"Linearization.vjp returned shape \(6, 2\)")):
        p = solvers.StepProblem(problem.loss_and_grad, problem.n_evaluations, N, K, linearize=linearize)
        with pytest.raises(solvers.SolverError, match=fragment):
            solvers.get_solver("gn-cg").run(p, np.zeros((N, K)), 2)


def test_non_finite_trials_are_rejected():
    """Residual ``x - 1`` (NaN beyond |x| > 1.5) with a Jacobian reported 10x too small, so the
    first Gauss-Newton trials overshoot into the NaN region: rejected, lam raised, converges."""

    def residual(x, rows):
        r = x - 1.0
        r[np.any(np.abs(x) > 1.5, axis=1)] = np.nan
        return r

    problem = least_squares_problem(residual, lambda x, rows: np.broadcast_to(0.1 * np.eye(2), (len(rows), 2, 2)).copy(), 3, 2)
    res = solvers.get_solver("gn-cg").run(problem, np.full((3, 2), -1.0), 40)
    assert np.all(np.isfinite(res.loss_history)) and np.all(np.diff(res.loss_history) <= 0)
    np.testing.assert_allclose(res.coefficients, 1.0, atol=1e-4)


def test_for_alternating():
    """The alternating form (FactIRL's D-step) is proximal and inexact by default: lam = 1 x
    the curvature scale, shrinking by 0.9 per accepted step, CG to a 0.1 relative residual;
    alternating_damping=None keeps the solver."""
    plain = solvers.get_solver("gn-cg")
    prox = plain.for_alternating()
    assert (prox.damping, prox.lam_down, prox.cg_tol, prox.name) == (1.0, 0.9, 0.1, "gn-cg")
    assert (plain.damping, plain.lam_down, plain.cg_tol) == (1e-3, 1.0 / 3.0, 1e-3)  # unchanged
    assert prox.cg_max_iter == plain.cg_max_iter and prox.lam_up == plain.lam_up
    custom = solvers.get_solver("gn-cg", alternating_damping=10.0, alternating_lam_down=0.5, alternating_cg_tol=0.0)
    assert (custom.for_alternating().damping, custom.for_alternating().lam_down, custom.for_alternating().cg_tol) == (10.0, 0.5, 0.0)
    with pytest.raises(solvers.SolverOptionError, match="alternating_cg_tol must be a finite number >= 0"):
        solvers.get_solver("gn-cg", alternating_cg_tol=-1.0)
    keep = solvers.get_solver("gn-cg", alternating_damping=None)
    assert keep.for_alternating() is keep


def test_damping_is_carried_over(rng):
    """The damping of a run warm-starts the next one (carry_over keeps the whole state)."""
    problem, _, _ = exp_problem(rng)
    solver = solvers.get_solver("gn-cg")
    first = solver.run(problem, np.zeros((N, K)), 3)
    carried = solver.carry_over(first.state)
    assert carried is first.state
    state = solver.init_state(problem, first.coefficients, previous=carried)
    np.testing.assert_allclose(state.lam, np.clip(first.state.lam, solver.lam_min * state.scale, solver.lam_max * state.scale))


def test_gradient_is_twice_the_state_half_gradient(rng):
    problem, A, y = linear_problem(rng)
    solver = solvers.get_solver("gn-cg")
    x = rng.standard_normal((N, K))
    state = solver.init_state(problem, x)
    np.testing.assert_allclose(solver.gradient(state), problem.loss_and_grad(x, np.arange(N))[1], rtol=1e-12)

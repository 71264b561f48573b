"""The L-BFGS step solver: exact minimiser of convex quadratics, the two-loop recursion against
the explicit inverse-Hessian update, the memory across runs, curvature-pair skipping, and the
line search's safeguards."""

import warnings

import numpy as np
import pytest

import solvers
from solvers.lbfgs import lbfgs_direction

from solver_problems import exp_problem


def quadratic_rows(rng, n=5, p=8, cond=50.0):
    """Rows ``f_i(x) = 0.5 x^T Q_i x - c_i^T x`` with SPD ``Q_i`` (condition ~cond); counts
    evaluations. Returns the problem and the exact minimisers ``Q_i^{-1} c_i``."""
    Q = np.empty((n, p, p))
    for i in range(n):
        U, _ = np.linalg.qr(rng.standard_normal((p, p)))
        Q[i] = (U * np.geomspace(1.0, cond, p)) @ U.T
    c = rng.standard_normal((n, p))
    count = [0]

    def loss_and_grad(x, rows):
        count[0] += 1
        Qx = np.einsum("nij,nj->ni", Q[rows], x)
        return 0.5 * np.einsum("ni,ni->n", x, Qx) - np.einsum("ni,ni->n", c[rows], x), Qx - c[rows]

    problem = solvers.StepProblem(loss_and_grad, lambda: count[0], n, p)
    return problem, np.linalg.solve(Q, c[..., None])[..., 0]


def test_converges_to_the_exact_minimiser_of_a_convex_quadratic(rng):
    problem, x_star = quadratic_rows(rng)
    res = solvers.get_solver("lbfgs").run(problem, np.zeros_like(x_star), 60, tol=0.0)
    np.testing.assert_allclose(res.coefficients, x_star, atol=1e-8)
    hist = np.array(res.loss_history)
    assert np.all(np.diff(hist) <= 0)
    assert res.n_evaluations == problem.n_evaluations()
    # far fewer evaluations than gradient descent needs on the same rows
    armijo = solvers.get_solver("armijo").run(problem, np.zeros_like(x_star), res.iterations, tol=0.0)
    assert np.sum(armijo.loss) - np.sum(res.loss) > 1e-3 * abs(np.sum(res.loss))


def test_rows_are_independent(rng):
    problem, x_star = quadratic_rows(rng, n=3)
    together = solvers.get_solver("lbfgs").run(problem, np.zeros_like(x_star), 12, tol=0.0).coefficients
    for i in range(3):
        sub = solvers.StepProblem(lambda x, rows, i=i: problem.loss_and_grad(x, rows + i), lambda: 0, 1, x_star.shape[1])
        alone = solvers.get_solver("lbfgs").run(sub, np.zeros((1, x_star.shape[1])), 12, tol=0.0)
        np.testing.assert_allclose(alone.coefficients[0], together[i], rtol=1e-12, atol=1e-14)


def test_two_loop_recursion_matches_the_explicit_update(rng):
    """``-H g`` from the two-loop recursion equals the explicit BFGS inverse update
    ``H <- (I - rho s y^T) H (I - rho y s^T) + rho s s^T`` from ``H0 = gamma I``."""
    n, m, p = 3, 4, 6
    s = rng.standard_normal((n, m, p))
    y = s + 0.3 * rng.standard_normal((n, m, p))  # positive curvature
    rho = 1.0 / np.einsum("nmp,nmp->nm", s, y)
    assert np.all(rho > 0)
    count = np.array([4, 2, 0])
    g = rng.standard_normal((n, p))
    d = lbfgs_direction(g, s, y, rho, count)
    for i in range(n):
        pairs = range(m - count[i], m)
        gamma = (s[i, -1] @ y[i, -1]) / (y[i, -1] @ y[i, -1]) if count[i] else 1.0
        H = gamma * np.eye(p)
        for j in pairs:
            V = np.eye(p) - rho[i, j] * np.outer(y[i, j], s[i, j])
            H = V.T @ H @ V + rho[i, j] * np.outer(s[i, j], s[i, j])
        np.testing.assert_allclose(d[i], -H @ g[i], rtol=1e-10, atol=1e-12)


def test_memory_is_kept_across_runs_and_reset_with_none(rng):
    problem, x_star = quadratic_rows(rng)
    solver = solvers.get_solver("lbfgs", memory=5)
    first = solver.run(problem, np.zeros_like(x_star), 3, tol=0.0)
    assert np.all(first.state.count == 3)
    kept = solver.init_state(problem, first.coefficients, previous=first.state)
    np.testing.assert_array_equal(kept.s, first.state.s)
    assert np.all(kept.count == 3)
    # carried memory: the next step starts with a quasi-Newton direction, not a gradient step
    warm = solver.run(problem, first.coefficients, 4, state=first.state, tol=0.0)
    cold = solver.run(problem, first.coefficients, 4, state=None, tol=0.0)
    assert np.sum(warm.loss) < np.sum(cold.loss)
    assert np.all(warm.state.count == 5)  # capped at memory
    fresh = solver.init_state(problem, first.coefficients, previous=None)
    assert np.all(fresh.count == 0)
    other = solvers.get_solver("lbfgs", memory=7).init_state(problem, first.coefficients, previous=first.state)
    assert np.all(other.count == 0)  # shapes differ: a new memory


def test_carry_over_drops_the_pairs_and_keeps_the_step_scale(rng):
    """Between two runs on a changed problem (alternating minimisation) only the scale
    s^T y / y^T y of each row's newest pair is kept; it sizes the first (gradient) step."""
    problem, x_star = quadratic_rows(rng)
    solver = solvers.get_solver("lbfgs", memory=5)
    first = solver.run(problem, np.zeros_like(x_star), 3, tol=0.0)
    carried = solver.carry_over(first.state)
    assert np.all(carried.count == 0) and not np.any(carried.s) and not np.any(carried.y)
    s, y = first.state.s[:, -1], first.state.y[:, -1]
    np.testing.assert_allclose(carried.first_scale, np.sum(s * y, axis=1) / np.sum(y * y, axis=1), rtol=1e-12)
    assert np.all(first.state.count == 3)  # the run's own state is untouched
    # the next run starts with the gradient step of that size
    state = solver.init_state(problem, first.coefficients, previous=carried)
    x1, _, _ = solver.update(problem, first.coefficients, state)
    g = problem.loss_and_grad(first.coefficients, np.arange(len(x_star)))[1]
    np.testing.assert_allclose(x1, first.coefficients - carried.first_scale[:, None] * g, rtol=1e-12)
    assert solver.carry_over(None) is None
    # a row without a pair (a fresh state) keeps no scale: its first step is capped at initial_step
    fresh = solver.carry_over(solver.init_state(problem, np.zeros_like(x_star)))
    assert np.all(np.isnan(fresh.first_scale))


def test_a_failed_line_search_forgets_the_carried_step_scale():
    """Every trial point is NaN: the line search fails, and the row falls back to a gradient
    step capped at initial_step (the carried scale is dropped with the memory)."""

    def loss_and_grad(x, rows):
        bad = np.any(x != 0.0, axis=1)
        loss, grad = np.where(bad, np.nan, 1.0), np.where(bad[:, None], np.nan, 1.0)
        return loss, np.broadcast_to(grad, x.shape).copy()

    problem = solvers.StepProblem(loss_and_grad, lambda: 0, 2, 3)
    solver = solvers.get_solver("lbfgs", max_backtracks=3)
    previous = solver.carry_over(solver.init_state(problem, np.zeros((2, 3))))
    previous.first_scale[:] = 5.0
    state = solver.init_state(problem, np.zeros((2, 3)), previous=previous)
    np.testing.assert_array_equal(state.first_scale, 5.0)
    x, state, progressed = solver.update(problem, np.zeros((2, 3)), state)
    assert not progressed and np.all(np.isnan(state.first_scale)) and state.n_resets == 2
    np.testing.assert_array_equal(x, 0.0)


def test_curvature_pairs_without_positive_curvature_are_skipped():
    """A double well ``x^4/4 - x^2`` near 0 is concave: ``s^T y < 0`` there."""

    def loss_and_grad(x, rows):
        return np.sum(0.25 * x**4 - x**2, axis=1), x**3 - 2 * x

    problem = solvers.StepProblem(loss_and_grad, lambda: 0, 1, 1)
    res = solvers.get_solver("lbfgs", initial_step=0.2).run(problem, np.array([[0.1]]), 30, tol=0.0)
    assert res.state.n_skipped >= 1
    assert np.all(np.diff(res.loss_history) <= 0)
    np.testing.assert_allclose(np.abs(res.coefficients), np.sqrt(2.0), atol=1e-6)


def test_non_finite_trials_are_backtracked():
    """Loss ``||x - 3||^2``, NaN (with its gradient) wherever ``|x_j| > 4``; from 0 the first
    quasi-Newton steps overshoot there and must be shortened, never accepted."""
    seen = []

    def loss_and_grad(x, rows):
        seen.append(x.copy())
        loss, grad = np.sum((x - 3) ** 2, axis=1), 2 * (x - 3)
        bad = np.any(np.abs(x) > 4, axis=1)
        loss[bad] = np.nan
        grad[bad] = np.nan
        return loss, grad

    problem = solvers.StepProblem(loss_and_grad, lambda: 0, 2, 3)
    res = solvers.get_solver("lbfgs", initial_step=50.0).run(problem, np.zeros((2, 3)), 20)
    assert np.max(np.abs(np.concatenate(seen))) > 4  # some trials were outside
    assert np.all(np.isfinite(res.loss_history)) and np.all(np.diff(res.loss_history) <= 0)
    np.testing.assert_allclose(res.coefficients, 3.0, atol=1e-6)


def test_steps_are_bounded():
    """A linear loss has no minimiser: every step is capped at max_step_norm * max(1, ||x||)."""
    problem = solvers.StepProblem(lambda x, rows: (-np.sum(x, axis=1), -np.ones_like(x)), lambda: 0, 1, 2)
    x = np.zeros((1, 2))
    solver = solvers.get_solver("lbfgs", initial_step=1e6, max_step_norm=3.0)
    state = solver.init_state(problem, x)
    for _ in range(4):
        x_new, state, progressed = solver.update(problem, x, state)
        assert progressed and np.linalg.norm(x_new - x) <= 3.0 * max(1.0, np.linalg.norm(x)) * (1 + 1e-12)
        x = x_new


def test_a_gradient_whose_squares_overflow_gives_a_first_step_of_initial_step_length():
    """A row whose gradient entries are near 1e300 (its squares overflow float64) still gets the first
    step of length ``initial_step`` along -g, without numpy's overflow warning; the other row is unchanged."""
    scale = np.array([[1e300], [1.0]])
    problem = solvers.StepProblem(lambda x, rows: (-np.sum(scale[rows] * x, axis=1), -scale[rows] * np.ones_like(x)),
                                  lambda: 0, 2, 2)
    solver = solvers.get_solver("lbfgs", initial_step=1.0)
    x = np.zeros((2, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        x_new, _, progressed = solver.update(problem, x, solver.init_state(problem, x))
    assert progressed
    np.testing.assert_allclose(x_new, np.full((2, 2), 1 / np.sqrt(2)), rtol=1e-12)


def test_zero_gradient_converges_without_evaluations():
    calls = [0]

    def loss_and_grad(x, rows):
        calls[0] += 1
        return np.sum((x - 1) ** 2, axis=1), 2 * (x - 1)

    problem = solvers.StepProblem(loss_and_grad, lambda: calls[0], 2, 2)
    res = solvers.get_solver("lbfgs").run(problem, np.ones((2, 2)), 5)
    assert res.status == "converged" and res.iterations == 1 and res.n_evaluations == 1


def test_nonlinear_least_squares_never_increases_any_row(rng):
    problem, A, y = exp_problem(rng)
    solver = solvers.get_solver("lbfgs")
    x = np.zeros((A.shape[0], A.shape[2]))
    state = solver.init_state(problem, x)
    for _ in range(20):
        before = state.loss.copy()
        x, state, _ = solver.update(problem, x, state)
        assert np.all(state.loss <= before)
    assert np.sum(state.loss) < 0.1 * np.sum(problem.loss_and_grad(np.zeros_like(x), np.arange(len(x)))[0])


@pytest.mark.parametrize("options, fragment", [({"memory": 0}, "memory must be an integer >= 1"), ({"curvature_eps": -1.0}, "curvature_eps")])
def test_options(options, fragment):
    with pytest.raises(solvers.SolverOptionError, match=fragment):
        solvers.get_solver("lbfgs", **options)
    assert solvers.get_solver("lbfgs").constraint == "none" and solvers.get_solver("lbfgs").name == "lbfgs"

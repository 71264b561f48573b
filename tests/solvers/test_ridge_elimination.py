"""A ridge block eliminated from the Gauss-Newton subproblem in closed form (solvers.gn_subproblem.eliminate_ridge)."""

import dataclasses

import numpy as np
import pytest

import solvers
from solvers import SolverOptionError
from solvers.gn_subproblem import eliminate_ridge, reduce_least_squares
from solvers.separable import restrict_rows


def stacked(A, B, r, x, penalty):
    """The residual model's stacked Jacobian and residuals: ``[[A, B], [0, sqrt(lambda) I]]`` and ``[r, sqrt(lambda) d]``."""
    n, m, k = A.shape
    q = B.shape[2]
    top = np.concatenate([A, B], axis=2)
    bottom = np.concatenate([np.zeros((n, q, k)), np.broadcast_to(np.sqrt(penalty) * np.eye(q), (n, q, q))], axis=2)
    return np.concatenate([top, bottom], axis=1), np.concatenate([r, np.sqrt(penalty) * x[:, k:]], axis=1)


def random_rows(rng, n, m, k, q, dead):
    """Jacobian blocks whose first ``dead`` rows are zero in some rows of the batch (unvisited states)."""
    A, B, r = rng.normal(size=(n, m, k)), rng.normal(size=(n, m, q)), rng.normal(size=(n, m))
    dead = min(dead, m)
    A[0, :dead] = B[0, :dead] = 0.0  # r stays nonzero there: a constant the step cannot change
    A[-1, m - dead:] = B[-1, m - dead:] = 0.0
    return A, B, r, rng.normal(size=(n, k + q))


# (m, q): fewer live rows than ridge parameters (W's side) and more (G's side), and no rows but the ridge's
SHAPES = [(14, 25), (40, 6), (9, 9), (0, 4)]


@pytest.mark.parametrize("m, q", SHAPES)
@pytest.mark.parametrize("penalty", [0.0, 0.05, 3.0])
def test_minimiser_is_the_stacked_subproblems(rng, m, q, penalty):
    n, k = 4, 3
    A, B, r, x = random_rows(rng, n, m, k, q, dead=5)
    lam = rng.uniform(1e-3, 2.0, size=n)
    J, res = stacked(A, B, r, x, penalty)
    R, b = reduce_least_squares(J, res, x, lam)
    expected = np.linalg.solve(R, b[..., None])[..., 0]
    got = eliminate_ridge(J, res, x, lam, q, penalty).minimiser()
    assert np.max(np.abs(got - expected)) <= 1e-10 * np.max(np.abs(expected))


@pytest.mark.parametrize("m, q", SHAPES)
def test_reduced_model_is_the_stacked_model_at_the_blocks_minimiser(rng, m, q):
    """For any kept coefficients h' (a constrained QP's too), ||R h' - b||^2 is the stacked damped model
    minimised over the block, up to one constant per row."""
    n, k, penalty = 3, 2, 0.4
    A, B, r, x = random_rows(rng, n, m, k, q, dead=3)
    lam = rng.uniform(1e-2, 1.0, size=n)
    J, res = stacked(A, B, r, x, penalty)
    elim = eliminate_ridge(J, res, x, lam, q, penalty)

    def stacked_model(z):
        lin = res + np.einsum("nij,nj->ni", J, z - x)
        return np.sum(lin * lin, axis=1) + lam * np.sum((z - x) ** 2, axis=1)

    gaps = []
    for _ in range(3):
        h = rng.normal(size=(n, k))
        z = np.concatenate([h, elim.block(h)], axis=1)
        reduced = np.sum((np.einsum("nij,nj->ni", elim.R, h) - elim.b) ** 2, axis=1)
        gaps.append(stacked_model(z) - reduced)
        # the block is the minimiser: the stacked model's gradient over it vanishes
        lin = res + np.einsum("nij,nj->ni", J, z - x)
        grad = 2.0 * np.einsum("nij,ni->nj", J, lin)[:, k:] + 2.0 * lam[:, None] * (z - x)[:, k:]
        assert np.max(np.abs(grad)) <= 1e-9 * max(1.0, np.max(np.abs(J)))
    np.testing.assert_allclose(gaps[1], gaps[0], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(gaps[2], gaps[0], rtol=1e-9, atol=1e-9)


def ridge_problem(rng, n=5, m=12, k=2, q=7, penalty=0.5):
    """A nonlinear residual model: ``r_i = exp(A_i h_i + B_i d_i) - y_i`` (some rows dead), plus ``sqrt(lambda) d_i``."""
    A, B = 0.4 * rng.normal(size=(n, m, k)), 0.3 * rng.normal(size=(n, m, q))
    A[:, :3] = B[:, :3] = 0.0
    y = np.exp(rng.normal(size=(n, m)))
    count = [0]

    def pieces(x, rows):
        h, d = x[:, :k], x[:, k:]
        e = np.exp(np.einsum("nmk,nk->nm", A[rows], h) + np.einsum("nmq,nq->nm", B[rows], d))
        r = np.concatenate([e - y[rows], np.sqrt(penalty) * d], axis=1)
        top = e[:, :, None] * np.concatenate([A[rows], B[rows]], axis=2)
        bottom = np.concatenate([np.zeros((len(rows), q, k)), np.broadcast_to(np.sqrt(penalty) * np.eye(q), (len(rows), q, q))],
                                axis=2)
        return r, np.concatenate([top, bottom], axis=1)

    def residual_jacobian(x, rows):
        count[0] += 1
        r, J = pieces(x, np.asarray(rows))
        return np.sum(r * r, axis=1), r, J

    def loss_and_grad(x, rows):
        loss, r, J = residual_jacobian(x, rows)
        return loss, 2.0 * np.einsum("nmk,nm->nk", J, r)

    return solvers.StepProblem(loss_and_grad=loss_and_grad, residual_jacobian=residual_jacobian, n_evaluations=lambda: count[0],
                               n_rows=n, n_params=k + q, ridge_params=q, ridge_penalty=penalty)


@pytest.mark.parametrize("separable", [True, False])
def test_solver_runs_as_with_the_stacked_system(rng, separable):
    problem = ridge_problem(rng)
    x0 = np.zeros((problem.n_rows, problem.n_params))
    runs = {route: solvers.get_solver("gn-qp-clarabel", ridge=route).run(problem, x0, 60, tol=1e-12, separable=separable)
            for route in ("eliminate", "stack")}
    a, b = runs["eliminate"], runs["stack"]
    assert np.max(np.abs(a.coefficients - b.coefficients)) <= 1e-6 * np.max(np.abs(b.coefficients))
    assert np.max(np.abs(a.coefficients)) > 0.1  # the runs moved
    if separable:  # the exact minimiser on both routes: the same steps
        assert a.iterations == b.iterations
        np.testing.assert_array_equal(a.row_iterations, b.row_iterations)


def test_each_row_is_its_run_alone(rng):
    problem = ridge_problem(rng)
    solver = solvers.get_solver("gn-qp-osqp")
    x0 = np.zeros((problem.n_rows, problem.n_params))
    together = solver.run(problem, x0, 40, tol=1e-8, separable=True)
    for i in range(problem.n_rows):
        alone = solver.run(restrict_rows(problem, np.array([i])), x0[i:i + 1], 40, tol=1e-8)
        np.testing.assert_allclose(together.coefficients[i], alone.coefficients[0], rtol=0, atol=1e-10)
        assert together.row_iterations[i] == alone.iterations


def test_step_bound_acts_on_the_whole_step(rng):
    """A small step bound: the eliminated route raises the damping where the stacked route does."""
    problem = ridge_problem(rng)
    x0 = np.zeros((problem.n_rows, problem.n_params))
    a, b = (solvers.get_solver("gn-qp-osqp", ridge=route, max_step_norm=0.05).run(problem, x0, 5, separable=True)
            for route in ("eliminate", "stack"))
    assert a.state.bounded_steps == b.state.bounded_steps > 0
    np.testing.assert_allclose(a.coefficients, b.coefficients, rtol=0, atol=1e-9)
    steps = np.linalg.norm(np.diff(np.stack([x0, a.coefficients]), axis=0)[0], axis=1)
    assert np.all(steps <= 5 * 0.05 * np.maximum(1.0, np.linalg.norm(a.coefficients, axis=1)) + 1e-12)


def test_a_constrained_solver_keeps_its_constraint_on_the_stacked_route(rng):
    problem = ridge_problem(rng)
    x0 = np.zeros((problem.n_rows, problem.n_params))
    a = solvers.get_solver("gn-qp-clarabel-nonneg").run(problem, x0, 15, separable=True)
    b = solvers.get_solver("gn-qp-clarabel-nonneg", ridge="stack").run(problem, x0, 15, separable=True)
    assert np.all(a.coefficients >= 0.0)
    np.testing.assert_array_equal(a.coefficients, b.coefficients)


def test_bad_ridge_declarations_and_options_are_refused(rng):
    problem = ridge_problem(rng)
    for changes, match in [({"ridge_params": -1}, "ridge_params"), ({"ridge_params": problem.n_params}, "ridge_params"),
                           ({"ridge_params": 2.0}, "ridge_params"), ({"ridge_penalty": -0.1}, "ridge_penalty"),
                           ({"ridge_penalty": np.inf}, "ridge_penalty")]:
        with pytest.raises(SolverOptionError, match=match):
            dataclasses.replace(problem, **changes)
    with pytest.raises(SolverOptionError, match="ridge"):
        solvers.get_solver("gn-qp-osqp", ridge="woodbury")

"""Rows whose objective tends to 0 (saturation) stop by the gradient or the saturation rule, per row; a separable
Levenberg-Marquardt run retries a rejected row in the next round (solvers.separable)."""

import numpy as np
import pytest
from solver_problems import GN, exp_problem, least_squares_problem

import solvers
from solvers.separable import restrict_rows

N, M, K = 5, 6, 3


def saturating_problem(rng):
    """``r_i(x) = exp(-A_i x_i)`` with positive ``A_i``: ``inf f_i = 0``, reached only as ``x -> inf``
    (as a Boltzmann policy matching its demonstrations exactly); a Gauss-Newton step divides
    the residual by about ``e``, so the relative decrease of every row stays near ``1 - e^-2``."""
    A = rng.uniform(0.5, 1.5, size=(N, M, K))

    def residual(x, rows):
        return np.exp(-np.einsum("nmk,nk->nm", A[rows], x))

    def jacobian(x, rows):
        return -residual(x, rows)[:, :, None] * A[rows]

    return least_squares_problem(residual, jacobian, N, K)


@pytest.mark.parametrize("name", ["lbfgs", "gn-cg", *GN[:1]])
def test_rows_tending_to_zero_stop_by_the_gradient_rule(rng, name):
    problem = saturating_problem(rng)
    solver = solvers.get_solver(name)
    x0 = np.zeros((N, K))
    fixed = solver.run(problem, x0, 60, tol=1e-5, separable=True)
    assert fixed.status == "max_iter" and list(fixed.row_status) == ["max_iter"] * N  # the decrease rule never holds
    res = solver.run(problem, x0, 60, tol=1e-5, gtol=1e-4, separable=True)
    assert res.status == "converged" and res.reason == f"per row, of {N}: {N} by gradient norm <= gtol=0.0001 x initial"
    assert np.all(res.row_iterations < 60) and res.n_evaluations < fixed.n_evaluations
    start = problem.loss_and_grad(x0, np.arange(N))[0]
    assert np.all(res.loss <= 1e-3 * start) and np.all(res.loss > 0)
    for i in (0, N - 1):  # each row stops where it stops alone
        alone = solver.run(restrict_rows(problem, np.array([i])), x0[i:i + 1], 60, tol=1e-5, gtol=1e-4)
        assert alone.iterations == res.row_iterations[i]
        np.testing.assert_allclose(res.coefficients[i], alone.coefficients[0], rtol=0, atol=1e-10)


@pytest.mark.parametrize("name", ["lbfgs", "gn-cg", *GN[:1]])
def test_rows_tending_to_zero_stop_by_the_saturation_rule(rng, name):
    """With the gradient rule off, each row stops once its decrease over a step is a fraction stol
    of its decrease since the start, at the step a run on that row alone stops (the
    Levenberg-Marquardt rows' retried trials included)."""
    problem = saturating_problem(rng)
    solver = solvers.get_solver(name)
    x0 = np.zeros((N, K))
    res = solver.run(problem, x0, 200, tol=1e-5, stol=1e-4, separable=True)
    assert res.status == "converged" and res.reason == (
        f"per row, of {N}: {N} by saturation (decrease <= stol=0.0001 x decrease since the start)")
    start = problem.loss_and_grad(x0, np.arange(N))[0]
    assert np.all(res.loss <= 1e-2 * start) and np.all(res.loss > 0) and np.all(res.row_iterations < 200)
    for i in range(N):  # each row stops where it stops alone, by the rule of a one-row run
        alone = solver.run(restrict_rows(problem, np.array([i])), x0[i:i + 1], 200, tol=1e-5, stol=1e-4)
        assert alone.reason.startswith("saturated: decrease") and alone.iterations == res.row_iterations[i]
        np.testing.assert_allclose(res.coefficients[i], alone.coefficients[0], rtol=0, atol=1e-10)
    loose = solver.run(problem, x0, 200, tol=1e-5, stol=1e-2, separable=True)
    assert np.all(loose.row_iterations <= res.row_iterations) and loose.n_evaluations < res.n_evaluations


def test_row_rules_saturation():
    """The rule of solvers.stopping.has_saturated per row, after the decrease and before the gradient."""
    from solvers.separable import row_rules

    start = np.array([1.0, 1.0, 1.0, 1.0])
    prev, cur = np.array([1.5e-5, 3e-5, 1e-5, 1e-5]), np.array([1e-5, 1e-5, 1e-5 * (1 - 1e-7), 0.0])
    gnorm, g0, progressed = np.array([1e-9, 1.0, 1.0, 1.0]), np.ones(4), np.ones(4, dtype=bool)
    rules = row_rules(prev, cur, gnorm, g0, progressed, 1e-6, 1e-6, start, 1e-5)
    assert [solvers.has_saturated(1.0, p, c, 1e-5) for p, c in zip(prev, cur)] == [True, False, True, True]
    assert list(rules) == ["saturation", "", "decrease", "saturation"]
    assert list(row_rules(prev, cur, gnorm, g0, progressed, 1e-6, 1e-6)) == ["gradient", "", "decrease", ""]


@pytest.mark.parametrize("name", [*GN, "gn-cg"])
def test_a_rejected_row_retries_in_the_next_round(name):
    """Rows retry their rejected steps at different iterations (seed 1): each retry shares the
    batched evaluation of the other rows' next steps, so the run costs the evaluations of its
    longest row, and each row's trials are still its own."""
    problem, *_ = exp_problem(np.random.default_rng(1))
    solver = solvers.get_solver(name)
    x0 = solver.project(np.zeros((problem.n_rows, problem.n_params)))
    res = solver.run(problem, x0, 40, tol=1e-8, separable=True)
    assert np.any(res.row_evaluations > res.row_iterations + 1)  # some row retried
    assert res.n_evaluations == res.row_evaluations.max()
    assert len(res.loss_history) == res.iterations + 1
    assert res.loss_history[-1] == pytest.approx(res.loss.sum(), rel=1e-12)
    for i in range(problem.n_rows):
        counts = np.zeros(problem.n_rows, dtype=np.intp)
        alone = solver.run(restrict_rows(problem, np.array([i]), counts), x0[i:i + 1], 40, tol=1e-8)
        assert alone.iterations == res.row_iterations[i] and counts[i] == res.row_evaluations[i]


def test_trial_rows_of_a_solver_without_retries_is_its_step():
    problem, *_ = exp_problem(np.random.default_rng(0))
    solver = solvers.get_solver("armijo")
    x0 = np.zeros((problem.n_rows, problem.n_params))
    a = solver.init_state(problem, x0)
    b = solver.init_state(problem, x0)
    xa, _, pa = solver.step_rows(problem, x0, a)
    xb, _, pb, pending = solver.trial_rows(problem, x0, b, np.zeros(problem.n_rows, dtype=np.intp))
    assert np.array_equal(xa, xb) and np.array_equal(pa, pb) and not pending.any()

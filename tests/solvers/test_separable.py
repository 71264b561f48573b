"""Separable runs: every row stops by its own rules and leaves the batch (solvers.separable)."""

import numpy as np
import pytest
from solver_problems import ALL, exp_problem

import solvers
from solvers import SolverError, SolverOptionError
from solvers.separable import restrict_rows, row_rules

SOLVERS = [name for name in ALL if not name.endswith("-sparse") or "clarabel" in name]


@pytest.mark.parametrize("name", SOLVERS)
def test_each_row_is_its_run_alone(rng, name):
    problem, *_ = exp_problem(rng)
    solver = solvers.get_solver(name)
    x0 = solver.project(np.zeros((problem.n_rows, problem.n_params)))
    res = solver.run(problem, x0, 40, tol=1e-8, separable=True)
    assert res.row_status.shape == res.row_iterations.shape == res.row_evaluations.shape == (problem.n_rows,)
    for i in range(problem.n_rows):
        alone = solver.run(restrict_rows(problem, np.array([i])), x0[i:i + 1], 40, tol=1e-8)
        np.testing.assert_allclose(res.coefficients[i], alone.coefficients[0], rtol=0, atol=1e-10)
        assert res.row_iterations[i] == alone.iterations and res.row_status[i] == alone.status
        assert abs(res.loss[i] - alone.loss[0]) <= 1e-10
    assert res.iterations == res.row_iterations.max() and len(res.loss_history) == res.iterations + 1
    assert res.loss_history[-1] == pytest.approx(res.loss.sum(), rel=1e-12)


def test_rows_that_stopped_are_not_evaluated_again(rng):
    problem, *_ = exp_problem(rng)
    res = solvers.get_solver("gn-qp-clarabel").run(problem, np.zeros((problem.n_rows, problem.n_params)), 40, tol=1e-8,
                                                   separable=True)
    assert len(set(res.row_iterations.tolist())) > 1  # the rows stop at different steps
    # Gauss-Newton: one evaluation per step (the trial point holds the next Jacobian), more when
    # a step is retried, none for a negligible last step
    assert np.all(res.row_evaluations >= res.row_iterations)
    assert res.row_evaluations.sum() < problem.n_rows * (res.iterations + 1)
    assert res.status == "converged" and res.reason.startswith(f"per row, of {problem.n_rows}: ")


def test_max_iter_names_the_rows(rng):
    problem, *_ = exp_problem(rng)
    res = solvers.get_solver("armijo").run(problem, np.zeros((problem.n_rows, problem.n_params)), 3, tol=1e-8,
                                           separable=True)
    assert res.status == "max_iter" and list(res.row_status) == ["max_iter"] * problem.n_rows
    assert res.reason.endswith(f"at max_iter=3: rows [{', '.join(map(str, range(problem.n_rows)))}]")
    zero = solvers.get_solver("armijo").run(problem, np.zeros((problem.n_rows, problem.n_params)), 0, separable=True)
    assert zero.status == "max_iter" and zero.iterations == 0 and np.all(zero.row_evaluations == 1)


def test_row_rules_match_the_run_rules():
    prev = np.array([1.0, 1.0, 1.0, 1.0, 0.0])
    cur = np.array([0.5, 1.0 - 1e-9, 1.0 + 1e-3, 0.9, 0.0])
    gnorm, g0 = np.array([1.0, 1.0, 1.0, 1e-9, np.nan]), np.ones(5)
    progressed = np.array([True, True, True, True, False])
    assert list(row_rules(prev, cur, gnorm, g0, progressed, 1e-6, 1e-6)) == ["", "decrease", "", "gradient", "stalled"]


def test_separable_must_be_a_bool(rng):
    problem, *_ = exp_problem(rng)
    with pytest.raises(SolverOptionError, match=r"separable must be True or False; got 1"):
        solvers.get_solver("armijo").run(problem, np.zeros((problem.n_rows, problem.n_params)), 2, separable=1)


class _Shapeless(solvers.ArmijoSolver):
    def step_rows(self, problem, x, state):
        x, state, progressed = super().step_rows(problem, x, state)
        return x, state, progressed[:1]


def test_a_solver_with_a_bad_step_rows_or_state_is_refused(rng):
    problem, *_ = exp_problem(rng)
    x0 = np.zeros((problem.n_rows, problem.n_params))
    with pytest.raises(SolverError, match=r"step_rows returned progress of shape \(1,\); expected \(6,\)"):
        _Shapeless().run(problem, x0, 5, separable=True)
    with pytest.raises(SolverError, match=r"a separable run needs a dataclass state with a loss array"):
        solvers.ArmijoSolver().take_rows(object(), np.arange(1))


def test_restrict_rows_maps_and_counts(rng):
    problem, *_ = exp_problem(rng)
    counts = np.zeros(problem.n_rows, dtype=np.intp)
    sub = restrict_rows(problem, np.array([4, 1]), counts)
    x = rng.standard_normal((2, problem.n_params))
    loss, grad = sub.loss_and_grad(x, np.array([1, 0]))
    ref_loss, ref_grad = problem.loss_and_grad(x, np.array([1, 4]))
    np.testing.assert_array_equal(loss, ref_loss)
    np.testing.assert_array_equal(grad, ref_grad)
    assert sub.n_rows == 2 and counts.tolist() == [0, 1, 0, 0, 1, 0]

"""The one relative-decrease stopping rule (solvers.stopping) and its use by StepSolver.run."""

import numpy as np
import pytest

import solvers
from solvers import SolverOptionError

TINY = np.finfo(np.float64).tiny


@pytest.mark.parametrize(
    "prev, current, expected",
    [
        (10.0, 9.0, 0.1),
        (10.0, 10.0, 0.0),
        (10.0, 11.0, -0.1),
        (-4.0, -5.0, 0.25),
        (0.0, 0.0, 0.0),
        (0.0, -1.0, 1.0 / TINY),  # divides by tiny, no ZeroDivisionError
    ],
)
def test_relative_decrease(prev, current, expected):
    assert solvers.relative_decrease(prev, current) == pytest.approx(expected)


def test_has_converged_rule():
    assert solvers.has_converged(10.0, 9.5, 0.1)  # 5% < 10%
    assert not solvers.has_converged(10.0, 8.0, 0.1)  # 20% > 10%
    assert solvers.has_converged(10.0, 9.0, 0.1)  # boundary: <= tol
    # tol = 0: stops only when the objective stays equal
    assert not solvers.has_converged(10.0, 10.0 - 1e-12, 0.0)
    assert solvers.has_converged(10.0, 10.0, 0.0)
    # a rise is never convergence (issue 9: the outer loop goes on and keeps its best point)
    assert not solvers.has_converged(10.0, 10.5, 0.0) and not solvers.has_converged(10.0, 10.5, 1.0)
    assert not solvers.has_converged(-4.0, -3.9, 0.5)
    # prev = 0 is guarded (relative to tiny)
    assert solvers.has_converged(0.0, 0.0, 0.0) and not solvers.has_converged(0.0, -TINY, 0.0)


@pytest.mark.parametrize("bad", [np.nan, np.inf, "1.0", None, True])
def test_rule_rejects_non_numbers(bad):
    with pytest.raises(SolverOptionError, match="prev must be a finite number"):
        solvers.relative_decrease(bad, 1.0)
    with pytest.raises(SolverOptionError, match="current must be a finite number"):
        solvers.has_converged(1.0, bad, 0.1)


@pytest.mark.parametrize("tol", [-1e-3, np.nan, "0"])
def test_rule_rejects_bad_tol(tol):
    with pytest.raises(SolverOptionError, match="tol must be a finite number >= 0"):
        solvers.has_converged(1.0, 0.5, tol)


def test_run_stops_by_the_rule():
    """Armijo with a fixed step 0.1 on x^2 multiplies the loss by 0.64 per step (relative
    decrease 0.36): it converges at once for tol >= 0.36 and never for a smaller tol."""
    problem = solvers.StepProblem(
        loss_and_grad=lambda x, rows: (np.sum(x * x, axis=1), 2 * x), n_evaluations=lambda: 0, n_rows=2, n_params=1
    )
    solver = solvers.ArmijoSolver(initial_step=0.1, grow=1.0)
    res = solver.run(problem, np.ones((2, 1)), 10, tol=0.4)
    assert res.status == "converged" and res.iterations == 1
    assert solvers.relative_decrease(*res.loss_history) == pytest.approx(0.36)
    res = solver.run(problem, np.ones((2, 1)), 10, tol=0.3)
    assert res.status == "max_iter" and res.iterations == 10
    np.testing.assert_allclose(np.array(res.loss_history[1:]) / res.loss_history[:-1], 0.64)

"""The stopping rules (solvers.stopping: relative decrease, gradient norm) and their use by StepSolver.run."""

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
    # a rise is never convergence (the outer loop goes on and keeps its best point)
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

    assert res.reason.startswith("max_iter=10 steps")


def test_gradient_rule():
    assert solvers.gradient_converged(1e-3, 1.0, 1e-3)  # boundary: <= gtol * initial
    assert not solvers.gradient_converged(1.1e-3, 1.0, 1e-3)
    assert solvers.gradient_converged(0.0, 1.0, 0.0) and not solvers.gradient_converged(1e-300, 1.0, 0.0)
    assert solvers.gradient_converged(0.0, 0.0, 0.5)  # a zero gradient from the start
    # an overflowed norm says nothing: never convergence
    assert not solvers.gradient_converged(np.inf, np.inf, 1.0) and not solvers.gradient_converged(1.0, np.inf, 1.0)
    assert not solvers.gradient_converged(np.inf, 1.0, 1e300)


@pytest.mark.parametrize("args, fragment", [((-1.0, 1.0, 0.1), "norm must be a finite number >= 0"),
                                            ((1.0, np.nan, 0.1), "initial must be a finite number >= 0"),
                                            ((-np.inf, 1.0, 0.1), "norm must be a finite number >= 0"),
                                            ((1.0, 1.0, np.inf), "gtol must be a finite number >= 0"),
                                            ((1.0, 1.0, -0.1), "gtol must be a finite number >= 0"),
                                            (("1", 1.0, 0.1), "norm must be a finite number")])
def test_gradient_rule_rejects_bad_values(args, fragment):
    with pytest.raises(SolverOptionError, match=fragment):
        solvers.gradient_converged(*args)


def _quadratic():
    return solvers.StepProblem(
        loss_and_grad=lambda x, rows: (np.sum(x * x, axis=1), 2 * x), n_evaluations=lambda: 0, n_rows=2, n_params=1
    )


def test_run_stops_by_the_gradient_rule():
    """Fixed step 0.1 on x^2 multiplies the gradient by 0.8 per step: ||g_t|| = 0.8^t ||g_0||,
    so gtol = 0.5 stops after 4 steps (0.8^4 = 0.41), with the values in the reason."""
    solver = solvers.ArmijoSolver(initial_step=0.1, grow=1.0)
    res = solver.run(_quadratic(), np.ones((2, 1)), 10, gtol=0.5)
    assert res.status == "converged" and res.iterations == 4
    assert res.gradient_norm == pytest.approx(0.8**4 * np.sqrt(8.0))
    assert res.reason == f"gradient norm {res.gradient_norm:.3g} <= gtol=0.5 x initial {np.sqrt(8.0):.3g}"
    res = solver.run(_quadratic(), np.ones((2, 1)), 10, tol=0.4)
    assert res.reason == "relative decrease 0.36 <= tol=0.4"
    with pytest.raises(SolverOptionError, match="armijo: gtol must be a finite number >= 0"):
        solver.run(_quadratic(), np.ones((2, 1)), 10, gtol=-1.0)


def test_stalled_run_says_so():
    problem = solvers.StepProblem(loss_and_grad=lambda x, rows: (np.ones(len(rows)), np.ones_like(x)),
                                  n_evaluations=lambda: 0, n_rows=1, n_params=1)
    res = solvers.ArmijoSolver(max_backtracks=2).run(problem, np.zeros((1, 1)), 5)
    assert res.status == "stalled" and res.reason == "stalled: no row could decrease its objective"


def test_optimality_measures():
    """Unconstrained: the gradient; nonneg: components at the bound pointing outwards dropped;
    sparse: the minimum-norm subgradient of f + alpha ||x||_1."""
    x = np.array([[0.0, 1.0, 0.0], [2.0, 0.0, -1.0]])
    g = np.array([[1.0, -2.0, -3.0], [0.5, 0.05, 0.2]])
    np.testing.assert_allclose(solvers.get_solver("armijo").optimality(x, g), np.linalg.norm(g, axis=1))
    np.testing.assert_allclose(solvers.get_solver("armijo-nonneg").optimality(np.abs(x), g),
                               [np.hypot(2.0, 3.0), np.linalg.norm([0.5, 0.0, 0.2])])
    sparse = [n for n in solvers.available_solvers() if n.endswith("-sparse")]
    if sparse:
        solver = solvers.get_solver(sparse[0], alpha=0.1)
        # row 0: x=0 with |g| > alpha -> g shrunk by alpha; x=1 -> g + alpha; row 1: |0.05| < alpha at 0 -> 0
        expected = [np.linalg.norm([0.9, -1.9, -2.9]), np.linalg.norm([0.6, 0.0, 0.1])]
        np.testing.assert_allclose(solver.optimality(x, g), expected)


def test_row_norms_neither_underflow_nor_overflow_needlessly():
    from solvers._base import row_norms

    a = np.array([[3e-200, 4e-200], [3e200, 4e200], [0.0, 0.0], [np.inf, 1.0], [3.0, -4.0]])
    np.testing.assert_allclose(row_norms(a), [5e-200, 5e200, 0.0, np.inf, 5.0], rtol=1e-15)


def test_gradient_rule_is_scale_invariant_and_skipped_without_a_gradient():
    """x^2 scaled by 1e-200: squared gradients underflow, the rule must not see zeros. A
    solver whose state has no ``grad`` stops by the other rules only."""
    for scale in (1.0, 1e-200, 1e150):
        problem = solvers.StepProblem(loss_and_grad=lambda x, rows, c=scale: (c * np.sum(x * x, axis=1), 2 * c * x),
                                      n_evaluations=lambda: 0, n_rows=2, n_params=1)
        res = solvers.ArmijoSolver(initial_step=0.1 / scale, grow=1.0, max_step=1e300).run(problem, np.ones((2, 1)), 10, gtol=0.5)
        assert res.iterations == 4 and res.status == "converged"

    class NoGradient(solvers.ArmijoSolver):
        def gradient(self, state):
            return None

    res = NoGradient(initial_step=0.1, grow=1.0).run(_quadratic(), np.ones((2, 1)), 10, gtol=0.99)
    assert res.status == "max_iter" and np.isnan(res.gradient_norm)



def test_saturation_rule():
    """0 <= f_{k-1} - f_k <= stol (f_0 - f_k): a step's decrease against the progress made."""
    assert solvers.has_saturated(1.0, 1e-5, 0.0, 1e-5)  # boundary: <= stol x progress
    assert not solvers.has_saturated(1.0, 1.1e-5, 0.0, 1e-5)
    # a geometric fall toward 0 saturates although its relative decrease stays 0.5 per step
    f = 0.5 ** np.arange(40)
    first = next(k for k in range(1, 40) if solvers.has_saturated(f[0], f[k - 1], f[k], 1e-4))
    assert f[first - 1] - f[first] <= 1e-4 * (f[0] - f[first]) < f[first - 2] - f[first - 1]
    assert f[first] <= 1e-4 * f[0] and not any(solvers.has_converged(f[k - 1], f[k], 1e-4) for k in range(1, 40))
    # invariant to a constant added to the objective and to its scale
    assert solvers.has_saturated(7.0 + 3 * f[0], 7.0 + 3 * f[first - 1], 7.0 + 3 * f[first], 1e-4)
    assert not solvers.has_saturated(7.0 + 3 * f[0], 7.0 + 3 * f[first - 2], 7.0 + 3 * f[first - 1], 1e-4)
    # stol = 0: only an objective that stayed equal; a rise never stops
    assert solvers.has_saturated(1.0, 0.5, 0.5, 0.0) and not solvers.has_saturated(1.0, 0.5, 0.5 - 1e-12, 0.0)
    assert not solvers.has_saturated(1.0, 0.5, 0.6, 1.0)
    # negative objectives
    assert solvers.has_saturated(-1.0, -3.0, -3.0 - 1e-6, 1e-5) and not solvers.has_saturated(-1.0, -3.0, -3.1, 1e-3)


@pytest.mark.parametrize("args, fragment", [((np.nan, 1.0, 0.5, 0.1), "start must be a finite number"),
                                            ((1.0, np.inf, 0.5, 0.1), "prev must be a finite number"),
                                            ((1.0, 1.0, "0.5", 0.1), "current must be a finite number"),
                                            ((1.0, 1.0, 0.5, -0.1), "stol must be a finite number >= 0"),
                                            ((1.0, 1.0, 0.5, np.nan), "stol must be a finite number >= 0")])
def test_saturation_rule_rejects_bad_values(args, fragment):
    with pytest.raises(SolverOptionError, match=f"saturation rule: {fragment}"):
        solvers.has_saturated(*args)


def test_run_stops_by_the_saturation_rule():
    """Fixed step 0.1 on x^2: f_k = 0.64^k f_0, a relative decrease of 0.36 per step; the step's
    decrease 0.36 f_{k-1} is at most stol (f_0 - f_k) from the first k with
    0.36 x 0.64^(k-1) <= stol (1 - 0.64^k)."""
    solver = solvers.ArmijoSolver(initial_step=0.1, grow=1.0)
    stol = 1e-3
    k = next(k for k in range(1, 100) if 0.36 * 0.64 ** (k - 1) <= stol * (1 - 0.64**k))
    res = solver.run(_quadratic(), np.ones((2, 1)), 100, tol=0.3, stol=stol)
    assert res.status == "converged" and res.iterations == k
    h = res.loss_history
    assert res.reason == (f"saturated: decrease {h[-2] - h[-1]:.3g} <= stol=0.001 x decrease {h[0] - h[-1]:.3g} "
                          f"since the start")
    assert solver.run(_quadratic(), np.ones((2, 1)), 100, tol=0.3).status == "max_iter"  # stol=0: off
    with pytest.raises(SolverOptionError, match="armijo: stol must be a finite number >= 0"):
        solver.run(_quadratic(), np.ones((2, 1)), 10, stol=-1.0)

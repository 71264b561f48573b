"""What every step solver shares: the problem it sees, its result type, and the outer loop.

A step solver never sees an MDP. It sees a :class:`StepProblem`: a smooth objective that is a
sum of independent rows (tasks), over parameters ``x`` of shape (n, p), given as callables.
Solvers follow the init/update pattern (as in jaxopt) so Armijo descent and Gauss-Newton steps
share one outer loop, :meth:`StepSolver.run`.
"""

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np

from factirl_opt.exceptions import ValidationError

__all__ = ["StepProblem", "SolverResult", "StepSolver"]


@dataclass(frozen=True)
class StepProblem:
    """A row-separable problem ``min_x sum_i f_i(x_i)`` as a step solver sees it.

    Every callable takes ``(x_rows, rows)``: the parameters of some rows, shape (r, p), and
    their row indices, shape (r,) (rows are tasks: the indices let the objective warm-start
    and pick each task's data).

    Attributes
    ----------
    loss_and_grad : callable
        ``(x_rows, rows) -> (loss (r,), grad (r, p))``.
    residual_jacobian : callable or None
        ``(x_rows, rows) -> (loss (r,), residual (r, m), jacobian (r, m, p))`` with
        ``loss = ||residual||^2`` per row; None when the problem has no least-squares form.
    n_evaluations : callable
        ``() -> int``, the objective's count of (batched) Q* evaluations so far.
    n_rows, n_params : int
        ``n`` and ``p``.
    """

    loss_and_grad: Callable
    n_evaluations: Callable[[], int]
    n_rows: int
    n_params: int
    residual_jacobian: Optional[Callable] = None


@dataclass
class SolverResult:
    """The one result type of every step solver.

    Attributes
    ----------
    coefficients : ndarray, shape (n, p)
        The new parameters (coefficients ``H`` for an H-step).
    status : str
        ``"converged"`` (relative decrease below ``tol``), ``"max_iter"``, or ``"stalled"``
        (no row could make progress).
    iterations : int
        Iterations (steps) taken.
    solve_time : float
        Wall time of the run, seconds.
    loss : ndarray, shape (n,)
        Final objective of each row (including any penalty the solver adds).
    n_evaluations : int
        Q* evaluations this run used.
    loss_history : list of float
        Total objective before the first step and after each step.
    state : object
        Solver state to warm-start the next run (step sizes, damping).
    """

    coefficients: np.ndarray
    status: str
    iterations: int
    solve_time: float
    loss: np.ndarray
    n_evaluations: int
    loss_history: list = field(default_factory=list)
    state: Any = None


class StepSolver:
    """Base class of step solvers: subclasses define ``init_state`` and ``update``.

    Class attributes
    ----------------
    name : str
        Registry name.
    needs_jacobian : bool
        Whether the solver calls ``problem.residual_jacobian``.
    constraint : str
        ``"none"``, ``"nonneg"`` (:meth:`project` keeps ``x >= 0``) or ``"sparse"``
        (:meth:`penalty` adds an L1 term); learners use it to keep the constraint in their
        initialisation.
    """

    name = "base"
    needs_jacobian = False
    constraint = "none"

    def project(self, x):
        """Map parameters to the solver's feasible set (identity when unconstrained)."""
        return np.asarray(x, dtype=np.float64)

    def penalty(self, x):
        """Per-row penalty the solver adds to the loss (zero when there is none), shape (n,)."""
        return np.zeros(np.shape(x)[0])

    def for_alternating(self):
        """The solver to use as one block of an alternating scheme (FactIRL's H-step in fit).

        In alternating minimisation the sub-problem over H need not (and, while D is still
        poor, should not) be solved accurately. The default is the solver itself; a solver
        whose steps solve their sub-problem aggressively returns a more conservative copy.
        """
        return self

    def init_state(self, problem, x, previous=None):  # pragma: no cover - interface
        raise NotImplementedError

    def update(self, problem, x, state):  # pragma: no cover - interface
        """One step for every row; returns ``(x_new, state, progressed)``."""
        raise NotImplementedError

    def run(self, problem, x0, max_iter, state=None, tol=0.0, callback=None):
        """Take up to ``max_iter`` steps from ``x0``.

        Parameters
        ----------
        problem : StepProblem
        x0 : ndarray, shape (n, p)
        max_iter : int
        state : object, optional
            The ``state`` of a previous :class:`SolverResult` (step sizes are carried over;
            losses and gradients are recomputed, since the problem may have changed).
        tol : float
            Stop when the relative decrease of the total objective over a step is below tol.
        callback : callable, optional
            Called as ``callback(iteration, total_objective)`` after each step.

        Returns
        -------
        SolverResult
        """
        x = self.project(np.array(x0, dtype=np.float64))
        if x.shape != (problem.n_rows, problem.n_params):
            raise ValidationError(f"x0 must have shape ({problem.n_rows}, {problem.n_params}); got {x.shape}")
        if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 0:
            raise ValidationError(f"max_iter must be an integer >= 0; got {max_iter!r}")
        t0 = time.perf_counter()
        ev0 = problem.n_evaluations()
        state = self.init_state(problem, x, previous=state)
        history = [float(np.sum(state.loss))]
        status = "max_iter"
        it = 0
        for it in range(1, max_iter + 1):
            x, state, progressed = self.update(problem, x, state)
            total = float(np.sum(state.loss))
            history.append(total)
            if callback is not None:
                callback(it, total)
            if not progressed:
                status = "stalled"
                break
            prev = history[-2]
            if prev - total <= tol * max(abs(prev), np.finfo(float).tiny):
                status = "converged"
                break
        return SolverResult(
            coefficients=x,
            status=status,
            iterations=it,
            solve_time=time.perf_counter() - t0,
            loss=state.loss.copy(),
            n_evaluations=problem.n_evaluations() - ev0,
            loss_history=history,
            state=state,
        )

"""Gradient descent with Armijo backtracking and step-size adaptation (the paper's descent; docs/maths.md §5).

Section 3.2: "the learner performs a fixed amount of gradient descent on each sub-problem
(...) with Armijo step size adaptation". Each row (task) keeps its own step size: a step
accepted at the first try doubles it for the next iteration, a step that needed backtracking
keeps the reduced size. With ``nonneg=True`` the step is projected onto ``x >= 0`` (projected
gradient with the Armijo condition on the actual displacement).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._base import StepProblem, StepSolver
from ._validation import boolean, check_evaluation, integer, number, option, validate_fields

__all__ = ["ArmijoSolver", "ArmijoState"]


@dataclass
class ArmijoState:
    loss: np.ndarray  # (n,) current objective per row
    grad: np.ndarray  # (n, p) current gradient per row
    step: np.ndarray  # (n,) step size per row


@dataclass
class ArmijoSolver(StepSolver):
    """Armijo gradient descent, batched over rows with one step size per row.

    Parameters
    ----------
    initial_step : float, default=1.0
        Step size of a row that has none yet, > 0.
    shrink : float, default=0.5
        Backtracking factor, in (0, 1).
    grow : float, default=2.0
        Growth after a step accepted at the first try, >= 1.
    c : float, default=1e-4
        Sufficient-decrease constant of the Armijo condition, in (0, 1).
    max_backtracks : int, default=30
        Trials per iteration before a row is declared stalled for this iteration, >= 1.
    max_step : float, default=1e8
        Upper bound on a step size, > 0.
    nonneg : bool, default=False
        Project onto ``x >= 0`` (projected gradient).

    Raises
    ------
    SolverOptionError
        When an option has the wrong type or value (every option is checked; numbers must be
        finite, ``bool`` is not a number, ``max_backtracks`` must be an ``int``).

    Notes
    -----
    A trial point where the objective or its gradient is not finite is never accepted: it
    counts as a failed Armijo test (the step shrinks).
    """

    initial_step: float = option(1.0, number(low=0.0, low_open=True))
    shrink: float = option(0.5, number(0.0, 1.0, low_open=True, high_open=True))
    grow: float = option(2.0, number(low=1.0))
    c: float = option(1e-4, number(0.0, 1.0, low_open=True, high_open=True))
    max_backtracks: int = option(30, integer(low=1))
    max_step: float = option(1e8, number(low=0.0, low_open=True))
    nonneg: bool = option(False, boolean())

    name = "armijo"

    def __post_init__(self) -> None:
        validate_fields(self, "armijo-nonneg" if self.nonneg is True else "armijo")
        if self.nonneg:
            self.name = "armijo-nonneg"
            self.constraint = "nonneg"

    def project(self, x: ArrayLike) -> NDArray[np.float64]:
        x = np.asarray(x, dtype=np.float64)
        return np.maximum(x, 0.0) if self.nonneg else x

    def _evaluate(self, problem, x, rows, start=False):
        loss, grad = problem.loss_and_grad(x, rows)
        loss, (grad,), finite = check_evaluation(self.name, "loss_and_grad", rows, loss, grad, shapes=[(problem.n_params,)], start=start)
        return loss, grad, finite

    def init_state(self, problem: StepProblem, x: NDArray[np.float64], previous: Any = None) -> ArmijoState:
        loss, grad, _ = self._evaluate(problem, x, np.arange(problem.n_rows), start=True)
        previous_step: Any = getattr(previous, "step", None)
        if previous is not None and np.shape(previous_step) == (problem.n_rows,):
            step = previous_step.copy()
        else:
            step = np.full(problem.n_rows, float(self.initial_step))
        return ArmijoState(loss=loss, grad=grad, step=step)

    def update(self, problem: StepProblem, x: NDArray[np.float64], state: ArmijoState) -> tuple[NDArray[np.float64], ArmijoState, bool]:
        x_new, state, progressed = self.step_rows(problem, x, state)
        return x_new, state, bool(progressed.any())

    def step_rows(self, problem: StepProblem, x: NDArray[np.float64], state: ArmijoState) -> tuple[NDArray[np.float64], ArmijoState, NDArray[np.bool_]]:
        """One step per row (each row's backtracking is its own); ``progressed``: the rows accepted."""
        x_new = x.copy()
        loss, grad, step = state.loss.copy(), state.grad.copy(), state.step.copy()
        rows = np.arange(problem.n_rows)
        t = step.copy()
        for b in range(int(self.max_backtracks)):
            trial = self.project(x[rows] - t[rows, None] * grad[rows])
            lt, gt, finite = self._evaluate(problem, trial, rows)
            decrease = np.sum(grad[rows] * (x[rows] - trial), axis=1)
            with np.errstate(invalid="ignore"):
                ok = finite & (lt <= loss[rows] - self.c * decrease)
            acc = rows[ok]
            x_new[acc] = trial[ok]
            loss[acc], grad[acc] = lt[ok], gt[ok]
            step[acc] = np.minimum(t[acc] * self.grow, self.max_step) if b == 0 else t[acc]
            rows = rows[~ok]
            if rows.size == 0:
                break
            t[rows] *= self.shrink
        step[rows] = t[rows]  # rows that never succeeded restart from a small step
        progressed = np.ones(problem.n_rows, dtype=bool)
        progressed[rows] = False
        return x_new, ArmijoState(loss=loss, grad=grad, step=step), progressed

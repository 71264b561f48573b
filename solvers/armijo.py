"""Gradient descent with Armijo backtracking and step-size adaptation (the paper's descent).

Section 3.2: "the learner performs a fixed amount of gradient descent on each sub-problem
(...) with Armijo step size adaptation". Each row (task) keeps its own step size: a step
accepted at the first try doubles it for the next iteration, a step that needed backtracking
keeps the reduced size. With ``nonneg=True`` the step is projected onto ``x >= 0`` (projected
gradient with the Armijo condition on the actual displacement).
"""

from dataclasses import dataclass

import numpy as np

from factirl_opt.exceptions import ValidationError

from ._base import StepSolver

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
        Step size of a row that has none yet.
    shrink : float, default=0.5
        Backtracking factor, in (0, 1).
    grow : float, default=2.0
        Growth after a step accepted at the first try, >= 1.
    c : float, default=1e-4
        Sufficient-decrease constant of the Armijo condition, in (0, 1).
    max_backtracks : int, default=30
        Trials per iteration before a row is declared stalled for this iteration.
    max_step : float, default=1e8
        Upper bound on a step size.
    nonneg : bool, default=False
        Project onto ``x >= 0`` (projected gradient).
    """

    initial_step: float = 1.0
    shrink: float = 0.5
    grow: float = 2.0
    c: float = 1e-4
    max_backtracks: int = 30
    max_step: float = 1e8
    nonneg: bool = False

    name = "armijo"

    def __post_init__(self):
        if not (0 < self.shrink < 1):
            raise ValidationError(f"shrink must be in (0, 1); got {self.shrink!r}")
        if not (self.grow >= 1):
            raise ValidationError(f"grow must be >= 1; got {self.grow!r}")
        if not (0 < self.c < 1):
            raise ValidationError(f"c must be in (0, 1); got {self.c!r}")
        if not (self.initial_step > 0 and np.isfinite(self.initial_step)):
            raise ValidationError(f"initial_step must be a finite number > 0; got {self.initial_step!r}")
        if int(self.max_backtracks) < 1:
            raise ValidationError(f"max_backtracks must be >= 1; got {self.max_backtracks!r}")
        if self.nonneg:
            self.name = "armijo-nonneg"
            self.constraint = "nonneg"

    def project(self, x):
        x = np.asarray(x, dtype=np.float64)
        return np.maximum(x, 0.0) if self.nonneg else x

    def init_state(self, problem, x, previous=None):
        loss, grad = problem.loss_and_grad(x, np.arange(problem.n_rows))
        if previous is not None and np.shape(previous.step) == (problem.n_rows,):
            step = previous.step.copy()
        else:
            step = np.full(problem.n_rows, float(self.initial_step))
        return ArmijoState(loss=np.asarray(loss, dtype=float), grad=np.asarray(grad, dtype=float), step=step)

    def update(self, problem, x, state):
        x_new = x.copy()
        loss, grad, step = state.loss.copy(), state.grad.copy(), state.step.copy()
        rows = np.arange(problem.n_rows)
        t = step.copy()
        for b in range(int(self.max_backtracks)):
            trial = self.project(x[rows] - t[rows, None] * grad[rows])
            lt, gt = problem.loss_and_grad(trial, rows)
            decrease = np.sum(grad[rows] * (x[rows] - trial), axis=1)
            ok = lt <= loss[rows] - self.c * decrease
            acc = rows[ok]
            x_new[acc] = trial[ok]
            loss[acc], grad[acc] = lt[ok], gt[ok]
            step[acc] = np.minimum(t[acc] * self.grow, self.max_step) if b == 0 else t[acc]
            rows = rows[~ok]
            if rows.size == 0:
                break
            t[rows] *= self.shrink
        step[rows] = t[rows]  # rows that never succeeded restart from a small step
        progressed = rows.size < problem.n_rows
        return x_new, ArmijoState(loss=loss, grad=grad, step=step), progressed

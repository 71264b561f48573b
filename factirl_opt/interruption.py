"""Interrupted fits keep the best point they have seen.

A Ctrl-C (``KeyboardInterrupt``) raised anywhere inside a fit (by a real SIGINT, a callback,
the objective) must neither lose the work done nor be swallowed. The fitting functions catch
it, and raise :class:`FitInterrupted` instead: a ``KeyboardInterrupt`` (so scripts stop as
before) that carries the best point seen as the function's usual result, with status
``"interrupted"``. The estimators store that result as their fitted state, warn with
:class:`InterruptedFitWarning` and let the exception propagate.

A fit whose parallel workers are lost for good (:class:`~factirl_opt.exceptions.WorkersLost`,
an ordinary library error, not a ``KeyboardInterrupt``) ends the same way: the fitting
functions catch every exception of :data:`INTERRUPTIONS`, the estimators keep the best point
and raise the ``WorkersLost`` itself again (:func:`raise_interrupted`), which a caller's
``except Exception`` catches.

For a row-separable step problem (a flat fit, an H-step with the dictionary fixed, transfer)
the tasks are independent, so the best point is taken per task: :class:`BestRows` records,
for every task, the lowest objective (with the solver's penalty) among the points at which
that task was evaluated, and those parameters.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any, Callable, NoReturn

import numpy as np

from solvers import Linearization, SolverResult, StepProblem, StepSolver

from .exceptions import FactIRLError, FitInterrupted, InterruptedFitWarning, WorkersLost

__all__ = ["BestRows", "run_keeping_best", "warn_interrupted", "raise_interrupted", "loss_phrase", "INTERRUPTIONS"]

#: the ``status`` (and ``stop_reason_``) of a fit stopped by a KeyboardInterrupt
INTERRUPTED = "interrupted"
#: what stops a fit keeping its best point (``except INTERRUPTIONS`` in the fitting functions): Ctrl-C,
#: and the library's error for parallel workers lost for good
INTERRUPTIONS: tuple[type[BaseException], ...] = (KeyboardInterrupt, WorkersLost)


def warn_interrupted(what: str, detail: str, cause: BaseException | None = None) -> None:
    """Issue the :class:`InterruptedFitWarning` of an estimator whose ``what`` was interrupted
    (by ``cause``: a KeyboardInterrupt, or a library error such as lost workers)."""
    while isinstance(cause, FitInterrupted):
        cause = cause.__cause__
    if isinstance(cause, FactIRLError):
        warnings.warn(f"{what} was stopped by an error ({cause}): {detail}. The error is raised again.",
                      InterruptedFitWarning, stacklevel=3)
        return
    warnings.warn(f"{what} was interrupted: {detail}. The KeyboardInterrupt is raised again.",
                  InterruptedFitWarning, stacklevel=3)


def loss_phrase(loss: np.ndarray) -> str:
    """How an interrupted fit's kept loss (per task, NaN where never evaluated) reads in its warning:
    the total, or plainly that it (or some tasks' part) was not evaluated."""
    loss = np.asarray(loss, dtype=np.float64)
    seen = np.isfinite(loss)
    if seen.all():
        return f"total loss {np.sum(loss):.6g}"
    if not seen.any():
        return "its loss was not evaluated before the interrupt: loss_ is NaN"
    return (f"total loss {np.sum(loss[seen]):.6g} over the {int(seen.sum())} tasks evaluated; loss_ is NaN for the "
            f"{int((~seen).sum())} tasks never evaluated")


def raise_interrupted(exc: FitInterrupted, what: str) -> NoReturn:
    """Raise again, from an estimator that kept ``exc.result``, what stopped its fit: the library
    error that did (:class:`~factirl_opt.exceptions.WorkersLost`), else a :class:`FitInterrupted`
    for ``what`` chained to the interrupt."""
    cause = exc.__cause__
    while isinstance(cause, FitInterrupted):  # an inner step's interruption, wrapped again
        cause = cause.__cause__
    if isinstance(cause, FactIRLError):
        raise cause
    raise FitInterrupted(exc.result, what) from cause


class _BestPoints:
    """The record of :class:`BestRows`: per row the best point seen, and the first full evaluation's
    total. It holds no reference to the problem, so the wrapped problem's functions (which refer
    to it) and the problem form no reference cycle: a finished fit's objective, and the model and
    planner caches it holds, are freed when the fit's last reference goes, not at the next full
    garbage collection."""

    def __init__(self, penalty: Callable, x0: np.ndarray) -> None:
        self.penalty = penalty
        # one tuple, replaced in one assignment: an interrupt never sees it half updated
        self.best = (x0, np.full(x0.shape[0], np.inf), np.full(x0.shape[0], np.nan))
        self.start_total: float | None = None

    def record(self, x_rows: np.ndarray, rows: np.ndarray, loss: np.ndarray) -> None:
        x_rows, rows = np.asarray(x_rows, dtype=np.float64), np.asarray(rows)
        with np.errstate(invalid="ignore", over="ignore"):
            score = np.asarray(loss, dtype=np.float64) + self.penalty(x_rows)
        X, best, plain = self.best
        if self.start_total is None and rows.size == X.shape[0] and np.all(np.isfinite(score)):
            self.start_total = float(np.sum(score))
        better = np.isfinite(score) & (score < best[rows])
        if better.any():
            X, best, plain = X.copy(), best.copy(), plain.copy()
            X[rows[better]], best[rows[better]] = x_rows[better], score[better]
            plain[rows[better]] = np.asarray(loss, dtype=np.float64)[better]
            self.best = (X, best, plain)


class BestRows:
    """Per-row best point of a row-separable :class:`solvers.StepProblem` over its evaluations.

    Parameters
    ----------
    problem : StepProblem
    solver : StepSolver
        Its ``penalty`` is added to each row's loss (the objective the solver minimises).
    x0 : ndarray, shape (n, p)
        Kept for rows never evaluated (their loss is NaN).

    Attributes
    ----------
    problem : StepProblem
        The same problem, recording every evaluation of ``loss_and_grad``,
        ``residual_jacobian`` and ``linearize`` (the values are passed on unchanged).
    start_total : float or None
        The objective's total at the first evaluation of every row (None before it).
    """

    def __init__(self, problem: StepProblem, solver: StepSolver, x0: np.ndarray) -> None:
        self._points = _BestPoints(solver.penalty, np.array(x0, dtype=np.float64))
        self.problem = dataclasses.replace(
            problem,
            loss_and_grad=_recording(self._points, problem.loss_and_grad, lambda out: out[0]),
            residual_jacobian=None if problem.residual_jacobian is None
            else _recording(self._points, problem.residual_jacobian, lambda out: out[0]),
            linearize=None if problem.linearize is None
            else _recording(self._points, problem.linearize, _linearization_loss),
        )

    @property
    def start_total(self) -> float | None:
        return self._points.start_total

    def record(self, x_rows: np.ndarray, rows: np.ndarray, loss: np.ndarray) -> None:
        """Keep ``x_rows`` for the rows whose objective ``loss + penalty`` is their lowest yet."""
        self._points.record(x_rows, rows, loss)

    def best(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(x, objective, loss)``: per row the best parameters (n, p), their objective with the
        penalty (n,) and without it (n,); NaN objective for rows never evaluated."""
        X, best, plain = self._points.best
        return X.copy(), np.where(np.isfinite(best), best, np.nan), plain.copy()


def _recording(points: _BestPoints, func: Callable, loss_of: Callable) -> Callable:
    """``func``, recording each evaluation's loss in ``points`` (which does not refer back to it)."""

    def recorded(x_rows, rows):
        out = func(x_rows, rows)
        points.record(x_rows, rows, loss_of(out))
        return out

    return recorded


def _linearization_loss(lin: Linearization) -> np.ndarray:
    return lin.loss


def run_keeping_best(solver: StepSolver, problem: StepProblem, x0: np.ndarray, max_iter: int, what: str,
                     callback: Callable | None = None, **options: Any) -> SolverResult:
    """``solver.run(problem, x0, max_iter, callback=..., **options)``, keeping the best point on Ctrl-C.

    Returns the solver's result unchanged when the run ends. A KeyboardInterrupt raised
    during the run (in an evaluation, in ``callback``, or by a signal), or a
    :class:`~factirl_opt.exceptions.WorkersLost` (:data:`INTERRUPTIONS`), becomes a
    :class:`FitInterrupted` whose ``result`` is a :class:`solvers.SolverResult` at the
    per-row best point seen (:class:`BestRows`), with ``status == "interrupted"``,
    ``loss_history`` the start and the iterations completed, and ``loss`` including the
    solver's penalty, as in a finished run.
    """
    tracker = BestRows(problem, solver, x0)
    history: list = []
    ev0 = problem.n_evaluations()

    def report(iteration, total):
        history.append(total)
        if callback is not None:
            callback(iteration, total)

    try:
        return solver.run(tracker.problem, x0, max_iter, callback=report, **options)
    except INTERRUPTIONS as exc:
        x, loss, _ = tracker.best()
        start: list = [] if tracker.start_total is None else [tracker.start_total]
        result = SolverResult(coefficients=x, status=INTERRUPTED, iterations=len(history), solve_time=float("nan"),
                              loss=loss, n_evaluations=int(problem.n_evaluations() - ev0), loss_history=start + history,
                              reason=INTERRUPTED)
        raise FitInterrupted(result, what) from exc

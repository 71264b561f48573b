"""Separable runs: every row stops by its own rules and leaves the batch (docs/maths.md §5).

A :class:`~solvers.StepProblem` is a sum of independent rows, ``min_x sum_i f_i(x_i)``. A run
of :meth:`solvers.StepSolver.run` stops when the rules of :mod:`solvers.stopping` hold for the
*total* objective, so a row's result depends on which other rows share the run (a row whose
own objective stopped decreasing long ago keeps stepping while another row still moves, and a
row still moving is stopped with the others). A separable run (``run(..., separable=True)``)
applies the same three rules, relative decrease (``tol``), gradient norm relative to the
start (``gtol``) and saturation (``stol``: the decrease over a step relative to the decrease
since the start), to every row's own objective and optimality measure, and a row that
could make no progress is stalled on its own. A row that stopped leaves the batch: the later steps
evaluate only the rows still running (:meth:`StepSolver.take_rows`), so the evaluations it
would have used are saved, and every row's iterate is the one of a run on that row alone
(up to the rounding of batched arithmetic).

The run goes in rounds, :meth:`StepSolver.trial_rows`: one trial of every row still running
per batched evaluation, in which a row's trial points do not depend on the other rows. A
Levenberg-Marquardt row whose trial was rejected retries in the next round, beside the other
rows' next steps (its step is not finished: no rule applies to it yet), so a retry costs no
evaluation of its own and a run costs about as many evaluations as its longest row has trials;
the other solvers finish a step every round (:meth:`StepSolver.step_rows`). A row's
iterations are the steps it finished; the run's history has one entry per iteration, the
most steps a row has finished, updated while the other rows catch up.

A row whose objective tends to 0 (a reward that matches its demonstrations exactly, the
Boltzmann policy saturating) is stopped by the saturation or the gradient rule, not by the
relative decrease (:mod:`solvers.stopping`): give ``stol > 0`` or ``gtol > 0``.
"""

from __future__ import annotations

import dataclasses
import time
from collections import Counter
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
from numpy.typing import NDArray

from .exceptions import SolverError

if TYPE_CHECKING:  # pragma: no cover
    from ._base import StepProblem, StepSolver

__all__ = ["run_separable", "restrict_rows", "row_rules"]

_TINY = np.finfo(np.float64).tiny

#: the statuses of a row in a separable run
ROW_STATUSES = ("converged", "max_iter", "stalled")


def restrict_rows(problem: StepProblem, rows: NDArray[np.intp], counts: NDArray[np.intp] | None = None) -> StepProblem:
    """The problem of rows ``rows`` of ``problem`` (local row ``j`` is row ``rows[j]``).

    Parameters
    ----------
    problem : StepProblem
    rows : ndarray of int, shape (r,)
        Distinct rows of ``problem``.
    counts : ndarray of int, shape (n,), optional
        Incremented at the rows of ``problem`` each callable is called with.
    """
    rows = np.asarray(rows, dtype=np.intp)

    def wrap(func: Callable) -> Callable:
        def restricted(x_rows, local):
            where = rows[np.asarray(local, dtype=np.intp)]
            if counts is not None:
                counts[where] += 1
            return func(x_rows, where)

        return restricted

    return dataclasses.replace(
        problem, loss_and_grad=wrap(problem.loss_and_grad),
        residual_jacobian=None if problem.residual_jacobian is None else wrap(problem.residual_jacobian),
        linearize=None if problem.linearize is None else wrap(problem.linearize),
        hessian=None if problem.hessian is None else wrap(problem.hessian), n_rows=int(rows.size))


def row_rules(prev: NDArray[np.float64], current: NDArray[np.float64], gnorm: NDArray[np.float64],
              g0: NDArray[np.float64], progressed: NDArray[np.bool_], tol: float,
              gtol: float, start: NDArray[np.float64] | None = None, stol: float = 0.0) -> NDArray[np.str_]:
    """The rule that stops each row after a step: ``"stalled"``, ``"decrease"``, ``"saturation"``,
    ``"gradient"`` or ``""``.

    The rules of :func:`solvers.stopping.has_converged`, :func:`solvers.stopping.has_saturated`
    and :func:`solvers.stopping.gradient_converged`, row by row, in the order of a run's own
    test (a row that made no progress is stalled first); the arithmetic is theirs, so a one-row
    problem stops where :meth:`StepSolver.run` stops.

    Parameters
    ----------
    prev, current : ndarray, shape (r,)
        Each row's objective before and after the step (finite).
    gnorm, g0 : ndarray, shape (r,)
        Each row's optimality measure now and at the start (inf when it overflowed, NaN when
        the solver's state holds no gradient: the gradient rule is then not applied).
    progressed : ndarray of bool, shape (r,)
    tol, gtol : float
    start : ndarray, shape (r,), optional
        Each row's objective at the start of the run; None: the saturation rule is not applied.
    stol : float, default=0.0
    """
    with np.errstate(over="ignore", invalid="ignore"):
        drop = prev - current
        decrease = (0.0 <= drop) & (drop <= tol * np.maximum(np.abs(prev), _TINY))
        gradient = np.isfinite(gnorm) & np.isfinite(g0) & (gnorm <= gtol * g0)
        saturation = (np.zeros(prev.shape, dtype=bool) if start is None
                      else (0.0 <= drop) & (drop <= stol * (start - current)))
    out = np.full(prev.shape, "", dtype=object)
    out[gradient] = "gradient"
    out[saturation] = "saturation"
    out[decrease] = "decrease"
    out[~np.asarray(progressed, dtype=bool)] = "stalled"
    return out


def _row_optimality(solver: StepSolver, x: NDArray[np.float64], state: Any) -> NDArray[np.float64]:
    """Every row's optimality measure (inf on overflow; NaN when the state holds no gradient)."""
    grad = solver.gradient(state)
    if grad is None:
        return np.full(x.shape[0], np.nan)
    with np.errstate(over="ignore", invalid="ignore"):
        g = np.asarray(solver.optimality(x, grad), dtype=np.float64)
    return np.where(np.isfinite(g), g, np.inf)


def _total(name: str, loss: NDArray[np.float64]) -> float:
    total = float(np.sum(loss))
    if not np.isfinite(total):
        raise SolverError(f"{name}: the total objective is not finite ({total}); the solver must reject such points")
    return total


def _summary(status: NDArray[np.str_], rule: NDArray[np.str_], max_iter: int, tol: float, gtol: float,
             stol: float) -> tuple[str, str]:
    """The run's status and reason from the rows'."""
    n = status.size
    counts = Counter(rule[status == "converged"])
    parts = []
    if counts["decrease"]:
        parts.append(f"{counts['decrease']} by relative decrease <= tol={tol:g}")
    if counts["saturation"]:
        parts.append(f"{counts['saturation']} by saturation (decrease <= stol={stol:g} x decrease since the start)")
    if counts["gradient"]:
        parts.append(f"{counts['gradient']} by gradient norm <= gtol={gtol:g} x initial")
    stalled = np.flatnonzero(status == "stalled")
    late = np.flatnonzero(status == "max_iter")
    if stalled.size:
        parts.append(f"{stalled.size} stalled (no decrease possible): rows {_rows(stalled)}")
    if late.size:
        parts.append(f"{late.size} at max_iter={max_iter}: rows {_rows(late)}")
    reason = f"per row, of {n}: " + "; ".join(parts)
    if late.size:
        return "max_iter", reason
    if stalled.size:
        return "stalled", reason
    return "converged", reason


def _norm(g: NDArray[np.float64]) -> float:
    """Euclidean norm of the rows' optimality measures (inf on overflow, NaN if one is NaN),
    scaled by the largest so that tiny values do not underflow."""
    if np.any(np.isnan(g)):
        return float("nan")
    top = float(np.max(g, initial=0.0))
    if not np.isfinite(top):
        return np.inf
    if top == 0.0:
        return 0.0
    with np.errstate(over="ignore"):
        norm = top * float(np.sqrt(np.sum(np.square(g / top))))
    return norm if np.isfinite(norm) else np.inf


def _rows(rows: NDArray[np.intp], limit: int = 20) -> str:
    shown = ", ".join(str(int(i)) for i in rows[:limit])
    return f"[{shown}{', ...' if rows.size > limit else ''}]"


def _trial(solver: StepSolver, problem: StepProblem, x: NDArray[np.float64], state: Any,
           tries: NDArray[np.intp]) -> tuple[NDArray[np.float64], Any, NDArray[np.bool_], NDArray[np.bool_]]:
    """:meth:`StepSolver.trial_rows`, its arrays checked."""
    x, state, progressed, pending = solver.trial_rows(problem, x, state, tries)
    r = tries.size
    progressed, pending = np.asarray(progressed, dtype=bool), np.asarray(pending, dtype=bool)
    for name, value in (("progress", progressed), ("pending rows", pending)):
        if value.shape != (r,):
            raise SolverError(f"{solver.name}: trial_rows returned {name} of shape {value.shape}; expected ({r},)")
    return x, state, progressed, pending


def run_separable(solver: StepSolver, problem: StepProblem, x: NDArray[np.float64], max_iter: int, state: Any,
                  tol: float, callback: Callable | None, gtol: float, stol: float = 0.0) -> dict[str, Any]:
    """:meth:`StepSolver.run` with ``separable=True`` (arguments already validated; ``x`` projected).

    Returns
    -------
    dict
        The fields of the run's :class:`~solvers.SolverResult`: ``status`` ``"converged"`` when every row converged, ``"max_iter"`` when a row took
        ``max_iter`` steps without meeting a rule, else ``"stalled"``; ``reason`` counts the
        rows by rule and names the rows at ``max_iter`` and the stalled ones. ``iterations``
        is the most steps a row took; ``loss_history`` the total objective (rows that stopped
        counted at their final value); ``row_status``, ``row_iterations`` and
        ``row_evaluations`` the rows' own records.
    """
    n = problem.n_rows
    t0 = time.perf_counter()
    ev0 = problem.n_evaluations()
    counts = np.zeros(n, dtype=np.intp)
    everyone = np.arange(n)
    full = solver.init_state(restrict_rows(problem, everyone, counts), x, previous=state)
    loss = np.array(full.loss, dtype=np.float64)
    history = [_total(solver.name, loss)]
    start = loss.copy()
    g0 = _row_optimality(solver, x, full)
    status = np.full(n, "max_iter", dtype=object)
    rule = np.full(n, "", dtype=object)
    steps = np.zeros(n, dtype=np.intp)
    tries = np.zeros(n, dtype=np.intp)
    active, part = everyone, full
    sub = restrict_rows(problem, active, counts)
    x = x.copy()
    while active.size and max_iter > 0:
        xa, part, progressed, pending = _trial(solver, sub, x[active], part, tries[active])
        new = np.array(part.loss, dtype=np.float64)
        rules = row_rules(loss[active], new, _row_optimality(solver, xa, part), g0[active], progressed, tol, gtol,
                          start[active], stol)
        rules[pending] = ""  # a row retrying a rejected step has not finished its step
        x[active], loss[active] = xa, new
        tries[active] = np.where(pending, tries[active] + 1, 0)
        steps[active[~pending]] += 1
        if steps.max() == len(history):  # a row took a step further than any before: a new iteration
            history.append(_total(solver.name, loss))
            if callback is not None:
                callback(len(history) - 1, history[-1])
        elif len(history) > 1:  # rows catching up: the iteration's total, updated
            history[-1] = _total(solver.name, loss)
        done = rules != ""
        leave = done | (~pending & (steps[active] >= max_iter))
        if not leave.any():
            continue
        rule[active[done]] = rules[done]
        status[active[done]] = np.where(rules[done] == "stalled", "stalled", "converged")
        full = solver.put_rows(full, active, part)
        keep = np.flatnonzero(~leave)
        if keep.size == 0:
            active = active[keep]
            break
        part = solver.take_rows(part, keep)
        active = active[keep]
        sub = restrict_rows(problem, active, counts)
    if active.size:
        full = solver.put_rows(full, active, part)
    run_status, reason = _summary(status, rule, max_iter, tol, gtol, stol)
    g = _row_optimality(solver, x, full)
    return dict(
        coefficients=x,
        status=run_status,
        iterations=int(steps.max(initial=0)),
        solve_time=time.perf_counter() - t0,
        loss=np.array(full.loss, dtype=np.float64),
        n_evaluations=problem.n_evaluations() - ev0,
        loss_history=history,
        state=full,
        reason=reason,
        gradient_norm=_norm(g),
        row_status=status.astype(str),
        row_iterations=steps,
        row_evaluations=counts,
    )

"""Proximal Armijo descent, and the proximal map of unit-norm columns (nonnegative and/or L1-penalised).

:class:`ProximalArmijoSolver` minimises ``f(x_i) + r(x_i)`` row by row, ``f`` smooth (the
problem's ``loss_and_grad``) and ``r`` given by a proximal map and its value, both callables
(the package sees arrays and callables only)::

    z_i = prox(x_i - t_i grad f(x_i), t_i)                         (the proximal-gradient step)
    accept when  f(z_i) + r(z_i) <= f(x_i) + r(x_i) - (c / t_i) ||z_i - x_i||^2

with Armijo backtracking on the step ``t_i`` (halved on rejection, doubled after a first-try
acceptance, as :class:`~solvers.armijo.ArmijoSolver`). ``prox(v, t)`` must return a minimiser
of ``||z - v||^2 / (2 t) + r(z)`` over a closed set (the set may be nonconvex, such as a
sphere): then ``f(z) + r(z) <= f(x) + r(x) - (1 / (2 t) - L / 2) ||z - x||^2`` for an
``L``-smooth ``f`` and a feasible ``x``, so the test holds for small steps when ``c < 1/2``.

:func:`unit_columns_prox` gives such a map for a matrix ``D`` (p, k) stored as a row
``vec(D)`` (row-major): every column on the unit sphere ``||d_l||_2 = 1``, optionally
nonnegative, optionally with the penalty ``alpha ||D||_1`` (FactIRL's constrained dictionary,
docs/maths.md §8b). On the sphere the proximal problem is ``max <d, v> - t alpha ||d||_1``,
solved in closed form: ``d = s / ||s||`` with ``s`` the soft-thresholded ``v`` (its positive
part for nonnegative columns); when ``s = 0`` (no entry above the threshold) the maximiser is
the unit vector at the largest ``|v_j|`` (largest ``v_j`` for nonnegative columns).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._base import StepProblem, row_norms
from ._validation import check_number, option, validate_fields
from .armijo import ArmijoSolver, ArmijoState
from .exceptions import SolverError, SolverOptionError

__all__ = ["ProximalArmijoSolver", "unit_columns_prox"]


def _callable(value: Any, name: str, owner: str) -> Any:
    if not callable(value):
        raise SolverOptionError(f"{owner}: option {name} must be callable; got {value!r} ({type(value).__name__})")
    return value


def _callable_check():
    def check(value, name, owner):
        return _callable(value, name, owner)

    return check


def _no_penalty(x: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.zeros(np.shape(x)[0])


@dataclass
class ProximalArmijoSolver(ArmijoSolver):
    """Proximal-gradient descent with Armijo backtracking, one step size per row.

    Parameters
    ----------
    prox : callable
        ``prox(v, t) -> z``: rows ``v`` (r, p) and their steps ``t`` (r,) to the proximal
        points (r, p) (see the module docstring); ``prox(v, 0)`` is the projection onto the
        feasible set (used on the starting point).
    prox_penalty : callable, optional
        ``prox_penalty(x) -> (r,)``: the value of ``r`` on every row (default zero: a plain
        projection). Included in the rows' losses, as the other solvers' penalties.
    initial_step, shrink, grow, c, max_backtracks, max_step
        As :class:`~solvers.armijo.ArmijoSolver` (``c`` here multiplies ``||z - x||^2 / t``).

    Raises
    ------
    SolverOptionError
        When ``prox`` or ``prox_penalty`` is not callable, or an Armijo option is malformed.
    SolverError
        During a run, when ``prox`` returns something other than finite points of the shape
        of its rows ``v`` (NaN, inf, another shape, not numbers), or ``prox_penalty`` other
        than one finite-or-inf value per row: the message names the callable, where it was
        called (the projection of the start, a step, the optimality measure) and what it
        returned.
    """

    prox: Callable = option(None, _callable_check())
    prox_penalty: Callable = option(_no_penalty, _callable_check())

    name = "armijo-prox"
    constraint = "proximal"

    def __post_init__(self) -> None:
        validate_fields(self, "armijo-prox")
        if self.nonneg:
            raise SolverOptionError("armijo-prox: option nonneg is not taken (give the projection as prox)")

    def _prox(self, v: NDArray[np.float64], t: NDArray[np.float64], where: str) -> NDArray[np.float64]:
        """``prox(v, t)``, checked: finite points of ``v``'s shape (r, p) for finite rows of ``v``.

        A user's map that returns NaN or another shape would otherwise surface far away (as a
        non-finite reward in the problem's objective, or numpy's broadcasting error).
        """
        out = self.prox(v, t)
        try:
            z = np.asarray(out, dtype=np.float64)
        except (TypeError, ValueError):
            raise SolverError(f"{self.name}: prox(v, t) {where} returned {type(out).__name__}, not an array of numbers; "
                              f"it must return the proximal points, shape {v.shape} like v") from None
        if z.shape != v.shape:
            got = f"shape {z.shape}" if isinstance(out, np.ndarray) else f"{type(out).__name__} (shape {z.shape})"
            raise SolverError(f"{self.name}: prox(v, t) {where} returned {got} for v of shape {v.shape}; it "
                              f"must return the proximal points, one row of {v.shape[1]} per row of v")
        bad = ~np.all(np.isfinite(z), axis=1) & np.all(np.isfinite(v), axis=1)
        if bad.any():
            rows = np.flatnonzero(bad)
            raise SolverError(f"{self.name}: prox(v, t) {where} returned non-finite values (NaN or inf) for finite v, "
                              f"in {rows.size} of {v.shape[0]} row(s) (rows {rows[:10].tolist()}"
                              f"{' ...' if rows.size > 10 else ''} of v, steps t = {np.asarray(t)[rows[:3]].tolist()}); "
                              "it must return finite proximal points")
        return z

    def project(self, x: ArrayLike) -> NDArray[np.float64]:
        x = np.asarray(x, dtype=np.float64)
        return self._prox(x, np.zeros(x.shape[0]), "at the starting point (t = 0, the projection)")

    def penalty(self, x: ArrayLike) -> NDArray[np.float64]:
        x = np.asarray(x, dtype=np.float64)
        out = self.prox_penalty(x)
        try:
            value = np.asarray(out, dtype=np.float64)
        except (TypeError, ValueError):
            raise SolverError(f"{self.name}: prox_penalty(x) returned {type(out).__name__}, not an array of numbers; "
                              f"it must return one value per row of x, shape ({x.shape[0]},)") from None
        if value.shape != (x.shape[0],):
            raise SolverError(f"{self.name}: prox_penalty(x) returned shape {value.shape} for x of shape {x.shape}; it "
                              f"must return one value per row, shape ({x.shape[0]},)")
        if np.isnan(value).any():
            raise SolverError(f"{self.name}: prox_penalty(x) returned NaN in rows "
                              f"{np.flatnonzero(np.isnan(value))[:10].tolist()} of x")
        return value

    def optimality(self, x: ArrayLike, grad: ArrayLike) -> NDArray[np.float64]:
        """The norm of the proximal-gradient map at unit step, ``||x_i - prox(x_i - g_i, 1)||``
        per row: zero exactly at the fixed points of the step (stationary points)."""
        x = np.asarray(x, dtype=np.float64)
        return row_norms(x - self._prox(x - np.asarray(grad, dtype=np.float64), np.ones(x.shape[0]),
                                        "in the optimality measure (t = 1)"))

    def init_state(self, problem: StepProblem, x: NDArray[np.float64], previous: Any = None) -> ArmijoState:
        state = super().init_state(problem, x, previous)
        state.loss = state.loss + self.penalty(x)
        return state

    def step_rows(self, problem: StepProblem, x: NDArray[np.float64],
                  state: ArmijoState) -> tuple[NDArray[np.float64], ArmijoState, NDArray[np.bool_]]:
        """One proximal step per row (each row's backtracking is its own); ``progressed``: the rows accepted."""
        x_new = x.copy()
        loss, grad, step = state.loss.copy(), state.grad.copy(), state.step.copy()
        rows = np.arange(problem.n_rows)
        t = step.copy()
        for b in range(int(self.max_backtracks)):
            trial = self._prox(x[rows] - t[rows, None] * grad[rows], t[rows], "at a proximal-gradient step")
            lt, gt, finite = self._evaluate(problem, trial, rows)
            with np.errstate(invalid="ignore", over="ignore"):
                lt = lt + self.penalty(trial)
                moved = np.sum(np.square(trial - x[rows]), axis=1)
                ok = finite & (lt <= loss[rows] - self.c * moved / t[rows])
            acc = rows[ok]
            x_new[acc] = trial[ok]
            loss[acc], grad[acc] = lt[ok], gt[ok]
            step[acc] = np.minimum(t[acc] * self.grow, self.max_step) if b == 0 else t[acc]
            rows = rows[~ok]
            if rows.size == 0:
                break
            t[rows] *= self.shrink
        step[rows] = t[rows]
        progressed = np.ones(problem.n_rows, dtype=bool)
        progressed[rows] = False
        return x_new, ArmijoState(loss=loss, grad=grad, step=step), progressed


def unit_columns_prox(n_params: int, n_columns: int, *, nonneg: bool = False,
                      alpha: float = 0.0) -> tuple[Callable, Callable]:
    """The proximal map and penalty of ``D`` (p, k) with unit-norm columns, optionally ``D >= 0``,
    optionally with ``alpha ||D||_1``, acting on rows ``vec(D)`` (r, p*k), row-major.

    Parameters
    ----------
    n_params, n_columns : int
        p and k.
    nonneg : bool, default=False
        Nonnegative columns.
    alpha : float, default=0.0
        Weight of the L1 penalty (>= 0; 0: a projection onto the feasible set).

    Returns
    -------
    prox : callable
        ``prox(v, t)`` with ``v`` (r, p*k) and steps ``t`` (r,): every column of every row
        ``d = s / ||s||``, ``s`` the soft-thresholded column (threshold ``t alpha``; its
        positive part if ``nonneg``), or the unit vector at the column's largest entry
        (largest magnitude, with its sign, without ``nonneg``) when ``s = 0``.
    penalty : callable
        ``penalty(x) = alpha ||x_i||_1`` per row, shape (r,).

    Raises
    ------
    SolverOptionError
        When p or k is not a positive integer, ``nonneg`` not a bool, ``alpha`` negative or
        not finite.
    """
    p = check_number(n_params, "n_params", "unit_columns_prox", low=1, integer=True)
    k = check_number(n_columns, "n_columns", "unit_columns_prox", low=1, integer=True)
    if not isinstance(nonneg, (bool, np.bool_)):
        raise SolverOptionError(f"unit_columns_prox: nonneg must be True or False; got {nonneg!r}")
    alpha = float(check_number(alpha, "alpha", "unit_columns_prox", low=0.0))

    def prox(v: ArrayLike, t: ArrayLike) -> NDArray[np.float64]:
        V = np.asarray(v, dtype=np.float64)
        r = V.shape[0]
        V = V.reshape(r, p, k)
        thr = alpha * np.asarray(t, dtype=np.float64).reshape(r, 1, 1)
        if nonneg:
            S = np.maximum(V - thr, 0.0)
            top = np.argmax(V, axis=1)  # (r, k)
            sign = np.ones((r, k))
        else:
            S = np.sign(V) * np.maximum(np.abs(V) - thr, 0.0)
            top = np.argmax(np.abs(V), axis=1)
            sign = np.take_along_axis(V, top[:, None, :], axis=1)[:, 0, :]
            sign = np.where(sign < 0, -1.0, 1.0)
        norms = np.linalg.norm(S, axis=1)  # (r, k)
        empty = norms == 0
        out = S / np.where(empty, 1.0, norms)[:, None, :]
        if empty.any():
            ri, ci = np.nonzero(empty)
            out[ri, :, ci] = 0.0
            out[ri, top[ri, ci], ci] = sign[ri, ci]
        return out.reshape(r, p * k)

    def penalty(x: ArrayLike) -> NDArray[np.float64]:
        X = np.asarray(x, dtype=np.float64)
        return alpha * np.sum(np.abs(X), axis=1)

    return prox, penalty

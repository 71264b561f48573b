"""Matrix-free Gauss-Newton / Levenberg-Marquardt steps solved by truncated conjugate gradients.

The maths: docs/maths.md §5 (the D-step that uses it: §8).

For each row ``i`` with residuals ``r_i`` (m,) and Jacobian ``J_i`` (m, p), never formed, the
step solves the damped normal equations

    (J_i^T J_i + lam_i I) delta_i = -J_i^T r_i

by conjugate gradients (Hestenes-Stiefel; Nocedal & Wright, *Numerical Optimization*, 2nd ed.,
Algorithm 5.2) from ``delta = 0``, batched over rows with per-row scalars: every CG iteration
is one batched ``jvp`` (``J v``: for the IRL objective a forward-mode solve through Q*) and one
batched ``vjp`` (``J^T u``: the adjoint) of the problem's :class:`~solvers.Linearization`. A row
stops after ``cg_max_iter`` iterations or when its residual ``||(J^T J + lam I) delta + J^T r||``
falls below ``cg_tol ||J^T r||``. Truncated CG from zero decreases the damped model at every
iteration, so ``delta`` is a descent direction even when truncated (Steihaug, 1983).

Levenberg-Marquardt as in :class:`~solvers.GaussNewtonSolver`: a row's step is accepted if its
loss ``||r_i||^2`` drops and is finite (``lam_i *= lam_down``), else rejected
(``lam_i *= lam_up``) and retried, up to ``max_retries`` times, while no row was accepted. The
initial ``lam_i = damping * scale_i`` with ``scale_i = ||J_i g_i||^2 / ||g_i||^2``, ``g_i = J_i^T
r_i``: the Rayleigh quotient of ``J_i^T J_i`` along the gradient (one ``jvp``), a matrix-free
stand-in for Marquardt's ``max diag(J^T J)``; ``lam`` stays within ``[lam_min, lam_max] *
scale_i``. Steps are bounded as in the QP solvers (``max_step_norm``).

Rows accepted at different steps hold linearisations from different calls of
``problem.linearize``; the products are then one batched call per such group (one call in a
one-row D-step, and in any step where every row moved together).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from ._base import StepProblem, StepSolver, limit_step, trial_every_row, update_damping
from ._validation import check_evaluation, integer, number, option, optional, validate_fields
from .exceptions import SolverError, SolverOptionError

__all__ = ["GaussNewtonCGSolver", "GaussNewtonCGState", "cg_normal_equations"]


class _Linearizations:
    """The linearisations of all rows, from possibly several ``linearize`` calls (internal).

    ``owner[i]`` is the call (piece) that holds row ``i``, ``local[i]`` its index there. The
    products of a set of rows call each piece once, padding the rows it holds but the set does
    not need with zeros (the products are linear).
    """

    def __init__(self, lin, n, owner_name):
        self.pieces = [lin]
        self.sizes = [n]
        self.owner = np.zeros(n, dtype=np.intp)
        self.local = np.arange(n)
        self.name = owner_name

    def replace(self, rows, lin, local, size):
        """Rows ``rows`` are now held by ``lin``, a call over ``size`` rows, at ``local``."""
        self.pieces.append(lin)
        self.sizes.append(int(size))
        self.owner[rows] = len(self.pieces) - 1
        self.local[rows] = local
        for u in range(len(self.pieces)):  # free pieces no row refers to any more
            if self.pieces[u] is not None and not np.any(self.owner == u):
                self.pieces[u] = None

    def _apply(self, kind, V, rows, width):
        out = np.empty((len(rows), width))
        owners = self.owner[rows]
        for u in np.unique(owners):
            sel = np.flatnonzero(owners == u)
            W = np.zeros((self.sizes[u],) + V.shape[1:])
            W[self.local[rows[sel]]] = V[sel]
            out[sel] = product(self.name, self.pieces[u], kind, W, width)[self.local[rows[sel]]]
        return out

    def subset(self, rows):
        """The linearisations of rows ``rows`` only (row ``j`` of the result is row ``rows[j]``)."""
        out = _Linearizations.__new__(_Linearizations)
        out.pieces, out.sizes, out.name = list(self.pieces), list(self.sizes), self.name
        out.owner, out.local = self.owner[rows].copy(), self.local[rows].copy()
        return out

    def merged(self, rows, part):
        """These linearisations with rows ``rows`` held as in ``part`` (a :meth:`subset` of them)."""
        out = self.subset(np.arange(len(self.owner)))
        shift = len(out.pieces)
        out.pieces += part.pieces
        out.sizes += part.sizes
        out.owner[rows] = part.owner + shift
        out.local[rows] = part.local
        for u in range(len(out.pieces)):  # free pieces no row refers to any more
            if out.pieces[u] is not None and not np.any(out.owner == u):
                out.pieces[u] = None
        return out

    def jvp(self, V, rows, m):
        """``J_i v_i`` for rows ``rows``; V (len(rows), p) -> (len(rows), m)."""
        return self._apply("jvp", V, rows, m)

    def vjp(self, U, rows, p):
        """``J_i^T u_i`` for rows ``rows``; U (len(rows), m) -> (len(rows), p)."""
        return self._apply("vjp", U, rows, p)


def product(owner: str, lin: Any, kind: str, V: NDArray[np.float64], width: int) -> NDArray[np.float64]:
    """``lin.jvp(V)`` or ``lin.vjp(V)`` as float64 of shape (len(V), width), checked."""
    out = np.asarray(getattr(lin, kind)(V), dtype=np.float64)
    if out.shape != (len(V), width):
        raise SolverError(f"{owner}: Linearization.{kind} returned shape {out.shape}; expected {(len(V), width)}")
    return out


def cg_normal_equations(
    jvp: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    vjp: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    grad: NDArray[np.float64],
    lam: NDArray[np.float64],
    max_iter: int,
    tol: float,
) -> tuple[NDArray[np.float64], NDArray[np.intp], int]:
    """Solve ``(J_i^T J_i + lam_i I) delta_i = -g_i`` for every row by conjugate gradients.

    Parameters
    ----------
    jvp : callable
        ``V (r, p) -> (r, m)``, ``J_i v_i``.
    vjp : callable
        ``U (r, m) -> (r, p)``, ``J_i^T u_i``.
    grad : ndarray, shape (r, p)
        ``g_i = J_i^T r_i``.
    lam : ndarray, shape (r,)
        Damping (> 0 makes every system positive definite).
    max_iter : int
        Iterations at most (each one ``jvp`` and one ``vjp`` of all rows still iterating).
    tol : float
        A row stops when its residual norm is ``<= tol * ||g_i||``.

    Returns
    -------
    delta : ndarray, shape (r, p)
    iterations : ndarray of int, shape (r,)
        CG iterations of each row.
    breakdowns : int
        Rows stopped because a product was not finite (their last finite iterate is kept).
    """
    delta = np.zeros_like(grad)
    res = -grad.copy()
    d = res.copy()
    rr = np.einsum("np,np->n", res, res)
    target = (tol**2) * rr
    active = rr > target
    iterations = np.zeros(len(grad), dtype=np.intp)
    breakdowns = 0
    for _ in range(int(max_iter)):
        if not active.any():
            break
        Ad = vjp(jvp(d)) + lam[:, None] * d
        dAd = np.einsum("np,np->n", d, Ad)
        finite = np.all(np.isfinite(Ad), axis=1) & np.isfinite(dAd)
        breakdowns += int(np.sum(active & ~finite))
        ok = active & finite & (dAd > 0)
        a = np.where(ok, rr / np.where(ok, dAd, 1.0), 0.0)
        delta += a[:, None] * d
        res -= a[:, None] * np.where(ok[:, None], Ad, 0.0)
        rr_new = np.einsum("np,np->n", res, res)
        b = np.where(ok, rr_new / np.where(rr > 0, rr, 1.0), 0.0)
        d = np.where(ok[:, None], res + b[:, None] * d, d)
        rr = np.where(ok, rr_new, rr)
        iterations += ok
        active = ok & (rr > target)
    return delta, iterations, breakdowns


@dataclass
class GaussNewtonCGState:
    """Levenberg-Marquardt state of every row (matrix-free).

    Attributes
    ----------
    loss : ndarray, shape (n,)
    residual : ndarray, shape (n, m)
    grad : ndarray, shape (n, p)
        ``J_i^T r_i`` (half the gradient of the loss).
    lam, scale : ndarray, shape (n,)
    n_jvp, n_vjp : int
        Batched product calls over the run (jvp: ``J v``; vjp: ``J^T u``).
    cg_iterations : int
        CG iterations summed over steps (the largest of the rows in each solve).
    cg_breakdowns : int
        Rows whose CG stopped on a non-finite product.
    """

    loss: np.ndarray
    residual: np.ndarray
    grad: np.ndarray
    lam: np.ndarray
    scale: np.ndarray
    lin: _Linearizations = field(repr=False)
    n_jvp: int = 0
    n_vjp: int = 0
    cg_iterations: int = 0
    cg_breakdowns: int = 0


@dataclass
class GaussNewtonCGSolver(StepSolver):
    """Matrix-free Levenberg-Marquardt steps by truncated CG (needs ``problem.linearize``).

    Parameters
    ----------
    damping : float, default=1e-3
        Initial ``lam_i = damping * scale_i`` (see the module docstring), > 0.
    lam_down, lam_up : float, default=1/3 and 4
        Damping factor after an accepted (in (0, 1)) and a rejected step (> 1).
    lam_min, lam_max : float, default=1e-10 and 1e10
        Bounds of ``lam_i`` relative to ``scale_i`` (``0 < lam_min < lam_max``).
    cg_max_iter : int, default=20
        CG iterations per step at most (each one batched jvp + one batched vjp), >= 1.
    cg_tol : float, default=1e-3
        Relative residual at which CG stops, >= 0.
    max_retries : int, default=10
        Extra trials within one step when no row was accepted, >= 0.
    xtol : float, default=1e-12
        A row whose step is below ``xtol * (||x|| + xtol)`` has converged (not evaluated).
    max_step_norm : float, default=100.0
        Step bound relative to ``max(1, ||x_i||)``, > 0.
    alternating_damping : float or None, default=1.0
        ``damping`` of the copy :meth:`for_alternating` returns, for a block of an alternating
        scheme (FactIRL's D-step): proximal steps, ``lam`` as large as the curvature along the
        gradient, shrinking by ``alternating_lam_down`` per accepted step (the damping is carried
        from one outer iteration to the next), so the block moves gradually while the other
        block is still poor and approaches Gauss-Newton steps as the fit settles. None: use
        this solver as configured.
    alternating_lam_down : float, default=0.9
        ``lam_down`` of that copy, in (0, 1).
    alternating_cg_tol : float, default=0.1
        ``cg_tol`` of that copy, >= 0: an inexact (truncated) Newton step is enough for a block
        whose sub-problem changes at every outer iteration.

    Notes
    -----
    The alternating defaults were measured on FactIRL fits with an Armijo H-step. 5x5 grid,
    30 tasks, k = 4: this solver as configured (``damping=1e-3``: nearly Gauss-Newton steps)
    drove the rewards into saturated plateaus (Boltzmann policies deterministic, gradient
    ~1e-6 of the initial one) and converged at loss 0.130 after 6 outer iterations, against
    0.020 for Armijo/Armijo; ``damping=1, lam_down=0.99`` reached 0.020 in 1394 Q*
    evaluations (Armijo/Armijo: 1170), ``damping=1, lam_down=0.9`` a loss below 1e-4 in 388,
    ``damping=10`` stopped at 0.31. Paper scale (10x10 grid, 100 tasks, k = 5, the
    ``bench fit`` setting; Armijo/Armijo: loss 0.210, 2976 evaluations, 3.6e5 linear solves):
    ``cg_tol=1e-3`` gave loss 0.069 in 484 evaluations and 2.5e5 linear solves, ``cg_tol=0.1``
    0.069 in 454 evaluations and 1.9e5 linear solves (gtol = 1e-4, ``cg_max_iter`` 10 and 20).

    Raises
    ------
    SolverOptionError
        When an option has the wrong type or value, or (at run time) when the problem has no
        ``linearize``.
    """

    damping: float = option(1e-3, number(low=0.0, low_open=True))
    lam_down: float = option(1.0 / 3.0, number(0.0, 1.0, low_open=True, high_open=True))
    lam_up: float = option(4.0, number(low=1.0, low_open=True))
    lam_min: float = option(1e-10, number(low=0.0, low_open=True))
    lam_max: float = option(1e10, number(low=0.0, low_open=True))
    cg_max_iter: int = option(20, integer(low=1))
    cg_tol: float = option(1e-3, number(low=0.0))
    max_retries: int = option(10, integer(low=0))
    xtol: float = option(1e-12, number(low=0.0))
    max_step_norm: float = option(100.0, number(low=0.0, low_open=True))
    alternating_damping: float = option(1.0, optional(number(low=0.0, low_open=True)))
    alternating_lam_down: float = option(0.9, number(0.0, 1.0, low_open=True, high_open=True))
    alternating_cg_tol: float = option(0.1, number(low=0.0))

    name = "gn-cg"
    needs_linearization = True

    def __post_init__(self) -> None:
        validate_fields(self, self.name)
        if not self.lam_min < self.lam_max:
            raise SolverOptionError(f"{self.name}: lam_max must be > lam_min = {self.lam_min!r}; got {self.lam_max!r}")

    def for_alternating(self) -> GaussNewtonCGSolver:
        """A proximal, inexact copy (``alternating_damping``, ``alternating_lam_down``,
        ``alternating_cg_tol``), or ``self`` when ``alternating_damping`` is None."""
        if self.alternating_damping is None:
            return self
        return replace(self, damping=self.alternating_damping, lam_down=self.alternating_lam_down,
                       cg_tol=self.alternating_cg_tol)

    def gradient(self, state: GaussNewtonCGState) -> NDArray[np.float64]:
        """``2 J_i^T r_i`` (the state holds half the gradient)."""
        return 2.0 * state.grad

    def _linearize(self, problem, x, rows, start=False):
        """``problem.linearize`` at ``x`` (rows ``rows``), checked."""
        lin = problem.linearize(x, rows)
        if not all(hasattr(lin, a) for a in ("loss", "residual", "jvp", "vjp")) or not (callable(lin.jvp) and callable(lin.vjp)):
            raise SolverError(f"{self.name}: problem.linearize must return a Linearization (loss, residual, jvp, vjp); got {type(lin).__name__}")
        loss, (r,), finite = check_evaluation(self.name, "linearize", rows, lin.loss, lin.residual, shapes=[(None,)], start=start)
        return lin, loss, r, finite

    def init_state(self, problem: StepProblem, x: NDArray[np.float64], previous: Any = None) -> GaussNewtonCGState:
        if problem.linearize is None:
            raise SolverOptionError(f"solver {self.name!r} needs problem.linearize (a StepProblem built with linearize=...)")
        n, p = problem.n_rows, problem.n_params
        rows = np.arange(n)
        lin, loss, r, _ = self._linearize(problem, x, rows, start=True)
        stack = _Linearizations(lin, n, self.name)
        grad = stack.vjp(r, rows, p)
        state = GaussNewtonCGState(loss=loss, residual=r, grad=grad, lam=np.empty(0), scale=np.empty(0), lin=stack, n_vjp=1)
        if not np.all(np.isfinite(grad)):
            bad = np.flatnonzero(~np.all(np.isfinite(grad), axis=1))
            raise SolverError(f"{self.name}: the objective returned a non-finite derivative at the starting point, rows {bad[:10].tolist()}")
        gg = np.einsum("np,np->n", grad, grad)
        Jg = stack.jvp(grad, rows, r.shape[1])
        state.n_jvp += 1
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            scale = np.einsum("nm,nm->n", Jg, Jg) / gg
        scale[~(np.isfinite(scale) & (scale > 0))] = 1.0
        lam: Any = getattr(previous, "lam", None)
        if not (np.shape(lam) == (n,) and np.all(np.isfinite(lam)) and np.all(lam > 0)):
            lam = self.damping * scale
        state.scale = scale
        state.lam = np.maximum(np.clip(lam, self.lam_min * scale, self.lam_max * scale), np.finfo(np.float64).tiny)
        return state

    def _steps(self, x, state, rows):
        """Truncated-CG steps of rows ``rows``, bounded; the trial points."""
        m, p = state.residual.shape[1], x.shape[1]
        counts = [0]

        def jvp(V):
            counts[0] += 1
            return state.lin.jvp(V, rows, m)

        def vjp(U):
            return state.lin.vjp(U, rows, p)

        delta, its, broken = cg_normal_equations(jvp, vjp, state.grad[rows], state.lam[rows], self.cg_max_iter, self.cg_tol)
        state.n_jvp += counts[0]
        state.n_vjp += counts[0]
        state.cg_iterations += int(np.max(its, initial=0))
        state.cg_breakdowns += broken
        return limit_step(x[rows], x[rows] + delta, self.max_step_norm)[0]

    def update(
        self, problem: StepProblem, x: NDArray[np.float64], state: GaussNewtonCGState
    ) -> tuple[NDArray[np.float64], GaussNewtonCGState, bool]:
        n = x.shape[0]
        x = x.copy()
        retry = np.ones(n, dtype=bool)
        accepted_any = converged_all = False
        for _ in range(int(self.max_retries) + 1):
            tried = self._trial(problem, x, state, np.flatnonzero(retry), np.zeros(n, dtype=bool))
            if tried is None:
                converged_all = True  # every row still allowed to move has a negligible step
                break
            acc, rej = tried
            retry = update_damping(self, state, acc, rej, n)
            if acc.size:
                accepted_any = True
                break
            if not retry.any():
                break
        return x, state, bool(accepted_any or converged_all)

    def step_rows(
        self, problem: StepProblem, x: NDArray[np.float64], state: GaussNewtonCGState
    ) -> tuple[NDArray[np.float64], GaussNewtonCGState, NDArray[np.bool_]]:
        """One step per row, each row as it would step alone: a rejected row retries with its
        larger damping (up to ``max_retries`` times) whatever the other rows did.
        ``progressed``: the rows accepted and the rows whose step was negligible (``xtol``)."""
        n = x.shape[0]
        x = x.copy()
        progressed = np.zeros(n, dtype=bool)
        todo = np.arange(n)
        for _ in range(int(self.max_retries) + 1):
            if todo.size == 0:
                break
            tried = self._trial(problem, x, state, todo, progressed)
            if tried is None:
                break
            todo = np.flatnonzero(update_damping(self, state, *tried, n))
        return x, state, progressed

    def _trial(
        self, problem: StepProblem, x: NDArray[np.float64], state: GaussNewtonCGState, todo: NDArray[np.intp],
        progressed: NDArray[np.bool_],
    ) -> tuple[NDArray[np.intp], NDArray[np.intp]] | None:
        """One trial of rows ``todo``: ``x``, ``state`` and ``progressed`` updated in place where a
        row is accepted or its step negligible; the accepted and rejected rows, or None where
        every step was negligible (no row evaluated)."""
        p = x.shape[1]
        z = self._steps(x, state, todo)
        moving = np.linalg.norm(z - x[todo], axis=1) > self.xtol * (np.linalg.norm(x[todo], axis=1) + self.xtol)
        progressed[todo[~moving]] = True  # a negligible step: the row has converged
        rows, z = todo[moving], z[moving]
        if rows.size == 0:
            return None
        lin, loss, r, finite = self._linearize(problem, z, rows)
        grad = product(self.name, lin, "vjp", np.where(finite[:, None], r, 0.0), p)
        state.n_vjp += 1
        with np.errstate(invalid="ignore"):
            ok = finite & np.all(np.isfinite(grad), axis=1) & (loss < state.loss[rows])
        acc, rej = rows[ok], rows[~ok]
        if acc.size:
            x[acc], state.loss[acc], state.residual[acc], state.grad[acc] = z[ok], loss[ok], r[ok], grad[ok]
            state.lin.replace(acc, lin, np.flatnonzero(ok), len(rows))
        progressed[acc] = True
        return acc, rej

    def trial_rows(
        self, problem: StepProblem, x: NDArray[np.float64], state: GaussNewtonCGState, tries: NDArray[np.intp]
    ) -> tuple[NDArray[np.float64], GaussNewtonCGState, NDArray[np.bool_], NDArray[np.bool_]]:
        """One trial of every row, the rounds of :meth:`step_rows` taken one at a time (a
        rejected row that may retry is ``pending``; as :meth:`GaussNewtonSolver.trial_rows`)."""
        return trial_every_row(self, problem, x, state, tries)

    def take_rows(self, state: GaussNewtonCGState, rows: NDArray[np.intp]) -> GaussNewtonCGState:
        """The per-row arrays sliced, and the linearisations of the rows kept."""
        part = super().take_rows(state, rows)
        part.lin = state.lin.subset(rows)
        return part

    def put_rows(self, state: GaussNewtonCGState, rows: NDArray[np.intp], part: GaussNewtonCGState) -> GaussNewtonCGState:
        """The per-row arrays merged; the linearisations of ``rows`` taken from ``part``."""
        lin = state.lin
        out = super().put_rows(state, rows, part)
        out.lin = lin.merged(rows, part.lin)
        return out

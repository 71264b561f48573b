"""Second-order steps, batched over rows: damped Newton with a trust-region ratio test (docs/maths.md §5).

Each row ``i`` (a task of a flat fit) has a loss ``f_i``, its gradient ``g_i`` and a curvature
matrix ``H_i`` (p, p) at the current point:

- the exact Hessian when the problem gives one (``StepProblem.hessian``; the MCE likelihood,
  :meth:`factirl_opt.objectives.MCEObjective.hessian`), possibly indefinite;
- otherwise the Gauss-Newton matrix ``2 J_i^T J_i`` of a least-squares problem
  (``StepProblem.residual_jacobian``: policy matching; or ``StepProblem.linearize``, the
  Jacobian then formed from ``p`` Jacobian-vector products), with ``g_i = 2 J_i^T r_i``.

The step solves ``(H_i + lam_i I) d_i = -g_i`` (Levenberg-Marquardt damping of the quadratic
model ``m_i(d) = g_i^T d + d^T H_i d / 2``, the form of a trust-region step whose radius the
damping sets; More 1978, Nocedal & Wright, *Numerical Optimization*, 2nd ed., §4.3 and
§10.3). Where ``H_i + lam_i I`` is not positive definite (a Cholesky factorisation fails),
``lam_i`` is first raised by ``-lambda_min(H_i)`` (one symmetric eigenvalue problem of that
row), so the step is a descent direction of a convex model. The step is bounded like the other
solvers' (``||d_i|| <= max_step_norm * max(1, ||x_i||)``, :func:`solvers._base.limit_step`).

A trial point is accepted when its loss is finite, lower, and the ratio ``rho_i`` of the
actual to the predicted decrease ``-m_i(d_i)`` is at least ``eta``; then ``lam_i`` shrinks by
``lam_down`` when ``rho_i > 0.75`` (the model is good: toward the Newton step, quadratic
convergence) and grows by ``lam_up`` when ``rho_i < 0.25``. A rejected row grows ``lam_i`` by
``lam_up`` and retries within the same step, on its own (up to ``max_retries`` times), so a
separable run (:mod:`solvers.separable`) moves every row as it would move alone. Damping stays
within ``[lam_min, lam_max]`` times the row's scale ``max_j |H_i[j, j]|`` at the start of the run.

One trial costs one evaluation of ``loss_and_grad`` (exact Hessian: the Hessian is then
computed at accepted points only, ``p`` right-hand sides per task on one factorisation) or of
``residual_jacobian`` (Gauss-Newton: ``p`` right-hand sides per trial). A row whose step is
below ``xtol * (||x_i|| + xtol)`` has converged and is not evaluated.

The curvature is a dense (p, p) matrix per row: meant for a moderate number of parameters per
row (feature weights, ``p`` in the hundreds), not for tabular rewards of large MDPs.
Unconstrained only (``constraint = "none"``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._base import StepProblem, StepSolver, limit_step
from ._validation import check_evaluation, integer, number, option, optional, validate_fields
from .exceptions import SolverError, SolverOptionError

__all__ = ["NewtonSolver", "NewtonState", "damped_newton_directions"]

#: a trial's ratio above which the model is trusted more (damping shrinks)
GOOD_RATIO = 0.75
#: a trial's ratio below which the model is trusted less (damping grows)
POOR_RATIO = 0.25


@dataclass
class NewtonState:
    """Damped-Newton state of every row.

    Attributes
    ----------
    loss : ndarray, shape (n,)
    grad : ndarray, shape (n, p)
    hess : ndarray, shape (n, p, p)
        Curvature at the current point (Hessian or Gauss-Newton matrix), symmetric.
    lam : ndarray, shape (n,)
        Damping per row.
    scale : ndarray, shape (n,)
        ``max_j |H_i[j, j]|`` at the start of the run (1 where zero); the damping bounds are
        relative to it.
    age : ndarray of int, shape (n,)
        Accepted steps taken since the row's curvature was computed (0: at the current point).
    n_indefinite : int
        Steps in which a row's damped curvature was not positive definite (damping raised).
    bounded_steps : int
        Row steps shortened by the step bound.
    """

    loss: NDArray[np.float64]
    grad: NDArray[np.float64]
    hess: NDArray[np.float64]
    lam: NDArray[np.float64]
    scale: NDArray[np.float64]
    age: NDArray[np.intp]
    n_indefinite: int = 0
    bounded_steps: int = 0


def damped_newton_directions(grad: NDArray[np.float64], hess: NDArray[np.float64],
                             lam: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """``d_i = -(H_i + lam_i I)^-1 g_i`` for every row, the damping raised where it is needed.

    Parameters
    ----------
    grad : ndarray, shape (n, p)
    hess : ndarray, shape (n, p, p)
        Symmetric.
    lam : ndarray, shape (n,)
        Damping, >= 0.

    Returns
    -------
    d : ndarray, shape (n, p)
    lam : ndarray, shape (n,)
        The damping used: ``lam_i``, or ``lam_i - lambda_min(H_i)`` (doubled until the
        factorisation succeeds) where ``H_i + lam_i I`` is not positive definite.
    raised : ndarray of bool, shape (n,)
        The rows whose damping was raised.
    """
    n, p = grad.shape
    lam = np.array(lam, dtype=np.float64)
    eye = np.eye(p)
    raised = np.zeros(n, dtype=bool)
    A = hess + lam[:, None, None] * eye
    try:
        L = np.linalg.cholesky(A)
    except np.linalg.LinAlgError:
        L = np.empty_like(A)
        for i in range(n):
            try:
                L[i] = np.linalg.cholesky(A[i])
                continue
            except np.linalg.LinAlgError:
                pass
            raised[i] = True
            low = float(np.linalg.eigvalsh(hess[i])[0])
            shift = max(lam[i], 1e-12 * max(1.0, abs(low)))
            lam[i] = shift - low if np.isfinite(low) else np.inf
            for _ in range(60):
                if not np.isfinite(lam[i]):
                    break
                try:
                    L[i] = np.linalg.cholesky(hess[i] + lam[i] * eye)
                    break
                except np.linalg.LinAlgError:
                    lam[i] = 2.0 * lam[i] + shift
            else:
                lam[i] = np.inf
            if not np.isfinite(lam[i]):
                L[i] = eye  # no usable curvature: a zero step (the row makes no progress)
    u = np.linalg.solve(L, -grad[..., None])
    d = np.linalg.solve(np.swapaxes(L, 1, 2), u)[..., 0]
    d[~np.isfinite(lam)] = 0.0
    return d, lam, raised


@dataclass
class NewtonSolver(StepSolver):
    """Damped Newton / Gauss-Newton steps with a trust-region ratio test, batched over rows.

    Parameters
    ----------
    damping : float, default=1e-3
        Initial ``lam_i = damping * max_j |H_i[j, j]|`` (Marquardt's scale-free start), > 0.
    lam_down, lam_up : float, default=1/3 and 4
        Damping factor after a good step (in (0, 1)) and after a poor or rejected one (> 1).
    lam_min, lam_max : float, default=1e-12 and 1e10
        Bounds of the damping relative to the row's scale (``0 < lam_min < lam_max``).
    eta : float, default=1e-4
        Smallest ratio of actual to predicted decrease of an accepted step, in [0, 1).
    max_retries : int, default=10
        Extra trials of a rejected row within one step, >= 0.
    xtol : float, default=1e-12
        A row whose step is below ``xtol * (||x_i|| + xtol)`` has converged (>= 0).
    max_step_norm : float, default=100.0
        Step bound relative to ``max(1, ||x_i||)``, > 0.
    alternating_damping : float or None, default=1.0
        ``damping`` of the copy returned by :meth:`for_alternating` (FactIRL's H-step inside
        ``fit``); None keeps this solver's own damping there.
    alternating_lam_down : float, default=0.99
        ``lam_down`` of that copy, in (0, 1).
    hessian_age : int, default=1
        Accepted steps for which a row keeps its curvature while its steps stay good (ratio
        above 0.75), >= 1. 1: the curvature is computed at every accepted point (Newton's
        method); larger values save curvature computations (each ``p`` right-hand sides) at the
        cost of more, cheaper steps with the gradient always current (a chord or lazy Newton
        method). With residuals and a value above 1, trial points are evaluated by
        ``loss_and_grad`` and the Gauss-Newton matrix by ``residual_jacobian`` where it is
        refreshed.

    Raises
    ------
    SolverOptionError
        When an option has the wrong type or value; at a run, when the problem gives neither a
        Hessian nor residuals.
    """

    damping: float = option(1e-3, number(low=0.0, low_open=True))
    lam_down: float = option(1.0 / 3.0, number(0.0, 1.0, low_open=True, high_open=True))
    lam_up: float = option(4.0, number(low=1.0, low_open=True))
    lam_min: float = option(1e-12, number(low=0.0, low_open=True))
    lam_max: float = option(1e10, number(low=0.0, low_open=True))
    eta: float = option(1e-4, number(0.0, 1.0, high_open=True))
    max_retries: int = option(10, integer(low=0))
    xtol: float = option(1e-12, number(low=0.0))
    max_step_norm: float = option(100.0, number(low=0.0, low_open=True))
    hessian_age: int = option(1, integer(low=1))
    alternating_damping: float | None = option(1.0, optional(number(low=0.0, low_open=True)))
    alternating_lam_down: float = option(0.99, number(0.0, 1.0, low_open=True, high_open=True))

    name = "newton"

    def __post_init__(self) -> None:
        validate_fields(self, self.name)
        if not self.lam_min < self.lam_max:
            raise SolverOptionError(f"{self.name}: lam_max must be > lam_min = {self.lam_min!r}; got {self.lam_max!r}")

    def for_alternating(self) -> NewtonSolver:
        """A proximal copy (``alternating_damping``, ``alternating_lam_down``) for FactIRL's fit.

        As :meth:`solvers.GaussNewtonSolver.for_alternating`: in an alternating scheme each
        H-step should move the coefficients gradually while the dictionary is still poor, so
        the damping stays near the curvature's scale instead of falling toward Newton's step.
        """
        if self.alternating_damping is None:
            return self
        return replace(self, damping=self.alternating_damping, lam_down=self.alternating_lam_down)

    # -- evaluations ------------------------------------------------------------------------
    @staticmethod
    def _exact(problem: StepProblem) -> bool:
        return problem.hessian is not None

    def _lazy(self, problem: StepProblem) -> bool:
        """Whether trial points are evaluated without their curvature (kept curvature, residuals)."""
        return not self._exact(problem) and int(self.hessian_age) > 1

    def _evaluate(self, problem, x, rows, start=False, curvature=True):
        """Loss, gradient and (Gauss-Newton, ``curvature``) curvature at ``x`` of ``rows``; the finite rows."""
        p = problem.n_params
        if self._exact(problem) or not curvature:
            loss, (grad,), finite = check_evaluation(self.name, "loss_and_grad", rows, *problem.loss_and_grad(x, rows),
                                                     shapes=[(p,)], start=start)
            return loss, grad, None, finite
        if problem.residual_jacobian is not None:
            out = problem.residual_jacobian(x, rows)
            what = "residual_jacobian"
            if not (isinstance(out, tuple) and len(out) == 3):
                raise SolverError(f"{self.name}: problem.residual_jacobian must return (loss, residual, jacobian)")
        else:  # matrix-free residuals: the Jacobian formed column by column (p products)
            lin, what = problem.linearize(x, rows), "linearize"
            eye = np.eye(p)
            out = (lin.loss, lin.residual,
                   np.stack([lin.jvp(np.broadcast_to(eye[j], (len(rows), p))) for j in range(p)], axis=2))
        loss, (r, J), finite = check_evaluation(self.name, what, rows, *out, shapes=[(None,), (None, p)], start=start)
        if J.shape[1] != r.shape[1]:
            raise SolverError(f"{self.name}: problem.{what} gave residuals {r.shape} and a Jacobian {J.shape}")
        with np.errstate(over="ignore", invalid="ignore"):
            grad = 2.0 * np.einsum("nmk,nm->nk", J, r)
            hess = 2.0 * np.matmul(np.swapaxes(J, 1, 2), J)
        finite &= np.all(np.isfinite(grad), axis=1) & np.all(np.isfinite(hess), axis=(1, 2))
        return loss, grad, hess, finite

    def _hessian(self, problem, x, rows):
        """The problem's Hessian at ``x`` of ``rows`` (just evaluated), checked and symmetrised."""
        H = np.asarray(problem.hessian(x, rows), dtype=np.float64)
        p = problem.n_params
        if H.shape != (len(rows), p, p):
            raise SolverError(f"{self.name}: problem.hessian returned shape {H.shape}; expected ({len(rows)}, {p}, {p})")
        if not np.all(np.isfinite(H)):
            bad = rows[~np.all(np.isfinite(H), axis=(1, 2))]
            raise SolverError(f"{self.name}: problem.hessian is not finite at rows {bad[:10].tolist()}")
        return 0.5 * (H + np.swapaxes(H, 1, 2))

    def _curvature(self, problem, x, rows):
        """Curvature at ``x`` of ``rows`` (a point just evaluated): the Hessian, or the
        Gauss-Newton matrix from a new evaluation of the residuals (its loss and gradient are
        those of the trial)."""
        if self._exact(problem):
            return self._hessian(problem, x, rows)
        _, _, hess, finite = self._evaluate(problem, x, rows)
        if not finite.all():
            raise SolverError(f"{self.name}: the residuals are not finite at the accepted rows {rows[~finite][:10].tolist()}")
        return hess

    def init_state(self, problem: StepProblem, x: NDArray[np.float64], previous: Any = None) -> NewtonState:
        if problem.hessian is None and problem.residual_jacobian is None and problem.linearize is None:
            raise SolverOptionError(f"solver {self.name!r} needs a Hessian (StepProblem.hessian) or residuals "
                                    "(StepProblem.residual_jacobian or linearize); the problem gives neither")
        rows = np.arange(problem.n_rows)
        loss, grad, hess, _ = self._evaluate(problem, x, rows, start=True)
        if hess is None:
            hess = self._hessian(problem, x, rows)
        with np.errstate(invalid="ignore"):
            scale = np.max(np.abs(np.diagonal(hess, axis1=1, axis2=2)), axis=1, initial=0.0)
        scale[~((scale > 0) & np.isfinite(scale))] = 1.0
        lam: Any = getattr(previous, "lam", None)
        if not (np.shape(lam) == (problem.n_rows,) and np.all(np.isfinite(lam)) and np.all(lam > 0)):
            lam = self.damping * scale
        lam = np.maximum(np.clip(lam, self.lam_min * scale, self.lam_max * scale), np.finfo(np.float64).tiny)
        return NewtonState(loss=loss, grad=grad, hess=hess, lam=np.array(lam, dtype=np.float64), scale=scale,
                           age=np.zeros(problem.n_rows, dtype=np.intp))

    # -- steps ------------------------------------------------------------------------------
    def update(self, problem: StepProblem, x: NDArray[np.float64], state: NewtonState) -> tuple[NDArray[np.float64], NewtonState, bool]:
        x, state, progressed = self.step_rows(problem, x, state)
        return x, state, bool(progressed.any())

    def step_rows(self, problem: StepProblem, x: NDArray[np.float64], state: NewtonState) -> tuple[NDArray[np.float64], NewtonState, NDArray[np.bool_]]:
        """One damped Newton step per row, each row as it would step alone (its retries are its
        own); ``progressed``: the rows accepted and the rows whose step was negligible."""
        n = x.shape[0]
        x = x.copy()
        progressed = np.zeros(n, dtype=bool)
        todo = np.arange(n)
        for _ in range(int(self.max_retries) + 1):
            if todo.size == 0:
                break
            d, lam, raised = damped_newton_directions(state.grad[todo], state.hess[todo], state.lam[todo])
            state.lam[todo] = np.where(np.isfinite(lam), lam, state.lam[todo])
            state.n_indefinite += int(raised.sum())
            z, shortened = limit_step(x[todo], x[todo] + d, self.max_step_norm)
            state.bounded_steps += int(shortened.sum())
            d = z - x[todo]
            moving = np.linalg.norm(d, axis=1) > self.xtol * (np.linalg.norm(x[todo], axis=1) + self.xtol)
            progressed[todo[~moving & np.isfinite(lam)]] = True  # a negligible step: converged
            rows, z, d = todo[moving], z[moving], d[moving]
            if rows.size == 0:
                break
            g, H = state.grad[rows], state.hess[rows]
            predicted = -(np.einsum("np,np->n", g, d) + 0.5 * np.einsum("np,npq,nq->n", d, H, d))
            lazy = self._lazy(problem)
            loss, grad, hess, finite = self._evaluate(problem, z, rows, curvature=not lazy)
            with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
                actual = state.loss[rows] - loss
                ratio = actual / predicted
                ok = finite & (actual > 0) & (ratio >= self.eta)
            acc, rej = rows[ok], rows[~ok]
            if acc.size:
                x[acc], state.loss[acc], state.grad[acc] = z[ok], loss[ok], grad[ok]
                keep = (state.age[acc] + 1 < int(self.hessian_age)) & (ratio[ok] > GOOD_RATIO)
                state.age[acc[keep]] += 1
                new = ~keep
                if new.any():
                    fresh = acc[new]
                    state.hess[fresh] = hess[ok][new] if hess is not None else self._curvature(problem, z[ok][new], fresh)
                    state.age[fresh] = 0
                progressed[acc] = True
            good = acc[ratio[ok] > GOOD_RATIO]
            poor = acc[ratio[ok] < POOR_RATIO]
            state.lam[good] *= self.lam_down
            state.lam[poor] *= self.lam_up
            state.lam[rej] *= self.lam_up
            state.lam[:] = np.clip(state.lam, self.lam_min * state.scale, self.lam_max * state.scale)
            todo = rej[state.lam[rej] < self.lam_max * state.scale[rej]]
        return x, state, progressed

"""Gauss-Newton / Levenberg-Marquardt steps whose subproblem is a QP (DESIGN section 3).

For each task (row) ``i`` with residuals ``r_i`` (m,) and Jacobian ``J_i = dr_i/dh`` (m, k) at
the current coefficients ``h_i`` (forward mode with k right-hand sides, from
``StepProblem.residual_jacobian``; never finite differences), the step ``delta`` solves

    min_delta ||r_i + J_i delta||^2 + lam_i ||delta||^2
              [subject to h_i + delta >= 0]              (constraint="nonneg")
              [+ alpha ||h_i + delta||_1]                (constraint="sparse")

Before any QP solver sees it, the (m + k, k) least squares is reduced to a k x k factor: with
``[J_i; sqrt(lam_i) I] = Q_i R_i`` (QR) and ``c_i = Q_i^T [r_i; 0]``, the objective is
``||R_i z - b_i||^2 + const`` over the new coefficients ``z = h_i + delta``, where
``b_i = R_i h_i - c_i``. All tasks' reduced subproblems of one step are solved together as one
block-separable QP (:mod:`solvers.qp_cvxpy`, compiled once per shape; or
:mod:`solvers.qp_direct`). For the constrained variants the backend's solution is then made
exact on its active set (:func:`solvers._blockqp.refine_active_set`: exact zeros, checked
against the KKT conditions), so the sparse variant reports true zeros whatever the backend.

Levenberg-Marquardt: a task's step is accepted if its true objective (loss plus penalty)
drops; then ``lam_i`` shrinks by ``lam_down``; otherwise the step is rejected and ``lam_i``
grows by ``lam_up``. Every task keeps its own ``lam_i``; all tasks are stepped together, so one
step costs one batched Q* evaluation (which also yields the Jacobian at the trial point, so
an accepted step needs no further evaluation). A step in which no task is accepted is retried
for the rejected tasks with their larger ``lam`` (up to ``max_retries`` times) before the solver
reports that it stalled.

Backend failures (``optimal_inaccurate``, ``user_limit``, other statuses, exceptions) are never
accepted silently: with ``fallback="backend"`` the QP is re-solved with the other backend,
then, if that fails too, a safe step is taken (one proximal-gradient step on the reduced
model, which cannot increase it), each time with a :class:`QPFallbackWarning`. With
``fallback="none"`` a failed status rejects the step (``lam`` up, with a warning) and a backend
exception is re-raised as :class:`factirl_opt.exceptions.SolverError`.
"""

import importlib.util
import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from factirl_opt.exceptions import SolverError, ValidationError

from ._base import StepSolver
from ._blockqp import BACKENDS, check_backend, check_constraint, refine_active_set

__all__ = ["GaussNewtonSolver", "GaussNewtonState", "QPFallbackWarning", "reduce_least_squares", "safe_step"]

INTERFACES = ("cvxpy", "direct")
FALLBACKS = ("backend", "safe-step", "none")


class QPFallbackWarning(RuntimeWarning):
    """A QP backend failed and the Gauss-Newton step used a fallback."""


@dataclass
class GaussNewtonState:
    """Levenberg-Marquardt state of every row.

    Attributes
    ----------
    loss : ndarray, shape (n,)
        Objective per row: ``||r_i||^2`` plus the solver's penalty.
    residual : ndarray, shape (n, m)
    jacobian : ndarray, shape (n, m, k)
        At the current coefficients.
    lam : ndarray, shape (n,)
        Damping per row.
    scale : ndarray, shape (n,)
        ``max(diag(J_i^T J_i))`` at the start of the run (1 where zero); ``lam`` bounds are
        relative to it.
    qp_time : float
        Total wall time spent in QP solves (backend calls included), seconds.
    qp_solves : int
        Number of block QP solves.
    qp_failures : int
        Block QP solves whose first backend failed.
    """

    loss: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray
    lam: np.ndarray
    scale: np.ndarray = None
    qp_time: float = 0.0
    qp_solves: int = 0
    qp_failures: int = 0


def reduce_least_squares(jacobian, residual, coefficients, lam):
    """Reduce each row's damped least squares to a k x k triangular factor (QR).

    ``||r + J (z - h)||^2 + lam ||z - h||^2 = ||R z - b||^2 + ||r_perp||^2`` for all z, with
    ``[J; sqrt(lam) I] = Q R`` and ``b = R h - Q^T [r; 0]``.

    Parameters
    ----------
    jacobian : ndarray, shape (n, m, k)
    residual : ndarray, shape (n, m)
    coefficients : ndarray, shape (n, k)
        ``h``.
    lam : ndarray, shape (n,)
        Damping (>= 0).

    Returns
    -------
    R : ndarray, shape (n, k, k)
        Upper triangular.
    b : ndarray, shape (n, k)
    """
    n, m, k = jacobian.shape
    M = np.concatenate([jacobian, np.sqrt(lam)[:, None, None] * np.eye(k)[None]], axis=1)
    Q, R = np.linalg.qr(M)  # batched, reduced: Q (n, m+k, k), R (n, k, k)
    c = np.einsum("nmk,nm->nk", Q[:, :m], residual)
    b = np.einsum("nij,nj->ni", R, coefficients) - c
    return R, b


def safe_step(R, b, coefficients, constraint="none", alpha=0.0):
    """One proximal-gradient step on ``||R z - b||^2 [+ alpha ||z||_1]`` from ``h`` (no QP solver).

    With step ``1 / L``, ``L = 2 ||R||_2^2`` (the gradient's Lipschitz constant), the step cannot
    increase the (damped) model; it is the fallback when every QP backend failed.

    Returns
    -------
    z : ndarray, shape (n, k)
        Feasible for ``constraint``.
    """
    h = np.asarray(coefficients, dtype=np.float64)
    L = 2.0 * np.linalg.norm(R, ord=2, axis=(1, 2)) ** 2
    L = np.where(L > 0, L, 1.0)
    grad = 2.0 * np.einsum("nji,nj->ni", R, np.einsum("nij,nj->ni", R, h) - b)
    z = h - grad / L[:, None]
    if constraint == "nonneg":
        z = np.maximum(z, 0.0)
    elif constraint == "sparse":
        z = np.sign(z) * np.maximum(np.abs(z) - alpha / L[:, None], 0.0)
    return z


def _check_number(value, name, low=None, high=None, low_open=True, integer=False):
    ok = not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating))
    if integer:
        ok = ok and float(value) == int(value)
    ok = ok and np.isfinite(float(value))
    if ok and low is not None:
        ok = value > low if low_open else value >= low
    if ok and high is not None:
        ok = value <= high
    if not ok:
        lo = "" if low is None else f"{'>' if low_open else '>='} {low}"
        hi = "" if high is None else f"<= {high}"
        bounds = " and ".join(b for b in (lo, hi) if b)
        kind = "an integer" if integer else "a finite number"
        raise ValidationError(f"{name} must be {kind}{' ' + bounds if bounds else ''}; got {value!r}")


@dataclass
class GaussNewtonSolver(StepSolver):
    """Levenberg-Marquardt steps with a QP subproblem per row, solved as one block QP.

    Parameters
    ----------
    backend : {"osqp", "clarabel"}, default="osqp"
        QP backend.
    constraint : {"none", "nonneg", "sparse"}, default="none"
        ``"nonneg"``: ``h >= 0`` (kept by :meth:`project`, so also in FactIRL's initialisation
        and transfer). ``"sparse"``: the objective gains ``alpha ||h||_1`` per row (reported by
        :meth:`penalty`).
    alpha : float, default=0.01
        L1 weight of the sparse variant (ignored otherwise), >= 0.
    interface : {"cvxpy", "direct"}, default="cvxpy"
        Solve the block QP through cvxpy (compiled once per shape with DPP parameters) or by
        calling the backend directly.
    fallback : {"backend", "safe-step", "none"}, default="backend"
        What to do when the backend fails (see the module docstring).
    damping : float, default=1e-3
        Initial ``lam_i = damping * max(diag(J_i^T J_i))`` (Marquardt's scale-free start), > 0.
    lam_down, lam_up : float, default=1/3 and 4
        Damping factor after an accepted (in (0, 1)) and a rejected step (> 1).
    lam_min, lam_max : float, default=1e-10 and 1e10
        Bounds on ``lam_i``, relative to the row's scale ``max(diag(J_i^T J_i))`` at the start of
        a run: the floor keeps the reduced factor ``R_i`` well conditioned (cond <= ~1e5) when
        some directions have no data (e.g. unvisited states of tabular rewards), which the
        backends need to certify optimality.
    max_retries : int, default=10
        Extra trials within one step when no row was accepted.
    xtol : float, default=1e-12
        A row whose step is below ``xtol * (||h|| + xtol)`` has converged: it is not evaluated.
    tolerance : dict, optional
        Per-backend accuracy, e.g. ``{"osqp": 1e-6, "clarabel": 1e-12}`` (OSQP's eps must be
        <= 1e-5; it always polishes). Defaults: :data:`solvers.qp_cvxpy.DEFAULT_TOLERANCE`.
    max_qp_iter : int, default=10000
        Backend iteration limit (reaching it counts as a failure).
    alternating_damping : float or None, default=1.0
        ``damping`` of the copy returned by :meth:`for_alternating`, i.e. of the H-step inside
        ``FactIRL.fit``; None keeps this solver's own damping there.
    alternating_lam_down : float, default=0.99
        ``lam_down`` of that copy.

    Notes
    -----
    In ``FactIRL.fit`` the H-step is one block of an alternating scheme. Plain LM (damping
    decreasing by 3x per accepted step) solves each task's coefficients almost exactly for the
    current, still poor dictionary: ``|h|`` grows until the Boltzmann policies saturate and
    the D-step's gradient vanishes (30 tasks, 10 outer iterations: loss 1.17 vs Armijo's
    0.18). The copy used there keeps the damping near ``1 * max(diag(J^T J))``: a proximal
    Gauss-Newton step that moves H gradually, as Armijo does, but along the Gauss-Newton
    direction (50 tasks, 40 outer iterations: loss 0.035 vs Armijo's 0.218, half the Q*
    evaluations). ``transfer`` (D fixed) uses the solver as configured.
    """

    backend: str = "osqp"
    constraint: str = "none"
    alpha: float = 0.01
    interface: str = "cvxpy"
    fallback: str = "backend"
    damping: float = 1e-3
    lam_down: float = 1.0 / 3.0
    lam_up: float = 4.0
    lam_min: float = 1e-10
    lam_max: float = 1e10
    max_retries: int = 10
    xtol: float = 1e-12
    tolerance: dict = None
    max_qp_iter: int = 10000
    alternating_damping: float = 1.0
    alternating_lam_down: float = 0.99
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    needs_jacobian = True

    def __post_init__(self):
        check_backend(self.backend)
        check_constraint(self.constraint)
        if self.interface not in INTERFACES:
            raise ValidationError(f"interface must be one of {INTERFACES}; got {self.interface!r}")
        if self.fallback not in FALLBACKS:
            raise ValidationError(f"fallback must be one of {FALLBACKS}; got {self.fallback!r}")
        _check_number(self.alpha, "alpha", low=0.0, low_open=False)
        _check_number(self.damping, "damping", low=0.0)
        _check_number(self.lam_down, "lam_down", low=0.0, high=1.0)
        if self.lam_down == 1.0:
            raise ValidationError(f"lam_down must be in (0, 1); got {self.lam_down!r}")
        _check_number(self.lam_up, "lam_up", low=1.0)
        _check_number(self.lam_min, "lam_min", low=0.0)
        _check_number(self.lam_max, "lam_max", low=self.lam_min)
        _check_number(self.max_retries, "max_retries", low=0, low_open=False, integer=True)
        _check_number(self.xtol, "xtol", low=0.0, low_open=False)
        _check_number(self.max_qp_iter, "max_qp_iter", low=0, integer=True)
        if self.alternating_damping is not None:
            _check_number(self.alternating_damping, "alternating_damping", low=0.0)
        _check_number(self.alternating_lam_down, "alternating_lam_down", low=0.0, high=1.0)
        if self.alternating_lam_down == 1.0:
            raise ValidationError(f"alternating_lam_down must be in (0, 1); got {self.alternating_lam_down!r}")
        tol = {} if self.tolerance is None else self.tolerance
        if not isinstance(tol, dict):
            raise ValidationError(f"tolerance must be a dict such as {{'osqp': 1e-6}}; got {type(tol).__name__}")
        for key, value in tol.items():
            check_backend(key)
            _check_number(value, f"tolerance[{key!r}]", low=0.0, high=1e-5 if key == "osqp" else 1e-6)
        self.tolerance = dict(tol)
        self.name = f"gn-qp-{self.backend}" + ("" if self.constraint == "none" else f"-{self.constraint}")
        if self.interface == "direct":
            self.name += "-direct"

    def for_alternating(self):
        """A proximal copy (``alternating_damping``, ``alternating_lam_down``) for FactIRL's fit."""
        if self.alternating_damping is None:
            return self
        return replace(self, damping=self.alternating_damping, lam_down=self.alternating_lam_down)

    # -- constraint handling shared with the learners ---------------------------------------
    def project(self, x):
        """Map coefficients to the feasible set: ``max(x, 0)`` for the nonneg variant."""
        x = np.asarray(x, dtype=np.float64)
        return np.maximum(x, 0.0) if self.constraint == "nonneg" else x

    def penalty(self, x):
        """``alpha ||x_i||_1`` per row for the sparse variant, zeros otherwise; shape (n,)."""
        x = np.asarray(x, dtype=np.float64)
        if self.constraint == "sparse":
            return self.alpha * np.abs(x).sum(axis=1)
        return np.zeros(x.shape[0])

    # -- the block QP -------------------------------------------------------------------------
    def _block_qp(self, n, k):
        key = (self.interface, n, k, self.constraint)
        if key not in self._cache:
            if self.interface == "cvxpy":
                from .qp_cvxpy import CvxpyBlockQP as cls
            else:
                from .qp_direct import DirectBlockQP as cls
            self._cache[key] = cls(n, k, self.constraint)
        return self._cache[key]

    def _backends(self):
        order = [self.backend]
        if self.fallback == "backend":
            order += [b for b in BACKENDS if b != self.backend and importlib.util.find_spec(BACKENDS[b]) is not None]
        return order if self.fallback != "safe-step" else order[:1]

    def solve_subproblems(self, R, b, x, state=None):
        """Solve the reduced subproblems of every row, with the failure handling.

        Parameters
        ----------
        R : ndarray, shape (n, k, k)
        b : ndarray, shape (n, k)
        x : ndarray, shape (n, k)
            Current coefficients (the safe step starts there).
        state : GaussNewtonState, optional
            Receives timing and failure counts.

        Returns
        -------
        z : ndarray, shape (n, k) or None
            New coefficients; None when the step must be rejected (``fallback="none"`` and a
            failed status).
        """
        n, k = x.shape
        qp = self._block_qp(n, k)
        # rescale every task to unit size: same minimiser (alpha / s^2 for the L1 term), and the
        # backends' absolute tolerances mean the same thing for a tiny Jacobian (near a fit)
        s = np.max(np.abs(R), axis=(1, 2))
        s[~(s > 0)] = 1.0
        Rs, bs, alphas = R / s[:, None, None], b / s[:, None], self.alpha / s**2
        failures = []
        for backend in self._backends():
            try:
                res = qp.solve(Rs, bs, backend, alpha=alphas, tolerance=self.tolerance.get(backend), max_iter=self.max_qp_iter)
            except ValidationError:
                raise
            except Exception as exc:  # any backend crash: recover below or re-raise as ours
                if self.fallback == "none":
                    raise SolverError(f"{self.name}: QP backend {backend!r} failed: {type(exc).__name__}: {exc}") from exc
                failures.append(f"{backend} raised {type(exc).__name__}: {exc}")
                continue
            finally:
                if state is not None:
                    state.qp_solves += 1
            if state is not None:
                state.qp_time += res.solve_time
            if res.ok:
                z, _ = refine_active_set(R, b, res.z, self.constraint, self.alpha)
                if failures:
                    warnings.warn(
                        f"{self.name}: {'; '.join(failures)}; used the {backend} solution instead",
                        QPFallbackWarning,
                        stacklevel=4,
                    )
                return z
            failures.append(f"{backend} returned status {res.status!r}")
            if state is not None and len(failures) == 1:
                state.qp_failures += 1
        if self.fallback == "none":
            warnings.warn(f"{self.name}: {'; '.join(failures)}; step rejected (damping increased)", QPFallbackWarning, stacklevel=4)
            return None
        reason = "; ".join(failures) if failures else "safe-step fallback requested"
        warnings.warn(f"{self.name}: {reason}; took a safe proximal-gradient step instead", QPFallbackWarning, stacklevel=4)
        z = safe_step(R, b, x, self.constraint, self.alpha)
        if not np.all(np.isfinite(z)):
            raise SolverError(f"{self.name}: every QP backend failed ({reason}) and the safe step is not finite")
        return z

    # -- init / update ------------------------------------------------------------------------
    def init_state(self, problem, x, previous=None):
        if problem.residual_jacobian is None:
            raise ValidationError(f"solver {self.name!r} needs a least-squares problem (StepProblem.residual_jacobian is None)")
        rows = np.arange(problem.n_rows)
        loss, r, J = problem.residual_jacobian(x, rows)
        loss = np.asarray(loss, dtype=np.float64) + self.penalty(x)
        if previous is not None and np.shape(getattr(previous, "lam", None)) == (problem.n_rows,):
            lam = previous.lam.copy()
        else:
            lam = None
        scale = np.max(np.einsum("nmk,nmk->nk", J, J), axis=1)
        scale[~(scale > 0)] = 1.0
        if lam is None:
            lam = self.damping * scale
        lam = np.clip(lam, self.lam_min * scale, self.lam_max * scale)
        return GaussNewtonState(
            loss=loss, residual=np.asarray(r, dtype=np.float64), jacobian=np.asarray(J, dtype=np.float64), lam=lam, scale=scale
        )

    def update(self, problem, x, state):
        n, k = x.shape
        x = x.copy()
        retry = np.ones(n, dtype=bool)  # rows allowed to try in this round
        accepted_any = converged_all = False
        for _ in range(int(self.max_retries) + 1):
            R, b = reduce_least_squares(state.jacobian, state.residual, x, state.lam)
            z = self.solve_subproblems(R, b, x, state)
            if z is None:  # failed status with fallback="none": reject every trying row
                state.lam[retry] = np.minimum(state.lam[retry] * self.lam_up, self.lam_max * state.scale[retry])
                break
            z = self.project(z)  # removes round-off below zero of a nonneg solution
            step = np.linalg.norm(z - x, axis=1)
            moving = step > self.xtol * (np.linalg.norm(x, axis=1) + self.xtol)
            trying = retry & moving
            if not trying.any():
                converged_all = True  # every row still allowed to move has a negligible step
                break
            rows = np.flatnonzero(trying)
            loss, r, J = problem.residual_jacobian(z[rows], rows)
            trial = np.asarray(loss, dtype=np.float64) + self.penalty(z[rows])
            ok = np.isfinite(trial) & (trial < state.loss[rows])
            acc, rej = rows[ok], rows[~ok]
            x[acc] = z[acc]
            state.loss[acc] = trial[ok]
            state.residual[acc] = r[ok]
            state.jacobian[acc] = J[ok]
            state.lam[acc] = np.maximum(state.lam[acc] * self.lam_down, self.lam_min * state.scale[acc])
            state.lam[rej] = np.minimum(state.lam[rej] * self.lam_up, self.lam_max * state.scale[rej])
            if ok.any():
                accepted_any = True
                break
            retry = np.zeros(n, dtype=bool)
            retry[rej[state.lam[rej] < self.lam_max * state.scale[rej]]] = True
            if not retry.any():
                break
        return x, state, bool(accepted_any or converged_all)

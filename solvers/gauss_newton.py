"""Gauss-Newton / Levenberg-Marquardt steps whose subproblem is a QP (docs/maths.md §5).

For each task (row) ``i`` with residuals ``r_i`` (m,) and Jacobian ``J_i = dr_i/dh`` (m, k) at
the current coefficients ``h_i`` (forward mode with k right-hand sides, from
``StepProblem.residual_jacobian``; never finite differences), the step ``delta`` solves

    min_delta ||r_i + J_i delta||^2 + lam_i ||delta||^2
              [subject to h_i + delta >= 0]              (constraint="nonneg")
              [+ alpha ||h_i + delta||_1]                (constraint="sparse")

Before any QP solver sees it, the (m + k, k) least squares is reduced to a k x k triangular
factor ``||R_i z - b_i||^2`` over the new coefficients ``z = h_i + delta``
(:func:`solvers.gn_subproblem.reduce_least_squares`). All tasks' reduced subproblems of one
step are solved together as one block-separable QP (:mod:`solvers.qp_cvxpy`, compiled once
per shape; or :mod:`solvers.qp_direct`). For the constrained variants the QP solver's solution
is then made exact on its active set (:func:`solvers._blockqp.refine_active_set`: exact
zeros, checked against the KKT conditions), so the sparse variant reports true zeros whatever
the QP solver.

Levenberg-Marquardt: a task's step is accepted if its true objective (loss plus penalty)
drops and is finite; then ``lam_i`` shrinks by ``lam_down``; otherwise the step is rejected and
``lam_i`` grows by ``lam_up``. Every task keeps its own ``lam_i``; all tasks are stepped together, so one
step costs one batched Q* evaluation (which also yields the Jacobian at the trial point, so
an accepted step needs no further evaluation). A step in which no task is accepted is retried
for the rejected tasks with their larger ``lam`` (up to ``max_retries`` times) before the solver
reports that it stalled.

QP solver failures (``optimal_inaccurate``, ``user_limit``, other statuses, exceptions) are never
accepted silently: with ``fallback="qp-solver"`` the QP is re-solved with the other QP solver,
then, if that fails too, a safe step is taken (one proximal-gradient step on the reduced
model, which cannot increase it), each time with a :class:`QPFallbackWarning`. With
``fallback="none"`` a failed status rejects the step (``lam`` up, with a warning) and a QP solver's
exception is re-raised as :class:`solvers.SolverError`.

Step bound (a trust-region-like cap): no row moves further than ``Delta_i = max_step_norm *
max(1, ||h_i||)`` in one step. Where the unconstrained step (``R_i^{-1} b_i - h_i``) would be
longer, ``lam_i`` is first raised to ``(2 ||J_i^T r_i|| + alpha sqrt(k)) / Delta_i``, which
bounds the damped subproblem's minimiser by ``Delta_i`` for every variant (the damped model is
``2 lam_i``-strongly convex); a constrained solution still longer than ``Delta_i`` is shortened
along its direction (:func:`solvers._base.limit_step`). This keeps the QP data bounded when a
row's Jacobian vanishes (saturated Boltzmann policies at large ``beta``: the undamped step
would be ``~ r / J``) and only acts on such steps: the default radius, 100, is 5x the longest
relative step seen in the well-behaved runs of the tests. A row whose Jacobian or residual is
exactly zero has a zero step: it makes no progress (and is not evaluated).

A ridge block (``StepProblem.ridge_params``: FactIRL's residual model, ``x_i = [h_i, delta_i]``
with ``lambda ||delta_i||^2``): with ``ridge="eliminate"`` (the default) and no constraint, the
block is eliminated from the subproblem in closed form
(:func:`solvers.gn_subproblem.eliminate_ridge`): the factorisations are of the Jacobian's
nonzero rows and the k kept coefficients, not of the stacked (m + p + k) x (k + p) system, and
the step is the stacked subproblem's exact minimiser (the same step up to round-off; the step
bound acts on the whole step, as without elimination). ``ridge="stack"`` factors the stacked
system as any other.
"""

from __future__ import annotations

import importlib.util
import warnings
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._base import StepProblem, StepSolver, limit_step, row_norms, trial_every_row, update_damping
from ._blockqp import CONSTRAINTS, DATA_LIMIT, QP_SOLVERS, check_constraint, check_qp_solver, refine_active_set
from ._validation import (
    check_evaluation,
    check_number,
    choice,
    deprecated,
    integer,
    number,
    option,
    optional,
    renamed_options,
    validate_fields,
)
from .exceptions import SolverError, SolverOptionError
from .gn_subproblem import (
    COMPILED_CACHE_SIZE,  # re-exported; the cache reads solvers.gn_subproblem.COMPILED_CACHE_SIZE
    compiled_block_qp,
    eliminate_ridge,
    reduce_least_squares,
    rescale_subproblems,
    safe_step,
    unconstrained_step_norm,
)

__all__ = [
    "GaussNewtonSolver",
    "GaussNewtonState",
    "QPFallbackWarning",
    "qp_solver_name",
    "reduce_least_squares",
    "rescale_subproblems",
    "safe_step",
]

INTERFACES = ("cvxpy", "direct")
RIDGE_ROUTES = ("eliminate", "stack")
FALLBACKS = ("qp-solver", "safe-step", "none")


def qp_solver_name(qp_solver: str, constraint: str = "none", interface: str = "cvxpy") -> str:
    """The name of a Gauss-Newton QP solver: ``gn-qp-{qp_solver}[-{constraint}][-direct]``.

    The one place the pattern is built: the registry registers ``qp_solver_name(b, c)`` for
    every QP solver and constraint; a solver with ``interface="direct"`` reports the same name
    with ``-direct`` appended (that name is not registered: pass ``interface="direct"``).

    Examples
    --------
    >>> qp_solver_name("osqp"), qp_solver_name("clarabel", "nonneg")
    ('gn-qp-osqp', 'gn-qp-clarabel-nonneg')
    """
    check_qp_solver(qp_solver)
    check_constraint(constraint)
    name = f"gn-qp-{qp_solver}" + ("" if constraint == "none" else f"-{constraint}")
    return name + ("-direct" if interface == "direct" else "")


class QPFallbackWarning(RuntimeWarning):
    """A QP solver failed and the Gauss-Newton step used a fallback."""


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
        Total wall time spent in QP solves (the QP solvers' calls included), seconds.
    qp_solves : int
        Number of block QP solves.
    qp_failures : int
        Block QP solves whose first QP solver failed.
    bounded_steps : int
        Row steps the step bound acted on (damping raised or step shortened).
    """

    loss: NDArray[np.float64]
    residual: NDArray[np.float64]
    jacobian: NDArray[np.float64]
    lam: NDArray[np.float64]
    scale: NDArray[np.float64]
    qp_time: float = 0.0
    qp_solves: int = 0
    qp_failures: int = 0
    bounded_steps: int = 0


@renamed_options(backend="qp_solver")
@dataclass
class GaussNewtonSolver(StepSolver):
    """Levenberg-Marquardt steps with a QP subproblem per row, solved as one block QP.

    Parameters
    ----------
    qp_solver : {"osqp", "clarabel"}, default="osqp"
        The QP solver (:data:`solvers.QP_SOLVERS`). ``backend`` is its deprecated name.
    constraint : {"none", "nonneg", "sparse"}, default="none"
        ``"nonneg"``: ``h >= 0`` (kept by :meth:`project`, so also in FactIRL's initialisation
        and transfer). ``"sparse"``: the objective gains ``alpha ||h||_1`` per row (reported by
        :meth:`penalty`).
    alpha : float, default=0.01
        L1 weight of the sparse variant (ignored otherwise), >= 0.
    interface : {"cvxpy", "direct"}, default="cvxpy"
        Solve the block QP through cvxpy (compiled once per shape with DPP parameters) or by
        calling the QP solver directly.
    fallback : {"qp-solver", "safe-step", "none"}, default="qp-solver"
        What to do when the QP solver fails (see the module docstring): re-solve with the
        other QP solver then take a safe step, take a safe step, or reject the step.
        ``"backend"`` is the deprecated name of ``"qp-solver"``.
    damping : float, default=1e-3
        Initial ``lam_i = damping * max(diag(J_i^T J_i))`` (Marquardt's scale-free start), > 0.
    lam_down, lam_up : float, default=1/3 and 4
        Damping factor after an accepted (in (0, 1)) and a rejected step (> 1).
    lam_min, lam_max : float, default=1e-10 and 1e10
        Bounds (``0 < lam_min < lam_max``) of the adaptation of ``lam_i``, relative to the row's scale ``max(diag(J_i^T J_i))`` at the start of
        a run: the floor keeps the reduced factor ``R_i`` well conditioned (cond <= ~1e5) when
        some directions have no data (e.g. unvisited states of tabular rewards), which the
        QP solvers need to certify optimality.
    max_retries : int, default=10
        Extra trials within one step when no row was accepted, >= 0.
    xtol : float, default=1e-12
        A row whose step is below ``xtol * (||h|| + xtol)`` has converged: it is not evaluated
        (>= 0).
    tolerance : dict, optional
        Accuracy per QP solver, e.g. ``{"osqp": 1e-6, "clarabel": 1e-12}`` (OSQP's eps must be
        <= 1e-5; it always polishes). Defaults: :data:`solvers.qp_cvxpy.DEFAULT_TOLERANCE`.
    max_qp_iter : int, default=10000
        QP solver iteration limit (reaching it counts as a failure), >= 1.
    alternating_damping : float or None, default=1.0
        ``damping`` of the copy returned by :meth:`for_alternating`, i.e. of the H-step inside
        ``FactIRL.fit``; None keeps this solver's own damping there.
    alternating_lam_down : float, default=0.99
        ``lam_down`` of that copy, in (0, 1).
    max_step_norm : float, default=100.0
        Step bound: no row moves further than ``max_step_norm * max(1, ||h_i||)`` in one step
        (see the module docstring), > 0.
    ridge : {"eliminate", "stack"}, default="eliminate"
        A problem's ridge block (``StepProblem.ridge_params``), with ``constraint="none"``:
        eliminated from each subproblem in closed form, or factored with the rest (the stacked
        system; the same steps up to round-off, at a higher cost). See the module docstring.

    Raises
    ------
    SolverOptionError
        When an option has the wrong type or value (every option is checked).

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

    qp_solver: str = option("osqp", choice(*QP_SOLVERS))
    constraint: str = option("none", choice(*CONSTRAINTS))
    alpha: float = option(0.01, number(low=0.0))
    interface: str = option("cvxpy", choice(*INTERFACES))
    fallback: str = option("qp-solver", choice(*FALLBACKS))
    damping: float = option(1e-3, number(low=0.0, low_open=True))
    lam_down: float = option(1.0 / 3.0, number(0.0, 1.0, low_open=True, high_open=True))
    lam_up: float = option(4.0, number(low=1.0, low_open=True))
    lam_min: float = option(1e-10, number(low=0.0, low_open=True))
    lam_max: float = option(1e10, number(low=0.0, low_open=True))
    max_retries: int = option(10, integer(low=0))
    xtol: float = option(1e-12, number(low=0.0))
    tolerance: dict[str, float] = option(None, lambda value, name, owner: _check_tolerance(value, owner))
    max_qp_iter: int = option(10000, integer(low=1))
    alternating_damping: float | None = option(1.0, optional(number(low=0.0, low_open=True)))
    alternating_lam_down: float = option(0.99, number(0.0, 1.0, low_open=True, high_open=True))
    max_step_norm: float = option(100.0, number(low=0.0, low_open=True))
    ridge: str = option("eliminate", choice(*RIDGE_ROUTES))
    _cache: dict[tuple[str, int, int, str], Any] = field(default_factory=dict, init=False, repr=False, compare=False)

    needs_jacobian = True

    def __post_init__(self) -> None:
        if self.fallback == "backend":
            deprecated('GaussNewtonSolver: fallback="backend" was renamed fallback="qp-solver"; the old value will be '
                       "removed in the next release", stacklevel=5)
            self.fallback = "qp-solver"
        valid = self.qp_solver in QP_SOLVERS and self.constraint in CONSTRAINTS
        validate_fields(self, qp_solver_name(self.qp_solver, self.constraint) if valid else "gn-qp")
        self.name = qp_solver_name(self.qp_solver, self.constraint, self.interface)
        if not self.lam_min < self.lam_max:
            raise SolverOptionError(f"{self.name}: lam_max must be > lam_min = {self.lam_min!r}; got {self.lam_max!r}")

    @property
    def backend(self) -> str:
        """Deprecated name of :attr:`qp_solver` (warns)."""
        deprecated("GaussNewtonSolver.backend was renamed qp_solver; the old name will be removed in the next release")
        return self.qp_solver

    def for_alternating(self) -> GaussNewtonSolver:
        """A proximal copy (``alternating_damping``, ``alternating_lam_down``) for FactIRL's fit."""
        if self.alternating_damping is None:
            return self
        return replace(self, damping=self.alternating_damping, lam_down=self.alternating_lam_down)

    def gradient(self, state: GaussNewtonState) -> NDArray[np.float64]:
        """``2 J_i^T r_i`` of the least-squares part (the penalty is handled by :meth:`optimality`)."""
        return 2.0 * np.einsum("nmk,nm->nk", state.jacobian, state.residual)

    def optimality(self, x: ArrayLike, grad: ArrayLike) -> NDArray[np.float64]:
        """The projected gradient (nonneg) or the minimum-norm subgradient of ``f + alpha ||x||_1`` (sparse)."""
        if self.constraint != "sparse":
            return super().optimality(x, grad)
        x, g = np.asarray(x, dtype=np.float64), np.asarray(grad, dtype=np.float64)
        at_zero = np.sign(g) * np.maximum(np.abs(g) - self.alpha, 0.0)
        return row_norms(np.where(x != 0.0, g + self.alpha * np.sign(x), at_zero))

    # -- constraint handling shared with the learners ---------------------------------------
    def project(self, x: ArrayLike) -> NDArray[np.float64]:
        """Map coefficients to the feasible set: ``max(x, 0)`` for the nonneg variant."""
        x = np.asarray(x, dtype=np.float64)
        return np.maximum(x, 0.0) if self.constraint == "nonneg" else x

    def penalty(self, x: ArrayLike) -> NDArray[np.float64]:
        """``alpha ||x_i||_1`` per row for the sparse variant, zeros otherwise; shape (n,)."""
        x = np.asarray(x, dtype=np.float64)
        if self.constraint == "sparse":
            return self.alpha * np.abs(x).sum(axis=1)
        return np.zeros(x.shape[0])

    # -- the block QP -------------------------------------------------------------------------
    def _block_qp(self, n: int, k: int) -> Any:
        """The compiled block QP of this shape: from this solver's cache, else this thread's."""
        key = (self.interface, n, k, self.constraint)
        if key not in self._cache:
            self._cache[key] = compiled_block_qp(*key)
        return self._cache[key]

    def _qp_solvers(self) -> list[str]:
        order = [self.qp_solver]
        if self.fallback == "qp-solver":
            order += [b for b in QP_SOLVERS if b != self.qp_solver and importlib.util.find_spec(b) is not None]
        return order if self.fallback != "safe-step" else order[:1]

    def solve_subproblems(
        self, R: NDArray[np.float64], b: NDArray[np.float64], x: NDArray[np.float64], state: GaussNewtonState | None = None
    ) -> NDArray[np.float64] | None:
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
        fresh = (self.interface, n, k, self.constraint) not in self._cache  # this solver's first use of the shape
        qp = self._block_qp(n, k)
        Rs, bs, alphas = rescale_subproblems(R, b, self.alpha if self.constraint == "sparse" else 0.0)
        failures, qp_solvers = [], self._qp_solvers()
        big = max(np.max(np.abs(bs), initial=0.0), np.max(alphas, initial=0.0))
        if not big <= DATA_LIMIT:  # cannot happen after the step bound; never feed it to a QP solver
            failures, qp_solvers = [f"the rescaled QP data reach {big:.3g} (limit {DATA_LIMIT:g})"], []
        for qp_solver in qp_solvers:
            try:
                res = qp.solve(Rs, bs, qp_solver, alpha=alphas, tolerance=self.tolerance.get(qp_solver), max_iter=self.max_qp_iter,
                               fresh=fresh)
                fresh = False
            except SolverOptionError as exc:  # our own data check: a bug, not the user's option
                raise SolverError(f"{self.name}: the block QP rejected its data: {exc}") from exc
            except Exception as exc:  # any QP solver crash: recover below or re-raise as ours
                if self.fallback == "none":
                    raise SolverError(f"{self.name}: QP solver {qp_solver!r} failed: {type(exc).__name__}: {exc}") from exc
                failures.append(f"{qp_solver} raised {type(exc).__name__}: {exc}")
                continue
            finally:
                if state is not None:
                    state.qp_solves += 1
            if state is not None:
                state.qp_time += res.solve_time
            if res.ok:
                z, _ = refine_active_set(R, b, res.z, self.constraint, self.alpha)
                if failures:
                    warnings.warn(f"{self.name}: {'; '.join(failures)}; used the {qp_solver} solution instead", QPFallbackWarning, stacklevel=4)
                return z
            failures.append(f"{qp_solver} returned status {res.status!r}")
            if state is not None and len(failures) == 1:
                state.qp_failures += 1
        return self._after_failures(R, b, x, failures)

    def _after_failures(self, R, b, x, failures):
        """Every QP solver failed: reject the step (``fallback="none"``) or take a safe step."""
        if self.fallback == "none":
            warnings.warn(f"{self.name}: {'; '.join(failures)}; step rejected (damping increased)", QPFallbackWarning, stacklevel=5)
            return None
        reason = "; ".join(failures) if failures else "safe-step fallback requested"
        warnings.warn(f"{self.name}: {reason}; took a safe proximal-gradient step instead", QPFallbackWarning, stacklevel=5)
        z = safe_step(R, b, x, self.constraint, self.alpha)
        if not np.all(np.isfinite(z)):
            raise SolverError(f"{self.name}: every QP solver failed ({reason}) and the safe step is not finite")
        return z

    # -- init / update ------------------------------------------------------------------------
    def _evaluate(self, problem, x, rows, start=False):
        """``residual_jacobian`` at ``x`` (rows ``rows``), checked; plus the penalty."""
        out = problem.residual_jacobian(x, rows)
        if not (isinstance(out, tuple) and len(out) == 3):
            raise SolverError(f"{self.name}: problem.residual_jacobian must return (loss, residual, jacobian)")
        k = problem.n_params
        loss, (r, J), finite = check_evaluation(self.name, "residual_jacobian", rows, *out, shapes=[(None,), (None, k)], start=start)
        if J.shape[1] != r.shape[1]:
            raise SolverError(f"{self.name}: problem.residual_jacobian returned residuals {r.shape} and a Jacobian {J.shape}")
        return loss + self.penalty(x), r, J, finite

    def init_state(self, problem: StepProblem, x: NDArray[np.float64], previous: Any = None) -> GaussNewtonState:
        if problem.residual_jacobian is None:
            raise SolverOptionError(f"solver {self.name!r} needs a least-squares problem (StepProblem.residual_jacobian is None)")
        rows = np.arange(problem.n_rows)
        loss, r, J, _ = self._evaluate(problem, x, rows, start=True)
        with np.errstate(over="ignore"):
            scale = np.max(np.einsum("nmk,nmk->nk", J, J), axis=1)
        if not np.all(np.isfinite(scale)):
            bad = np.flatnonzero(~np.isfinite(scale))
            raise SolverError(
                f"{self.name}: the Jacobian of rows {bad[:10].tolist()} is too large to square (max |J| = "
                f"{np.max(np.abs(J[bad])):.3g}); rescale the problem"
            )
        scale[~(scale > 0)] = 1.0
        lam: Any = getattr(previous, "lam", None)
        if not (np.shape(lam) == (problem.n_rows,) and np.all(np.isfinite(lam)) and np.all(lam > 0)):
            lam = self.damping * scale
        lam = np.maximum(np.clip(lam, self.lam_min * scale, self.lam_max * scale), np.finfo(np.float64).tiny)
        return GaussNewtonState(loss=loss, residual=r, jacobian=J, lam=lam.copy(), scale=scale)

    def _factors(self, x, state):
        """The reduced factors of every row, after enforcing the step bound on ``lam``."""
        R, b = reduce_least_squares(state.jacobian, state.residual, x, state.lam)
        radius = self.max_step_norm * np.maximum(1.0, np.linalg.norm(x, axis=1))
        far = ~(unconstrained_step_norm(R, b, x) <= radius)  # too long, or not finite
        if far.any():
            J, r = state.jacobian[far], state.residual[far]
            g = np.linalg.norm(np.einsum("nmk,nm->nk", J, r), axis=1)
            extra = self.alpha * np.sqrt(x.shape[1]) if self.constraint == "sparse" else 0.0
            state.lam[far] = np.maximum(state.lam[far], (2.0 * g + extra) / radius[far])
            R[far], b[far] = reduce_least_squares(J, r, x[far], state.lam[far])
            state.bounded_steps += int(far.sum())
        return R, b

    def update(
        self, problem: StepProblem, x: NDArray[np.float64], state: GaussNewtonState
    ) -> tuple[NDArray[np.float64], GaussNewtonState, bool]:
        n, k = x.shape
        x = x.copy()
        retry = np.ones(n, dtype=bool)  # rows allowed to try in this round
        accepted_any = converged_all = False
        ridge = self._ridge(problem)
        for _ in range(int(self.max_retries) + 1):
            z = None if ridge is None else self._eliminated_steps(x, state, np.arange(n), *ridge)
            if z is None:
                R, b = self._factors(x, state)
                z = self.solve_subproblems(R, b, x, state)
            if z is None:  # failed status with fallback="none": reject every trying row
                state.lam[retry] = np.minimum(state.lam[retry] * self.lam_up, self.lam_max * state.scale[retry])
                break
            z = self.project(z)  # removes round-off below zero of a nonneg solution
            z, shortened = limit_step(x, z, self.max_step_norm)
            state.bounded_steps += int(shortened.sum())
            step = np.linalg.norm(z - x, axis=1)
            moving = step > self.xtol * (np.linalg.norm(x, axis=1) + self.xtol)
            trying = retry & moving
            if not trying.any():
                converged_all = True  # every row still allowed to move has a negligible step
                break
            rows = np.flatnonzero(trying)
            trial, r, J, finite = self._evaluate(problem, z[rows], rows)
            with np.errstate(invalid="ignore"):
                ok = finite & (trial < state.loss[rows])
            acc, rej = rows[ok], rows[~ok]
            x[acc] = z[acc]
            state.loss[acc] = trial[ok]
            state.residual[acc] = r[ok]
            state.jacobian[acc] = J[ok]
            retry = update_damping(self, state, acc, rej, n)
            if ok.any():
                accepted_any = True
                break
            if not retry.any():
                break
        return x, state, bool(accepted_any or converged_all)


    # -- separable runs -----------------------------------------------------------------------
    def _row_factors(self, x, state, rows):
        """:meth:`_factors` of rows ``rows`` only (the step bound raises only their ``lam``)."""
        J, r, lam = state.jacobian[rows], state.residual[rows], state.lam[rows]
        R, b = reduce_least_squares(J, r, x, lam)
        radius = self.max_step_norm * np.maximum(1.0, np.linalg.norm(x, axis=1))
        far = ~(unconstrained_step_norm(R, b, x) <= radius)
        if far.any():
            g = np.linalg.norm(np.einsum("nmk,nm->nk", J[far], r[far]), axis=1)
            extra = self.alpha * np.sqrt(x.shape[1]) if self.constraint == "sparse" else 0.0
            lam[far] = np.maximum(lam[far], (2.0 * g + extra) / radius[far])
            state.lam[rows] = lam
            R[far], b[far] = reduce_least_squares(J[far], r[far], x[far], lam[far])
            state.bounded_steps += int(far.sum())
        return R, b

    def _ridge(self, problem: StepProblem) -> tuple[int, float] | None:
        """``(q, lambda)`` of the problem's ridge block where this solver eliminates it, else None."""
        q = int(getattr(problem, "ridge_params", 0))
        if q > 0 and self.ridge == "eliminate" and self.constraint == "none":
            return q, float(problem.ridge_penalty)
        return None

    def _eliminated_steps(self, x, state, rows, size, penalty):
        """The exact minimisers ``[h', d']`` (r, k + q) of rows ``rows``' damped subproblems with
        the ridge block eliminated, after the step bound (which raises only their ``lam``, as
        :meth:`_row_factors`); None where a minimiser is not finite (the stacked route then
        takes the step)."""
        J, r, lam = state.jacobian[rows], state.residual[rows], state.lam[rows]
        z = eliminate_ridge(J, r, x, lam, size, penalty).minimiser()
        radius = self.max_step_norm * np.maximum(1.0, np.linalg.norm(x, axis=1))
        with np.errstate(all="ignore"):
            far = ~(np.linalg.norm(z - x, axis=1) <= radius)
        if far.any():
            g = np.linalg.norm(np.einsum("nmk,nm->nk", J[far], r[far]), axis=1)
            lam[far] = np.maximum(lam[far], 2.0 * g / radius[far])
            state.lam[rows] = lam
            z[far] = eliminate_ridge(J[far], r[far], x[far], lam[far], size, penalty).minimiser()
            state.bounded_steps += int(far.sum())
        return z if np.all(np.isfinite(z)) else None

    def _solve_rows(self, R, b, x, state):
        """The subproblems of a separable step: without a constraint, the exact minimiser
        ``R_i^{-1} b_i`` of every row (a QP solver's answer depends on the other rows through
        its joint stopping test); with one, the block QP (:meth:`solve_subproblems`)."""
        if self.constraint == "none":
            try:
                z = np.linalg.solve(R, b[..., None])[..., 0]
            except np.linalg.LinAlgError:
                z = None
            if z is not None and np.all(np.isfinite(z)):
                return z
        return self.solve_subproblems(R, b, x, state)

    def step_rows(
        self, problem: StepProblem, x: NDArray[np.float64], state: GaussNewtonState
    ) -> tuple[NDArray[np.float64], GaussNewtonState, NDArray[np.bool_]]:
        """One Levenberg-Marquardt step per row, each row as it would step alone: a rejected row
        retries with its larger damping (up to ``max_retries`` times) whatever the other rows
        did, and the unconstrained subproblem is solved exactly (:meth:`_solve_rows`).
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
        self, problem: StepProblem, x: NDArray[np.float64], state: GaussNewtonState, todo: NDArray[np.intp],
        progressed: NDArray[np.bool_],
    ) -> tuple[NDArray[np.intp], NDArray[np.intp]] | None:
        """One trial of rows ``todo``: ``x``, ``state`` and ``progressed`` updated in place where a
        row is accepted or its step negligible; the accepted and rejected rows, or None where no
        row was evaluated (every step negligible, or a failed QP whose rows' damping was raised)."""
        ridge = self._ridge(problem)
        z = None if ridge is None else self._eliminated_steps(x[todo], state, todo, *ridge)
        if z is None:
            R, b = self._row_factors(x[todo], state, todo)
            z = self._solve_rows(R, b, x[todo], state)
        if z is None:  # failed status with fallback="none": reject every trying row
            state.lam[todo] = np.minimum(state.lam[todo] * self.lam_up, self.lam_max * state.scale[todo])
            return None
        z = self.project(z)
        z, shortened = limit_step(x[todo], z, self.max_step_norm)
        state.bounded_steps += int(shortened.sum())
        step = np.linalg.norm(z - x[todo], axis=1)
        moving = step > self.xtol * (np.linalg.norm(x[todo], axis=1) + self.xtol)
        progressed[todo[~moving]] = True  # a negligible step: the row has converged
        rows, z = todo[moving], z[moving]
        if rows.size == 0:
            return None
        trial, r, J, finite = self._evaluate(problem, z, rows)
        with np.errstate(invalid="ignore"):
            ok = finite & (trial < state.loss[rows])
        acc, rej = rows[ok], rows[~ok]
        x[acc] = z[ok]
        state.loss[acc] = trial[ok]
        state.residual[acc] = r[ok]
        state.jacobian[acc] = J[ok]
        progressed[acc] = True
        return acc, rej

    def trial_rows(
        self, problem: StepProblem, x: NDArray[np.float64], state: GaussNewtonState, tries: NDArray[np.intp]
    ) -> tuple[NDArray[np.float64], GaussNewtonState, NDArray[np.bool_], NDArray[np.bool_]]:
        """One trial of every row, the rounds of :meth:`step_rows` taken one at a time: a
        rejected row that may retry (damping below its cap, fewer than ``max_retries`` retries
        in this step: ``tries``) is ``pending`` and retries in the next round, so each row's
        trials are those of :meth:`step_rows` while rows at different retries share one batched
        evaluation (:func:`solvers.separable.run_separable`)."""
        return trial_every_row(self, problem, x, state, tries)


def _check_tolerance(value: Any, owner: str) -> dict[str, float]:
    """The ``tolerance`` option: None or a dict from QP solver names to accuracies."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise SolverOptionError(f"{owner}: tolerance must be a dict such as {{'osqp': 1e-6}}; got {value!r} ({type(value).__name__})")
    for key, tol in value.items():
        if key not in QP_SOLVERS:
            raise SolverOptionError(f"{owner}: tolerance keys must be QP solvers {QP_SOLVERS}; got {key!r}")
        check_number(tol, f"tolerance[{key!r}]", owner, low=0.0, high=1e-5 if key == "osqp" else 1e-6, low_open=True)
    return dict(value)



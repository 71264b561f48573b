"""What every step solver shares: the problem it sees, its result type, and the outer loop.

A step solver never sees an MDP. It sees a :class:`StepProblem`: a smooth objective that is a
sum of independent rows (tasks), over parameters ``x`` of shape (n, p), given as callables.
Solvers follow the init/update pattern (as in jaxopt) so Armijo descent, L-BFGS and the
Gauss-Newton steps share one outer loop, :meth:`StepSolver.run`, and one stopping rule,
:func:`solvers.stopping.has_converged`.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .exceptions import SolverError, SolverOptionError
from .observe import notify, observing
from ._validation import check_number
from .stopping import gradient_converged, has_converged, has_saturated, relative_decrease

__all__ = ["StepProblem", "Linearization", "SolverResult", "StepSolver", "limit_step", "row_norms"]


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
    linearize : callable or None
        ``(x_rows, rows) -> Linearization``: loss, residual and matrix-free products with the
        Jacobian of the residual at ``x_rows`` (see :class:`Linearization`); None when the
        problem has no least-squares form or no matrix-free derivative. Used by ``gn-cg``.
    hessian : callable or None
        ``(x_rows, rows) -> (r, p, p)``: the Hessian of every row's loss at ``x_rows``
        (symmetric, possibly indefinite); None when the problem gives none. Called at points
        where ``loss_and_grad`` was just evaluated. Used by ``newton``.
    ridge_params : int, default=0
        q > 0 declares a ridge block: the last q parameters ``d_i`` of every row enter the loss
        also through ``ridge_penalty * ||d_i||^2``, whose residuals ``sqrt(ridge_penalty) d_i``
        are the last q entries of ``residual_jacobian``'s residuals (its Jacobian's last q rows
        ``[0, sqrt(ridge_penalty) I]``). The Gauss-Newton QP solver then eliminates the block
        in closed form (:func:`solvers.gn_subproblem.eliminate_ridge`); other solvers ignore it.
        0 <= q < ``n_params``.
    ridge_penalty : float, default=0.0
        The ridge block's penalty, finite and >= 0.

    Raises
    ------
    SolverOptionError
        When a callable is not callable or a size is not a positive integer.
    """

    loss_and_grad: Callable
    n_evaluations: Callable[[], int]
    n_rows: int
    n_params: int
    residual_jacobian: Optional[Callable] = None
    linearize: Optional[Callable] = None
    hessian: Optional[Callable] = None
    ridge_params: int = 0
    ridge_penalty: float = 0.0

    def __post_init__(self) -> None:
        for name in ("loss_and_grad", "n_evaluations", "residual_jacobian", "linearize", "hessian"):
            value = getattr(self, name)
            if not callable(value) and not (value is None and name in ("residual_jacobian", "linearize", "hessian")):
                raise SolverOptionError(f"StepProblem: {name} must be callable; got {value!r} ({type(value).__name__})")
        check_number(self.n_rows, "n_rows", "StepProblem", low=1, integer=True)
        check_number(self.n_params, "n_params", "StepProblem", low=1, integer=True)
        check_number(self.ridge_params, "ridge_params", "StepProblem", low=0, high=self.n_params - 1, integer=True)
        check_number(self.ridge_penalty, "ridge_penalty", "StepProblem", low=0.0)


@dataclass(frozen=True)
class Linearization:
    """A least-squares problem linearised at some rows: residuals and matrix-free Jacobian products.

    What ``StepProblem.linearize(x_rows, rows)`` returns for ``r`` rows with residuals
    ``r_i(x_i)`` of size ``m`` and Jacobians ``J_i = dr_i/dx_i`` (m, p) that are never formed.

    Attributes
    ----------
    loss : ndarray, shape (r,)
        ``||r_i||^2`` per row (the row's objective, as for ``residual_jacobian``).
    residual : ndarray, shape (r, m)
    jvp : callable
        ``V (r, p) -> (r, m)``: ``J_i v_i`` for every row (forward mode; for the IRL
        objective one batched linear solve through Q*).
    vjp : callable
        ``U (r, m) -> (r, p)``: ``J_i^T u_i`` for every row (the adjoint).

    Notes
    -----
    The two products must be consistent, ``<J_i v, u> = <v, J_i^T u>`` for every row; the
    gradient of the loss is ``2 J_i^T r_i = 2 vjp(residual)``.
    """

    loss: NDArray[np.float64]
    residual: NDArray[np.float64]
    jvp: Callable
    vjp: Callable


@dataclass
class SolverResult:
    """The one result type of every step solver.

    Attributes
    ----------
    coefficients : ndarray, shape (n, p)
        The new parameters (coefficients ``H`` for an H-step).
    status : str
        ``"converged"`` (relative decrease below ``tol``, or gradient norm below ``gtol`` times
        its initial value; :mod:`solvers.stopping`), ``"max_iter"``, or ``"stalled"`` (no row
        could make progress).
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
    reason : str
        Why the run stopped, in words (the rule and the values that met it).
    gradient_norm : float
        Norm of the first-order optimality measure at the final point, over all rows
        (:meth:`StepSolver.optimality`); inf if it overflowed, NaN if the solver's state
        holds no gradient.
    row_status : ndarray of str, shape (n,), optional
        A separable run's status of every row (``"converged"``, ``"max_iter"`` or
        ``"stalled"``, by the row's own rules; :mod:`solvers.separable`); None otherwise.
    row_iterations : ndarray of int, shape (n,), optional
        A separable run's steps taken by every row before it stopped; None otherwise.
    row_evaluations : ndarray of int, shape (n,), optional
        A separable run's evaluations of every row (calls of the problem's callables that
        included the row); None otherwise.
    """

    coefficients: NDArray[np.float64]
    status: str
    iterations: int
    solve_time: float
    loss: NDArray[np.float64]
    n_evaluations: int
    loss_history: list[float] = field(default_factory=list)
    state: Any = None
    reason: str = ""
    gradient_norm: float = float("nan")
    row_status: Optional[NDArray[np.str_]] = None
    row_iterations: Optional[NDArray[np.intp]] = None
    row_evaluations: Optional[NDArray[np.intp]] = None


class StepSolver:
    """Base class of step solvers: subclasses define ``init_state`` and ``update``.

    Attributes
    ----------
    name : str
        Registry name (a class attribute, as are the three below).
    needs_jacobian : bool
        Whether the solver calls ``problem.residual_jacobian``.
    needs_linearization : bool
        Whether the solver calls ``problem.linearize``.
    constraint : str
        ``"none"``, ``"nonneg"`` (:meth:`project` keeps ``x >= 0``) or ``"sparse"``
        (:meth:`penalty` adds an L1 term); learners use it to keep the constraint in their
        initialisation. ``"proximal"``: a projection and/or penalty given as callables
        (:class:`solvers.proximal.ProximalArmijoSolver`).
    """

    name: str = "base"
    needs_jacobian: bool = False
    needs_linearization: bool = False
    constraint: str = "none"

    def project(self, x: ArrayLike) -> NDArray[np.float64]:
        """Map parameters to the solver's feasible set (identity when unconstrained)."""
        return np.asarray(x, dtype=np.float64)

    def penalty(self, x: ArrayLike) -> NDArray[np.float64]:
        """Per-row penalty the solver adds to the loss (zero when there is none), shape (n,)."""
        return np.zeros(np.shape(x)[0])

    def for_alternating(self) -> StepSolver:
        """The solver to use as one block of an alternating scheme (FactIRL's H-step in fit).

        In alternating minimisation the sub-problem over H need not (and, while D is still
        poor, should not) be solved accurately. The default is the solver itself; a solver
        whose steps solve their sub-problem aggressively returns a more conservative copy.
        """
        return self

    def gradient(self, state: Any) -> NDArray[np.float64] | None:
        """Gradient of every row's smooth objective at the state's point, shape (n, p), or None.

        The default reads ``state.grad`` (None when the state has none: the run then stops by
        the other rules only); solvers whose state holds another quantity (half the gradient,
        or residuals and a Jacobian) override this.
        """
        return getattr(state, "grad", None)

    def optimality(self, x: ArrayLike, grad: ArrayLike) -> NDArray[np.float64]:
        """First-order optimality measure of every row, shape (n,): zero at a stationary point.

        The norm of the gradient for an unconstrained solver; of the projected gradient for
        ``constraint="nonneg"`` (components at the bound pointing outwards are dropped).
        Solvers with a penalty override this (the minimum-norm subgradient).

        Parameters
        ----------
        x : ndarray, shape (n, p)
        grad : ndarray, shape (n, p)
            Gradient of the smooth objective at ``x`` (:meth:`gradient`).
        """
        g = np.asarray(grad, dtype=np.float64)
        if self.constraint == "nonneg":
            g = np.where((np.asarray(x) <= 0.0) & (g > 0.0), 0.0, g)
        return row_norms(g)

    def _gradient_norm(self, x: NDArray[np.float64], state: Any) -> float:
        """Total optimality measure over all rows (the gradient rule's norm): inf on overflow,
        NaN when the solver's state has no gradient."""
        grad = self.gradient(state)
        if grad is None:
            return float("nan")
        with np.errstate(over="ignore", invalid="ignore"):
            norm = float(row_norms(self.optimality(x, grad)[None])[0])
        return norm if np.isfinite(norm) else np.inf

    def carry_over(self, state: Any) -> Any:
        """What of a run's final ``state`` should warm-start a run on a *changed* problem.

        In an alternating scheme a block's sub-problem changes between two of its runs (the
        other block moved). Scalars that describe the scale of a step (Armijo step sizes,
        Levenberg-Marquardt damping) remain good guesses; information tied to the old
        problem's curvature (L-BFGS pairs) is stale and misleads the next run. The default
        keeps the whole state; solvers with problem-specific memory override this.
        """
        return state

    def init_state(self, problem: StepProblem, x: NDArray[np.float64], previous: Any = None) -> Any:  # pragma: no cover - interface
        raise NotImplementedError

    def update(self, problem: StepProblem, x: NDArray[np.float64], state: Any) -> tuple[NDArray[np.float64], Any, bool]:  # pragma: no cover - interface
        """One step for every row; returns ``(x_new, state, progressed)``."""
        raise NotImplementedError

    def step_rows(self, problem: StepProblem, x: NDArray[np.float64], state: Any) -> tuple[NDArray[np.float64], Any, NDArray[np.bool_]]:
        """One step of every row in which each row moves as it would alone; ``(x_new, state, progressed)``
        with ``progressed`` of shape (n,), the rows that made progress (or converged by a
        negligible step).

        The step of a separable run (:mod:`solvers.separable`): a row's trial points may not
        depend on the other rows (e.g. no retry decided by whether another row was accepted).
        The default is :meth:`update` with its one flag repeated, exact for solvers whose rows
        never interact; the registered solvers override it.
        """
        x_new, state, progressed = self.update(problem, x, state)
        return x_new, state, np.full(problem.n_rows, bool(progressed))

    def trial_rows(self, problem: StepProblem, x: NDArray[np.float64], state: Any,
                   tries: NDArray[np.intp]) -> tuple[NDArray[np.float64], Any, NDArray[np.bool_], NDArray[np.bool_]]:
        """One round of a separable run: ``(x_new, state, progressed, pending)``, each (n,) for the last two.

        A row is ``pending`` when it tried a step, was rejected, and retries it in the next
        round (its retries in this step so far: ``tries``, shape (n,)); the other rows finished
        a step as in :meth:`step_rows` (``progressed`` as there). Rounds let a row retry while
        the others go on, so a retry shares a batched evaluation with the other rows' next
        steps instead of costing one of its own, and each row's trials stay those of a run on
        that row alone. The default is :meth:`step_rows` with no row pending; the
        Levenberg-Marquardt solvers take one trial per round.
        """
        x_new, state, progressed = self.step_rows(problem, x, state)
        progressed = np.asarray(progressed, dtype=bool)
        if progressed.shape != (problem.n_rows,):
            raise SolverError(f"{self.name}: step_rows returned progress of shape {progressed.shape}; expected "
                              f"({problem.n_rows},)")
        return x_new, state, progressed, np.zeros(problem.n_rows, dtype=bool)

    def take_rows(self, state: Any, rows: NDArray[np.intp]) -> Any:
        """The state of rows ``rows`` only (a separable run drops the rows that stopped).

        The default slices every array field of a dataclass state whose leading axis has one
        entry per row (its length is that of ``state.loss``) and keeps the other fields;
        solvers whose state holds other per-row objects override it.

        Raises
        ------
        SolverError
            When the state is not a dataclass with a ``loss`` array.
        """
        n = _state_rows(self.name, state)
        return dataclasses.replace(state, **{f.name: getattr(state, f.name)[rows] for f in dataclasses.fields(state)
                                             if _per_row(getattr(state, f.name), n)})

    def put_rows(self, state: Any, rows: NDArray[np.intp], part: Any) -> Any:
        """``state`` with the rows ``rows`` replaced by those of ``part`` (a :meth:`take_rows`
        state that was stepped on); its other fields (counters) are taken from ``part``."""
        n = _state_rows(self.name, state)
        out = {}
        for f in dataclasses.fields(state):
            value, new = getattr(state, f.name), getattr(part, f.name)
            if _per_row(value, n):
                value = value.copy()
                value[rows] = new
                out[f.name] = value
            else:
                out[f.name] = new
        return dataclasses.replace(state, **out)

    def run(
        self,
        problem: StepProblem,
        x0: ArrayLike,
        max_iter: int,
        state: Any = None,
        tol: float = 0.0,
        callback: Callable[[int, float], Any] | None = None,
        gtol: float = 0.0,
        separable: bool = False,
        stol: float = 0.0,
    ) -> SolverResult:
        """Take up to ``max_iter`` steps from ``x0``, stopping early by the rules of :mod:`solvers.stopping`.

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
        gtol : float
            Stop when the total optimality measure (gradient norm, :meth:`optimality`) is at
            most ``gtol`` times its value at ``x0``.
        separable : bool, default=False
            Apply both rules to every row on its own (its objective, its optimality measure)
            and drop the rows that stopped from the later steps, so each row's result is the
            one of a run on that row alone (:mod:`solvers.separable`). False: the rules apply
            to the total objective, and every row steps until the run stops.
        stol : float, default=0.0
            Stop when the decrease of the total objective over a step is at most ``stol`` times
            its decrease since ``x0`` (:func:`~solvers.stopping.has_saturated`: the objective
            has saturated, e.g. falling geometrically toward a minimum at infinity); 0 turns
            the rule off.

        Returns
        -------
        SolverResult

        Raises
        ------
        SolverOptionError
            When an argument is malformed (``x0`` of the wrong shape or not finite, ...).
        SolverError
            When the objective is not finite at ``x0`` or the solver fails.
        """
        if not observing():
            return self._run(problem, x0, max_iter, state, tol, callback, gtol, separable, stol)
        c0 = time.thread_time()
        result = self._run(problem, x0, max_iter, state, tol, callback, gtol, separable, stol)
        notify(self, problem, result, separable=bool(separable), cpu_seconds=time.thread_time() - c0)
        return result

    def _run(self, problem: StepProblem, x0: ArrayLike, max_iter: int, state: Any, tol: float,
             callback: Callable[[int, float], Any] | None, gtol: float, separable: bool,
             stol: float = 0.0) -> SolverResult:
        """:meth:`run` without its observers (:func:`solvers.observe_runs`)."""
        x = self._check_run(problem, x0, max_iter, tol, callback)
        check_number(gtol, "gtol", self.name, low=0.0)
        check_number(stol, "stol", self.name, low=0.0)
        if separable is not False:
            if separable is not True:
                raise SolverOptionError(f"{self.name}: separable must be True or False; got {separable!r}")
            from .separable import run_separable

            return SolverResult(**run_separable(self, problem, x, max_iter, state, tol, callback, gtol, stol))
        t0 = time.perf_counter()
        ev0 = problem.n_evaluations()
        state = self.init_state(problem, x, previous=state)
        history = [self._total(state)]
        g0 = gnorm = self._gradient_norm(x, state)
        status, reason, it = "max_iter", f"max_iter={max_iter} steps taken", 0
        for it in range(1, max_iter + 1):
            x, state, progressed = self.update(problem, x, state)
            history.append(self._total(state))
            gnorm = self._gradient_norm(x, state)
            if callback is not None:
                callback(it, history[-1])
            stopped = _stop_reason(progressed, history, gnorm, g0, tol, gtol, stol)
            if stopped is not None:
                status, reason = stopped
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
            reason=reason,
            gradient_norm=gnorm,
        )

    def _check_run(self, problem: Any, x0: ArrayLike, max_iter: int, tol: float, callback: Any) -> NDArray[np.float64]:
        """Validate the arguments of :meth:`run`; the projected starting point."""
        if not isinstance(problem, StepProblem):
            raise SolverOptionError(f"{self.name}: problem must be a StepProblem; got {type(problem).__name__}")
        try:
            x = np.array(x0, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise SolverOptionError(f"{self.name}: x0 must be a numeric array: {exc}") from None
        if x.shape != (problem.n_rows, problem.n_params):
            raise SolverOptionError(f"{self.name}: x0 must have shape ({problem.n_rows}, {problem.n_params}); got {x.shape}")
        if not np.all(np.isfinite(x)):
            bad = np.unique(np.nonzero(~np.isfinite(x))[0])
            raise SolverOptionError(f"{self.name}: x0 must be finite; rows {bad[:10].tolist()} hold NaN or inf")
        check_number(max_iter, "max_iter", self.name, low=0, integer=True)
        check_number(tol, "tol", self.name, low=0.0)
        if callback is not None and not callable(callback):
            raise SolverOptionError(f"{self.name}: callback must be callable; got {type(callback).__name__}")
        return self.project(x)

    def _total(self, state: Any) -> float:
        total = float(np.sum(state.loss))
        if not np.isfinite(total):
            raise SolverError(f"{self.name}: the total objective is not finite ({total}); the solver must reject such points")
        return total


def row_norms(a: ArrayLike) -> NDArray[np.float64]:
    """Euclidean norm of every row of ``a`` (n, p), without underflow or needless overflow.

    Each row is divided by its largest magnitude before squaring, so gradients of 1e-200 (a
    consistently rescaled problem) keep their relative size instead of squaring to zero.
    """
    a = np.asarray(a, dtype=np.float64)
    top = np.max(np.abs(a), axis=1, initial=0.0)
    safe = np.where((top > 0) & np.isfinite(top), top, 1.0)
    with np.errstate(over="ignore", invalid="ignore"):
        return np.where(np.isfinite(top), safe * np.sqrt(np.sum(np.square(a / safe[:, None]), axis=1)), np.inf)


def _state_rows(name: str, state: Any) -> int:
    """Number of rows of a dataclass solver state (the length of its ``loss``)."""
    loss = getattr(state, "loss", None)
    if not (dataclasses.is_dataclass(state) and isinstance(loss, np.ndarray) and loss.ndim == 1):
        raise SolverError(f"{name}: a separable run needs a dataclass state with a loss array (n,); got "
                          f"{type(state).__name__} (override take_rows and put_rows)")
    return loss.shape[0]


def _per_row(value: Any, n: int) -> bool:
    return isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == n


def _stop_reason(
    progressed: bool, history: list[float], gnorm: float, g0: float, tol: float, gtol: float, stol: float = 0.0
) -> tuple[str, str] | None:
    """``(status, reason)`` of a run after a step, or None to go on."""
    if not progressed:
        return "stalled", "stalled: no row could decrease its objective"
    if has_converged(history[-2], history[-1], tol):
        return "converged", f"relative decrease {relative_decrease(history[-2], history[-1]):.3g} <= tol={tol:g}"
    if has_saturated(history[0], history[-2], history[-1], stol):
        return "converged", (f"saturated: decrease {history[-2] - history[-1]:.3g} <= stol={stol:g} x decrease "
                             f"{history[0] - history[-1]:.3g} since the start")
    if not (np.isnan(gnorm) or np.isnan(g0)) and gradient_converged(gnorm, g0, gtol):
        return "converged", f"gradient norm {gnorm:.3g} <= gtol={gtol:g} x initial {g0:.3g}"
    return None


def update_damping(solver: Any, state: Any, acc: NDArray[np.intp], rej: NDArray[np.intp], n: int) -> NDArray[np.bool_]:
    """Levenberg-Marquardt damping after a trial step; returns the rows that may retry.

    Accepted rows ``acc`` shrink ``state.lam`` by ``solver.lam_down`` (not below
    ``lam_min * scale``), rejected rows ``rej`` grow it by ``solver.lam_up`` (not above
    ``lam_max * scale``); a rejected row may retry while its damping is below the cap.
    Shared by the Gauss-Newton QP and CG solvers.
    """
    state.lam[acc] = np.maximum(state.lam[acc] * solver.lam_down, solver.lam_min * state.scale[acc])
    state.lam[rej] = np.minimum(state.lam[rej] * solver.lam_up, solver.lam_max * state.scale[rej])
    retry = np.zeros(n, dtype=bool)
    retry[rej[state.lam[rej] < solver.lam_max * state.scale[rej]]] = True
    return retry


def trial_every_row(solver: Any, problem: StepProblem, x: NDArray[np.float64], state: Any,
                    tries: NDArray[np.intp]) -> tuple[NDArray[np.float64], Any, NDArray[np.bool_], NDArray[np.bool_]]:
    """The ``trial_rows`` of both Gauss-Newton solvers: one ``solver._trial`` of every row on a copy
    of ``x``, then :func:`update_damping`; a rejected row whose damping may grow and whose ``tries``
    are below ``solver.max_retries`` is ``pending``. Returns ``(x, state, progressed, pending)``."""
    n = x.shape[0]
    x = x.copy()
    progressed, pending = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    tried = solver._trial(problem, x, state, np.arange(n), progressed)
    if tried is not None:
        acc, rej = tried
        pending[:] = update_damping(solver, state, acc, rej, n) & (np.asarray(tries) < int(solver.max_retries))
    return x, state, progressed, pending


def limit_step(
    x: NDArray[np.float64], z: NDArray[np.float64], max_step_norm: float | None
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Shorten every row's step ``z_i - x_i`` to at most ``max_step_norm * max(1, ||x_i||)``.

    A trust-region-like cap shared by the solvers: rows within the radius are returned
    unchanged (bit for bit); longer steps keep their direction. The shortened point lies on
    the segment from ``x_i`` to ``z_i``, so it stays feasible for a convex constraint that
    both satisfy, and it cannot increase a convex model that decreases from ``x_i`` to ``z_i``.

    Parameters
    ----------
    x : ndarray, shape (n, p)
        Current parameters.
    z : ndarray, shape (n, p)
        Proposed parameters (finite).
    max_step_norm : float or None
        Relative radius (> 0); None: no cap.

    Returns
    -------
    z : ndarray, shape (n, p)
        A new array when a row was shortened, else ``z`` itself.
    shortened : ndarray of bool, shape (n,)
    """
    if max_step_norm is None:
        return z, np.zeros(x.shape[0], dtype=bool)
    delta = z - x
    norm = np.linalg.norm(delta, axis=1)
    radius = max_step_norm * np.maximum(1.0, np.linalg.norm(x, axis=1))
    shortened = norm > radius
    if shortened.any():
        z = z.copy()
        z[shortened] = x[shortened] + delta[shortened] * (radius[shortened] / norm[shortened])[:, None]
    return z, shortened

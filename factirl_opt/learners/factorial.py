"""The factorial scheme: alternating minimisation of eq. (10) over a dictionary and coefficients.

Every task's reward is ``R_i = Phi D h_i``: base features ``Phi`` (S*A, p) (the identity for
tabular rewards, p = S*A), dictionary ``D`` (p, k), coefficients ``H`` (n, k), tasks on the
leading axis (docs/maths.md §8). :func:`fit_factorial` minimises
``J_Xi(D, H) = sum_i J_i(Phi D h_i)`` from a given start by alternating a fixed number of
steps on H with D fixed (the H-step, gradient eq. 12) and on D with H fixed (the D-step,
gradient eq. 11), each with any registered step solver; :func:`run_factorial` does the same
on an objective and solvers already built (what ``FactIRL.fit`` hands down). The rewards are
those of the fit's :class:`~factirl_opt.tasks.basis.RewardBasis` ``Phi_i`` (tabular, state,
shared or per-task features alike).

**What residual_penalty runs.** The one parameter ``lambda`` (``FactIRL(residual_penalty=...)``, :func:`run_factorial`) selects
the model; the alternating loop (:func:`_alternate`) is the same for all of them, only its
blocks differ (docs/maths.md §8, §8a):

- ``inf`` (the default): the paper's factorial model ``R_i = Phi_i D h_i`` (eq. 10). The
  H-step moves the coefficients with ``solver`` (any constraint), the D-step the dictionary
  with ``d_solver``.
- finite ``lambda > 0``: the residual model ``R_i = Phi_i (D h_i + delta_i)`` with the penalty
  ``lambda ||delta_i||^2``. The H-step moves ``[h_i, delta_i]`` together with ``solver``
  (unconstrained only), task by task; the D-step as above.
- ``0``: the residual model without penalty, i.e. the flat model reparametrised: ``fit`` runs
  the loop above with ``lambda = 0`` from the flat start itself (with ``init="pca"``, the
  residuals start at ``delta_i = w_i - D h_i`` of the flat weights ``w_i``, the flat model's
  optimum, so the loop stops as soon as it no longer gains), but the dictionary plays no part in the rewards, so
  ``FactIRL.transfer`` fits each new task as the flat learner does, with ``flat_solver``
  (and ``flat_max_iter``, from zero weights) instead of ``solver``
  (:func:`factirl_opt.learners.transfer.run_transfer`). Why another solver there: with
  ``lambda = 0`` the transfer is exactly ``GradIRL``'s problem on the new tasks, and
  ``flat_solver`` is the one the model's own flat start (``init="pca"``) used, so the
  transferred rewards are those GradIRL gives with that solver and budget, whatever H-step
  solver the factorial fit used.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

import solvers

from .._progress import fit_progress
from .._validation import check_array, check_int, check_tol
from .dictionary import normalise_dictionary
from ..exceptions import FitInterrupted, ValidationError, translate_solver_errors
from .fitting import GTOL, first_step_stall, learner_entry, resolve_step_solver, task_objective
from ..tasks.basis import DICTIONARY_NAMES, StateBasis, TabularBasis
from ..tasks.task_set import task_set
from ..interruption import INTERRUPTED, INTERRUPTIONS
from ..objectives.problems import dictionary_problem, weights_problem
from ..objectives.residuals import check_residual_penalty, residual_dictionary_problem, residual_weights, residual_weights_problem

__all__ = ["fit_factorial", "run_factorial", "FactorialFit", "GTOL", "SCHEMES", "check_scheme", "resolve_scheme"]

#: the outer schemes of a factorial fit (:func:`run_factorial`): the paper's alternating
#: minimisation, or quasi-Newton steps on the dictionary and the coefficients together; and
#: ``"auto"``, FactIRL's default, one of them chosen from the reward basis (:func:`resolve_scheme`)
SCHEMES = ("auto", "alternating", "joint")


@dataclasses.dataclass
class FactorialFit:
    """Result of :func:`fit_factorial` (the best point seen).

    Attributes
    ----------
    dictionary : ndarray, shape (p, k)
    coefficients : ndarray, shape (n, k)
    loss : ndarray, shape (n,)
        Per-task objective (without a solver's penalty).
    loss_history : list of float
        Total objective (with the H-solver's penalty) at the start and after each outer iteration.
    n_iter : int
    n_evaluations : int
    status : str
        ``"converged"`` (relative decrease below ``tol``, or gradient norm below ``gtol`` times
        the initial one), ``"max_iter"``, ``"stalled"`` (the first outer iteration changed
        nothing), or ``"interrupted"`` (a KeyboardInterrupt; the fields describe the best point
        seen until then, ``loss`` is NaN if no point was evaluated).
    reason : str
        Why the loop stopped, with the values that met the rule.
    gradient_norm : float
        First-order optimality measure of the total objective over ``(H, D)`` at the last point
        (the norm of the gradient; projected or minimum-norm subgradient for H under a
        constrained or penalised H-solver).
    evaluation_history : list of int
        Q* evaluations used so far at the start and after each outer iteration (aligned with
        ``loss_history``: plot one against the other).
    residuals : ndarray, shape (n, p), optional
        The tasks' residuals ``delta_i`` of a fit with a finite ``residual_penalty``
        (:mod:`factirl_opt.objectives.residuals`; ``loss`` is then without their penalty, ``loss_history``
        with it); None for the factorial model.
    """

    dictionary: np.ndarray
    coefficients: np.ndarray
    loss: np.ndarray
    loss_history: list
    n_iter: int
    n_evaluations: int
    status: str
    reason: str = ""
    gradient_norm: float = float("nan")
    evaluation_history: list = dataclasses.field(default_factory=list)
    residuals: np.ndarray | None = None


def _optimality(gradients, D, H, h_solver, unit_norm, d_solver=None):
    """Norm of the first-order optimality measure of eq. (10) over ``(H, D)``, from ``gradients``
    (:meth:`~factirl_opt.objectives.contract.TaskObjective.factorial_point`).

    ``dJ/dh_i = F^T y_i`` with ``F = Phi D`` (eq. 12; projected or minimum-norm subgradient
    for a constrained or penalised H-solver, :meth:`solvers.StepSolver.optimality`) and
    ``dJ/dD = Phi^T sum_i y_i h_i^T`` (eq. 11), restricted to the tangent space of unit-norm
    primitives when the D-step keeps them at unit norm; for a constrained dictionary
    (``d_solver.constraint == "proximal"``, docs/maths.md §8b) its proximal-gradient map.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        gH, gD = gradients(D, H)
        if d_solver is not None and d_solver.constraint == "proximal":
            gD = d_solver.optimality(D.reshape(1, -1), gD.reshape(1, -1))
        elif unit_norm:
            gD = gD - D * np.sum(D * gD, axis=0)
        norm = float(np.hypot(np.linalg.norm(h_solver.optimality(H, gH)), np.linalg.norm(gD)))
    return norm if np.isfinite(norm) else np.inf


def _dictionary_penalty(d_solver, D):
    """The D-solver's penalty at ``D`` (a constrained dictionary's L1 term; 0.0 otherwise)."""
    return float(d_solver.penalty(D.reshape(1, -1)).sum()) if d_solver.constraint == "proximal" else 0.0


def _evaluate_point(objective, basis, D, H, h_solver, band, unit_norm, d_solver=None):
    """Loss per task at ``(D, H)`` (served from the objective's cache after a D-step), the
    normalised pair, the total (with the H-solver's and a constrained D-solver's penalty) and
    the optimality measure."""
    loss, gradients = objective.factorial_point(basis, D, H)
    D, H = normalise_dictionary(D, H, band)
    total = float(loss.sum() + h_solver.penalty(H).sum())
    if d_solver is not None and d_solver.constraint == "proximal":
        total += _dictionary_penalty(d_solver, D)
    return loss, D, H, total, _optimality(gradients, D, H, h_solver, unit_norm, d_solver)


def _evaluate_residual_point(objective, basis, D, H, Delta, lam, band, d_solver=None):
    """:func:`_evaluate_point` of the residual model (:mod:`factirl_opt.objectives.residuals`): the loss per
    task without the penalty, the normalised pair, the total with it (and a constrained
    D-solver's penalty), and the optimality measure over ``(H, D, Delta)`` from the flat
    gradient ``g_i = Phi_i^T y_i``."""
    flat = weights_problem(objective, basis, DICTIONARY_NAMES)
    loss, G = flat.loss_and_grad(residual_weights(D, H, Delta), np.arange(H.shape[0]))
    D, H = normalise_dictionary(D, H, band)
    total = float(loss.sum() + lam * np.sum(Delta * Delta))
    constrained = d_solver is not None and d_solver.constraint == "proximal"
    if constrained:
        total += _dictionary_penalty(d_solver, D)
    with np.errstate(over="ignore", invalid="ignore"):
        gD = G.T @ H
        if constrained:
            gD = d_solver.optimality(D.reshape(1, -1), gD.reshape(1, -1))
        norm = float(np.sqrt(np.sum(np.square(G @ D)) + np.sum(np.square(gD))
                             + np.sum(np.square(G + 2.0 * lam * Delta))))
    return loss, D, H, total, norm if np.isfinite(norm) else np.inf


def _outer_stop(history, gnorm, g0, tol, gtol, it):
    """``(status, reason)`` after outer iteration ``it``, or ``(None, None)`` to go on."""
    stall = first_step_stall(history, it)  # neither block moved: nothing will
    if stall is not None:
        return stall
    if solvers.has_converged(history[-2], history[-1], tol):  # a rise is not convergence
        return "converged", f"relative decrease {solvers.relative_decrease(history[-2], history[-1]):.3g} <= tol={tol:g}"
    if solvers.gradient_converged(gnorm, g0, gtol):
        return "converged", f"gradient norm {gnorm:.3g} <= gtol={gtol:g} x initial {g0:.3g}"
    return None, None


class _FactorialBlocks:
    """The blocks of the factorial model (``residual_penalty = inf``, eq. 10): the H-step on the
    coefficients over the basis ``Phi_i D`` (eq. 12), the D-step on ``vec(D)`` (eq. 11), kept at
    unit norm under a sparse H-solver."""

    extra: tuple = ()

    def __init__(self, objective, basis, h_solver, d_solver):
        self.objective, self.basis, self.h_solver, self.d_solver = objective, basis, h_solver, d_solver
        self.unit_norm = h_solver.constraint == "sparse"
        self.band = 1.0 if self.unit_norm else 2.0

    def evaluate(self, D, H, band):
        return _evaluate_point(self.objective, self.basis, D, H, self.h_solver, band, self.unit_norm, self.d_solver)

    def h_step(self, D, H, state, inner_steps, gtol):
        rh = self.h_solver.run(weights_problem(self.objective, self.basis.compose(D)), H, inner_steps, state=state,
                               gtol=gtol)
        return rh.coefficients, self.h_solver.carry_over(rh.state)

    def d_problem(self, H):
        return dictionary_problem(self.objective, H, self.basis, unit_norm=self.unit_norm)


class _ResidualBlocks:
    """The blocks of the residual model (finite ``residual_penalty``, :mod:`factirl_opt.objectives.residuals`):
    the H-step runs on ``[h_i, delta_i]`` jointly (:func:`residual_weights_problem`), each task
    stepping as it would alone (``separable=True``: the tasks are independent given ``D``; an
    unconstrained Gauss-Newton subproblem of ``k + p`` variables per task is then solved
    exactly, never compiled into one block QP over every task, whose size grows as
    ``(n (k + p))^2``), the D-step with ``H`` and ``Delta`` fixed
    (:func:`residual_dictionary_problem`). The best point carries ``Delta``."""

    band = 2.0

    def __init__(self, objective, basis, h_solver, d_solver, residuals, penalty):
        self.objective, self.basis, self.h_solver, self.d_solver = objective, basis, h_solver, d_solver
        self.Delta, self.lam = residuals, penalty

    @property
    def extra(self):
        return (self.Delta,)

    def evaluate(self, D, H, band):
        return _evaluate_residual_point(self.objective, self.basis, D, H, self.Delta, self.lam, band, self.d_solver)

    def h_step(self, D, H, state, inner_steps, gtol):
        k = H.shape[1]
        rh = self.h_solver.run(residual_weights_problem(self.objective, self.basis, D, self.lam, DICTIONARY_NAMES),
                               np.concatenate([H, self.Delta], axis=1), inner_steps, state=state, gtol=gtol,
                               separable=True)
        self.Delta = rh.coefficients[:, k:]
        return rh.coefficients[:, :k], self.h_solver.carry_over(rh.state)

    def d_problem(self, H):
        return residual_dictionary_problem(self.objective, self.basis, H, self.Delta)


def check_residual_solver(h_solver: solvers.StepSolver, value: Any) -> float:
    """The validated finite residual penalty ``lambda`` (``value``) or np.inf; a finite one refused with a
    constrained H-solver (the H-step moves each task's coefficients and residual together)."""
    lam = cast(float, check_residual_penalty(value, allow_auto=False))  # not "auto": refused there
    if np.isfinite(lam) and h_solver.constraint != "none":
        raise ValidationError(
            f"residual_penalty={lam!r} needs an unconstrained h_solver (the H-step moves each task's coefficients and "
            f"residual together); {h_solver.name!r} has constraint {h_solver.constraint!r}")
    return lam


def check_scheme(scheme: Any, h_solver: solvers.StepSolver, d_solver: solvers.StepSolver,
                 residual_penalty: float = np.inf) -> str:
    """The validated outer ``scheme`` (one of :data:`SCHEMES`).

    ``"joint"`` applies to the factorial model (``residual_penalty = inf``) with an
    unconstrained H-solver and an unconstrained D-solver that needs only the loss and its
    gradient (``armijo``, ``lbfgs``): the joint problem has no residual Jacobian, Hessian or
    proximal map.

    Raises
    ------
    ValidationError
        For an unknown scheme, or ``"joint"`` where it does not apply (the message says why).
    """
    if not isinstance(scheme, str) or scheme not in SCHEMES:
        raise ValidationError(f"scheme must be one of {', '.join(map(repr, SCHEMES))}; got {scheme!r}")
    if scheme == "joint":
        why = None
        if np.isfinite(residual_penalty):
            why = f"residual_penalty={residual_penalty!r} (the residual model's H-step moves h_i and delta_i per task)"
        elif h_solver.constraint != "none":
            why = f"the H-solver {h_solver.name!r} with constraint {h_solver.constraint!r}"
        elif d_solver.constraint != "none":
            why = f"a constrained dictionary (D-solver {d_solver.name!r}, constraint {d_solver.constraint!r})"
        elif d_solver.needs_jacobian or d_solver.needs_linearization or d_solver.name == "newton":
            why = (f"the D-solver {d_solver.name!r}, which needs residuals or a Hessian (the joint problem gives only "
                   "the loss and its gradient; use 'lbfgs' or 'armijo')")
        if why is not None:
            raise ValidationError(f"scheme='joint' does not apply to {why}; use scheme='alternating'")
    return scheme


def resolve_scheme(scheme: Any, basis: Any, h_solver: solvers.StepSolver, d_solver: solvers.StepSolver,
                   residual_penalty: float = np.inf) -> str:
    """The outer scheme a fit runs: ``scheme`` validated (:func:`check_scheme`), ``"auto"`` resolved.

    ``"auto"`` (FactIRL's default) is ``"joint"`` on features (any basis but the tables of
    :class:`~factirl_opt.tasks.basis.TabularBasis` and :class:`~factirl_opt.tasks.basis.StateBasis`)
    where the joint scheme applies, and ``"alternating"`` on tables and wherever it does not
    (a finite ``residual_penalty``, a constrained H-solver or dictionary, a D-solver that needs
    residuals or a Hessian). Measured (``results/defaults/README.md``): on features the joint
    scheme with L-BFGS D-steps was 5-10x cheaper than the alternation at a train and test
    deviation within noise or better on every world at seed 0; on the paper's tabular grid it
    was worse on the test tasks by 1.5-3.3 standard errors, where the alternation with L-BFGS
    D-steps was within noise of the paper's and cheaper.

    Parameters
    ----------
    scheme : {"auto", "alternating", "joint"}
    basis : RewardBasis or None
        The fit's reward basis (None: tabular rewards).
    h_solver, d_solver : solvers.StepSolver
        The resolved H- and D-step solvers (the D-solver after any dictionary constraint).
    residual_penalty : float, default=np.inf
        The fit's lambda: ``"auto"`` alternates at finite values (``"joint"`` is refused there).

    Returns
    -------
    str
        ``"alternating"`` or ``"joint"``.
    """
    scheme = check_scheme(scheme, h_solver, d_solver, residual_penalty)
    if scheme != "auto":
        return scheme
    if np.isfinite(residual_penalty) or basis is None or isinstance(basis, (TabularBasis, StateBasis)):
        return "alternating"
    try:
        return check_scheme("joint", h_solver, d_solver, residual_penalty)
    except ValidationError:
        return "alternating"


def _joint_problem(objective, basis, p, k, n):
    """One-row problem over ``x = [vec(D), vec(H)]`` (1, p k + n k): the total loss of eq. (10)
    and its gradient in both blocks (eqs. 11-12) from one evaluation of every task."""

    def loss_and_grad(x, rows):
        D, H = _unpack(x, p, k, n)
        loss, gradients = objective.factorial_point(basis, D, H)
        gH, gD = gradients(D, H)
        return np.array([loss.sum()]), np.concatenate([gD.ravel(), gH.ravel()])[None]

    return solvers.StepProblem(loss_and_grad=loss_and_grad, n_evaluations=lambda: objective.n_evaluations, n_rows=1,
                               n_params=(p + n) * k)


def _pack(D, H):
    return np.concatenate([D.ravel(), H.ravel()])[None]


def _unpack(x, p, k, n):
    x = np.asarray(x)[0]
    return x[:p * k].reshape(p, k), x[p * k:].reshape(n, k)


def _alternate(objective, blocks, D, H, d_solver, max_iter, inner_steps, tol, gtol, report, ev0, joint=False):
    """The outer loop of eqs. (10)-(12), for either model's ``blocks``; returns the best point
    seen, the history and the stop.

    Alternating (the default): each block runs ``inner_steps`` steps of its solver's alternating
    form, warm-started by what the solver carries over from its previous run
    (:meth:`solvers.StepSolver.carry_over`); the inner runs stop early only by the gradient rule
    or a stall (:func:`fit_factorial`). ``joint``: each outer iteration runs ``inner_steps``
    steps of ``d_solver`` on ``(D, H)`` together (:func:`_joint_problem`), keeping the
    solver's whole state (an L-BFGS memory) from one outer iteration to the next, since the
    problem does not change; the dictionary is rescaled (:func:`normalise_dictionary`) only
    at the start and on the best point returned, so the steps' memory stays consistent.
    A KeyboardInterrupt (or lost workers, :data:`~factirl_opt.interruption.INTERRUPTIONS`) becomes a
    :class:`FitInterrupted` carrying the same tuple, at the best
    point among the start and the completed outer iterations (the start, loss NaN, if even its
    evaluation was interrupted).
    """
    best = (np.nan, D, H, np.full(H.shape[0], np.nan), *blocks.extra)
    history, evaluations, gnorm, it = [], [], np.nan, 0
    try:
        D, H = normalise_dictionary(D, H, blocks.band)  # the H-step starts where the loss is evaluated (no band: no rescaling)
        loss, D, H, total, g0 = blocks.evaluate(D, H, np.inf)
        history, evaluations, gnorm = [total], [objective.n_evaluations - ev0], g0
        best = (total, D, H, loss, *blocks.extra)
        h_state = d_state = None
        status, reason = "max_iter", f"max_iter={max_iter} outer iterations done"
        band = np.inf if joint else blocks.band
        (p, k), n = D.shape, H.shape[0]
        joint_problem = _joint_problem(objective, blocks.basis, p, k, n) if joint else None
        for it in range(1, max_iter + 1):
            if joint:
                rj = d_solver.run(joint_problem, _pack(D, H), inner_steps, state=d_state, gtol=gtol)
                (D, H), d_state = _unpack(rj.coefficients, p, k, n), rj.state
            else:
                H, h_state = blocks.h_step(D, H, h_state, inner_steps, gtol)
                rd = d_solver.run(blocks.d_problem(H), D.reshape(1, -1), inner_steps, state=d_state, gtol=gtol)
                D, d_state = rd.coefficients.reshape(D.shape), d_solver.carry_over(rd.state)
            loss, D, H, total, gnorm = blocks.evaluate(D, H, band)
            history.append(total)
            evaluations.append(objective.n_evaluations - ev0)
            if total <= best[0]:
                best = (total, D, H, loss, *blocks.extra)
            report(it, total)
            stop = _outer_stop(history, gnorm, g0, tol, gtol, it)
            if stop[0] is not None:
                status, reason = stop
                break
    except INTERRUPTIONS as exc:
        done = len(history) - 1 if history else 0
        best = _rescaled(best, blocks.band) if joint else best
        raise FitInterrupted((best, (history, evaluations), done, INTERRUPTED, INTERRUPTED, gnorm), "fit") from exc
    return (_rescaled(best, blocks.band) if joint else best), (history, evaluations), it, status, reason, gnorm


def _rescaled(best, band):
    """The best point with its primitives rescaled into the band (a joint fit does not rescale as it goes)."""
    total, D, H, *rest = best
    return (total, *normalise_dictionary(D, H, band), *rest)


@learner_entry
def fit_factorial(mdp: Any, demos_per_task: Any, dictionary: ArrayLike, coefficients: ArrayLike, *, beta: float = 5.0,
                  base_features: ArrayLike | None = None, h_solver: Any = "armijo", h_solver_options: dict | None = None,
                  d_solver: Any = "armijo", d_solver_options: dict | None = None, max_iter: int = 100,
                  inner_steps: int = 5, tol: float = 1e-5, gtol: float = GTOL, objective: Any = "policy-matching",
                  planner: str = "auto", callback: Callable | None = None, verbose: bool = False,
                  reward: str = "state-action", scheme: str = "alternating") -> FactorialFit:
    """Learn a dictionary and coefficients from a starting point by alternating minimisation.

    Each outer iteration runs up to ``inner_steps`` steps of the H-solver on the coefficients
    (D fixed; eq. 12), then of the D-solver on ``vec(D)`` (H fixed; eq. 11). Returns the best
    point seen, so a fit never ends on a worse point than one it visited.

    Stopping (the rules of :mod:`solvers.stopping`, checked in this order):

    - outer loop, after each outer iteration: ``"stalled"`` when the first one changed
      nothing (:func:`factirl_opt.learners.fitting.first_step_stall`, the rule of every learner); ``"converged"`` when the relative decrease of the total
      objective (eq. 10, plus a sparse H-solver's penalty) over the iteration is in
      ``[0, tol]`` (a rise is not convergence), or when the optimality measure over ``(H, D)``
      (the norm of the gradient, eqs. 11-12; projected or minimum-norm subgradient for a
      constrained or penalised H-solver) is at most ``gtol`` times its value at the start; else ``"max_iter"`` after
      ``max_iter`` iterations. ``reason`` says which rule stopped the fit, with its values.
    - inner runs (each block, each outer iteration): ``inner_steps`` steps, the paper's "fixed
      amount of gradient descent on each sub-problem", ended early only by the gradient rule
      (``gtol``, relative to the run's start) or when the solver stalls (no step decreases the
      block's objective). The relative-decrease rule is not applied inside the loop: stopping
      a block on ``tol`` saved 9% of the Q* evaluations of an Armijo/Armijo fit on a 5x5 grid
      (30 tasks) at the same final loss, but it changes the paper's algorithm, which the
      default (Armijo) fit reproduces unchanged.

    Both solvers are used in their alternating form (``solver.for_alternating()``: the
    Gauss-Newton solvers take proximal, strongly damped steps there), and each run is
    warm-started by what the solver carries over from its previous one
    (``solver.carry_over(state)``: step sizes and damping, but not L-BFGS's curvature pairs,
    which describe the sub-problem before the other block moved).

    Parameters
    ----------
    mdp : TabularMDP or sequence of n TabularMDP
        One MDP shared by every task, or one per task (then ``base_features`` are needed; see
        :func:`factirl_opt.tasks.task_set.task_set`).
    demos_per_task : list of n task demonstrations
    dictionary : array_like, shape (p, k)
        Initial ``D``; p = S*A (tabular) or the number of base features.
    coefficients : array_like, shape (n, k)
        Initial ``H``.
    beta : float
    base_features : array_like, shape (S*A, p) or (S, p), or sequence of n such, optional
        ``Phi``, shared or one per task (each (S_i*A, p) or (S_i, p)); None for tabular rewards.
    reward : {"state-action", "state"}, default="state-action"
        Without ``base_features``: ``"state"`` learns rewards of the states only (p = S),
        ``Phi = kron(I_S, 1_A)`` applied without forming it (docs/maths.md §7).
    h_solver, d_solver : str or solvers.StepSolver
        Step solvers of the two blocks (``solvers.available_solvers()``); the H-solver is used
        in its alternating form (``solver.for_alternating()``).
    h_solver_options, d_solver_options : dict, optional
    max_iter, inner_steps : int
    tol : float
        Relative-decrease tolerance (outer loop and inner runs), >= 0.
    gtol : float, default=GTOL
        Gradient-norm tolerance relative to the start (outer loop and inner runs), >= 0.
        The default stops the long tails of fits whose loss keeps falling geometrically as the
        Boltzmann policies saturate (rewards growing along the fitted directions) and is never
        reached by the paper-scale Armijo/Armijo fit (its gradient stays above 5e-4 x the
        initial one over 100 outer iterations).
    objective : str
        See ``factirl_opt.available_objectives()``.
    planner : str
    callback : callable, optional
        ``callback(iteration, total_objective)`` after each outer iteration.
    verbose : bool
        Progress bar on stderr.
    scheme : {"alternating", "joint", "auto"}, default="alternating"
        ``"auto"``: one of the two chosen from the reward basis (:func:`resolve_scheme`: joint on
        features, alternating on tables). ``"alternating"``: the paper's alternation of H- and D-steps, as above. ``"joint"``:
        every outer iteration takes ``inner_steps`` steps of ``d_solver`` on the dictionary
        and the coefficients together (one row ``[vec(D), vec(H)]``; each evaluation of the
        tasks gives the gradients of both blocks, eqs. 11-12), keeping the solver's memory
        across outer iterations (the problem does not change between them); the H-solver
        only states the model and is not run. With L-BFGS (``d_solver="lbfgs"``) it reaches
        a lower loss than the alternation in a fraction of the evaluations on Objectworld
        (``results/fit-speed/README.md``). The stopping rules are the same, per outer
        iteration. It needs the factorial model with an unconstrained H-solver and a
        D-solver that needs only gradients (:func:`check_scheme`).

    Returns
    -------
    FactorialFit

    Raises
    ------
    FitInterrupted
        A KeyboardInterrupt during the fit; its ``result`` is the :class:`FactorialFit` of the
        best point seen (status ``"interrupted"``).
    """
    tasks = task_set(mdp, demos_per_task, base_features, reward)
    p = tasks.n_params
    D = check_array(dictionary, "dictionary", ndim=2)
    H = check_array(coefficients, "coefficients", ndim=2)
    if D.shape[0] != p or H.shape[1] != D.shape[1]:
        raise ValidationError(f"dictionary (p, k) and coefficients (n, k) must have p = {p} and equal k; got {D.shape} and {H.shape}")
    max_iter, inner_steps = check_int(max_iter, "max_iter", minimum=0), check_int(inner_steps, "inner_steps", minimum=1)
    tol, gtol = check_tol(tol), check_tol(gtol, "gtol")
    obj = task_objective(tasks, beta, objective, planner)
    if H.shape[0] != obj.n_tasks:
        raise ValidationError(f"coefficients describe {H.shape[0]} tasks but the demonstrations {obj.n_tasks}")
    h = resolve_step_solver(h_solver, h_solver_options, objective, "h_solver")
    d = resolve_step_solver(d_solver, d_solver_options, objective, "d_solver")
    scheme = resolve_scheme(scheme, tasks.basis, h, d)
    return run_factorial(obj, D, H, h, d, base_features=tasks.basis, max_iter=max_iter, inner_steps=inner_steps, tol=tol,
                         gtol=gtol, callback=callback, verbose=verbose, scheme=scheme)

def run_factorial(objective: Any, dictionary: NDArray[np.float64], coefficients: NDArray[np.float64],
                  h_solver: solvers.StepSolver, d_solver: solvers.StepSolver, *, base_features: Any = None,
                  max_iter: int = 100, inner_steps: int = 5, tol: float = 1e-5, gtol: float = GTOL,
                  callback: Callable | None = None, verbose: bool = False, residual_penalty: float = np.inf,
                  residuals: NDArray[np.float64] | None = None, scheme: str = "alternating") -> FactorialFit:
    """:func:`fit_factorial` on pieces already built and validated (``FactIRL.fit`` hands them down).

    Parameters
    ----------
    objective : Objective
        Bound to the n tasks' statistics; its evaluations from here on are counted.
    dictionary : ndarray, shape (p, k)
    coefficients : ndarray, shape (n, k)
    h_solver, d_solver : solvers.StepSolver
        Resolved and checked (:func:`factirl_opt.learners.fitting.resolve_step_solver`); used in their
        alternating form.
    base_features : RewardBasis
        The fit's basis ``Phi_i``, as its task set built it (:attr:`factirl_opt.tasks.task_set.TaskSet.basis`;
        a :class:`~factirl_opt.tasks.basis.TaskBasis` with a
        :class:`~factirl_opt.objectives.environments.MultiEnvironmentObjective`).
    max_iter, inner_steps, tol, gtol, callback, verbose
        As in :func:`fit_factorial`.
    residual_penalty : float, default=np.inf
        ``lambda`` of the residual model ``R_i = Phi_i (D h_i + delta_i)``
        (:mod:`factirl_opt.objectives.residuals`); np.inf is the factorial model (see "What
        residual_penalty runs" in :mod:`factirl_opt.learners.factorial`). A finite value needs an
        unconstrained H-solver (the H-step moves ``[h_i, delta_i]`` together).
    residuals : ndarray, shape (n, p), optional
        Initial ``Delta`` of a finite ``residual_penalty`` (default zeros).
    scheme : {"alternating", "joint", "auto"}, default="alternating"
        As in :func:`fit_factorial` (resolved here by :func:`resolve_scheme`); ``"joint"`` runs
        ``d_solver`` itself, not its alternating form.

    Returns
    -------
    FactorialFit
    """
    joint = resolve_scheme(scheme, base_features, h_solver, d_solver, residual_penalty) == "joint"
    ev0 = objective.n_evaluations
    h, d = h_solver.for_alternating(), (d_solver if joint else d_solver.for_alternating())
    blocks: _FactorialBlocks | _ResidualBlocks
    if np.isfinite(residual_penalty):
        p = dictionary.shape[0]
        Delta = np.zeros((coefficients.shape[0], p)) if residuals is None else np.array(residuals, dtype=np.float64)
        blocks, H0 = _ResidualBlocks(objective, base_features, h, d, Delta, float(residual_penalty)), coefficients
    else:
        blocks, H0 = _FactorialBlocks(objective, base_features, h, d), h.project(coefficients)
    with translate_solver_errors(), fit_progress(callback, verbose, max_iter, "FactIRL") as report:
        try:
            out = _alternate(objective, blocks, dictionary, H0, d, max_iter, inner_steps, tol, gtol, report, ev0, joint)
        except FitInterrupted as exc:
            raise FitInterrupted(_result(out=exc.result, n_evaluations=objective.n_evaluations - ev0),
                                 "fit_factorial") from exc.__cause__
    return _result(out, objective.n_evaluations - ev0)


def _result(out, n_evaluations):
    (_, D, H, loss, *residuals), (history, evaluations), it, status, reason, gnorm = out
    return FactorialFit(D, H, loss, history, it, int(n_evaluations), status, reason, gnorm, evaluations,
                        residuals[0] if residuals else None)

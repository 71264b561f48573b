"""The factorial scheme: alternating minimisation of eq. (10) over a dictionary and coefficients.

Every task's reward is ``R_i = Phi D h_i``: base features ``Phi`` (S*A, p) (the identity for
tabular rewards, p = S*A), dictionary ``D`` (p, k), coefficients ``H`` (n, k), tasks on the
leading axis (docs/maths.md §8). :func:`fit_factorial` minimises
``J_Xi(D, H) = sum_i J_i(Phi D h_i)`` from a given start by alternating a fixed number of
steps on H with D fixed (the H-step, gradient eq. 12) and on D with H fixed (the D-step,
gradient eq. 11), each with any registered step solver; :func:`run_factorial` does the same
on an objective and solvers already built (what ``FactIRL.fit`` hands down).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

import solvers

from .._progress import fit_progress
from .._validation import check_array, check_int, check_tol
from .dictionary import normalise_dictionary
from ..exceptions import FitInterrupted, ValidationError, translate_solver_errors
from .fitting import GTOL, first_step_stall, learner_entry, resolve_step_solver, task_objective
from ..tasks.task_set import task_set
from ..interruption import INTERRUPTED, INTERRUPTIONS
from ..objectives.problems import dictionary_problem, weights_problem
from ..tasks.features import TaskFeatures, factorial_rewards
from ..objectives.residuals import residual_dictionary_problem, residual_weights, residual_weights_problem

__all__ = ["fit_factorial", "run_factorial", "FactorialFit", "GTOL"]


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


def _optimality(y, Phi, D, H, h_solver, unit_norm, G=None, d_solver=None):
    """Norm of the first-order optimality measure of eq. (10) over ``(H, D)``, from ``y = dJ/dR``.

    ``dJ/dh_i = F^T y_i`` with ``F = Phi D`` (eq. 12; projected or minimum-norm subgradient
    for a constrained or penalised H-solver, :meth:`solvers.StepSolver.optimality`) and
    ``dJ/dD = Phi^T sum_i y_i h_i^T`` (eq. 11), restricted to the tangent space of unit-norm
    primitives when the D-step keeps them at unit norm; for a constrained dictionary
    (``d_solver.constraint == "proximal"``, docs/maths.md §8b) its proximal-gradient map.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        if G is not None or isinstance(Phi, TaskFeatures):
            G = Phi.pull(y) if G is None else G  # Phi_i^T y_i (n, p)
            gH, gD = G @ D, G.T @ H
        else:
            Y = y.reshape(H.shape[0], -1)
            gH = Y @ (D if Phi is None else Phi @ D)
            gD = Y.T @ H if Phi is None else Phi.T @ (Y.T @ H)
        if d_solver is not None and d_solver.constraint == "proximal":
            gD = d_solver.optimality(D.reshape(1, -1), gD.reshape(1, -1))
        elif unit_norm:
            gD = gD - D * np.sum(D * gD, axis=0)
        norm = float(np.hypot(np.linalg.norm(h_solver.optimality(H, gH)), np.linalg.norm(gD)))
    return norm if np.isfinite(norm) else np.inf


def _dictionary_penalty(d_solver, D):
    """The D-solver's penalty at ``D`` (a constrained dictionary's L1 term; 0.0 otherwise)."""
    return float(d_solver.penalty(D.reshape(1, -1)).sum()) if d_solver.constraint == "proximal" else 0.0


def _evaluate_point(objective, Phi, D, H, h_solver, band, unit_norm, d_solver=None):
    """Loss per task at ``(D, H)`` (served from the objective's cache after a D-step), the
    normalised pair, the total (with the H-solver's and a constrained D-solver's penalty) and
    the optimality measure."""
    if hasattr(objective, "factorial_point"):  # a sharded objective: G = Phi^T y_i formed where the tasks are
        (loss, G), y = objective.factorial_point(Phi, D, H), None
    else:
        (loss, y), G = objective.loss_and_grad(factorial_rewards(objective.mdp, Phi, D, H)), None
    D, H = normalise_dictionary(D, H, band)
    total = float(loss.sum() + h_solver.penalty(H).sum())
    if d_solver is not None and d_solver.constraint == "proximal":
        total += _dictionary_penalty(d_solver, D)
    return loss, D, H, total, _optimality(y, Phi, D, H, h_solver, unit_norm, G, d_solver)


def _evaluate_residual_point(objective, Phi, D, H, Delta, lam, band, d_solver=None):
    """:func:`_evaluate_point` of the residual model (:mod:`factirl_opt.objectives.residuals`): the loss per
    task without the penalty, the normalised pair, the total with it (and a constrained
    D-solver's penalty), and the optimality measure over ``(H, D, Delta)`` from the flat
    gradient ``g_i = Phi_i^T y_i``."""
    flat = weights_problem(objective, Phi, ("features @ dictionary", "coefficients"))
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


def _alternate(objective, Phi, D, H, h_solver, d_solver, max_iter, inner_steps, tol, gtol, report, ev0):
    """The alternating loop of eqs. (10)-(12); returns the best point seen, the history and the stop.

    Each block runs ``inner_steps`` steps of its solver's alternating form, warm-started by
    what the solver carries over from its previous run (:meth:`solvers.StepSolver.carry_over`);
    the inner runs stop early only by the gradient rule or a stall (:func:`fit_factorial`).
    A KeyboardInterrupt (or lost workers, :data:`~factirl_opt.interruption.INTERRUPTIONS`) becomes a
    :class:`FitInterrupted` carrying the same tuple, at the best
    point among the start and the completed outer iterations (the start, loss NaN, if even its
    evaluation was interrupted).
    """
    penalised = h_solver.constraint == "sparse"
    band = 1.0 if penalised else 2.0
    names = ("dictionary" if Phi is None else "features @ dictionary", "coefficients")
    best = (np.nan, D, H, np.full(H.shape[0], np.nan))
    history, evaluations, gnorm, it = [], [], np.nan, 0
    try:
        D, H = normalise_dictionary(D, H, band)  # the H-step starts where the loss is evaluated (no band: no rescaling)
        loss, D, H, total, g0 = _evaluate_point(objective, Phi, D, H, h_solver, np.inf, penalised, d_solver)
        history, evaluations, gnorm = [total], [objective.n_evaluations - ev0], g0
        best = (total, D, H, loss)
        h_state = d_state = None
        status, reason = "max_iter", f"max_iter={max_iter} outer iterations done"
        for it in range(1, max_iter + 1):
            F = D if Phi is None else Phi.times(D) if isinstance(Phi, TaskFeatures) else Phi @ D
            rh = h_solver.run(weights_problem(objective, F, names), H, inner_steps, state=h_state, gtol=gtol)
            H, h_state = rh.coefficients, h_solver.carry_over(rh.state)
            rd = d_solver.run(dictionary_problem(objective, H, Phi, unit_norm=penalised), D.reshape(1, -1),
                              inner_steps, state=d_state, gtol=gtol)
            D, d_state = rd.coefficients.reshape(D.shape), d_solver.carry_over(rd.state)
            loss, D, H, total, gnorm = _evaluate_point(objective, Phi, D, H, h_solver, band, penalised, d_solver)
            history.append(total)
            evaluations.append(objective.n_evaluations - ev0)
            if total <= best[0]:
                best = (total, D, H, loss)
            report(it, total)
            stop = _outer_stop(history, gnorm, g0, tol, gtol, it)
            if stop[0] is not None:
                status, reason = stop
                break
    except INTERRUPTIONS as exc:
        done = len(history) - 1 if history else 0
        raise FitInterrupted((best, (history, evaluations), done, INTERRUPTED, INTERRUPTED, gnorm), "fit") from exc
    return best, (history, evaluations), it, status, reason, gnorm


def _alternate_residual(objective, Phi, D, H, Delta, lam, h_solver, d_solver, max_iter, inner_steps, tol, gtol, report, ev0):
    """:func:`_alternate` for the residual model (:mod:`factirl_opt.objectives.residuals`): the H-step runs on
    ``[h_i, delta_i]`` jointly (:func:`residual_weights_problem`), each task stepping as it would
    alone (``separable=True``: the tasks are independent given ``D``; an unconstrained Gauss-Newton
    subproblem of ``k + p`` variables per task is then solved exactly, never compiled into one
    block QP over every task, whose size grows as ``(n (k + p))^2``), the D-step with ``H`` and
    ``Delta`` fixed (:func:`residual_dictionary_problem`). The best point carries ``Delta``."""
    band = 2.0
    names = ("dictionary" if Phi is None else "features @ dictionary", "coefficients")
    k = H.shape[1]
    best = (np.nan, D, H, np.full(H.shape[0], np.nan), Delta)
    history, evaluations, gnorm, it = [], [], np.nan, 0
    try:
        D, H = normalise_dictionary(D, H, band)
        loss, D, H, total, g0 = _evaluate_residual_point(objective, Phi, D, H, Delta, lam, np.inf, d_solver)
        history, evaluations, gnorm = [total], [objective.n_evaluations - ev0], g0
        best = (total, D, H, loss, Delta)
        h_state = d_state = None
        status, reason = "max_iter", f"max_iter={max_iter} outer iterations done"
        for it in range(1, max_iter + 1):
            rh = h_solver.run(residual_weights_problem(objective, Phi, D, lam, names), np.concatenate([H, Delta], axis=1),
                              inner_steps, state=h_state, gtol=gtol, separable=True)
            H, Delta, h_state = rh.coefficients[:, :k], rh.coefficients[:, k:], h_solver.carry_over(rh.state)
            rd = d_solver.run(residual_dictionary_problem(objective, Phi, H, Delta), D.reshape(1, -1), inner_steps,
                              state=d_state, gtol=gtol)
            D, d_state = rd.coefficients.reshape(D.shape), d_solver.carry_over(rd.state)
            loss, D, H, total, gnorm = _evaluate_residual_point(objective, Phi, D, H, Delta, lam, band, d_solver)
            history.append(total)
            evaluations.append(objective.n_evaluations - ev0)
            if total <= best[0]:
                best = (total, D, H, loss, Delta)
            report(it, total)
            stop = _outer_stop(history, gnorm, g0, tol, gtol, it)
            if stop[0] is not None:
                status, reason = stop
                break
    except INTERRUPTIONS as exc:
        done = len(history) - 1 if history else 0
        raise FitInterrupted((best, (history, evaluations), done, INTERRUPTED, INTERRUPTED, gnorm), "fit") from exc
    return best, (history, evaluations), it, status, reason, gnorm


@learner_entry
def fit_factorial(mdp: Any, demos_per_task: Any, dictionary: ArrayLike, coefficients: ArrayLike, *, beta: float = 5.0,
                  base_features: ArrayLike | None = None, h_solver: Any = "armijo", h_solver_options: dict | None = None,
                  d_solver: Any = "armijo", d_solver_options: dict | None = None, max_iter: int = 100,
                  inner_steps: int = 5, tol: float = 1e-5, gtol: float = GTOL, objective: Any = "policy-matching",
                  planner: str = "auto", callback: Callable | None = None, verbose: bool = False,
                  reward: str = "state-action") -> FactorialFit:
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
    Phi, p = tasks.features, tasks.n_params
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
    return run_factorial(obj, D, H, h, d, base_features=Phi, max_iter=max_iter, inner_steps=inner_steps, tol=tol,
                         gtol=gtol, callback=callback, verbose=verbose)

def run_factorial(objective: Any, dictionary: NDArray[np.float64], coefficients: NDArray[np.float64],
                  h_solver: solvers.StepSolver, d_solver: solvers.StepSolver, *, base_features: Any = None,
                  max_iter: int = 100, inner_steps: int = 5, tol: float = 1e-5, gtol: float = GTOL,
                  callback: Callable | None = None, verbose: bool = False, residual_penalty: float = np.inf,
                  residuals: NDArray[np.float64] | None = None) -> FactorialFit:
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
    base_features : ndarray, shape (S*A, p), StateBroadcast or TaskFeatures, optional
        Validated ``Phi``; TaskFeatures (one matrix per task) with a
        :class:`~factirl_opt.objectives.environments.MultiEnvironmentObjective`.
    max_iter, inner_steps, tol, gtol, callback, verbose
        As in :func:`fit_factorial`.
    residual_penalty : float, default=np.inf
        ``lambda`` of the residual model ``R_i = Phi_i (D h_i + delta_i)``
        (:mod:`factirl_opt.objectives.residuals`); np.inf is the factorial model. A finite value needs an
        unconstrained H-solver (the H-step moves ``[h_i, delta_i]`` together).
    residuals : ndarray, shape (n, p), optional
        Initial ``Delta`` of a finite ``residual_penalty`` (default zeros).

    Returns
    -------
    FactorialFit
    """
    ev0 = objective.n_evaluations
    h, d = h_solver.for_alternating(), d_solver.for_alternating()
    with translate_solver_errors(), fit_progress(callback, verbose, max_iter, "FactIRL") as report:
        try:
            if np.isfinite(residual_penalty):
                p = dictionary.shape[0]
                Delta = np.zeros((coefficients.shape[0], p)) if residuals is None else np.array(residuals, dtype=np.float64)
                out = _alternate_residual(objective, base_features, dictionary, coefficients, Delta, float(residual_penalty),
                                          h, d, max_iter, inner_steps, tol, gtol, report, ev0)
            else:
                out = _alternate(objective, base_features, dictionary, h.project(coefficients), h, d, max_iter,
                                 inner_steps, tol, gtol, report, ev0)
        except FitInterrupted as exc:
            raise FitInterrupted(_result(out=exc.result, n_evaluations=objective.n_evaluations - ev0),
                                 "fit_factorial") from exc.__cause__
    return _result(out, objective.n_evaluations - ev0)


def _result(out, n_evaluations):
    (_, D, H, loss, *residuals), (history, evaluations), it, status, reason, gnorm = out
    return FactorialFit(D, H, loss, history, it, int(n_evaluations), status, reason, gnorm, evaluations,
                        residuals[0] if residuals else None)

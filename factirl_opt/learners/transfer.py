"""Transfer: the coefficients of new tasks with a learnt dictionary fixed (paper section 4.2).

With ``D`` fixed, each new task's reward is ``R_i = Phi D h_i`` and only ``h_i`` (k numbers)
is fitted: a row-separable problem over the coefficients, the H-step of the factorial scheme
run to convergence from ``h = 0`` (docs/maths.md §8). :func:`transfer_coefficients` validates
and builds the objective; :func:`run_transfer` runs on pieces already built (``FactIRL.transfer``).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

import solvers

from .._progress import fit_progress
from .._validation import check_array, check_features, check_int, check_tol
from ..exceptions import FitInterrupted, NotFittedError, ValidationError, translate_solver_errors
from .fitting import (
    GTOL, first_step_stall, held_by_constraint, learner_entry, resolve_step_solver, task_objective, warn_if_max_iter,
)
from ..tasks.task_set import environment_tasks, one_environment, per_task_features, task_set
from ..interruption import INTERRUPTED, run_keeping_best
from ..objectives.problems import weights_problem
from ..tasks.features import TaskFeatures, linear_rewards, weights_rewards
from ..mdp.environments import check_environments
from ..objectives.residuals import residual_weights, residual_weights_problem
from .gradirl import fit_weights

__all__ = ["transfer_coefficients", "run_transfer", "TransferFit", "environments_transfer_setup"]


@dataclasses.dataclass
class TransferFit:
    """Result of :func:`transfer_coefficients`.

    Attributes
    ----------
    coefficients : ndarray, shape (n_new, k)
    rewards : ndarray, shape (n_new, S, A), or list of n_new arrays (S_i, A)
        A list when the new tasks' environments differ in size.
    loss : ndarray, shape (n_new,)
        Per-task objective, without a solver's penalty.
    loss_history : list of float
        Total objective (with the penalty) at the start and after each step.
    n_iter, n_evaluations : int
    status : str
        ``"converged"``, ``"max_iter"``, ``"stalled"`` or ``"interrupted"`` (a KeyboardInterrupt:
        each task's best coefficients seen until then; loss NaN for a task never evaluated).
    reason : str
        Why the run stopped, with the values that met the rule.
    residuals : ndarray, shape (n_new, p), optional
        The new tasks' residuals ``delta_i`` of a transfer with a finite ``residual_penalty``
        (``rewards`` include them; ``loss`` is without their penalty, ``loss_history`` with
        it); None otherwise.
    """

    coefficients: np.ndarray
    rewards: np.ndarray
    loss: np.ndarray
    loss_history: list
    n_iter: int
    n_evaluations: int
    status: str
    reason: str = ""
    residuals: np.ndarray | None = None


@learner_entry
def transfer_coefficients(mdp: Any, demos_per_task: Any, dictionary: ArrayLike, *, beta: float = 5.0,
                          base_features: ArrayLike | None = None, h_solver: Any = "armijo",
                          h_solver_options: dict | None = None, max_iter: int = 100, tol: float = 1e-5,
                          objective: Any = "policy-matching", planner: str = "auto", callback: Callable | None = None,
                          verbose: bool = False, reward: str = "state-action", gtol: float = GTOL) -> TransferFit:
    """Coefficients of new tasks with the dictionary fixed (section 4.2).

    Starts from ``h = 0`` (projected onto the solver's feasible set) and runs the H-solver for
    up to ``max_iter`` steps. The new tasks are independent given the dictionary: each stops
    by its own rule and leaves the batch (:mod:`solvers.separable`), so its coefficients are
    those of a transfer to that task alone; tasks that reach ``max_iter`` first are named in a
    :class:`ConvergenceWarning`. Parameters as in :func:`factirl_opt.fit_factorial`;
    ``dictionary`` is (p, k). ``mdp`` may be a sequence of one MDP per new task, with
    ``base_features`` shared or one matrix per task (tasks in several environments). A task
    stops when the relative decrease of its loss is at most ``tol``, or when its gradient norm
    is at most ``gtol`` times its value at ``h = 0``: the rule that stops a task whose one
    demonstration its coefficients match exactly, where the loss falls toward 0 as they grow
    without bound (docs/maths.md §5); ``gtol=0`` turns it off.

    Returns
    -------
    TransferFit

    Raises
    ------
    FitInterrupted
        A KeyboardInterrupt during the run; its ``result`` is the :class:`TransferFit` of each
        task's best coefficients seen (status ``"interrupted"``).
    """
    tasks = task_set(mdp, demos_per_task, base_features, reward)
    D = check_features(dictionary, tasks.n_params, name="dictionary")
    max_iter, tol, gtol = check_int(max_iter, "max_iter", minimum=0), check_tol(tol), check_tol(gtol, "gtol")
    obj = task_objective(tasks, beta, objective, planner)
    solver = resolve_step_solver(h_solver, h_solver_options, objective, "h_solver")
    return run_transfer(obj, D, solver, base_features=tasks.features, max_iter=max_iter, tol=tol, callback=callback,
                        verbose=verbose, gtol=gtol)


def run_transfer(objective: Any, dictionary: NDArray[np.float64], solver: solvers.StepSolver, *,
                 base_features: Any = None, max_iter: int = 100, tol: float = 1e-5, callback: Callable | None = None,
                 verbose: bool = False, residual_penalty: float = np.inf, flat: tuple | None = None,
                 gtol: float = 0.0) -> TransferFit:
    """:func:`transfer_coefficients` on pieces already built and validated.

    Parameters
    ----------
    objective : Objective
        Bound to the new tasks' statistics.
    dictionary : ndarray, shape (p, k)
    solver : solvers.StepSolver
        Resolved and checked.
    base_features : ndarray, shape (S*A, p), StateBroadcast or TaskFeatures, optional
        TaskFeatures for new tasks in several environments (``objective`` then a
        :class:`~factirl_opt.objectives.environments.MultiEnvironmentObjective`).
    max_iter, tol, callback, verbose
        As in :func:`transfer_coefficients`.
    residual_penalty : float, default=np.inf
        ``lambda`` of the residual model (:mod:`factirl_opt.objectives.residuals`): each new task's
        ``[h_i, delta_i]`` is fitted from zero with ``lambda ||delta_i||^2`` added to its loss
        (an unconstrained ``solver``); np.inf fits the coefficients only.
    flat : (solvers.StepSolver, int, float), optional
        With ``residual_penalty=0`` (the flat model, where the dictionary plays no part): the
        flat learner's solver, iterations and tolerance; each new task's weights are then
        fitted as the flat learner fits them (:func:`~factirl_opt.learners.gradirl.fit_weights`,
        from zero), ``h_i = 0`` and ``delta_i`` the weights, instead of running ``solver`` on
        ``[h_i, delta_i]``.
    gtol : float, default=0.0
        The gradient rule's tolerance, per task (:func:`solvers.gradient_converged`); 0 turns
        it off. With ``flat``, the flat learner's ``gtol``.

    Returns
    -------
    TransferFit
    """
    if residual_penalty == 0.0 and flat is not None:
        flat_solver, flat_max_iter, flat_tol = flat
        return _run_flat_transfer(objective, dictionary, base_features, flat_solver, flat_max_iter, flat_tol, callback,
                                  verbose, gtol)
    if np.isfinite(residual_penalty):
        return _run_residual_transfer(objective, dictionary, solver, base_features, max_iter, tol, callback, verbose,
                                      float(residual_penalty), gtol)
    mdp = objective.mdp
    F: Any
    if isinstance(base_features, TaskFeatures):
        F = base_features.times(dictionary)
    else:
        F = dictionary if base_features is None else base_features @ dictionary
    names = ("dictionary" if base_features is None else "features @ dictionary", "coefficients")
    problem = weights_problem(objective, F, names)
    ev0 = objective.n_evaluations
    x0 = solver.project(np.zeros((problem.n_rows, problem.n_params)))
    with translate_solver_errors(), fit_progress(callback, verbose, max_iter, "transfer") as report:
        try:
            res = run_keeping_best(solver, problem, x0, max_iter, "transfer", callback=report, tol=tol, gtol=gtol,
                                   separable=True)
        except FitInterrupted as exc:
            raise FitInterrupted(_transfer_fit(mdp, F, solver, exc.result, objective.n_evaluations - ev0, names),
                                 "transfer") from exc.__cause__
    warn_if_max_iter(res, "transfer", max_iter)
    return _transfer_fit(mdp, F, solver, res, objective.n_evaluations - ev0, names)


def _run_residual_transfer(objective, D, solver, Phi, max_iter, tol, callback, verbose, lam, gtol):
    """:func:`run_transfer` of the residual model: ``[h_i, delta_i]`` from zero, separable."""
    names = ("dictionary" if Phi is None else "features @ dictionary", "coefficients")
    problem = residual_weights_problem(objective, Phi, D, lam, names)
    ev0 = objective.n_evaluations
    k = D.shape[1]
    with translate_solver_errors(), fit_progress(callback, verbose, max_iter, "transfer") as report:
        try:
            res = run_keeping_best(solver, problem, np.zeros((problem.n_rows, problem.n_params)), max_iter, "transfer",
                                   callback=report, tol=tol, gtol=gtol, separable=True)
        except FitInterrupted as exc:
            raise FitInterrupted(_residual_fit(objective, Phi, D, k, lam, exc.result, objective.n_evaluations - ev0),
                                 "transfer") from exc.__cause__
    warn_if_max_iter(res, "transfer", max_iter)
    return _residual_fit(objective, Phi, D, k, lam, res, objective.n_evaluations - ev0)


def _run_flat_transfer(objective, D, Phi, flat_solver, max_iter, tol, callback, verbose, gtol):
    """:func:`run_transfer` of the flat model (``lambda = 0``): the flat learner's fit of each new
    task (separable), returned as ``h_i = 0`` and ``delta_i = w_i``."""
    ev0 = objective.n_evaluations
    k = D.shape[1]

    def as_transfer(res):
        x = np.concatenate([np.zeros((res.coefficients.shape[0], k)), res.coefficients], axis=1)
        return _residual_fit(objective, Phi, D, k, 0.0, dataclasses.replace(res, coefficients=x),
                             objective.n_evaluations - ev0)

    with translate_solver_errors():
        try:
            res = fit_weights(objective, Phi, flat_solver, max_iter, tol, callback, verbose, what="transfer (flat model)",
                              gtol=gtol)
        except FitInterrupted as exc:
            raise FitInterrupted(as_transfer(exc.result), "transfer") from exc.__cause__
    warn_if_max_iter(res, "transfer", max_iter)
    return as_transfer(res)


def _residual_fit(objective, Phi, D, k, lam, res, n_evaluations):
    H, Delta = res.coefficients[:, :k], res.coefficients[:, k:]
    W = residual_weights(D, H, Delta)
    if isinstance(Phi, TaskFeatures):
        rewards = Phi.rewards(W)
    else:
        mdp = objective.mdp
        rewards = weights_rewards(Phi, W, mdp.n_states, mdp.n_actions)
    loss = res.loss - lam * np.einsum("np,np->n", Delta, Delta)
    status, reason = res.status, res.reason
    if status != INTERRUPTED:
        status, reason = first_step_stall(res.loss_history, res.iterations) or (status, reason)
    return TransferFit(H.copy(), rewards, loss, res.loss_history, res.iterations, int(n_evaluations), status, reason,
                       Delta.copy())


def _transfer_fit(mdp, F, solver, res, n_evaluations, names):
    if isinstance(F, TaskFeatures):
        rewards = F.rewards(res.coefficients)
    else:
        rewards = linear_rewards(F, res.coefficients, mdp.n_states, mdp.n_actions, names)
    loss = res.loss - solver.penalty(res.coefficients)
    status, reason = res.status, res.reason
    if status != INTERRUPTED:
        status, reason = first_step_stall(res.loss_history, res.iterations, held_by_constraint(solver, res)) or (status, reason)
    return TransferFit(res.coefficients, rewards, loss, res.loss_history, res.iterations, int(n_evaluations), status,
                       reason)


def transfer_mdp(mdp: Any, demos_per_task: Any, model: Any) -> Any:
    """The one MDP of a transfer on the one-MDP path (no features given), else None.

    ``mdp`` itself when it is not a sequence (the one-MDP path checks it); a sequence of one
    MDP object (``[m] * n_new``, as in ``fit``); or, for a model fitted without features on
    one MDP, a sequence of MDPs that each have that MDP's saved signature (equal models).
    """
    one = one_environment(mdp, demos_per_task, None)
    if one is not None or model.features is not None:
        return one
    sig = getattr(model, "mdp_signature_", None)
    mdps = check_environments(mdp)  # their count is checked against the demonstrations' by the one-MDP path
    return mdps[0] if isinstance(sig, dict) and all(m.signature() == sig for m in mdps) else None


def environments_transfer_setup(mdp: Any, demos_per_task: Any, features: Any, model: Any, beta: float,
                                objective: Any = "policy-matching",
                                planner: Any = "auto") -> tuple[Any, TaskFeatures, NDArray[np.float64]] | None:
    """Objective, features and dictionary of new tasks in their own environments, checked against a model.

    Parameters
    ----------
    mdp : TabularMDP or sequence of n_new TabularMDP
    demos_per_task : list of n_new task demonstrations
    features : array_like or sequence of n_new array_like, or None
        The new tasks' features: one shared matrix or one (S_i*A, p) or (S_i, p) per task;
        None: the model's own shared features.
    model : FactIRL
        Fitted: its ``features``, ``dictionary_`` (p, k), ``mdp_signature_`` (one dict, a list
        of one per task, or None) and ``features_sha256_`` are read.
    beta, objective, planner
        The model's.

    Returns
    -------
    (objective, features, dictionary) or None
        A :class:`~factirl_opt.objectives.environments.MultiEnvironmentObjective`, the
        :class:`TaskFeatures` and the validated dictionary; None when the new tasks share one
        MDP object and no features are given (the one-MDP path, whose signature is checked).

    Raises
    ------
    NotFittedError
        The model has no dictionary.
    ValidationError
        Features missing for a model fitted with per-task features, given to a tabular model,
        with another p than the dictionary's, environments with another number of actions than
        the model's, the model's shared features changed since ``fit``, or as
        :func:`factirl_opt.tasks.task_set.task_set` does.
    """
    fitted = model.features
    per_task = per_task_features(fitted)
    if features is None and not per_task and transfer_mdp(mdp, demos_per_task, model) is not None:
        return None
    if not hasattr(model, "dictionary_"):
        raise NotFittedError("this FactIRL has no dictionary_: call fit first, or set dictionary_ by hand")
    if fitted is None:
        raise ValidationError("this FactIRL model was fitted without features (tabular rewards): its dictionary lives "
                              "on the states of its MDP, so it transfers only to that MDP, without features")
    if features is None and per_task:
        raise ValidationError("this FactIRL model was fitted with one feature matrix per task: transfer to new "
                              "environments needs their features (features=[one (S_i*A, p) or (S_i, p) per new task])")
    D = check_array(model.dictionary_, "dictionary_", ndim=2)
    tasks = environment_tasks(mdp, demos_per_task, fitted if features is None else features)
    obj = task_objective(tasks, beta, objective, planner)
    if tasks.n_params != D.shape[0]:
        raise ValidationError(f"the new tasks' features have p = {tasks.n_params} columns, but the dictionary "
                              f"is over p = {D.shape[0]} features: give features with the columns of fit")
    sig = getattr(model, "mdp_signature_", None)
    n_actions = sig["n_actions"] if isinstance(sig, dict) else sig[0]["n_actions"] if sig else None
    new_actions = tasks.mdps[0].n_actions if tasks.mdps else None
    if n_actions is not None and new_actions != n_actions:
        raise ValidationError(f"the new tasks' environments have {new_actions} actions, but the model was fitted with "
                              f"{n_actions}")
    expected = getattr(model, "features_sha256_", tasks.digest)
    if features is None and expected != tasks.digest:
        raise ValidationError(f"this FactIRL model was fitted with other features than the ones set now (sha256 "
                              f"{str(tasks.digest)[:12]}... instead of {str(expected)[:12]}...): restore them or fit again")
    return obj, tasks.features, D

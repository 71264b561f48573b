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
from ..tasks.basis import DICTIONARY_NAMES, WEIGHT_NAMES
from ..tasks.task_set import TaskSet, task_set, transfer_task_set
from ..interruption import INTERRUPTED, run_keeping_best
from ..objectives.problems import as_problem_basis, weights_problem
from ..objectives.residuals import residual_weights, residual_weights_problem
from .gradirl import fit_weights

__all__ = ["transfer_coefficients", "run_transfer", "TransferFit", "transfer_tasks"]


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
    return run_transfer(obj, D, solver, base_features=tasks.basis, max_iter=max_iter, tol=tol, callback=callback,
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
    base_features : RewardBasis
        The new tasks' basis (:attr:`factirl_opt.tasks.task_set.TaskSet.basis`; a per-task one
        for new tasks in several environments, ``objective`` then a
        :class:`~factirl_opt.objectives.environments.MultiEnvironmentObjective`). The older
        forms (None for tabular, a validated matrix) are read on the objective's MDP.
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
        ``[h_i, delta_i]`` (why: "What residual_penalty runs" in :mod:`factirl_opt.learners.factorial`).
    gtol : float, default=0.0
        The gradient rule's tolerance, per task (:func:`solvers.gradient_converged`); 0 turns
        it off. With ``flat``, the flat learner's ``gtol``.

    Returns
    -------
    TransferFit
    """
    basis = as_problem_basis(objective, base_features)
    if residual_penalty == 0.0 and flat is not None:
        flat_solver, flat_max_iter, flat_tol = flat
        return _run_flat_transfer(objective, dictionary, basis, flat_solver, flat_max_iter, flat_tol, callback, verbose,
                                  gtol)
    if np.isfinite(residual_penalty):
        return _run_residual_transfer(objective, dictionary, solver, basis, max_iter, tol, callback, verbose,
                                      float(residual_penalty), gtol)
    F = basis.compose(dictionary)
    problem = weights_problem(objective, F)
    ev0 = objective.n_evaluations
    x0 = solver.project(np.zeros((problem.n_rows, problem.n_params)))
    with translate_solver_errors(), fit_progress(callback, verbose, max_iter, "transfer") as report:
        try:
            res = run_keeping_best(solver, problem, x0, max_iter, "transfer", callback=report, tol=tol, gtol=gtol,
                                   separable=True)
        except FitInterrupted as exc:
            raise FitInterrupted(_transfer_fit(F, solver, exc.result, objective.n_evaluations - ev0),
                                 "transfer") from exc.__cause__
    warn_if_max_iter(res, "transfer", max_iter)
    return _transfer_fit(F, solver, res, objective.n_evaluations - ev0)


def _run_residual_transfer(objective, D, solver, basis, max_iter, tol, callback, verbose, lam, gtol):
    """:func:`run_transfer` of the residual model: ``[h_i, delta_i]`` from zero, separable."""
    problem = residual_weights_problem(objective, basis, D, lam, DICTIONARY_NAMES)
    ev0 = objective.n_evaluations
    k = D.shape[1]
    with translate_solver_errors(), fit_progress(callback, verbose, max_iter, "transfer") as report:
        try:
            res = run_keeping_best(solver, problem, np.zeros((problem.n_rows, problem.n_params)), max_iter, "transfer",
                                   callback=report, tol=tol, gtol=gtol, separable=True)
        except FitInterrupted as exc:
            raise FitInterrupted(_residual_fit(objective, basis, D, k, lam, exc.result, objective.n_evaluations - ev0),
                                 "transfer") from exc.__cause__
    warn_if_max_iter(res, "transfer", max_iter)
    return _residual_fit(objective, basis, D, k, lam, res, objective.n_evaluations - ev0)


def _run_flat_transfer(objective, D, basis, flat_solver, max_iter, tol, callback, verbose, gtol):
    """:func:`run_transfer` of the flat model (``lambda = 0``): the flat learner's fit of each new
    task (separable), returned as ``h_i = 0`` and ``delta_i = w_i``."""
    ev0 = objective.n_evaluations
    k = D.shape[1]

    def as_transfer(res):
        x = np.concatenate([np.zeros((res.coefficients.shape[0], k)), res.coefficients], axis=1)
        return _residual_fit(objective, basis, D, k, 0.0, dataclasses.replace(res, coefficients=x),
                             objective.n_evaluations - ev0)

    with translate_solver_errors():
        try:
            res = fit_weights(objective, basis, flat_solver, max_iter, tol, callback, verbose, what="transfer (flat model)",
                              gtol=gtol)
        except FitInterrupted as exc:
            raise FitInterrupted(as_transfer(exc.result), "transfer") from exc.__cause__
    warn_if_max_iter(res, "transfer", max_iter)
    return as_transfer(res)


def _residual_fit(objective, basis, D, k, lam, res, n_evaluations):
    H, Delta = res.coefficients[:, :k], res.coefficients[:, k:]
    rewards = basis.rewards(residual_weights(D, H, Delta), names=WEIGHT_NAMES)
    loss = res.loss - lam * np.einsum("np,np->n", Delta, Delta)
    status, reason = res.status, res.reason
    if status != INTERRUPTED:
        status, reason = first_step_stall(res.loss_history, res.iterations) or (status, reason)
    return TransferFit(H.copy(), rewards, loss, res.loss_history, res.iterations, int(n_evaluations), status, reason,
                       Delta.copy())


def _transfer_fit(F, solver, res, n_evaluations):
    rewards = F.rewards(res.coefficients)
    loss = res.loss - solver.penalty(res.coefficients)
    status, reason = res.status, res.reason
    if status != INTERRUPTED:
        status, reason = first_step_stall(res.loss_history, res.iterations, held_by_constraint(solver, res)) or (status, reason)
    return TransferFit(res.coefficients, rewards, loss, res.loss_history, res.iterations, int(n_evaluations), status,
                       reason)


def transfer_tasks(mdp: Any, demos_per_task: Any, features: Any, model: Any) -> tuple[TaskSet, NDArray[np.float64]]:
    """The new tasks of ``model.transfer`` as a :class:`~factirl_opt.tasks.task_set.TaskSet`, and the
    model's dictionary, both checked against what the model was fitted on.

    Parameters
    ----------
    mdp : TabularMDP or sequence of n_new TabularMDP
    demos_per_task : list of n_new task demonstrations
    features : array_like or sequence of n_new array_like, or None
        The new tasks' features: one shared matrix or one (S_i*A, p) or (S_i, p) per task;
        None: the model's own.
    model : FactIRL
        Fitted: its ``features``, ``reward``, ``dictionary_`` (p, k), ``mdp_signature_`` (one
        dict, a list of one per task, or None) and ``features_sha256_`` are read.

    Returns
    -------
    tasks : TaskSet
        The model's own MDP (one object, or MDPs equal to it) with its basis, or the new
        environments with their features (:func:`~factirl_opt.tasks.task_set.transfer_task_set`).
    dictionary : ndarray, shape (p, k)

    Raises
    ------
    NotFittedError
        The model has no dictionary.
    ValidationError
        As :func:`~factirl_opt.tasks.task_set.transfer_task_set`; a dictionary with another
        p than the tasks' basis or another number of primitives than the model's.
    """
    if not hasattr(model, "dictionary_"):
        raise NotFittedError("this FactIRL has no dictionary_: call fit first, or set dictionary_ by hand")
    k = getattr(model, "n_primitives_", model.n_primitives)
    tasks = transfer_task_set(mdp, demos_per_task, features, model.features, reward=model.reward,
                              signature=getattr(model, "mdp_signature_", None), digest=getattr(model, "features_sha256_", None),
                              check_digest=hasattr(model, "features_sha256_"), min_columns=1 if isinstance(k, str) else k)
    D = check_array(model.dictionary_, "dictionary_", ndim=2)
    if D.shape[0] != tasks.n_params:
        if tasks.shared:
            raise ValidationError(f"dictionary_ must have shape (p, k) with p = {tasks.n_params} (the reward dimension); "
                                  f"got {D.shape}")
        raise ValidationError(f"the new tasks' features have p = {tasks.n_params} columns, but the dictionary "
                              f"is over p = {D.shape[0]} features: give features with the columns of fit")
    if tasks.shared and D.shape[1] != k:
        raise ValidationError(f"dictionary_ has {D.shape[1]} primitives but n_primitives={k}")
    return tasks, D

"""Transfer: the coefficients of new tasks with a learnt dictionary fixed (paper section 4.2).

With ``D`` fixed, each new task's reward is ``R_i = Phi D h_i`` and only ``h_i`` (k numbers)
is fitted: a row-separable problem over the coefficients, the H-step of the factorial scheme
run to convergence from ``h = 0`` (docs/maths.md §8). :func:`transfer_coefficients` validates
and builds the objective; :func:`run_transfer` runs on pieces already built (``FactIRL.transfer``).

**A prior on the coefficients.** One demonstration is matched exactly only by coefficients that
grow without bound, so the maximum-likelihood transfer has no finite optimum there and runs to
``max_iter``. With ``prior=(m, P, c)`` each new task's objective becomes

    J_i(h_i) + c_i / 2 (h_i - m)^T P (h_i - m),      c_i = scale / N_i,

the maximum a posteriori coefficients under the Gaussian ``N(m, P^-1)`` fitted to the training
tasks' coefficients (:func:`coefficient_prior`), ``J_i`` read as
a log-likelihood of the ``N_i`` demonstrated pairs scaled by ``N_i / scale`` (the MCE likelihood
is ``N_i J_i`` exactly: ``scale = 1``; policy matching's is ``N_i J_i / (2 sigma^2)``). The
optimum is finite. :func:`prior_problem` adds the term to a step problem (as ``k`` more
residuals ``sqrt(c_i / 2) L^T (h_i - m)``, ``P = L L^T``, for the Gauss-Newton solvers);
:func:`transfer_prior_weights` gives ``c_i``;
:func:`fit_prior_scale` fits ``scale`` on held-out training tasks.

**The saturation rule.** ``stol > 0`` (:func:`solvers.has_saturated`) stops a task when its
loss decreases over a step by at most ``stol`` times its decrease since the start: where
the loss stops paying for the growth of the coefficients. Measured against the prior on the
"which learner when" benchmark (results/transfer/README.md), it is the rule
``FactIRL(transfer_stol=TRANSFER_STOL)`` applies.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any, Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

import solvers

from .._progress import fit_progress
from .._validation import check_array, check_features, check_int, check_tol
from ..exceptions import ConvergenceWarning, FitInterrupted, NotFittedError, ValidationError, translate_solver_errors
from .fitting import (
    GTOL, first_step_stall, held_by_constraint, learner_entry, resolve_step_solver, task_objective, warn_if_max_iter,
)
from ..tasks.basis import DICTIONARY_NAMES, WEIGHT_NAMES
from ..tasks.task_set import TaskSet, task_set, transfer_task_set
from ..interruption import INTERRUPTED, run_keeping_best
from ..objectives.problems import weights_problem
from ..objectives.residuals import residual_weights, residual_weights_problem
from .gradirl import fit_weights
from .solver_settings import SolverSettings, estimator_solvers, step_solver

__all__ = ["transfer_coefficients", "run_transfer", "TransferFit", "transfer_tasks", "transfer_dictionary", "prior_problem",
           "transfer_prior_weights", "TRANSFER_STOL", "fit_prior_scale", "choose_prior_scale", "leave_one_out_priors",
           "PRIOR_SCALES", "PRIOR_HELD_OUT", "coefficient_prior", "PRIOR_RIDGE"]

#: the saturation rule's tolerance of ``FactIRL(transfer_stol=...)`` that stops a transfer where its
#: loss stops paying (module docstring; results/transfer/README.md); the default ``transfer_stol``
#: is 0 (off)
TRANSFER_STOL = 1e-3


@dataclasses.dataclass
class TransferFit:
    """Result of :func:`transfer_coefficients`.

    Attributes
    ----------
    coefficients : ndarray, shape (n_new, k)
    rewards : ndarray, shape (n_new, S, A), or list of n_new arrays (S_i, A)
        A list when the new tasks' environments differ in size.
    loss : ndarray, shape (n_new,)
        Per-task objective, without a solver's penalty or the prior's term.
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
                          verbose: bool = False, reward: str = "state-action", gtol: float = GTOL,
                          prior: tuple[ArrayLike, ArrayLike] | None = None, prior_scale: float = 1.0,
                          stol: float = 0.0) -> TransferFit:
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

    ``prior=(mean (k,), precision (k, k))`` (:func:`coefficient_prior`
    of the training coefficients) fits the maximum a posteriori coefficients instead, with
    ``c_i = prior_scale / N_i`` (module docstring): a finite optimum. ``stol > 0`` also stops
    a task by the saturation rule (module docstring).

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
    stol = check_tol(stol, "stol")
    obj = task_objective(tasks, beta, objective, planner)
    solver = resolve_step_solver(h_solver, h_solver_options, objective, "h_solver")
    weights = None
    if prior is not None:
        weights = (*_check_prior(prior, D.shape[1]), transfer_prior_weights(tasks, prior_scale))
    return run_transfer(obj, D, solver, base_features=tasks.basis, max_iter=max_iter, tol=tol, callback=callback,
                        verbose=verbose, gtol=gtol, prior=weights, stol=stol)


def _check_prior(prior, k):
    """``(mean (k,), precision (k, k))`` validated, the precision symmetric positive definite."""
    if not isinstance(prior, tuple) or len(prior) != 2:
        raise ValidationError(f"prior must be a (mean, precision) pair; got {type(prior).__name__}")
    m = check_array(prior[0], "prior mean", ndim=1)
    P = check_array(prior[1], "prior precision", ndim=2)
    if m.shape != (k,) or P.shape != (k, k):
        raise ValidationError(f"prior must be a mean ({k},) and a precision ({k}, {k}) for k = {k} primitives; got "
                              f"{m.shape} and {P.shape}")
    P = 0.5 * (P + P.T)
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        raise ValidationError("the prior precision must be positive definite") from None
    return m, P


def transfer_prior_weights(tasks: TaskSet, scale: float) -> NDArray[np.float64]:
    """``c_i = scale / N_i`` (n,): the prior's weight on each task's loss, ``N_i`` its demonstrated pairs
    (module docstring); ``scale`` > 0."""
    scale = float(scale)
    if not (np.isfinite(scale) and scale > 0):
        raise ValidationError(f"prior_scale must be a finite number > 0; got {scale!r}")
    return scale / np.maximum(tasks.n_pairs, 1.0)


def prior_problem(problem: solvers.StepProblem, mean: ArrayLike, precision: ArrayLike, weights: ArrayLike,
                  k: int) -> solvers.StepProblem:
    """``problem`` with ``c_i / 2 (h_i - m_i)^T P_i (h_i - m_i)`` added to row i's loss, ``h_i`` its first ``k`` parameters.

    Parameters
    ----------
    problem : solvers.StepProblem
        n rows; a declared ridge block (the residual model's ``delta_i``) stays the last
        residuals, the prior's ``k`` residuals ``sqrt(c_i / 2) L_i^T (h_i - m_i)`` (``P_i = L_i
        L_i^T``) coming before it, so the Gauss-Newton step still eliminates the block.
    mean : array_like, shape (k,) or (n, k)
    precision : array_like, shape (k, k) or (n, k, k)
        Symmetric positive definite.
    weights : array_like, shape (n,)
        ``c_i`` >= 0 (:func:`transfer_prior_weights`).
    k : int

    Returns
    -------
    solvers.StepProblem
    """
    n = problem.n_rows
    M = np.broadcast_to(np.asarray(mean, dtype=np.float64), (n, k))
    L = np.linalg.cholesky(np.broadcast_to(np.asarray(precision, dtype=np.float64), (n, k, k)))
    U = np.sqrt(0.5 * np.asarray(weights, dtype=np.float64))[:, None, None] * np.swapaxes(L, 1, 2)  # r = U (h - m)
    q = problem.ridge_params

    def prior_residual(x, rows):
        return np.einsum("nij,nj->ni", U[rows], x[:, :k] - M[rows])

    def insert(a, b):  # b's entries (rows) before the last q of a's (axis 1)
        cut = a.shape[1] - q
        return np.concatenate([a[:, :cut], b, a[:, cut:]], axis=1)

    def loss_and_grad(x, rows):
        loss, g = problem.loss_and_grad(x, rows)
        r = prior_residual(x, rows)
        g = g.copy()
        g[:, :k] += 2.0 * np.einsum("nij,ni->nj", U[rows], r)
        return loss + np.einsum("ni,ni->n", r, r), g

    def residual_jacobian(x, rows):
        loss, res, J = problem.residual_jacobian(x, rows)
        r = prior_residual(x, rows)
        Jp = np.zeros((len(rows), k, J.shape[2]))
        Jp[:, :, :k] = U[rows]
        return loss + np.einsum("ni,ni->n", r, r), insert(res, r), insert(J, Jp)

    def linearize(x, rows):
        lin = problem.linearize(x, rows)
        r = prior_residual(x, rows)
        m = lin.residual.shape[1] - q
        Ur = U[rows]

        def jvp(V):
            return insert(lin.jvp(V), np.einsum("nij,nj->ni", Ur, V[:, :k]))

        def vjp(W):
            g = lin.vjp(np.concatenate([W[:, :m], W[:, m + k:]], axis=1))
            g = g.copy()
            g[:, :k] += np.einsum("nij,ni->nj", Ur, W[:, m:m + k])
            return g

        return solvers.Linearization(lin.loss + np.einsum("ni,ni->n", r, r), insert(lin.residual, r), jvp, vjp)

    def hessian(x, rows):
        Hs = problem.hessian(x, rows).copy()
        Hs[:, :k, :k] += 2.0 * np.einsum("nji,njl->nil", U[rows], U[rows])
        return Hs

    return dataclasses.replace(
        problem, loss_and_grad=loss_and_grad,
        residual_jacobian=None if problem.residual_jacobian is None else residual_jacobian,
        linearize=None if problem.linearize is None else linearize,
        hessian=None if problem.hessian is None else hessian)


def _prior_value(prior, x, k):
    """``c_i / 2 (h_i - m_i)^T P_i (h_i - m_i)`` (n,) of ``prior=(m, P, c)`` at ``x`` (n, >= k); zeros without a prior."""
    if prior is None:
        return np.zeros(x.shape[0])
    m, P, c = prior
    n = x.shape[0]
    e = x[:, :k] - np.broadcast_to(m, (n, k))
    return 0.5 * np.asarray(c) * np.einsum("ni,nij,nj->n", e, np.broadcast_to(P, (n, k, k)), e)


def run_transfer(objective: Any, dictionary: NDArray[np.float64], solver: solvers.StepSolver, *,
                 base_features: Any = None, max_iter: int = 100, tol: float = 1e-5, callback: Callable | None = None,
                 verbose: bool = False, residual_penalty: float = np.inf, flat: tuple | None = None,
                 gtol: float = 0.0, prior: tuple[Any, Any, Any] | None = None, stol: float = 0.0) -> TransferFit:
    """:func:`transfer_coefficients` on pieces already built and validated.

    Parameters
    ----------
    objective : Objective
        Bound to the new tasks' statistics.
    dictionary : ndarray, shape (p, k)
    solver : solvers.StepSolver
        Resolved and checked.
    base_features : RewardBasis
        The new tasks' basis, as their task set built it (:attr:`factirl_opt.tasks.task_set.TaskSet.basis`;
        a per-task one for new tasks in several environments, ``objective`` then a
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
        ``[h_i, delta_i]`` (why: "What residual_penalty runs" in :mod:`factirl_opt.learners.factorial`).
    gtol : float, default=0.0
        The gradient rule's tolerance, per task (:func:`solvers.gradient_converged`); 0 turns
        it off. With ``flat``, the flat learner's ``gtol``.
    prior : (mean (k,) or (n, k), precision (k, k) or (n, k, k), weights (n,)), optional
        Fit the maximum a posteriori coefficients (:func:`prior_problem`, module docstring);
        Not read by the flat model (its ``h_i`` are 0).
    stol : float, default=0.0
        The saturation rule (:func:`solvers.has_saturated`): a task also stops when its loss
        decreases over a step by at most ``stol`` times its decrease since the start; 0 turns
        it off. With ``flat``, the flat learner's fit of each task stops by it too.

    Returns
    -------
    TransferFit
    """
    if residual_penalty == 0.0 and flat is not None:
        flat_solver, flat_max_iter, flat_tol = flat
        return _run_flat_transfer(objective, dictionary, base_features, flat_solver, flat_max_iter, flat_tol, callback,
                                  verbose, gtol, stol)
    if np.isfinite(residual_penalty):
        return _run_residual_transfer(objective, dictionary, solver, base_features, max_iter, tol, callback, verbose,
                                      float(residual_penalty), gtol, prior, stol)
    F = base_features.compose(dictionary)
    problem = weights_problem(objective, F)
    k = dictionary.shape[1]
    if prior is not None:
        problem = prior_problem(problem, *prior, k)
    ev0 = objective.n_evaluations
    x0 = solver.project(np.zeros((problem.n_rows, problem.n_params)))
    with translate_solver_errors(), fit_progress(callback, verbose, max_iter, "transfer") as report:
        try:
            res = run_keeping_best(solver, problem, x0, max_iter, "transfer", callback=report, tol=tol, gtol=gtol,
                                   separable=True, stol=stol)
        except FitInterrupted as exc:
            raise FitInterrupted(_transfer_fit(F, solver, exc.result, objective.n_evaluations - ev0, prior, k),
                                 "transfer") from exc.__cause__
    warn_if_max_iter(res, "transfer", max_iter)
    return _transfer_fit(F, solver, res, objective.n_evaluations - ev0, prior, k)


def _run_residual_transfer(objective, D, solver, basis, max_iter, tol, callback, verbose, lam, gtol, prior=None, stol=0.0):
    """:func:`run_transfer` of the residual model: ``[h_i, delta_i]`` from zero, separable."""
    problem = residual_weights_problem(objective, basis, D, lam, DICTIONARY_NAMES)
    ev0 = objective.n_evaluations
    k = D.shape[1]
    if prior is not None:
        problem = prior_problem(problem, *prior, k)
    with translate_solver_errors(), fit_progress(callback, verbose, max_iter, "transfer") as report:
        try:
            res = run_keeping_best(solver, problem, np.zeros((problem.n_rows, problem.n_params)), max_iter, "transfer",
                                   callback=report, tol=tol, gtol=gtol, separable=True, stol=stol)
        except FitInterrupted as exc:
            raise FitInterrupted(_residual_fit(objective, basis, D, k, lam, exc.result, objective.n_evaluations - ev0,
                                               prior), "transfer") from exc.__cause__
    warn_if_max_iter(res, "transfer", max_iter)
    return _residual_fit(objective, basis, D, k, lam, res, objective.n_evaluations - ev0, prior)


def _run_flat_transfer(objective, D, basis, flat_solver, max_iter, tol, callback, verbose, gtol, stol=0.0):
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
                              gtol=gtol, stol=stol)
        except FitInterrupted as exc:
            raise FitInterrupted(as_transfer(exc.result), "transfer") from exc.__cause__
    warn_if_max_iter(res, "transfer", max_iter)
    return as_transfer(res)


def _residual_fit(objective, basis, D, k, lam, res, n_evaluations, prior=None):
    H, Delta = res.coefficients[:, :k], res.coefficients[:, k:]
    rewards = basis.rewards(residual_weights(D, H, Delta), names=WEIGHT_NAMES)
    loss = res.loss - lam * np.einsum("np,np->n", Delta, Delta) - _prior_value(prior, res.coefficients, k)
    status, reason = res.status, res.reason
    if status != INTERRUPTED:
        status, reason = first_step_stall(res.loss_history, res.iterations) or (status, reason)
    return TransferFit(H.copy(), rewards, loss, res.loss_history, res.iterations, int(n_evaluations), status, reason,
                       Delta.copy())


def _transfer_fit(F, solver, res, n_evaluations, prior=None, k=0):
    rewards = F.rewards(res.coefficients)
    loss = res.loss - solver.penalty(res.coefficients) - _prior_value(prior, res.coefficients, k)
    status, reason = res.status, res.reason
    if status != INTERRUPTED:
        status, reason = first_step_stall(res.loss_history, res.iterations, held_by_constraint(solver, res)) or (status, reason)
    return TransferFit(res.coefficients, rewards, loss, res.loss_history, res.iterations, int(n_evaluations), status,
                       reason)


def transfer_solver(model: Any, solver: Any = None, solver_options: dict | None = None) -> tuple[Any, dict | None]:
    """The H-step ``(solver, options)`` of ``model.transfer``: the call's ``solver`` (a name with
    ``solver_options``, or a SolverSettings' H-step solver and options), else the model's transfer solver."""
    if solver is None:
        if solver_options is not None:
            raise ValidationError("solver_options given without solver")
        return step_solver(SolverSettings.of(model.solver), "transfer", estimator_solvers(model)[:2])
    if isinstance(solver, SolverSettings):
        if solver_options is not None:
            raise ValidationError(f"solver_options given with solver settings {solver.label()!r}: give the options "
                                  "in the SolverSettings")
        return solver.h_solver, solver.h_options or None
    return solver, solver_options


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
    return tasks, transfer_dictionary(model, tasks)


def transfer_dictionary(model: Any, tasks: TaskSet) -> NDArray[np.float64]:
    """``model.dictionary_`` (p, k), checked against the new tasks' basis (a ValidationError for another p, or
    another k than the model's)."""
    k = getattr(model, "n_primitives_", model.n_primitives)
    D = check_array(model.dictionary_, "dictionary_", ndim=2)
    if D.shape[0] != tasks.n_params:
        if tasks.shared:
            raise ValidationError(f"dictionary_ must have shape (p, k) with p = {tasks.n_params} (the reward dimension); "
                                  f"got {D.shape}")
        raise ValidationError(f"the new tasks' features have p = {tasks.n_params} columns, but the dictionary "
                              f"is over p = {D.shape[0]} features: give features with the columns of fit")
    if tasks.shared and D.shape[1] != k:
        raise ValidationError(f"dictionary_ has {D.shape[1]} primitives but n_primitives={k}")
    return D


#: ridge added to the prior covariance of the coefficients, relative to its mean variance
PRIOR_RIDGE = 1e-3


def coefficient_prior(coefficients: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The Gaussian fitted to the training tasks' coefficients: mean (k,) and precision (k, k).

    The covariance is the sample covariance (ddof 1) plus :data:`PRIOR_RIDGE` times its mean
    variance on the diagonal, so that it stays invertible with fewer tasks than primitives.

    Raises
    ------
    ValidationError
        Fewer than 2 tasks, or non-finite coefficients.
    """
    H = check_array(coefficients, "coefficients", ndim=2)
    n, k = H.shape
    if n < 2:
        raise ValidationError(f"the coefficients' prior is fitted to the training tasks' coefficients; got {n} task(s), "
                              "need at least 2")
    C = np.atleast_2d(np.cov(H, rowvar=False, ddof=1))
    scale = float(np.trace(C)) / k
    C = C + PRIOR_RIDGE * (scale if scale > 0 else 1.0) * np.eye(k)
    P = np.linalg.inv(C)
    return H.mean(axis=0), 0.5 * (P + P.T)


#: the prior scales :func:`fit_prior_scale` tries (``c_i = scale / N_i``, :mod:`factirl_opt.learners.transfer`)
PRIOR_SCALES = (0.01, 0.03, 0.1, 0.3, 1.0, 3.0)
#: held-out training tasks :func:`fit_prior_scale` transfers at most (evenly spaced over the tasks)
PRIOR_HELD_OUT = 20


def leave_one_out_priors(coefficients: ArrayLike, rows: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`coefficient_prior` of the training coefficients (n, k) without
    each task of ``rows`` (r,) in turn: means (r, k) and precisions (r, k, k). Needs n >= 3."""
    H = check_array(coefficients, "coefficients", ndim=2)
    rows = np.asarray(rows, dtype=np.intp)
    pairs = [coefficient_prior(np.delete(H, i, axis=0)) for i in rows]
    return np.array([m for m, _ in pairs]).reshape(len(rows), H.shape[1]), \
        np.array([P for _, P in pairs]).reshape(len(rows), H.shape[1], H.shape[1])


def choose_prior_scale(scores: dict, rule: str = "min") -> float:
    """The scale of :func:`fit_prior_scale`'s ``scores`` ``{scale: per-task deviations (r,)}``: the lowest mean
    (``"min"``; ties to the larger scale), or the largest scale whose mean is within one standard error of the
    lowest (``"1se"``, the paired differences' standard error over the held-out tasks); 0.0 for no scores."""
    if not scores:
        return 0.0
    means = {s: float(np.mean(v)) for s, v in scores.items()}
    best = min(means, key=lambda s: (means[s], -s))
    if rule == "min":
        return float(best)
    if rule != "1se":
        raise ValidationError(f"rule must be 'min' or '1se'; got {rule!r}")
    ok = []
    for s, v in scores.items():
        diff = np.asarray(v) - np.asarray(scores[best])
        se = float(np.std(diff, ddof=1) / np.sqrt(len(diff))) if len(diff) > 1 else 0.0
        if means[s] - means[best] <= se:
            ok.append(s)
    return float(max(ok))


def fit_prior_scale(model: Any, mdp: Any, demos_per_task: Any, scales: tuple = PRIOR_SCALES,
                    n_held_out: int = PRIOR_HELD_OUT, solver: Any = None, rule: str = "min") -> tuple[float, dict]:
    """The scale of the transfer's prior (:mod:`factirl_opt.learners.transfer`) that transfers the training
    tasks best, held out one at a time.

    Up to ``n_held_out`` training tasks (evenly spaced over them) are transferred from their first
    demonstration, each with the prior fitted to the other training tasks' coefficients
    (:func:`leave_one_out_priors`), at every ``scale`` of ``scales``; the score of a scale is the
    mean deviation (:func:`factirl_opt.deviation`) of the transferred rewards from the tasks' own
    fitted ``rewards_`` (all their demonstrations); :func:`choose_prior_scale` (``rule``) takes the scale.

    Parameters
    ----------
    model : FactIRL
        Fitted on ``mdp`` and ``demos_per_task`` (its ``dictionary_``, ``coefficients_``,
        ``rewards_``, ``residual_penalty_``; its ``beta``, ``objective``, ``planner``, ``solver``,
        ``transfer_max_iter``, ``tol`` and ``gtol`` as its ``transfer`` reads them).
    mdp, demos_per_task
        The training tasks, as given to ``fit``.
    scales : tuple of float
    n_held_out : int
    solver : solvers.StepSolver, optional
        The transfer's step solver (default: the model's H-step solver).

    Returns
    -------
    scale : float
        0.0 where no prior applies (fewer than 3 training tasks, or the flat model).
    scores : dict
        ``{scale: each held-out task's deviation (r,)}``.
    """
    from ..evaluation import deviation

    H = np.asarray(model.coefficients_, dtype=np.float64)
    lam = float(getattr(model, "residual_penalty_", np.inf))
    n, k = H.shape
    if n < 3 or lam == 0.0:
        return 0.0, {}
    idx = np.unique(np.round(np.linspace(0, n - 1, min(n, int(n_held_out)))).astype(np.intp))
    feats = model.features if isinstance(model.features, (list, tuple)) else None
    tasks, D = transfer_tasks(mdp, demos_per_task, feats, model)
    tasks = tasks.subset(idx).episodes(0, 1)  # each held-out task's first demonstration
    obj = task_objective(tasks, model.beta, model.objective, model._group("execution").planner)
    if solver is None:
        name, options = estimator_solvers(model)[:2]
        solver = resolve_step_solver(name, options, model.objective, "solver")
    M, P = leave_one_out_priors(H, idx)
    refs = [model.rewards_[i] for i in idx]
    mdps: Any = tasks.mdp if tasks.mdps is None else tasks.mdps
    max_iter = check_int(model.transfer_max_iter, "transfer_max_iter", minimum=0)
    scores = {}
    for scale in scales:
        c = transfer_prior_weights(tasks, scale)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            res = run_transfer(obj, D, solver, base_features=tasks.basis, max_iter=max_iter, tol=check_tol(model.tol),
                               gtol=check_tol(model.gtol, "gtol"), residual_penalty=lam, prior=(M, P, c))
        scores[float(scale)] = np.atleast_1d(np.asarray(deviation(mdps, refs, res.rewards, planner=model._group("execution").planner),
                                                            dtype=np.float64))
    return choose_prior_scale(scores, rule), scores

"""GradIRL, the flat learner (Neu & Szepesvari 2007; paper section 3.1).

:class:`GradIRL` is the estimator; :func:`fit_weights` is its fit on an objective and a solver
already built, which ``FactIRL`` also runs for its PCA start on the same objective.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Callable, ClassVar

import numpy as np
from numpy.typing import ArrayLike

import solvers

from .._progress import fit_progress
from .._validation import check_fit_parameters, check_int, check_tol
from .estimator import EXECUTION_PARAM_KINDS, EXECUTION_RENAMED, Estimator, renamed_params
from ..exceptions import FitInterrupted, translate_solver_errors
from .fitting import (
    GTOL, check_solver_applies, first_step_stall, held_by_constraint, learner_entry, learner_tasks, make_objective,
    resolve_step_solver, task_objective, warn_if_max_iter, warn_if_stalled,
)
from ..tasks.basis import RewardBasis
from ..tasks.task_set import TaskSet
from ..interruption import INTERRUPTED, loss_phrase, raise_interrupted, run_keeping_best, warn_interrupted
from ..objectives.sharding import Execution
from ..objectives.problems import weights_problem
from .solver_settings import SolverSettings, estimator_solvers
from ..objectives import Objective


__all__ = ["GradIRL", "fit_weights", "make_objective", "warn_if_stalled", "check_solver_applies"]

#: GradIRL's default saturation rule (:func:`solvers.stopping.has_saturated`): a task whose loss
#: falls toward 0 stops once its last iterations add at most this fraction of its progress
STOL = 1e-5


def fit_weights(objective: Any, features: Any, solver: solvers.StepSolver, max_iter: int, tol: float,
                callback: Callable | None = None, verbose: bool = False, what: str = "GradIRL", *,
                gtol: float = 0.0, stol: float = 0.0) -> solvers.SolverResult:
    """The flat fit on pieces already built: ``solver`` from zero weights on every task at once.

    A separable run (:mod:`solvers.separable`): each task stops by its own rules (``tol`` on the
    relative decrease of its own loss, ``stol`` on its decrease over an iteration relative to
    its decrease since the start, ``gtol`` on its own gradient norm relative to its
    start) and leaves the batch, so its weights are those of a fit of that task alone.

    Parameters
    ----------
    objective : Objective
        Bound to the n tasks' statistics.
    features : RewardBasis
        The tasks' basis (:attr:`factirl_opt.tasks.task_set.TaskSet.basis`); the older forms
        (None for tabular weights, a validated matrix) are read on the objective's MDP.
    solver : solvers.StepSolver
        Resolved and checked against the objective.
    max_iter : int
    tol : float
    callback : callable, optional
        ``callback(iteration, total_loss)`` after each iteration.
    verbose : bool
    what : str
        Names the fit in the progress bar and in an interruption.
    gtol : float, default=0.0
        The gradient rule's tolerance (:func:`solvers.gradient_converged`); 0 applies only the
        relative decrease (FactIRL's flat start).
    stol : float, default=0.0
        The saturation rule's tolerance (:func:`solvers.stopping.has_saturated`); 0 turns it off
        (FactIRL's flat start).

    Returns
    -------
    solvers.SolverResult
        ``coefficients`` (n, p) are the weights; ``row_status``, ``row_iterations`` and
        ``row_evaluations`` each task's record. A first iteration that left the total loss
        unchanged is reported ``"stalled"`` (:func:`factirl_opt.learners.fitting.first_step_stall`).

    Raises
    ------
    FitInterrupted
        A KeyboardInterrupt during the fit; its ``result`` holds each task's best weights seen
        (status ``"interrupted"``, :func:`factirl_opt.interruption.run_keeping_best`).
    """
    problem = weights_problem(objective, features)
    with translate_solver_errors(), fit_progress(callback, verbose, max_iter, "GradIRL") as report:
        res = run_keeping_best(solver, problem, np.zeros((problem.n_rows, problem.n_params)), max_iter, what,
                               callback=report, tol=tol, gtol=gtol, stol=stol, separable=True)
    stall = first_step_stall(res.loss_history, res.iterations, held_by_constraint(solver, res))
    if stall is not None:
        res.status, res.reason = stall
    return res


class GradIRL(Estimator):
    """Flat learner: one reward per task whose Boltzmann policy on Q* matches the expert's.

    Minimises eq. (5) (or another registered objective) for every task, batched over the task
    axis, by gradient descent with Armijo step-size adaptation (or any registered step solver),
    from zero weights. Each task stops by its own rule and leaves the batch
    (:mod:`solvers.separable`): a task's reward is the one of a fit of that task alone, whatever
    other tasks share the fit (to rounding), and tasks that stopped use no more evaluations.

    Parameters
    ----------
    beta : float, default=5.0
        Boltzmann inverse temperature (eq. 7).
    features : array_like, shape (S*A, p) or (S, p), or sequence of n such, optional
        Linear reward features ``R = F w`` (state features are repeated over actions); None
        learns tabular rewards (``theta = R``, d = S*A). A sequence gives one matrix per task,
        (S_i*A, p) or (S_i, p) with the same p: ``R_i = Phi_i w_i`` on task i's own
        environment (tasks in several environments; docs/maths.md §7). Or any
        :class:`~factirl_opt.tasks.basis.RewardBasis` (another kind of features), taken as it is.
    reward : {"state-action", "state"}, default="state-action"
        Without features: ``"state-action"`` learns ``R(s, a)`` (d = S*A); ``"state"`` learns a
        reward of the states only, ``R(s, a) = r(s)`` (d = S), at the cost of the tabular fit
        (the gradient sums ``dJ/dR`` over the actions; no feature matrix is formed). It gives
        the fit of ``features=np.kron(np.eye(S), np.ones((A, 1)))`` (docs/maths.md §7).
        Refused together with ``features``.
    max_iter : int, default=100
        Maximum descent iterations.
    tol : float, default=1e-5
        A task stops when the relative decrease of its own loss over an iteration is below tol
        (or when no step decreases it: stalled).
    gtol : float, default=1e-4
        A task also stops when the norm of its gradient (projected or minimum-norm subgradient
        for a constrained or penalised solver) is at most ``gtol`` times its value at the start.
        This is the rule that stops a task whose demonstrations its reward matches exactly: its
        loss then falls toward 0 as the reward grows without bound (the Boltzmann policy
        saturates), and the relative decrease of a loss that tends to 0 never becomes small
        (docs/maths.md §5). 0 turns the rule off (a fixed budget for such tasks).
    stol : float, default=1e-5
        A task also stops when its loss has saturated: when the decrease of its loss over an
        iteration is at most ``stol`` times its decrease since the start
        (:func:`solvers.stopping.has_saturated`). Measured against the progress made, not
        against the current loss, it stops a task whose loss falls geometrically toward 0 (the
        Boltzmann policy saturating on its demonstrations) once the loss is about ``stol`` of
        its start, whatever its gradient does; a task whose loss stays above half its start
        meets the relative decrease (``tol``, the same default) first. 0 turns the rule off.
    solver : str, solvers.StepSolver or SolverSettings, default="armijo"
        Step solver (see ``solvers.available_solvers()``), or a
        :class:`~factirl_opt.SolverSettings` (its H-step solver and options; it must not name
        a D-step solver, which GradIRL does not have).
    objective : str, default="policy-matching"
        Per-task loss (see ``factirl_opt.available_objectives()``).
    execution : Execution, optional
        Where and how the fit runs and is watched (:class:`~factirl_opt.Execution`: ``n_jobs``,
        ``backend``, ``client``, ``planner``, ``planner_options``, ``verbose``, ``callback``);
        None: ``Execution()``, one process, the automatic planner. With ``n_jobs``, each
        shard's worker keeps its tasks' statistics, warm starts and factorisations between
        evaluations; the result equals ``n_jobs=1``'s to rounding, with the same number of
        evaluations, and tasks in several environments are sharded by whole environments.
        ``planner_options={"max_bytes": B}`` is the planning memory budget per process
        (:mod:`factirl_opt.planning.budget`), also of FactIRL's ``transfer``.

    Only ``beta`` and ``features`` may be given by position; the others are keyword-only.
    ``get_params``, ``set_params``, :func:`~factirl_opt.learners.estimator.clone` and the ``repr`` come
    from :class:`~factirl_opt.learners.estimator.Estimator`.

    Attributes
    ----------
    weights_ : ndarray, shape (n, p)
        Learnt parameters (tabular theta, p = S*A; state rewards, p = S; or feature weights,
        also with per-task features, so a reward can be carried to another map).
    rewards_ : ndarray, shape (n, S, A), or list of n arrays (S_i, A)
        A list when the tasks' environments differ in their number of states; stacked
        otherwise.
    loss_ : ndarray, shape (n,)
        Final loss of each task.
    loss_history_ : list of float
        Total loss (sum over tasks) before the first step and after each iteration.
    n_evaluations_ : int
        Batched planning evaluations used.
    n_iter_ : int
        The most iterations a task took.
    status_ : str
        ``"converged"`` (every task), ``"max_iter"`` (a task took ``max_iter`` iterations
        before its rule held: a :class:`ConvergenceWarning` names those tasks), ``"stalled"``
        (a task could not decrease its loss; a :class:`ConvergenceWarning` is issued when the
        fit stalls at its first step) or ``"interrupted"``.
    stop_reason_ : str
        How the tasks stopped: how many by each rule, and which stalled or reached
        ``max_iter`` (``"interrupted"`` after Ctrl-C).
    mdp_signature_ : dict or list of dict
        The signature of the MDP it was fitted on; with a sequence of MDPs (not all the same
        object) one signature per task.
    features_sha256_ : str or None
        SHA-256 of the validated features (S*A, p) of the fit
        (:func:`factirl_opt.tasks.task_set.features_digest`); None without features and with
        per-task features.

    Notes
    -----
    A KeyboardInterrupt (Ctrl-C) during ``fit`` leaves the estimator fitted with each task's
    best weights seen so far (``status_ == stop_reason_ == "interrupted"``, ``loss_`` their
    loss, NaN for a task never evaluated), warns with :class:`InterruptedFitWarning`, and
    propagates (as :class:`factirl_opt.exceptions.FitInterrupted`, a KeyboardInterrupt).
    """

    #: The learnt attributes and their kinds, from which ``save_model`` derives what to store and
    #: ``load_model`` what to check (factirl_opt.persistence.learnt): a tuple names the axes of a
    #: finite float array (same name, same length; S, A of the MDP, p parameters), a string a kind.
    learnt_attributes: ClassVar[dict[str, tuple[str, ...] | str]] = {
        "weights_": ("n", "p"), "rewards_": ("n", "S", "A"), "loss_": ("n",), "loss_history_": "history",
        "n_evaluations_": "count", "n_iter_": "count", "status_": "text", "stop_reason_": "text",
        "mdp_signature_": "mdp-signature", "features_sha256_": "features-digest",
    }

    #: How ``save_model`` stores the parameters that are not plain JSON (factirl_opt.persistence.params).
    param_kinds: ClassVar[dict[str, str]] = {"features": "features", "solver": "solver", "objective": "objective",
                                             **EXECUTION_PARAM_KINDS}
    param_groups: ClassVar[dict[str, type]] = {"solver": SolverSettings, "execution": Execution}
    #: The former flat names of grouped settings (warned once; :mod:`factirl_opt.learners.estimator`).
    deprecated_params: ClassVar[dict[str, str]] = {"solver_options": "solver__h_solver_options", **EXECUTION_RENAMED}

    @renamed_params
    def __init__(self, beta: float = 5.0, features: ArrayLike | Sequence[ArrayLike] | RewardBasis | None = None, *,
                 reward: str = "state-action", max_iter: int = 100, tol: float = 1e-5, gtol: float = GTOL,
                 stol: float = STOL, solver: str | solvers.StepSolver | SolverSettings = "armijo",
                 objective: str | type[Objective] = "policy-matching", execution: Execution | None = None) -> None:
        self.beta = beta
        self.features = features
        self.reward = reward
        self.max_iter = max_iter
        self.tol = tol
        self.gtol = gtol
        self.stol = stol
        self.solver = solver
        self.objective = objective
        self.execution = execution

    @learner_entry
    def fit(self, mdp: Any, demos_per_task: Any) -> GradIRL:
        """Learn one reward per task.

        Parameters
        ----------
        mdp : TabularMDP or sequence of n TabularMDP
            One MDP shared by every task, or one per task (tasks in several environments, with
            the same number of actions; tasks given the same object are planned as one batch).
            Several environments need ``features``: one shared matrix (equal-sized
            environments) or one per task.
        demos_per_task : list of n task demonstrations
            Each an int array (m, L, 2) or a list of (L_j, 2) episodes, on its task's MDP.

        Returns
        -------
        self
        """
        check_fit_parameters(self)
        return self._fit_tasks(learner_tasks(self, mdp, demos_per_task))

    def _fit_tasks(self, tasks: TaskSet) -> GradIRL:
        """:meth:`fit` on a task set (FactIRL's sharing search fits its flat start so, once for every fold)."""
        max_iter, tol = check_int(self.max_iter, "max_iter", minimum=0), check_tol(self.tol)
        gtol, stol = check_tol(self.gtol, "gtol"), check_tol(self.stol, "stol")
        objective = task_objective(tasks, self.beta, self.objective, self._group("execution").planner)
        solver = resolve_step_solver(*estimator_solvers(self, d_step=False)[:2], self.objective, "solver")
        execution = self._group("execution")
        try:
            with execution.evaluate(objective) as objective:  # n_jobs=1: the objective itself
                res = fit_weights(objective, tasks.basis, solver, max_iter, tol, execution.callback, execution.verbose,
                                  "GradIRL.fit", gtol=gtol, stol=stol)
        except FitInterrupted as exc:
            self._store(tasks, exc.result, objective)
            warn_interrupted("GradIRL.fit", f"kept each task's best weights seen ({loss_phrase(self.loss_)}, "
                                            f"after {self.n_iter_} iterations)", exc.__cause__)
            raise_interrupted(exc, "GradIRL.fit")
        self._store(tasks, res, objective)
        warn_if_stalled(res.status, res.iterations, "GradIRL.fit")
        warn_if_max_iter(res, "GradIRL.fit", max_iter)
        return self

    def _store(self, tasks, res, objective):
        self.weights_ = res.coefficients
        self.rewards_ = tasks.rewards(res.coefficients)
        self.mdp_signature_ = tasks.signature()
        self.features_sha256_ = tasks.digest
        self.loss_ = res.loss
        self.loss_history_ = res.loss_history
        self.n_evaluations_ = int(objective.n_evaluations)
        self.n_iter_ = res.iterations
        self.status_ = res.status
        self.stop_reason_ = INTERRUPTED if res.status == INTERRUPTED else res.reason

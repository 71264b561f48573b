"""FactIRL, the factorial learner (paper section 3.2): a shared dictionary of primitive rewards.

Every task's reward is ``R_i = Phi D h_i``: base features ``Phi`` (S*A, p) (the identity for
tabular rewards, p = S*A), dictionary ``D`` (p, k), coefficients ``H`` (n, k), tasks on the
leading axis (docs/maths.md §8). Tasks in several environments (a sequence of MDPs, one
feature matrix ``Phi_i`` per task) share the dictionary in feature space:
``R_i = Phi_i D h_i``. :class:`FactIRL` is the estimator: it validates, builds the
objective and the solvers once, initialises (PCA of the flat learner's parameters, or random)
and hands them down to the alternating scheme (:mod:`factirl_opt.learners.factorial`) and to transfer
(:mod:`factirl_opt.learners.transfer`); the dictionary helpers live in :mod:`factirl_opt.learners.dictionary`.
The plain functions stay importable from here.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

import solvers

from .._validation import as_rng, check_bool, check_fit_parameters, check_int, check_tol
from .estimator import EXECUTION_PARAM_KINDS, EXECUTION_RENAMED, Estimator, renamed_params
from .dictionary import (
    PCA_MAX_HALVINGS,
    DictionaryConstraint,
    check_dictionary_constraint,
    constrained_dictionary_solver,
    constrained_start,
    normalise_dictionary,
    orient_nonneg,
    pca_dictionary,
    shrink_coefficients,
)
from ..exceptions import FitInterrupted, ValidationError
from .factorial import GTOL, FactorialFit, check_residual_solver, fit_factorial, resolve_scheme, run_factorial
from .fitting import learner_entry, learner_tasks, resolve_step_solver, task_objective, warn_if_stalled
from ..tasks.basis import RewardBasis
from ..tasks.task_set import TaskSet
from ..interruption import loss_phrase, raise_interrupted, warn_interrupted
from ..objectives.sharding import Execution
from .solver_settings import SolverSettings, estimator_solvers
from .start import FLAT_TOL, Start, factorial_start, flat_solver
from ..objectives import Objective

from .transfer import (TRANSFER_STOL, TransferFit, run_transfer, transfer_coefficients, transfer_dictionary, transfer_solver,
                       transfer_tasks)
from .posterior import cached_transfer_posterior, keep_transfer
from .noise_levels import task_noise_levels
from .dictionary_ensemble import PosteriorSettings, check_posterior_settings, fit_posterior_terms
from .active import request_starts
from .gpi import GPIReport, generalised_policy_improvement
from .selection.results import validation_attribute
from .selection.sharing_search import SharingSearch, fit_auto, is_auto
from .._deprecation import moved_names
from ..objectives.residuals import residual_weights

__all__ = ["FactIRL", "PAPER_SETTINGS", "pca_dictionary", "fit_factorial", "transfer_coefficients", "FactorialFit",
           "TransferFit", "shrink_coefficients", "normalise_dictionary", "GTOL", "PCA_MAX_HALVINGS"]

#: The paper's algorithm (section 3.2) as FactIRL keyword arguments, ``FactIRL(5, **PAPER_SETTINGS)``:
#: Armijo steps everywhere, an unsaturated flat start, the alternation, 5 steps per sub-problem,
#: fixed budgets (``gtol=0``), the maximum-likelihood transfer; FactIRL's defaults until the
#: defaults study (``results/defaults/README.md``), pinned by the reproduction presets (whose
#: ``paper`` rows also set ``pca_shrink=False``: pass your own ``start`` to change the start).
PAPER_SETTINGS: Mapping[str, Any] = MappingProxyType(dict(
    solver=SolverSettings("armijo", d_solver="armijo", flat_solver="armijo"), start=Start(flat_stol=0.0),
    scheme="alternating", inner_steps=5, max_iter=100, tol=1e-5, gtol=0.0, transfer_stol=0.0))

class FactIRL(Estimator):
    """Factorial learner: shared dictionary ``D`` and per-task coefficients ``H`` (eqs. 10-12).

    Parameters
    ----------
    n_primitives : int or "auto", default=5
        Number of primitive rewards k. ``"auto"``: chosen by validation over tasks
        (:mod:`factirl_opt.learners.selection`), as ``residual_penalty="auto"``.
    beta : float, default=5.0
        Boltzmann inverse temperature (eq. 7).
    features : array_like, shape (S*A, p) or (S, p), or sequence of n such, optional
        Base features ``Phi``: rewards ``R_i = Phi D h_i`` with ``D`` of shape (p, k), p >= k
        (state features are repeated over actions). None: tabular, p = S*A. A sequence gives
        one matrix per task, (S_i*A, p) or (S_i, p) with the same p: ``R_i = Phi_i D h_i`` on
        task i's own environment, the dictionary living in feature space (docs/maths.md §8);
        ``transfer`` then needs the new environments' features. Or any
        :class:`~factirl_opt.tasks.basis.RewardBasis` (another kind of features), taken as it is.
    reward : {"state-action", "state"}, default="state-action"
        Without features: ``"state"`` learns primitives of the states only, ``D`` of shape
        (S, k) and ``R_i(s, a) = (D h_i)(s)``, at the cost of the tabular fit (docs/maths.md §7).
        Refused together with ``features``.
    start : Start, optional
        Where the fit starts (:class:`~factirl_opt.Start`: ``init``, ``pca_shrink``,
        ``flat_max_iter``, ``flat_tol``, ``flat_stol``); None: ``Start()``, the PCA of the
        flat learner's rewards (GradIRL's default fit: the solver settings' ``flat_solver``, the
        saturation rule ``flat_stol``), shrunk while the loss decreases. ``flat_max_iter`` is also
        the budget of the flat model's ``transfer`` (``residual_penalty=0``).
    max_iter : int, default=100
        Maximum outer iterations (one H-step and one D-step each).
    inner_steps : int, default=2
        Fixed number of solver steps per sub-problem (per outer iteration of the joint scheme).
    tol : float, default=1e-5
        Stop when the relative decrease of the total loss over an outer iteration is below tol
        (a rise is not convergence; the best point seen is kept); see :func:`fit_factorial` for
        both rules and for the inner runs. Transfer stops on ``tol``.
    gtol : float, default=1e-4
        The fit also stops when the gradient norm over (H, D) falls to ``gtol`` times its initial
        value; ``0`` runs the outer iterations to ``tol`` or ``max_iter`` only (the paper's
        fixed budgets, as the ``paper`` preset does). In ``transfer`` each new task also stops
        when its own gradient norm falls to ``gtol`` times its value at ``h = 0``: the rule that
        stops a task whose demonstration its coefficients match exactly (the loss falls toward 0
        as they grow without bound; docs/maths.md §5).
    transfer_max_iter : int, default=100
        Maximum solver steps in ``transfer``.
    solver : str, solvers.StepSolver or SolverSettings, default="armijo"
        The step solvers (:class:`~factirl_opt.SolverSettings`: H-step, D-step, the flat
        learner's and the transfer's, with their options), or a solver name, the H-step solver
        (any name of ``solvers.available_solvers()``, e.g. ``"gn-qp-osqp"``) with the others at
        their defaults: the D-step ``"lbfgs"`` (``"armijo"`` with a ``dictionary_constraint``),
        the flat learner ``"armijo"``, the transfer the H-step's. A constrained H-step solver keeps
        its constraint in the start (projected) and in transfer; a sparse one's L1 penalty is part
        of the H objective and of ``loss_history_`` (the guide's page on solvers).
    objective : str, default="policy-matching"
        Per-task loss (``factirl_opt.available_objectives()``).
    rng : numpy.random.Generator or int or None
        Randomness of the "random" initialisation (and of completing a rank-deficient PCA).
    execution : Execution, optional
        Where and how ``fit`` and ``transfer`` run and are watched (:class:`~factirl_opt.Execution`:
        ``n_jobs``, ``backend``, ``client``, ``planner``, ``planner_options``, ``verbose``,
        ``callback``, the last called as ``callback(iteration, total_loss)`` after each outer
        iteration of ``fit`` and each step of ``transfer``); None: ``Execution()``.
    residual_penalty : float or "auto", default=np.inf
        ``lambda`` of the residual model ``R_i = Phi_i (D h_i + delta_i)`` with the penalty
        ``lambda ||delta_i||^2`` on each task's residual (docs/maths.md §8a,
        :mod:`factirl_opt.objectives.residuals`): np.inf is the paper's factorial model (no residuals),
        0 lets every task's weights free (the flat model, reparametrised), values between
        share as much as the penalty makes worth it. The residuals are fitted in ``fit`` (the
        H-step moves ``[h_i, delta_i]`` together, from ``delta = 0``) and in ``transfer``. A
        finite value needs an unconstrained ``h_solver``. With 0 the dictionary plays no part and
        ``transfer`` fits each new task as the flat learner does ("What residual_penalty runs" in
        :mod:`factirl_opt.learners.factorial`). ``"auto"``: chosen by validation over tasks
        (:mod:`factirl_opt.learners.selection`).
    dictionary_constraint : DictionaryConstraint or {None, "nonneg", "sparse", "nonneg-sparse"}, optional
        Constrain the dictionary's columns, the primitives (:class:`~factirl_opt.DictionaryConstraint`:
        ``kind`` and the L1 weight ``alpha`` of a sparse kind; a kind's name takes the default
        ``alpha``; docs/maths.md §8b). None: the paper's free dictionary. A constrained
        dictionary takes projected/proximal Armijo D-steps, with the options of ``d_solver``,
        which must be ``"armijo"``.
    scheme : {"auto", "alternating", "joint"}, default="auto"
        The outer scheme of ``fit`` (:func:`~factirl_opt.learners.factorial.fit_factorial`):
        ``"auto"`` chooses from the reward basis (:func:`~factirl_opt.learners.factorial.resolve_scheme`,
        recorded in ``scheme_``): ``"joint"`` with ``features`` wherever it applies,
        ``"alternating"`` on tables. Otherwise the paper's alternation of H- and D-steps, or
        ``inner_steps`` steps of ``d_solver`` on the dictionary and coefficients together per
        outer iteration, its memory kept across them (``"joint"``: it needs an unconstrained
        ``solver`` and dictionary, and a ``d_solver`` that needs only gradients; the residual
        model's fits alternate).
    transfer_stol : float, default=1e-3
        The saturation rule of ``transfer`` (:data:`~factirl_opt.learners.transfer.TRANSFER_STOL`):
        each new task also stops when a step decreases its loss by at most ``transfer_stol``
        times its decrease since the start, where the loss stops paying for coefficients that
        grow (one demonstration is matched exactly only by unbounded ones;
        results/transfer/README.md). 0: the maximum-likelihood transfer. The flat model's
        transfer (``residual_penalty=0``) stops by it too.
    posterior : PosteriorSettings, optional
        What ``transfer_posterior_`` includes besides the coefficients' uncertainty
        (:class:`~factirl_opt.learners.dictionary_ensemble.PosteriorSettings`: dictionaries refitted
        on resampled tasks, and the misfit noise level; docs/maths.md §10). None: the posterior
        conditional on ``dictionary_``, at the multinomial noise level.

    Only ``n_primitives`` and ``beta`` may be given by position; the others are keyword-only.
    ``get_params``, ``set_params``, :func:`~factirl_opt.learners.estimator.clone` and the ``repr`` come
    from :class:`~factirl_opt.learners.estimator.Estimator`.

    Attributes
    ----------
    dictionary_ : ndarray, shape (p, k)
        p = S*A (tabular), S (``reward="state"``) or the number of features.
    coefficients_ : ndarray, shape (n, k)
    rewards_ : ndarray, shape (n, S, A), or list of n arrays (S_i, A)
        ``Phi D h_i`` reshaped; a list when the tasks' environments differ in their number of
        states (stacked otherwise; ``transfer_rewards_`` likewise).
    loss_ : ndarray, shape (n,)
    loss_history_ : list of float
        Total loss (eq. 10, plus a sparse solver's penalty) after the initialisation and after
        each outer iteration.
    n_evaluations_ : int
        Batched planning evaluations used by ``fit`` (including the flat learner of the PCA init).
    n_iter_ : int
        Outer iterations of ``fit``.
    scheme_ : str
        The outer scheme ``fit`` ran, ``"alternating"`` or ``"joint"`` (``scheme`` resolved;
        the residual model's fits alternate).
    status_ : str
        ``"converged"``, ``"max_iter"``, ``"stalled"`` (with a :class:`ConvergenceWarning`) or
        ``"interrupted"``.
    stop_reason_ : str
        Which stopping rule ended ``fit`` and its values (see :func:`fit_factorial`);
        ``"interrupted"`` after Ctrl-C.
    mdp_signature_ : dict or list of dict
        Signature of the MDP of ``fit`` (one per task on several), which ``transfer`` without
        ``features`` checks (on several MDPs: the number of actions and p only).
    features_sha256_ : str or None
        SHA-256 of the shared features of ``fit``, which ``transfer`` without ``features`` checks.
    transfer_coefficients_, transfer_rewards_, transfer_loss_, transfer_loss_history_,
    transfer_n_evaluations_, transfer_status_, transfer_stop_reason_
        The same records for the last ``transfer`` call (``transfer_loss_`` is the loss per new
        task without a solver's penalty; the history includes it, as ``loss_history_`` does).
        ``transfer_rewards_`` include the new tasks' residuals.
    residual_penalty_ : float
        The ``lambda`` of the fit (np.inf: no residuals).
    n_primitives_ : int
        The k of the fit.
    residuals_ : ndarray, shape (n, p)
        The tasks' residuals ``delta_i`` (zeros for ``residual_penalty=np.inf``); ``rewards_``
        include them, ``loss_`` is without their penalty, ``loss_history_`` with it.
    transfer_residuals_ : ndarray, shape (n_new, p)
        The new tasks' residuals of the last ``transfer`` (zeros without residuals).
    noise_levels_ : ndarray, shape (n,)
        Policy matching only: each training task's noise level from its misfit
        (:func:`~factirl_opt.learners.noise_levels.misfit_noise_levels`).
    dictionary_ensemble_, ensemble_prior_means_, ensemble_prior_precisions_ : ndarray, shapes (B, p, k), (B, k), (B, k, k)
        With ``posterior=PosteriorSettings(n_dictionaries=B > 0)``: the refitted dictionaries and
        their coefficients' priors (:func:`~factirl_opt.learners.transfer.coefficient_prior`).
    cv_results_ : dict of arrays
        With ``n_primitives="auto"`` or ``residual_penalty="auto"`` only: the search's table, one
        entry per candidate (:mod:`factirl_opt.learners.selection.results`; ``validation_``, its
        rows, is deprecated).

    Notes
    -----
    A KeyboardInterrupt (Ctrl-C) during ``fit`` or ``transfer`` keeps the best point seen so far
    as the fitted state (status ``"interrupted"``: the best of the start and the completed outer
    iterations, the PCA of the flat rewards learnt so far during the start, each new task's best
    coefficients in ``transfer``), warns (:class:`factirl_opt.exceptions.InterruptedFitWarning`)
    and propagates (:class:`factirl_opt.exceptions.FitInterrupted`, a KeyboardInterrupt).
    """

    #: The learnt attributes and their kinds, from which ``save_model`` derives what to store and
    #: ``load_model`` what to check (factirl_opt.persistence.learnt): a tuple names the axes of a
    #: finite float array (same name, same length; S, A of the MDP, p parameters), a string a kind.
    learnt_attributes: ClassVar[dict[str, tuple[str, ...] | str]] = {
        "dictionary_": ("p", "k"), "coefficients_": ("n", "k"), "rewards_": ("n", "S", "A"), "loss_": ("n",),
        "loss_history_": "history", "n_evaluations_": "count", "n_iter_": "count", "scheme_": "text", "status_": "text",
        "stop_reason_": "text", "mdp_signature_": "mdp-signature", "features_sha256_": "features-digest",
        "transfer_coefficients_": ("n_new", "k"), "transfer_rewards_": ("n_new", "S", "A"), "transfer_loss_": ("n_new",),
        "transfer_loss_history_": "history", "transfer_n_evaluations_": "count", "transfer_status_": "text",
        "transfer_stop_reason_": "text", "residuals_": ("n", "p"), "transfer_residuals_": ("n_new", "p"),
        "n_primitives_": "count", "residual_penalty_": "penalty", "cv_results_": "cv-results",
        "validation_": "validation", "noise_levels_": ("n",), "dictionary_ensemble_": ("B", "p", "k"),
        "ensemble_prior_means_": ("B", "k"), "ensemble_prior_precisions_": ("B", "k", "k"),
    }

    #: Old parameter names, still accepted with a DeprecatedNameWarning (factirl_opt.learners.estimator).
    #: The former names of grouped settings: the start's, the solvers' and the execution's.
    deprecated_params: ClassVar[dict[str, str]] = {
        "h_solver": "solver", "h_solver_options": "solver__h_solver_options",
        "solver_options": "solver__h_solver_options", "d_solver": "solver__d_solver",
        "d_solver_options": "solver__d_solver_options", "flat_solver": "solver__flat_solver",
        **{name: f"start__{name}" for name in ("init", "pca_shrink", "flat_max_iter", "flat_tol", "flat_stol")},
        "dictionary_alpha": "dictionary_constraint__alpha",
        **EXECUTION_RENAMED,
    }
    param_groups: ClassVar[dict[str, type]] = {"solver": SolverSettings, "start": Start, "execution": Execution,
                                               "posterior": PosteriorSettings, "dictionary_constraint": DictionaryConstraint}
    #: The D-step solver when the solver settings name none (:attr:`default_d_solver`), and with a
    #: ``dictionary_constraint``, whose projected/proximal steps are Armijo's.
    unconstrained_d_solver: ClassVar[str] = "lbfgs"
    constrained_d_solver: ClassVar[str] = "armijo"
    #: How ``save_model`` stores the parameters that are not plain JSON (factirl_opt.persistence.params).
    param_kinds: ClassVar[dict[str, str]] = {
        "features": "features", "start": "group", "start__init": "dictionary-start", "solver": "solver", "posterior": "group",
        "dictionary_constraint": "group",
        "objective": "objective", "rng": "rng", "sharing_search": "sharing-search", **EXECUTION_PARAM_KINDS,
    }

    @renamed_params
    def __init__(self, n_primitives: int | Literal["auto"] = 5, beta: float = 5.0, *,
                 features: ArrayLike | Sequence[ArrayLike] | RewardBasis | None = None, reward: str = "state-action",
                 start: Start | None = None, max_iter: int = 100, inner_steps: int = 2, tol: float = 1e-5,
                 gtol: float = GTOL, transfer_max_iter: int = 100,
                 solver: str | solvers.StepSolver | SolverSettings = "armijo",
                 objective: str | type[Objective] = "policy-matching", rng: np.random.Generator | int | None = None,
                 execution: Execution | None = None, residual_penalty: float | Literal["auto"] = np.inf,
                 dictionary_constraint: str | DictionaryConstraint | None = None,
                 sharing_search: SharingSearch | None = None, scheme: str = "auto",
                 transfer_stol: float = TRANSFER_STOL, posterior: PosteriorSettings | None = None) -> None:
        self.n_primitives = n_primitives
        self.beta = beta
        self.features = features
        self.reward = reward
        self.start = start
        self.max_iter, self.inner_steps, self.tol, self.gtol = max_iter, inner_steps, tol, gtol
        self.transfer_max_iter = transfer_max_iter
        self.solver = solver
        self.objective = objective
        self.rng = rng
        self.execution = execution
        self.residual_penalty = residual_penalty
        self.dictionary_constraint = dictionary_constraint
        self.sharing_search = sharing_search
        self.scheme = scheme
        self.transfer_stol = transfer_stol
        self.posterior = posterior

    @property
    def default_d_solver(self) -> str:
        """The D-step solver when the solver settings name none: ``"lbfgs"``, or ``"armijo"`` with a
        ``dictionary_constraint`` (its projected/proximal steps are Armijo's)."""
        constrained = self._group("dictionary_constraint").kind is not None
        return self.constrained_d_solver if constrained else self.unconstrained_d_solver

    validation_ = validation_attribute  # deprecated: the rows of cv_results_

    def _check_params(self, tasks):
        """Validate the hyper-parameters against the task set; the loop's settings ``(max_iter, inner_steps, tol, gtol)``."""
        k = check_int(self.n_primitives, "n_primitives", minimum=1)
        if k > tasks.n_params:
            raise ValidationError(f"n_primitives={k} exceeds the reward dimension p={tasks.n_params}")
        start = self._group("start")
        check_int(start.flat_max_iter, "flat_max_iter", minimum=0)
        check_tol(start.flat_tol, "flat_tol")
        check_tol(start.flat_stol, "flat_stol")
        check_bool(start.pca_shrink, "pca_shrink")
        return (check_int(self.max_iter, "max_iter", minimum=0), check_int(self.inner_steps, "inner_steps", minimum=1),
                check_tol(self.tol), check_tol(self.gtol, "gtol"))

    @learner_entry
    def fit(self, mdp: Any, demos_per_task: Any, flat_rewards: ArrayLike | None = None) -> FactIRL:
        """Learn the dictionary and the coefficients of every task.

        The objective (one parse of the demonstrations) and the solvers are built once, here,
        and serve the PCA start (flat fit and shrinking) and the alternating fit in turn.

        Parameters
        ----------
        mdp : TabularMDP or sequence of n TabularMDP
            One MDP shared by every task, or one per task (tasks in several environments,
            with the same number of actions; tasks given the same object are planned as one
            batch). Several environments need ``features``: one shared matrix (equal-sized
            environments) or one per task.
        demos_per_task : list of n task demonstrations
            Each an int array (m, L, 2) or a list of (L_j, 2) episodes, on its task's MDP.
        flat_rewards : array_like, shape (n, S, A), or list of n arrays (S_i, A), optional
            Rewards already learnt by the flat learner on these demonstrations; with
            ``init="pca"`` they are used instead of fitting the flat learner again (with
            ``features``, their least-squares feature weights are).

        Returns
        -------
        self
        """
        self.__dict__.pop("_transfer", None)  # the last transfer's tasks and posterior belong to the former fit
        check_fit_parameters(self)  # every budget and solver, whether or not this fit's path reads it
        check_posterior_settings(self)
        tasks = learner_tasks(self, mdp, demos_per_task)
        if is_auto(self.n_primitives) or is_auto(self.residual_penalty):
            fit_auto(self, tasks, flat_rewards)  # its candidates and final fit refit no ensemble
        else:
            self._fit_tasks(tasks, flat_rewards)
        return fit_posterior_terms(self, tasks, flat_rewards)

    def _fit_tasks(self, tasks: TaskSet, flat_rewards: Any = None) -> FactIRL:
        """:meth:`fit` with a fixed k and lambda on a task set (the sharing search's candidates and final fit)."""
        self.__dict__.pop("cv_results_", None)  # a fixed fit: an earlier search's table does not describe it
        self.__dict__.pop("noise_levels_", None)  # an earlier fit's (set again below under a least-squares objective)
        basis = tasks.basis
        max_iter, inner_steps, tol, gtol = self._check_params(tasks)
        h_name, h_options, d_name, d_options = estimator_solvers(self)
        h_solver = resolve_step_solver(h_name, h_options, self.objective, "solver")
        d_solver = resolve_step_solver(d_name, d_options, self.objective, "d_solver")
        constraint, alpha = check_dictionary_constraint(self.dictionary_constraint)
        if constraint is not None:
            d_solver = constrained_dictionary_solver(d_solver, constraint, alpha, tasks.n_params,
                                                     check_int(self.n_primitives, "n_primitives", minimum=1),
                                                     len(tasks.demos_per_task))
        lam = check_residual_solver(h_solver, self.residual_penalty)
        scheme = resolve_scheme(self.scheme, basis, h_solver, d_solver) if np.isinf(lam) else "alternating"
        execution, init = self._group("execution"), self._group("start").init
        obj = task_objective(tasks, self.beta, self.objective, execution.planner)
        try:
            with execution.evaluate(obj) as obj:
                D, H, init_evals, W = factorial_start(self, obj.n_tasks, basis, flat_rewards, as_rng(self.rng), obj, lam)
                if h_solver.constraint == "nonneg" and not isinstance(init, tuple):
                    D, H = orient_nonneg(D, H, init == "random")
                if constraint is not None:
                    D, H = constrained_start(d_solver, D, H, constraint.startswith("nonneg"))
                Delta = None if W is None else W - residual_weights(D, H, None)  # lam = 0: start at the flat start
                fit = run_factorial(obj, D, H, h_solver, d_solver, base_features=basis, max_iter=max_iter, inner_steps=inner_steps,
                                    tol=tol, gtol=gtol, callback=execution.callback, verbose=execution.verbose,
                                    residual_penalty=lam, residuals=Delta, scheme=scheme)
        except FitInterrupted as exc:
            self._store(tasks, exc.result, int(obj.n_evaluations), lam)
            self.scheme_ = scheme
            kept = "the start" if self.n_iter_ == 0 else f"the best of {self.n_iter_} outer iterations"
            warn_interrupted("FactIRL.fit", f"kept {kept} ({loss_phrase(self.loss_)})", exc.__cause__)
            raise_interrupted(exc, "FactIRL.fit")
        self._store(tasks, fit, int(fit.n_evaluations + init_evals), lam)
        self.scheme_ = scheme
        warn_if_stalled(fit.status, fit.n_iter, "FactIRL.fit")
        if getattr(obj, "least_squares", False):  # policy matching: eq. (5)'s misfit has a noise level
            self.noise_levels_ = task_noise_levels(tasks, fit.loss, self.n_primitives_)
        return self

    def _store(self, tasks, fit, n_evaluations, lam=np.inf):
        self.dictionary_, self.coefficients_ = fit.dictionary, fit.coefficients
        self.residual_penalty_, self.n_primitives_ = lam, int(fit.dictionary.shape[1])
        if fit.residuals is None:
            self.rewards_ = tasks.basis.factorial_rewards(fit.dictionary, fit.coefficients)
            self.residuals_ = np.zeros((fit.coefficients.shape[0], fit.dictionary.shape[0]))
        else:
            self.residuals_ = fit.residuals
            self.rewards_ = tasks.rewards(residual_weights(fit.dictionary, fit.coefficients, fit.residuals))
        self.loss_, self.loss_history_ = fit.loss, fit.loss_history
        self.n_evaluations_ = n_evaluations
        self.n_iter_, self.status_, self.stop_reason_ = fit.n_iter, fit.status, fit.reason
        self.mdp_signature_, self.features_sha256_ = tasks.signature(), tasks.digest

    @renamed_params
    @learner_entry
    def transfer(self, mdp: Any, demos_per_task: Any, features: Any = None, max_iter: int | None = None,
                 solver: Any = None, solver_options: dict | None = None) -> NDArray[np.float64]:
        """Fit the coefficients of new tasks with the dictionary fixed (section 4.2).

        Starts from ``h = 0`` (projected onto the solver's feasible set) and runs the H-step
        solver for up to ``max_iter`` steps, each task stopping by its own rules
        (:func:`transfer_coefficients`).

        Parameters
        ----------
        mdp : TabularMDP or sequence of n_new TabularMDP
            The MDP of ``fit`` (checked against ``mdp_signature_`` without ``features``), or the
            new tasks' own environments (one per task, or one shared).
        demos_per_task : list of n_new task demonstrations
        features : array_like or sequence of n_new array_like, optional
            The new environments' features, over the p features of ``fit``: one shared
            matrix, or one (S_i*A, p) or (S_i, p) per new task. Required for a model fitted
            with per-task features; with them no MDP signature is checked (the dictionary is
            carried to the new environments). Default: the model's own (shared) features.
        max_iter : int, optional
            Default ``transfer_max_iter``.
        solver : str, solvers.StepSolver or SolverSettings, optional
            H-step solver for this call only (e.g. fit with ``"armijo"``, transfer with
            ``"gn-qp-clarabel"``; of a SolverSettings, its H-step solver and options); default
            the model's ``solver``. Formerly ``h_solver`` (deprecated alias).
        solver_options : dict, optional
            Options for a ``solver`` given by name here. Formerly ``h_solver_options``.

        Returns
        -------
        coefficients : ndarray, shape (n_new, k)
            ``transfer_rewards_`` holds the new tasks' rewards: (n_new, S, A), or a list of
            (S_i, A) arrays when their environments differ in size.

        Raises
        ------
        ValidationError
            Features other than those of ``fit``, or missing for a per-task model; a dictionary,
            p or number of actions that does not fit.
        """
        tasks, D = transfer_tasks(mdp, demos_per_task, features, self)
        return self._transfer_tasks(tasks, D, max_iter, solver, solver_options, (mdp, demos_per_task, features))

    def _transfer_tasks(self, tasks: TaskSet, D: Any = None, max_iter: int | None = None, solver: Any = None,
                        solver_options: dict | None = None, inputs: tuple | None = None) -> NDArray[np.float64]:
        """:meth:`transfer` of a task set on this model's basis (``inputs``: the call's, for :meth:`request_starts`)."""
        D = transfer_dictionary(self, tasks) if D is None else D
        solver, solver_options = transfer_solver(self, solver, solver_options)
        max_iter = check_int(self.transfer_max_iter if max_iter is None else max_iter, "max_iter", minimum=0)
        tol, gtol = check_tol(self.tol), check_tol(self.gtol, "gtol")
        execution = self._group("execution")
        obj = task_objective(tasks, self.beta, self.objective, execution.planner)
        h_solver = resolve_step_solver(solver, solver_options, self.objective, "solver")
        lam = check_residual_solver(h_solver, getattr(self, "residual_penalty_", self.residual_penalty))
        flat = None
        if lam == 0.0:  # the flat model: fitted as the flat learner fits
            flat = (resolve_step_solver(*flat_solver(self), self.objective, "flat_solver"),
                    check_int(self._group("start").flat_max_iter, "flat_max_iter", minimum=0), FLAT_TOL)
        stol = check_tol(self.transfer_stol, "transfer_stol")
        try:
            with execution.evaluate(obj) as obj:
                res = run_transfer(obj, D, h_solver, base_features=tasks.basis, max_iter=max_iter, tol=tol,
                                   callback=execution.callback, verbose=execution.verbose, residual_penalty=lam, flat=flat,
                                   gtol=gtol, stol=stol)
        except FitInterrupted as exc:
            self._store_transfer(exc.result)
            keep_transfer(self, inputs, tasks, D)
            warn_interrupted("FactIRL.transfer", "kept each new task's best coefficients seen", exc.__cause__)
            raise_interrupted(exc, "FactIRL.transfer")
        self._store_transfer(res)
        keep_transfer(self, inputs, tasks, D)  # transfer_posterior_ is built from them when first read
        warn_if_stalled(res.status, res.n_iter, "FactIRL.transfer")
        return res.coefficients.copy()  # the caller's own array: editing it leaves transfer_coefficients_ alone

    def _store_transfer(self, res):
        self.transfer_coefficients_, self.transfer_rewards_ = res.coefficients, res.rewards
        self.transfer_residuals_ = (np.zeros((res.coefficients.shape[0], self.dictionary_.shape[0]))
                                    if res.residuals is None else res.residuals)
        self.transfer_loss_, self.transfer_loss_history_ = res.loss, res.loss_history
        self.transfer_n_evaluations_, self.transfer_status_ = res.n_evaluations, res.status
        self.transfer_stop_reason_ = res.reason

    @property
    @learner_entry
    def transfer_posterior_(self) -> list | None:
        """Each new task's Laplace posterior over its coefficients (and residual) after ``transfer``.

        A list of n_new :class:`~factirl_opt.learners.posterior.LaplacePosterior` (docs/maths.md
        §10), built from the last transfer's tasks when first read (about one transfer's cost;
        each refitted dictionary of ``posterior`` adds one, as a member the samples marginalise
        over) and kept with the model (pickled, saved). None when undefined (fewer than 2 training
        tasks, or the flat model); AttributeError before any transfer and after a refit.
        """
        return cached_transfer_posterior(self)

    def request_starts(self, mdp: Any, demos_per_task: Any, n_requests: int = 1, candidates: Any = None, *,
                       features: Any = None, criterion: str = "information", policy: str = "boltzmann",
                       demonstrated: str = "count", marginal: bool = False) -> list[NDArray[np.intp]]:
        """Start states to ask a demonstration from, per new task, most informative first.

        :func:`factirl_opt.learners.active.request_starts` (its parameters, criteria and errors)
        on the posterior of these tasks: the last ``transfer``'s when it was given the same
        objects, else built here. By default the candidates are ranked by the expected
        information gain about the coefficients (D-optimal on the Laplace covariance).

        Parameters
        ----------
        mdp, demos_per_task, features
            As in :meth:`transfer`.
        n_requests : int, default=1
            States returned per task.
        candidates : array_like of int, or sequence of n_new of them, optional
            Start states to rank (default: every state).
        criterion : {"information", "value", "regret"}, default="information"
        policy : {"boltzmann", "greedy"}, default="boltzmann"
        demonstrated : {"count", "skip"}, default="count"
        marginal : bool, default=False
            Average the criterion over the posterior's dictionaries (``posterior.n_dictionaries``).

        Returns
        -------
        list of n_new int arrays, each (n_requests,)
        """
        return request_starts(self, mdp, demos_per_task, n_requests, candidates, features=features,
                              criterion=criterion, policy=policy, demonstrated=demonstrated, marginal=marginal)

    def gpi_policies(self, mdp: Any, coefficients: ArrayLike, *, improvement_steps: int = 0, features: Any = None,
                     library: Any = None, start: Any = None, evaluate: bool = True) -> NDArray[np.intp]:
        """Greedy policies of new tasks without planning: GPI over the successor features of a library.

        :func:`~factirl_opt.learners.gpi.generalised_policy_improvement` (its parameters and errors):
        for each task ``h``, ``pi(s) = argmax_a max_l psi_l(s, a) h`` over the library's policies
        (by default those of the primitives, of their negatives and of the training tasks), whose
        successor features are computed once per environment and cached on the model. At least as
        good as every library policy on each task (Barreto et al. 2017, Theorem 1);
        ``gpi_report_`` holds the values.

        Parameters
        ----------
        mdp : TabularMDP or sequence of n TabularMDP
            The environment of ``fit`` (fitted on several: each new task's must be one of them).
        coefficients : array_like, shape (n, k) or (k,)
            The new tasks' coefficients (e.g. from :meth:`transfer`).
        improvement_steps : int, default=0
            Exact policy-improvement steps after GPI.
        features : array_like or sequence of n array_like, optional
            With one feature matrix per task: each new task's (its map's).
        library : str or sequence of {"primitives", "negatives", "tasks", "other-tasks"}, optional
        start : None, int or array_like (S,) or (n, S), optional
            Start distribution of the reported values (default uniform, as eq. 13).
        evaluate : bool, default=True
            Evaluate the policies exactly for ``gpi_report_``.

        Returns
        -------
        policies : ndarray of intp, shape (n, S) (or (S,) for coefficients (k,))
        """
        policies, self._gpi_report = generalised_policy_improvement(
            self, mdp, coefficients, features=features, improvement_steps=improvement_steps, library=library, start=start,
            evaluate=evaluate)
        return policies

    @property
    def gpi_report_(self) -> GPIReport:
        """The :class:`~factirl_opt.learners.gpi.GPIReport` of the last :meth:`gpi_policies` call (not saved)."""
        report = self.__dict__.get("_gpi_report")
        if report is None:
            raise AttributeError("gpi_report_: call gpi_policies first")
        return report


#: the start's constants moved with it (:mod:`~factirl_opt.learners.start`); resolved here for one release
moved_names(__name__, dict.fromkeys(("INITS", "RANDOM_INIT_SCALE", "FLAT_SOLVER"), "factirl_opt.learners.start"))

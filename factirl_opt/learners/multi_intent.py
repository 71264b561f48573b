"""Unlabeled demonstrations: EM over intentions, with or without a shared dictionary.

:class:`MultiIntentIRL` clusters a flat list of episodes into K intentions and learns a reward
for each, by expectation-maximisation (Babes-Vroman et al. 2011). The E-step scores each
episode under each intention's policy (:mod:`factirl_opt.learners.em`); the M-step fits the rewards to
the responsibility-weighted statistics by the learners' machinery, warm-started from the
previous parameters: the flat step problem of GradIRL (each intention its own reward,
``n_primitives=None``), or the factorial scheme of FactIRL (``R_c = Phi D h_c``, a dictionary
shared by the intentions; docs/maths.md §8); the loop and its M-steps are in
:mod:`factirl_opt.learners.multi_intent_fit`, whose :class:`~factirl_opt.learners.multi_intent_fit.WeightedObjective` weights each
intention's loss by its expected number of steps, so that with the MCE objective the M-step
minimises exactly minus EM's expected complete-data log-likelihood (docs/maths.md §6).

``n_intentions="auto"`` chooses K over a range by held-out log-likelihood or BIC
(:mod:`factirl_opt.learners.intention_count`).

:func:`adjusted_rand_index` and :func:`match_intentions` score a clustering against true
labels and pair recovered intentions with true tasks.
"""

from __future__ import annotations

from typing import Any, Callable, ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

import solvers

from .._progress import fit_progress
from .._validation import as_rng, check_array, check_bool, check_fit_parameters, check_int, check_mdp
from .estimator import EXECUTION_PARAM_KINDS, EXECUTION_RENAMED, Estimator, renamed_params
from ..exceptions import NotFittedError, ValidationError
from .factirl import FactIRL
from .fitting import learner_entry, learner_tasks
from .intention_count import (SELECTIONS, best_candidate, bic_scores, check_candidates, fold_assignment,
                              free_parameters, held_out_scores, one_standard_error_choice)
from .multi_intent_fit import EMSettings, best_of_runs, episode_log_likelihoods, episode_subset
from ..objectives.sharding import Execution
from .solver_settings import SolverSettings, estimator_solvers
from .start import IntentionStart

from ..tasks.basis import RewardBasis
from ..tasks.trajectories import TaskDemonstrations, parse_demonstrations, parse_episodes as parse_unlabeled

__all__ = ["MultiIntentIRL", "adjusted_rand_index", "match_intentions", "INITS"]

#: starts of :class:`MultiIntentIRL`: the episodes' agreements, k-means of their frequencies, or random
INITS = ("agreement", "frequencies", "random")

#: largest K tried by ``n_intentions="auto"`` when no ``n_intentions_range`` is given
DEFAULT_MAX_INTENTIONS = 10


def parse_episodes(mdp: Any, episodes: Any) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """A flat list of episodes (or an (m, L, 2) array) as concatenated steps (N, 2) and lengths (m,)."""
    if isinstance(episodes, np.ndarray) and episodes.ndim != 3:
        raise ValidationError(f"episodes must be a list of (L, 2) arrays or an int array (m, L, 2); got an array of shape {episodes.shape}")
    if not isinstance(episodes, np.ndarray) and not isinstance(episodes, (list, tuple)):
        raise ValidationError(f"episodes must be a list of (L, 2) arrays or an int array (m, L, 2); got {type(episodes).__name__}")
    task = parse_unlabeled(episodes, mdp.n_states, mdp.n_actions, "episodes")
    if len(task.lengths) == 0:
        raise ValidationError("episodes is empty: give at least one episode")
    return task.steps, task.lengths


class MultiIntentIRL(Estimator):
    """EM over K intentions from unlabeled episodes; rewards flat or on a shared dictionary.

    Parameters
    ----------
    n_intentions : int or "auto"
        K, at least 1 and at most the number of episodes; ``"auto"`` chooses K over
        ``n_intentions_range`` by ``selection`` (:mod:`factirl_opt.learners.intention_count`).
    n_primitives : int, optional
        None: each intention has its own reward (Babes-Vroman's EM; the M-step is GradIRL's
        fit). k: ``R_c = Phi D h_c`` with a dictionary D (p, k) shared by the intentions (the
        M-step is FactIRL's alternating fit; the first one starts from the PCA of flat rewards).
    features : array_like, shape (S*A, p) or (S, p), optional
        Base features ``Phi``; None for tabular rewards; or a shared
        :class:`~factirl_opt.tasks.basis.RewardBasis`, taken as it is.
    reward : {"state-action", "state"}, default="state-action"
        As in :class:`GradIRL`.
    objective : {"policy-matching", "mce"}, default="policy-matching"
        The M-step's loss, and the policy that scores episodes in the E-step: the Boltzmann
        policy of ``Q*`` (eq. 7) or the soft-optimal policy (docs/maths.md §6). With ``"mce"``
        the M-step raises EM's expected log-likelihood, so the log-likelihood never decreases;
        with policy matching it is monitored and the best point kept.
    beta : float, default=5.0
        Inverse temperature of both the objective and the E-step's policy.
    n_intentions_range : (int, int), optional
        ``(low, high)``, both included: the K tried by ``n_intentions="auto"``. Default
        ``(1, min(10, m))`` with m the episodes one fit sees (all of them for the BIC, those
        outside the largest fold when held out).
    selection : {"held-out", "bic"}, default="held-out"
        Criterion of ``n_intentions="auto"``. ``"held-out"``: the episodes are split at random
        into ``n_folds`` folds, EM is fitted on all folds but one and scored by the
        log-likelihood of the held-out one; the smallest K whose total held-out log-likelihood
        is within one standard error (over the episodes) of the best is refitted on all
        episodes (``n_folds`` x m + 1 EM fits for m candidates). ``"bic"``:
        ``-2 log L + n_free log N`` of the fit on all episodes (N demonstrated steps, n_free
        from :func:`factirl_opt.learners.intention_count.free_parameters`), lowest kept (m fits); its
        count of ``S*A`` parameters per tabular reward penalises K heavily, so prefer it with
        a few reward features.
    n_folds : int, default=3
        Folds of ``selection="held-out"``, at least 2.
    start : IntentionStart, optional
        Where EM starts (:class:`~factirl_opt.IntentionStart`: ``init``, the starting
        responsibilities, and ``n_init``, the runs from independent starts); None:
        ``IntentionStart()``, one run from the agreement start (the closest to the true tasks on
        the paper's grid).
    max_iter : int, default=20
        EM iterations (each one M-step and one E-step).
    tol : float, default=1e-6
        Stop when the log-likelihood changes by at most ``tol * max(1, |log-likelihood|)``.
    m_step_max_iter : int, default=20
        Solver iterations of a flat M-step; outer iterations of a factorial one.
    m_step_tol : float, default=1e-5
        Relative-decrease tolerance of each M-step's solver.
    inner_steps : int, default=5
        Solver steps per block of the factorial M-step.
    solver : str, solvers.StepSolver or SolverSettings, default="armijo"
        Step solver of a flat M-step and of the H-step of a factorial one
        (``solvers.available_solvers()``), or a :class:`~factirl_opt.SolverSettings` (its
        ``d_solver``: the D-step of a factorial M-step; not named, the H-step's solver).
    rng : numpy.random.Generator or int or None
        Randomness of the starts (and of completing a rank-deficient PCA).
    execution : Execution, optional
        :class:`~factirl_opt.Execution` (None: ``Execution()``). ``n_jobs``, ``backend`` and
        ``client`` shard each M-step's objective over the K intentions (started for each M-step
        and stopped after it, so they pay off when an M-step plans large MDPs; the E-step plans
        in this process; the result equals ``n_jobs=1``'s to rounding); ``planner_options`` is
        the planning budget of ``fit``; ``verbose`` shows the EM iterations of the final fit's
        ``n_init`` runs; ``callback(iteration, log_likelihood)`` is called after each EM
        iteration of the final fit only (not of the fits that choose K with
        ``n_intentions="auto"``; with ``selection="bic"`` the kept fit is one of those).

    Only ``n_intentions`` and ``n_primitives`` may be given by position; the others are
    keyword-only. ``get_params``, ``set_params``, :func:`~factirl_opt.learners.estimator.clone` and the
    ``repr`` come from :class:`~factirl_opt.learners.estimator.Estimator`; a fitted model saves and
    loads with :func:`~factirl_opt.save_model` and :func:`~factirl_opt.load_model`.

    Attributes
    ----------
    labels_ : ndarray of int, shape (n_episodes,)
        The most responsible intention of each episode.
    responsibilities_ : ndarray, shape (n_episodes, K)
        ``P(c | episode)`` at the kept parameters.
    mixture_weights_ : ndarray, shape (K,)
    rewards_ : ndarray, shape (K, S, A)
    weights_ : ndarray, shape (K, p)
        Flat parameters (``n_primitives=None`` only).
    dictionary_ : ndarray, shape (p, k)
        Shared dictionary (``n_primitives=k`` only).
    coefficients_ : ndarray, shape (K, k)
        (``n_primitives=k`` only.)
    log_likelihood_ : list of float
        The log-likelihood after each EM iteration of the kept run: ``sum_j log sum_c w_c
        prod_t pi_c(a_t | s_t)``, the likelihood of the actions given the states (the start
        and transition probabilities do not depend on the intention and are left out).
    best_log_likelihood_ : float
        That of the kept parameters (the maximum of ``log_likelihood_``).
    n_iter_ : int
        EM iterations of the kept run.
    n_intentions_ : int
        K of the fit (the chosen one with ``n_intentions="auto"``).
    n_intentions_candidates_ : ndarray of int, shape (m,)
        (``n_intentions="auto"`` only.) The K tried.
    n_intentions_scores_ : ndarray, shape (m,)
        (``n_intentions="auto"`` only.) Their scores: held-out log-likelihood summed over the
        folds (higher is better) or BIC (lower is better).
    converged_ : bool
        Whether the kept run stopped on ``tol``.
    mdp_signature_ : dict
    features_sha256_ : str or None

    Notes
    -----
    Transfer to new tasks from the learnt dictionary: :meth:`to_factirl` returns a fitted
    :class:`FactIRL` holding ``dictionary_`` and ``coefficients_``, whose
    :meth:`FactIRL.transfer` fits new tasks' coefficients.
    """

    #: How ``save_model`` stores the parameters that are not plain JSON (factirl_opt.persistence.params).
    param_kinds: ClassVar[dict[str, str]] = {
        "features": "features", "start": "group", "start__init": "responsibility-start", "solver": "solver",
        "objective": "objective", "rng": "rng", **EXECUTION_PARAM_KINDS,
    }
    param_groups: ClassVar[dict[str, type]] = {"solver": SolverSettings, "start": IntentionStart, "execution": Execution}
    #: The former names of grouped settings: the start's, the solvers' and the execution's.
    deprecated_params: ClassVar[dict[str, str]] = {
        "init": "start__init", "n_init": "start__n_init", "solver_options": "solver__h_solver_options",
        "d_solver": "solver__d_solver", "d_solver_options": "solver__d_solver_options", **EXECUTION_RENAMED,
    }
    #: The learnt attributes and their kinds, from which ``save_model`` derives what to store and
    #: ``load_model`` what to check (factirl_opt.persistence.learnt): m episodes, K intentions,
    #: S, A of the MDP, p parameters, k primitives, c candidate K.
    learnt_attributes: ClassVar[dict[str, tuple[str, ...] | str]] = {
        "labels_": ("integers", "m"), "responsibilities_": ("m", "K"), "mixture_weights_": ("K",),
        "rewards_": ("K", "S", "A"), "weights_": ("K", "p"), "dictionary_": ("p", "k"), "coefficients_": ("K", "k"),
        "log_likelihood_": "history", "best_log_likelihood_": "number", "n_iter_": "count", "n_intentions_": "count",
        "n_intentions_candidates_": ("integers", "c"), "n_intentions_scores_": ("c",), "converged_": "flag",
        "mdp_signature_": "mdp-signature", "features_sha256_": "features-digest",
    }

    @renamed_params
    def __init__(self, n_intentions: int | Literal["auto"], n_primitives: int | None = None, *,
                 features: ArrayLike | RewardBasis | None = None,
                 reward: str = "state-action", objective: str = "policy-matching", beta: float = 5.0,
                 n_intentions_range: tuple[int, int] | None = None, selection: str = "held-out", n_folds: int = 3,
                 start: IntentionStart | None = None, max_iter: int = 20, tol: float = 1e-6,
                 m_step_max_iter: int = 20, m_step_tol: float = 1e-5, inner_steps: int = 5,
                 solver: str | solvers.StepSolver | SolverSettings = "armijo",
                 rng: np.random.Generator | int | None = None, execution: Execution | None = None) -> None:
        self.n_intentions = n_intentions
        self.n_primitives = n_primitives
        self.features = features
        self.reward = reward
        self.objective = objective
        self.beta = beta
        self.n_intentions_range = n_intentions_range
        self.selection = selection
        self.n_folds = n_folds
        self.start = start
        self.max_iter = max_iter
        self.tol = tol
        self.m_step_max_iter = m_step_max_iter
        self.m_step_tol = m_step_tol
        self.inner_steps = inner_steps
        self.solver = solver
        self.rng = rng
        self.execution = execution

    def _given_start(self, n, K):
        """Starting responsibilities (n, K) from ``init`` given as labels or responsibilities."""
        start = check_array(self._group("start").init, "init")
        if start.ndim == 1:
            labels = start.astype(np.int64)
            if start.shape != (n,) or np.any(labels != start) or np.any((labels < 0) | (labels >= K)):
                raise ValidationError(f"init labels must be {n} integers in [0, {K}); got shape {start.shape}")
            return np.eye(K)[labels]
        if start.shape != (n, K) or np.any(start < 0) or np.any(np.abs(start.sum(axis=1) - 1.0) > 1e-6):
            raise ValidationError(f"init responsibilities must have shape ({n}, {K}), be nonnegative and sum to 1 per row; "
                                  f"got shape {start.shape}")
        return start

    def _check_init(self):
        init = self._group("start").init
        if isinstance(init, str):
            if init not in INITS:
                raise ValidationError(f"init must be one of {', '.join(map(repr, INITS))} or an array; got {init!r}")
            return init
        return "given"

    @learner_entry
    def fit(self, mdp: Any, episodes: Any) -> MultiIntentIRL:
        """Cluster the episodes into intentions and learn their rewards.

        Parameters
        ----------
        mdp : TabularMDP
        episodes : list of int arrays (L_j, 2), or int array (m, L, 2)
            (state, action) steps of each episode; lengths may differ. No task labels.

        Returns
        -------
        self

        Raises
        ------
        ValidationError
            Naming the bad input: ``mdp`` not a TabularMDP; episodes of a wrong layout, empty,
            or with states or actions out of range; ``n_intentions`` below 1 or above the number
            of episodes (or a string other than ``"auto"``); with ``"auto"``, an
            ``n_intentions_range`` that is not ``1 <= low <= high`` integers with ``high`` at most
            the episodes a fit sees, a bad ``selection`` or ``n_folds``, or an array ``init``;
            an objective without a policy to score episodes; a bad ``init`` or hyper-parameter.
        """
        check_fit_parameters(self)
        steps, lengths = parse_episodes(check_mdp(mdp), episodes)
        tasks = learner_tasks(self, mdp, [episodes], [TaskDemonstrations(steps, lengths, "list")])  # as one task
        init = self._check_init()
        execution = self._group("execution")
        n_init = check_int(self._group("start").n_init, "n_init", minimum=1)
        check_bool(execution.verbose, "verbose")
        if execution.callback is not None and not callable(execution.callback):
            raise ValidationError(f"callback must be callable as callback(iteration, log_likelihood); "
                                  f"got {type(execution.callback).__name__}")
        rng = as_rng(self.rng)
        with execution.budget():
            if isinstance(self.n_intentions, str):
                K, run = self._select(tasks, steps, lengths, init, n_init, rng)
            else:
                K = check_int(self.n_intentions, "n_intentions", minimum=1)
                if K > len(lengths):
                    raise ValidationError(f"n_intentions={K} exceeds the number of episodes ({len(lengths)})")
                run = None
                for stale in ("n_intentions_candidates_", "n_intentions_scores_"):  # of an earlier "auto" fit
                    self.__dict__.pop(stale, None)
            settings = EMSettings.build(self, tasks, K)
            if run is None:
                given = self._given_start(len(lengths), K) if init == "given" else None
                with fit_progress(None, execution.verbose, n_init * settings.max_iter, "MultiIntentIRL.fit",
                                  "log-likelihood") as bar:
                    run = best_of_runs(mdp, steps, lengths, settings, init, given, rng, n_init,
                                       self._watch(bar))
        self._store(mdp, settings, run)
        return self

    def _watch(self, bar: Callable) -> Callable | None:
        """The EM loop's callback: the progress bar over every run's iterations, and the user's ``callback``."""
        execution = self._group("execution")
        if not execution.verbose and execution.callback is None:
            return None
        done = 0

        def watch(iteration: int, log_likelihood: float) -> None:
            nonlocal done
            done += 1
            bar(done, log_likelihood)
            if execution.callback is not None:
                execution.callback(iteration, log_likelihood)

        return watch

    def _select(self, tasks, steps, lengths, init, n_init, rng):
        """``n_intentions="auto"``: K chosen over ``n_intentions_range``; the BIC's fit of that K, or None."""
        mdp = tasks.mdp
        if self.n_intentions != "auto":
            raise ValidationError(f"n_intentions must be a positive integer or 'auto'; got {self.n_intentions!r}")
        if init == "given":
            raise ValidationError("n_intentions='auto' needs a named init (a given start fixes K); got an array")
        if self.selection not in SELECTIONS:
            raise ValidationError(f"selection must be one of {', '.join(map(repr, SELECTIONS))}; got {self.selection!r}")
        n = len(lengths)
        n_folds = check_int(self.n_folds, "n_folds", minimum=2) if self.selection == "held-out" else None
        if n_folds is not None and n_folds > n:
            raise ValidationError(f"n_folds={n_folds} exceeds the number of episodes ({n})")
        bounds = self.n_intentions_range
        if bounds is None:
            bounds = (1, min(DEFAULT_MAX_INTENTIONS, n if n_folds is None else n - -(-n // n_folds)))
        candidates = check_candidates(bounds, n, n_folds)
        settings = {int(K): EMSettings.build(self, tasks, int(K)) for K in candidates}

        def fit(idx, K):
            st, ln = episode_subset(steps, lengths, idx)
            return best_of_runs(mdp, st, ln, settings[K], init, None, rng, n_init)

        if n_folds is not None:
            folds = fold_assignment(n, n_folds, rng)
            per_episode = held_out_scores(fit, lambda run, idx: episode_log_likelihoods(
                mdp, *episode_subset(steps, lengths, idx), settings[int(candidates[0])], run), candidates, folds)
            scores, best, runs = per_episode.sum(axis=1), one_standard_error_choice(per_episode), None
        else:
            first = settings[int(candidates[0])]
            p = first.basis.n_params
            scores, runs = bic_scores(fit, lambda run: run.best_log_likelihood,
                                      lambda K: free_parameters(K, p, first.n_primitives), candidates, n,
                                      int(lengths.sum()))
            best = best_candidate(scores)
        self.n_intentions_candidates_, self.n_intentions_scores_ = candidates, scores
        return int(candidates[best]), None if runs is None else runs[best]

    def _store(self, mdp, settings, run):
        self.rewards_ = run.rewards
        self.responsibilities_ = run.responsibilities
        self.labels_ = np.argmax(run.responsibilities, axis=1)
        self.mixture_weights_ = run.mixture_weights
        if settings.n_primitives is None:
            self.weights_ = run.params
        else:
            self.dictionary_, self.coefficients_ = run.params
        self.log_likelihood_ = list(run.history)
        self.best_log_likelihood_ = run.best_log_likelihood
        self.n_iter_ = len(run.history)
        self.converged_ = run.converged
        self.n_intentions_ = run.rewards.shape[0]
        self.mdp_signature_ = mdp.signature()
        self.features_sha256_ = settings.basis.digest()

    def to_factirl(self) -> FactIRL:
        """A fitted :class:`FactIRL` holding the learnt dictionary, ready for :meth:`FactIRL.transfer`.

        Its ``coefficients_`` and ``rewards_`` are the intentions'; its hyper-parameters (beta,
        objective, features, reward, planner, solvers, tol, and the execution settings) are this
        estimator's.

        Raises
        ------
        NotFittedError
            Before ``fit``, or when the model has no dictionary (``n_primitives=None``).
        """
        if not hasattr(self, "dictionary_"):
            raise NotFittedError("this MultiIntentIRL has no dictionary_: fit it with n_primitives=k first")
        solver, options, d_solver, d_options = estimator_solvers(self)
        if d_solver is None:  # the M-step's D-step solver: the H-step's
            d_solver, d_options = solver, options
        model = FactIRL(n_primitives=self.dictionary_.shape[1], beta=self.beta, tol=self.m_step_tol,
                        inner_steps=self.inner_steps, solver=SolverSettings(solver, options, d_solver, d_options),
                        features=self.features, reward=self.reward, objective=self.objective, rng=self.rng,
                        execution=self.execution)
        model.dictionary_, model.coefficients_ = self.dictionary_.copy(), self.coefficients_.copy()
        model.rewards_ = self.rewards_.copy()
        model.mdp_signature_, model.features_sha256_ = self.mdp_signature_, self.features_sha256_
        return model


def adjusted_rand_index(labels_true: ArrayLike, labels_pred: ArrayLike) -> float:
    """Adjusted Rand index of two labellings of the same items (Hubert & Arabie 1985).

    ``ARI = (sum_ij C(n_ij, 2) - E) / ((sum_i C(a_i, 2) + sum_j C(b_j, 2)) / 2 - E)`` with
    ``E = sum_i C(a_i, 2) sum_j C(b_j, 2) / C(n, 2)``, from the contingency table ``n_ij`` and
    its row and column sums ``a_i``, ``b_j``. 1 for identical partitions (up to renaming),
    about 0 for independent ones; 1 by convention when both are trivial (one cluster, or all
    singletons, for both).

    Parameters
    ----------
    labels_true, labels_pred : array_like of int, shape (n,)

    Returns
    -------
    float
    """
    a, b = np.asarray(labels_true), np.asarray(labels_pred)
    if a.ndim != 1 or a.shape != b.shape:
        raise ValidationError(f"labels must be two 1-d arrays of the same length; got shapes {a.shape} and {b.shape}")
    _, ia = np.unique(a, return_inverse=True)
    _, ib = np.unique(b, return_inverse=True)
    table = np.zeros((ia.max(initial=-1) + 1, ib.max(initial=-1) + 1))
    np.add.at(table, (ia, ib), 1.0)

    def pairs(x):
        return float(np.sum(x * (x - 1.0) / 2.0))

    index, rows, cols = pairs(table), pairs(table.sum(axis=1)), pairs(table.sum(axis=0))
    n = float(len(a))
    expected = rows * cols / (n * (n - 1.0) / 2.0) if n > 1 else 0.0
    top = (rows + cols) / 2.0
    if top == expected:
        return 1.0
    return float((index - expected) / (top - expected))


def match_intentions(cost: ArrayLike) -> NDArray[np.int64]:
    """Pair recovered intentions with true tasks at least total cost (the Hungarian algorithm).

    Parameters
    ----------
    cost : array_like, shape (n_true, K)
        ``cost[i, c]``: e.g. the deviation on true task i of intention c's reward, or minus the
        number of episodes of task i labelled c.

    Returns
    -------
    ndarray of int, shape (n_true,)
        The intention matched to each true task (-1 for tasks left unmatched when K < n_true).
    """
    C = check_array(cost, "cost", ndim=2)
    rows, cols = linear_sum_assignment(C)
    match = np.full(C.shape[0], -1, dtype=np.int64)
    match[rows] = cols
    return match

"""How much to share, chosen from the training data: ``FactIRL(n_primitives="auto", residual_penalty="auto")``.

The number of primitives k and the residual penalty lambda (:mod:`factirl_opt.objectives.residuals`) are
chosen by a validation that imitates the use of the learner: learn a dictionary on some tasks,
transfer it to a new task from a few demonstrations, and judge the transferred reward on what
that task's expert does elsewhere.

K-fold over tasks (:func:`choose_sharing`): the tasks are split into ``n_folds`` folds; for each
fold and each candidate ``(k, lambda)`` a FactIRL is fitted on the other folds' tasks, each
held-out task is transferred from its first ``n_transfer_demos`` demonstrations, and scored on
its remaining demonstrations by their negative log-likelihood per step under the learner's
policy model with the transferred reward (policy matching: the Boltzmann policy of its Q*, eq. 7;
MCE: the soft-optimal policy), the policy's inverse temperature profiled out per task
(:func:`held_out_nll`: a reward's scale is not what transfer is judged on; ``score="fixed-beta"``
keeps the learner's ``beta``, ``score="objective"`` scores by the learner's objective, which for
policy matching is the squared policy difference; ``score="occupancy"`` compares where the
transferred reward's optimal policy goes with where the expert went, :func:`held_out_occupancy_gap`).

The choice (:func:`choose_sharing`). The candidate of lowest mean score leads (ties: the earlier
candidate, i.e. more sharing); it replaces the flat model (``lambda = 0``, each task learnt
alone) only if its gain over it, paired over the held-out tasks, is significant: more than
``t_(n-1)(1 - SHARE_LEVEL)`` standard errors of the gains (a one-sided paired t-test; the
standard-error rule of :func:`~factirl_opt.learners.intention_count.one_standard_error_choice`
with the t quantile for a multiple). Sharing has to earn its place: where the candidates'
held-out scores are within their noise, the learner keeps what each task's own demonstrations
say. By default the folds are a race: every candidate is scored on the first fold, only those
within ``RACE_MARGIN`` of the best there (and the flat model) on the others (``search``). When a
shared candidate is chosen and k is ``"auto"``, k is then bisected around it at its lambda
(:func:`choose_sharing`): ``K_CANDIDATES`` doubles, and the true number of primitives rarely
is a power of two.

Cost. The flat fit of the PCA start is computed once for all tasks and indexed by fold: the
flat learner is separable over tasks (:mod:`solvers.separable`), so a task's flat reward is
the same whichever tasks share the fit. A candidate then costs one alternating fit on
``(K-1)/K`` of the tasks per fold and one transfer; ``lambda = 0`` (the flat model: the
dictionary plays no part) is tried once, with the smallest k, and in a race takes the
dictionary of another candidate instead of a fit of its own.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import minimize_scalar
from scipy.special import log_softmax
from scipy.stats import t as t_dist

from .._validation import as_rng, check_int, check_rewards
from ..exceptions import ConvergenceWarning, FitInterrupted, ValidationError
from .fitting import resolve_step_solver, task_objective
from ..objectives.sharding import Execution
from ..tasks.task_set import TaskSet, per_task_features, task_set
from .solver_settings import estimator_solvers
from .em import log_policies
from .intention_count import one_standard_error_choice
from .gradirl import GradIRL
from .estimator import clone
from .approximate_cv import leave_task_out_scores
from .evidence import (confirmation_primitives, evidence_penalties, evidence_primitives, flat_start_evidence,
                       plausible_ranks)
from ..mdp.tabular import TabularMDP
from ..planning import get_planner, optimal_q
from ..tasks.trajectories import parse_demonstrations

__all__ = ["AUTO", "K_CANDIDATES", "LAMBDA_CANDIDATES", "N_FOLDS", "N_TRANSFER_DEMOS", "SEARCHES", "DEFAULT_SEARCH",
           "SCORES", "DEFAULT_SCORE", "SHARE_LEVEL", "RULES", "DEFAULT_RULE", "held_out_occupancy_gap",
           "RACE_MARGIN", "WARM_BUDGET", "choose_sharing", "choose_row", "search_sharing", "SearchResult", "SearchProgress",
           "score_candidates", "score_rows", "bisection_midpoints", "sharing_candidates", "max_primitives", "task_folds", "take_tasks", "task_subset",
           "task_mdp", "fixed_learner", "flat_start_rewards", "held_out_nll", "cv_results", "validation_rows",
           "rows_cv_results", "check_cv_results", "CV_RESULTS_KEYS", "plot_validation"]

#: the value of ``n_primitives`` / ``residual_penalty`` that asks for validation
AUTO = "auto"
#: candidate numbers of primitives (those <= min(p, number of training tasks of a fold) are tried)
K_CANDIDATES = (1, 2, 4, 8, 16)
#: candidate residual penalties, from the factorial model (inf) to the flat one (0)
LAMBDA_CANDIDATES = (np.inf, 1.0, 1e-2, 0.0)
#: folds over tasks
N_FOLDS = 3
#: demonstrations a held-out task is transferred from (the one-demonstration use)
N_TRANSFER_DEMOS = 1
#: the searches of :func:`choose_sharing`: every candidate on every fold, a race, a race with warm starts (see there);
#: ``"evidence"``: k from Minka's evidence of the flat start (:mod:`~factirl_opt.learners.evidence`), its
#: candidates on every fold (:func:`search_sharing`)
SEARCHES = ("full", "race", "race-warm", "evidence", "approx-loo")
#: the search ``FactIRL.fit`` uses
DEFAULT_SEARCH = "race"
#: a race keeps, after the first fold, the candidates whose score there is within this fraction of the best one's
RACE_MARGIN = 0.1
#: a warm-started candidate's outer iterations, as a fraction of ``max_iter`` (at least one)
WARM_BUDGET = 0.5
#: held-out scores of :func:`choose_sharing`: the negative log-likelihood under the learner's
#: policy model with its inverse temperature fitted per task (:func:`held_out_nll`), the same
#: with the learner's ``beta``, the learner's own objective, or the distance between the
#: occupancies of the transferred reward's optimal policy and of the demonstrations
#: (:func:`held_out_occupancy_gap`)
SCORES = ("likelihood", "fixed-beta", "objective", "occupancy")
#: the score ``FactIRL.fit`` uses
DEFAULT_SCORE = "likelihood"
#: a sharing candidate replaces the flat model only if a one-sided paired t-test over the held-out
#: tasks finds its gain significant at this level
SHARE_LEVEL = 0.05


def _count(demos: Any) -> int:
    return len(demos)


def take_tasks(seq: Any, idx: Sequence[int] | np.ndarray) -> Any:
    """Tasks ``idx`` of a per-task sequence (a list, or an array with tasks on the leading axis)."""
    if isinstance(seq, np.ndarray):
        return seq[np.asarray(idx)]
    return [seq[i] for i in idx]


def task_subset(mdp: Any, features: Any, idx: Sequence[int] | np.ndarray) -> tuple[Any, Any]:
    """The MDP(s) and features of tasks ``idx``: a shared MDP or feature matrix as it is, per-task ones indexed."""
    sub_mdp = mdp if isinstance(mdp, TabularMDP) else take_tasks(mdp, idx)
    sub_features = take_tasks(features, idx) if per_task_features(features) else features
    return sub_mdp, sub_features


def task_mdp(mdp: Any, i: int) -> Any:
    """Task ``i``'s MDP: the shared one, or its own."""
    return mdp if isinstance(mdp, TabularMDP) else mdp[i]


def _candidates(k_fixed: Any, lam_fixed: Any, k_max: int, constrained: bool, k_grid: Sequence[int] = K_CANDIDATES,
                lam_grid: Sequence[float] = LAMBDA_CANDIDATES) -> list[tuple[int, float]]:
    """The candidate pairs: k up to ``k_max``; lambda from inf to 0 (inf only for a constrained
    H-solver, which the residual model does not take)."""
    if k_fixed == AUTO:
        ks = [int(k) for k in k_grid if k <= k_max] or [1]
    else:
        ks = [int(k_fixed)]
    if lam_fixed == AUTO:
        lams = [np.inf] if constrained else [float(lam) for lam in lam_grid]
    else:
        lams = [float(lam_fixed)]
    out = []
    for lam in lams:
        for k in (ks[:1] if lam == 0.0 else ks):  # lambda = 0: the dictionary plays no part
            out.append((k, lam))
    return out


def _one_reward(mdp: Any, rewards: ArrayLike) -> np.ndarray:
    """One task's reward, validated (finite, shape (S, A) or (S,)), as (S, A)."""
    R, single = check_rewards(mdp, rewards, "rewards")
    if not single:
        raise ValidationError(f"rewards must be one task's reward, of shape (S, A) = ({mdp.n_states}, {mdp.n_actions}) "
                              f"or (S,) = ({mdp.n_states},); got {np.shape(rewards)}")
    return R[0]


def held_out_nll(mdp: Any, demos: Any, rewards: ArrayLike, model: Any, temper: bool = True) -> float:
    """Negative log-likelihood per step of demonstrations under the policy a learner models for a reward.

    The policy is the one the learner's objective models (:func:`~factirl_opt.learners.em.log_policies`;
    policy matching: the Boltzmann policy of the optimal Q*, eq. 7; MCE: the soft-optimal policy),
    ``log pi(a|s)``. With ``temper`` its logits are rescaled by the ``c >= 0`` that fits the
    demonstrations best, ``min_c -sum_(s,a) mu(s) pi_hat(a|s) log softmax_a(c log pi(.|s))``
    (convex in c; ``c = 0`` is the uniform policy, so the score is at most ``log |A|``). For policy
    matching this is exactly the likelihood of the Boltzmann policy with the inverse temperature
    ``c * beta`` (Q* is positively homogeneous in the reward), i.e. the likelihood of the best
    rescaled reward: transfer is judged on the reward's direction, which the policy it induces
    depends on, and not on its scale, which one demonstration does not fix.

    Parameters
    ----------
    mdp : TabularMDP
    demos : array of int, shape (n_demos, horizon, 2)
        (state, action) pairs.
    rewards : array, shape (S, A)
    model : FactIRL or GradIRL
        Its ``beta``, ``objective`` and ``planner``.
    temper : bool, default True

    Returns
    -------
    float

    Raises
    ------
    ValidationError
        ``rewards`` not finite, or not one task's reward of the MDP's shape.
    """
    R = _one_reward(mdp, rewards)
    mu, pi_hat = task_set(mdp, [demos]).statistics()
    weights = mu[0][:, None] * pi_hat[0]
    log_pi = log_policies(get_planner(mdp, model.planner), R[None], model.beta, model.objective)[0]
    if not temper:
        return float(-np.sum(weights * log_pi))
    seen = weights.sum(axis=1) > 0
    weights, log_pi = weights[seen], log_pi[seen]
    log_pi = log_pi - log_pi.max(axis=1, keepdims=True)  # finite, and the same policy

    def nll(log_c: float) -> float:
        return float(-np.sum(weights * log_softmax(np.exp(log_c) * log_pi, axis=1)))

    best = minimize_scalar(nll, bounds=(-12.0, 12.0), method="bounded", options={"xatol": 1e-6})
    return min(best.fun, float(np.log(log_pi.shape[1]) * weights.sum()))


def held_out_occupancy_gap(mdp: Any, demos: Any, rewards: ArrayLike, planner: str = "auto") -> float:
    """Where the reward's optimal policy goes against where the demonstrations went.

    The total variation ``sum_(s,a) |rho_pi(s, a) - rho_hat(s, a)|`` between two discounted
    state-action occupancies over the demonstrations' horizon: ``rho_hat`` of the
    demonstrations themselves (``sum_t gamma^t 1[(s_t, a_t) = (s, a)]``, averaged over the
    episodes), and ``rho_pi`` of the optimal (greedy) policy of ``rewards`` started from each
    episode's first state and run for as many steps as the episode has (``d_(t+1) = P^T (d_t *
    pi)``, through the model), averaged over the episodes. It bounds the difference of values for
    any reward ``r``: ``|V_hat(r) - V_pi(r)| <= max|r| * gap``. Unlike a likelihood it does not
    reward a model for imitating how the expert moves between equally good actions, only for
    going where the expert goes (BabyAI: the bot's tie-breaking, shared by every mission,
    improves the held-out likelihood of a shared model whose transferred rewards reach the target
    less often; ``results/which-learner/README.md``).

    Parameters
    ----------
    mdp : TabularMDP
    demos : array of int, shape (n_demos, horizon, 2), or list of (L_j, 2) episodes
    rewards : array, shape (S, A)
    planner : str, default="auto"

    Returns
    -------
    float
        In ``[0, 2 (1 - gamma^L) / (1 - gamma)]``, L the longest episode; 0 when the
        demonstrations follow the greedy policy through a deterministic model.

    Raises
    ------
    ValidationError
        ``rewards`` not finite, or not one task's reward of the MDP's shape.
    """
    R = _one_reward(mdp, rewards)
    episodes = parse_demonstrations([demos], mdp.n_states, mdp.n_actions)[0].episodes()
    S, A, gamma = mdp.n_states, mdp.n_actions, mdp.gamma
    _, greedy = optimal_q(mdp, R[None], planner=planner)
    pi = np.zeros((S, A))
    pi[np.arange(S), np.asarray(greedy).reshape(S)] = 1.0
    P = mdp.csr()
    expert, learnt = np.zeros((S, A)), np.zeros((S, A))
    for e in episodes:  # each episode's start, for its own length
        np.add.at(expert, (e[:, 0], e[:, 1]), gamma ** np.arange(len(e)))
        d = np.zeros(S)
        d[e[0, 0]] = 1.0
        for t in range(len(e)):
            x = d[:, None] * pi
            learnt += gamma ** t * x
            d = P.T @ x.reshape(-1)
    learnt /= len(episodes)
    expert /= len(episodes)
    return float(np.abs(learnt - expert).sum())


def _fit_inputs(tasks: TaskSet, features: Any) -> tuple[Any, Any]:
    """The ``(mdp, features)`` a FactIRL ``fit`` or ``transfer`` takes for a task set's tasks: on one
    environment its MDP and ``features`` (a learner's own parameter for a fit, None for a
    transfer: the model's own); else the tasks' MDPs and their rows of the basis."""
    return (tasks.mdp, features) if tasks.shared else (tasks.mdps, tasks.basis)


def _score(model: Any, tasks: TaskSet, idx: Sequence[int] | np.ndarray, t: int,
           score: str = DEFAULT_SCORE, transfer_max_iter: int | None = None) -> np.ndarray:
    """Held-out score of tasks ``idx`` of ``tasks``: transfer from their first t demonstrations, then, on the
    others, :func:`held_out_nll` (``score="likelihood"``: tempered; ``"fixed-beta"``: not), the
    learner's objective (``"objective"``) or :func:`held_out_occupancy_gap` (``"occupancy"``);
    one value per task."""
    demos = tasks.demos_per_task
    held = tasks.subset(idx)
    sub_mdp, sub_features = _fit_inputs(held, None)
    model.transfer(sub_mdp, [demos[i][:t] for i in idx], features=sub_features, max_iter=transfer_max_iter)
    rewards = model.transfer_rewards_
    out = np.empty(len(idx))
    for j, i in enumerate(idx):
        one, rest = held.mdp if held.mdps is None else held.mdps[j], demos[i][t:]
        if score == "occupancy":
            out[j] = held_out_occupancy_gap(one, rest, rewards[j], model.planner)
        elif score == "objective":
            obj = task_objective(held.subset([j]).with_demonstrations([rest]), model.beta, model.objective, model.planner)
            out[j] = obj.loss_and_grad(np.asarray(rewards[j])[None])[0][0]
        else:
            out[j] = held_out_nll(one, rest, rewards[j], model, temper=score == "likelihood")
    return out


def choose_sharing(learner: Any, mdp: Any, demos_per_task: Any, flat_rewards: Any = None,
                   search: str = DEFAULT_SEARCH, score: str = DEFAULT_SCORE, **options: Any) -> tuple[int, float, list[dict]]:
    """Choose ``(k, lambda)`` for ``learner`` (a FactIRL with ``"auto"`` values) by K-fold over tasks.

    ``search="full"`` scores every candidate on every fold. ``"race"`` (the default) scores
    every candidate on the first fold, keeps those whose score there is at most
    ``(1 + RACE_MARGIN)`` times the best one (within ``RACE_MARGIN |best|`` of it), and the flat
    model, and scores only these on the other folds: a candidate far behind on one fold has no
    chance of the best mean, and the folds after the first cost only the contenders (a race, as
    in F-race or successive halving). The pruned candidates keep their first fold's scores (one
    entry in ``fold_scores``); the choice is among the candidates scored on every fold (the flat
    model alone, if it is the only contender left). In a race ``lambda = 0`` is not fitted when
    another candidate was fitted on the fold: its transfer, the flat learner's, takes that
    candidate's model (whose dictionary plays no part there). ``"race-warm"`` also warm-starts
    along lambda: on each fold, a candidate whose predecessor (the candidate before it with the
    same k: the next larger lambda) was fitted on that fold starts from the predecessor's
    dictionary and coefficients, with ``WARM_BUDGET * max_iter`` outer iterations (at least one;
    the predecessor already spent ``max_iter``). Measured (results/README.md): on the ``tiny`` grid the race
    cost 19-21x one fixed fit against 26-30x for the full search, with the same choice, on the
    ``quick`` grid 11.9x against 30.3x; the warm race 16-18x on ``tiny``, but its shortened fits
    moved the scores enough to change the choice on both seeds, to pairs that transferred worse.

    The choice: the candidate of lowest ``score``, unless the flat model (``lambda = 0``) is a
    candidate and the leader's mean gain over it, paired over the n held-out tasks, is at most
    ``t_(n-1)(1 - SHARE_LEVEL)`` standard errors of that gain (not significant): then the flat
    model.

    Then, if k is ``"auto"`` and the choice shares (``lambda > 0``), a bisection of k at the
    chosen lambda: the midpoints between the chosen k and its nearest tried neighbours
    (:func:`_between`; 8 between 4 and 16 gives 6 and 12) are scored on every fold and the choice
    is made again over the whole table; while it moves to a midpoint, the step repeats around it.
    On the paper's grid with 100 tasks (seed 0) the race chose (8, 1) and transferred at 5.89,
    where k = 6 and k = 5 without residuals transfer at 5.06 and 4.87
    (``results/which-learner/README.md``).

    Parameters
    ----------
    learner : FactIRL
        Its other hyper-parameters are used by every candidate fit.
    mdp, demos_per_task
        As in ``FactIRL.fit``.
    flat_rewards : optional
        The flat learner's rewards of every task (:func:`flat_start_rewards`), the PCA start of
        every candidate (``init="pca"``); None: each candidate fit runs its own flat fit.
    search : {"full", "race", "race-warm", "evidence", "approx-loo"}
        ``"evidence"``: k is not searched but read from Minka's evidence of the PCA of the flat
        rewards (:func:`~factirl_opt.learners.evidence.flat_start_evidence`; one SVD, no fit):
        the candidates are that k, half and twice it
        (:func:`~factirl_opt.learners.evidence.evidence_primitives`) at inf, the largest finite
        lambda and 0 (:func:`~factirl_opt.learners.evidence.evidence_penalties`), scored on
        every fold; a shared choice at the smallest k tried is followed, at its lambda, by half
        that k while the choice moves there, then by the bisection below; when the evidence finds no shared direction, or more
        than half the training tasks of a fold, the flat model is chosen unscored (its row has
        NaN scores and no fold). A shared choice of k with at least
        :data:`~factirl_opt.learners.evidence.CONFIRM_TASKS_PER_PRIMITIVE` training tasks of a fold
        per primitive is then confirmed: k - 1, k and k + 1 at its lambda are refitted with the
        learner's ``max_iter`` on every fold, their screen scores replaced, and the rule chooses
        among them (:func:`~factirl_opt.learners.evidence.confirmation_primitives`). Needs
        ``flat_rewards``.
        ``"approx-loo"``: no folds (``cv`` unused); each candidate is fitted once on every task and
        every task scored as held out, with the dictionary of one Gauss-Newton step from that fit
        toward the fit without it (:mod:`~factirl_opt.learners.approximate_cv`; the table has one
        fold of all n tasks, k up to n - 1). The policy-matching objective on one MDP only.
    score : {"likelihood", "fixed-beta", "objective", "occupancy"}
        The held-out score (:data:`SCORES`; module docstring).
    **options
        The other settings of :func:`search_sharing` (``cv``, the grids, the rule, ...).

    Returns
    -------
    k : int
    lambda : float
    validation : list of dict
        One row per candidate, the grid's then the bisection's in the order they were scored:
        ``n_primitives``, ``residual_penalty``, ``score`` (mean held-out
        score over the held-out tasks of the folds it was scored on), ``score_std`` (of the
        folds' means), ``fold_scores`` (each fold's mean), ``task_scores`` (each held-out task's
        score, fold after fold), ``chosen``.

    Raises
    ------
    ValidationError
        Fewer than 2 tasks, or a task with at most ``N_TRANSFER_DEMOS`` demonstrations (no
        demonstration left to score it on), or an unknown ``search`` or ``score``.
    """
    return search_sharing(learner, mdp, demos_per_task, flat_rewards, search=search, score=score, **options).as_tuple()


@dataclasses.dataclass
class SearchResult:
    """What :func:`search_sharing` found.

    Attributes
    ----------
    n_primitives : int
        The chosen k.
    residual_penalty : float
        The chosen lambda.
    rows : list of dict
        The validation table (``choose_sharing``'s third value), the chosen row marked.
    folds : list of ndarray of int
        The held-out tasks of each fold, in the order scored.
    scores : dict
        ``{(k, lambda): [per-task scores of each fold scored, in the order of folds]}``.
    n_tasks : int
    """

    n_primitives: int
    residual_penalty: float
    rows: list
    folds: list
    scores: dict
    n_tasks: int

    def as_tuple(self) -> tuple[int, float, list[dict]]:
        return self.n_primitives, self.residual_penalty, self.rows


#: choice rules of :func:`search_sharing`: the candidate of best mean score, kept over the flat model only
#: when its paired gain is significant (``"significant-gain"``); the same, then, among the sharing
#: candidates whose paired difference with that leader is not significant, the one that shares most
#: (the largest lambda, then the smallest k; ``"share-within-noise"``); or, after the first test, the
#: fewest primitives at the leader's lambda within one standard error of its paired difference
#: with the leader (``"fewest-within-se"``, Breiman et al.'s one-standard-error rule on k)
RULES = ("significant-gain", "share-within-noise", "fewest-within-se")
#: the rule ``FactIRL.fit`` uses
DEFAULT_RULE = "significant-gain"


def task_folds(n_tasks: int, cv: Any = N_FOLDS, rng: Any = None) -> list[np.ndarray]:
    """The held-out tasks of each fold of a validation over ``n_tasks`` tasks.

    Parameters
    ----------
    n_tasks : int
    cv : int, splitter or iterable, default=N_FOLDS
        An int K: K folds of a random permutation of the tasks (``np.array_split``; at most
        ``n_tasks``). An object with ``split(X)`` (a scikit-learn splitter such as ``KFold``):
        its test indices for ``X`` of one row per task. An iterable: of ``(train, test)``
        pairs, or of held-out index arrays.
    rng : numpy.random.Generator or int or None
        The permutation of an int ``cv``.

    Returns
    -------
    list of ndarray of int
        One array of held-out tasks per fold; every fold leaves at least one task to train on.

    Raises
    ------
    ValidationError
        For ``cv`` < 2, an index outside ``[0, n_tasks)``, an empty fold, or a fold holding
        every task out.
    """
    if isinstance(cv, (int, np.integer)) and not isinstance(cv, bool):
        if cv < 2:
            raise ValidationError(f"cv must be at least 2 folds; got {cv}")
        return np.array_split(as_rng(rng).permutation(n_tasks), min(int(cv), n_tasks))
    if isinstance(cv, (str, bytes)):
        raise ValidationError(f"cv must be an int, a splitter with split(X) or an iterable of folds; got {cv!r:.80}")
    if hasattr(cv, "split"):
        parts = [test for _, test in cv.split(np.zeros((n_tasks, 1)))]
    else:
        try:
            parts = [part[1] if isinstance(part, tuple) and len(part) == 2 else part for part in cv]
        except TypeError:
            raise ValidationError(f"cv must be an int, a splitter with split(X) or an iterable of folds; got {cv!r:.80}") from None
    folds = []
    for f, part in enumerate(parts):
        idx = np.asarray(part)
        if idx.ndim != 1 or idx.size == 0 or idx.dtype.kind not in "iu" or idx.min() < 0 or idx.max() >= n_tasks:
            raise ValidationError(f"cv fold {f} must be a non-empty array of task indices in [0, {n_tasks}); got {part!r:.80}")
        if np.unique(idx).size == n_tasks:
            raise ValidationError(f"cv fold {f} holds every task out: no task is left to fit on")
        folds.append(idx.astype(np.int64))
    if not folds:
        raise ValidationError("cv gave no fold")
    return folds


def sharing_candidates(learner: Any, k_max: int, k_grid: Sequence[int] = K_CANDIDATES,
                       lam_grid: Sequence[float] = LAMBDA_CANDIDATES) -> list[tuple[int, float]]:
    """The candidate pairs ``(k, lambda)`` of ``learner``'s ``"auto"`` values, in the order scored.

    k from ``k_grid`` up to ``k_max`` (or the learner's fixed k); lambda from ``lam_grid`` (or the
    fixed one), np.inf only for a constrained H-solver (the residual model needs an
    unconstrained one); ``lambda = 0`` once, with the smallest k (the dictionary plays no part).
    """
    h_name, h_options, _, _ = estimator_solvers(learner)
    constrained = resolve_step_solver(h_name, h_options, learner.objective, "solver").constraint != "none"
    return _candidates(learner.n_primitives, learner.residual_penalty, k_max, constrained, k_grid, lam_grid)


def max_primitives(learner: Any, mdp: Any, n_tasks: int, folds: Sequence[np.ndarray]) -> int:
    """The largest k a candidate may have: the reward dimension p, and the training tasks of the smallest fold's fit."""
    return min(_reward_dimension(learner, mdp, n_tasks), min(n_tasks - len(f) for f in folds))


def search_sharing(learner: Any, mdp: Any, demos_per_task: Any, flat_rewards: Any = None, *,
                   search: str = DEFAULT_SEARCH, score: str = DEFAULT_SCORE, cv: Any = N_FOLDS,
                   k_grid: Sequence[int] = K_CANDIDATES, lam_grid: Sequence[float] = LAMBDA_CANDIDATES,
                   n_transfer_demos: int = N_TRANSFER_DEMOS, race_margin: float = RACE_MARGIN,
                   share_level: float = SHARE_LEVEL, rule: str = DEFAULT_RULE,
                   candidate_max_iter: int | None = None, transfer_max_iter: int | None = None) -> SearchResult:
    """:func:`choose_sharing` with every setting of the search given (the defaults are today's
    ``FactIRL.fit``), and the folds and scores returned too.

    Parameters
    ----------
    learner, mdp, demos_per_task, flat_rewards, search, score
        As in :func:`choose_sharing`.
    cv : int, splitter or iterable, default=N_FOLDS
        The folds over tasks (:func:`task_folds`; an int's permutation drawn from ``learner.rng``).
    k_grid, lam_grid : sequences
        Candidate numbers of primitives and residual penalties (:func:`sharing_candidates`).
    n_transfer_demos : int, default=N_TRANSFER_DEMOS
        Demonstrations a held-out task is transferred from; it is scored on the others.
    race_margin : float, default=RACE_MARGIN
    share_level : float, default=SHARE_LEVEL
        Level of the one-sided paired t-tests of the choice rule.
    rule : {"significant-gain", "share-within-noise"}
        :data:`RULES`.
    candidate_max_iter : int or None
        Outer iterations of each candidate fit (0: the candidate is its PCA start, from the
        training tasks' flat rewards); None: the learner's ``max_iter``. The final fit of
        ``FactIRL.fit`` always has the learner's.
    transfer_max_iter : int or None
        Steps of each held-out task's transfer (None: the learner's ``transfer_max_iter``).

    Returns
    -------
    SearchResult
    """
    if search not in SEARCHES:
        raise ValidationError(f"search must be one of {SEARCHES}; got {search!r}")
    if score not in SCORES:
        raise ValidationError(f"score must be one of {SCORES}; got {score!r}")
    if rule not in RULES:
        raise ValidationError(f"rule must be one of {RULES}; got {rule!r}")
    t = check_int(n_transfer_demos, "n_transfer_demos", minimum=1)
    if candidate_max_iter is not None:
        check_int(candidate_max_iter, "candidate_max_iter", minimum=0)
    if transfer_max_iter is not None:
        check_int(transfer_max_iter, "transfer_max_iter", minimum=0)
    n = _count(demos_per_task)
    if n < 2:
        raise ValidationError(f"choosing n_primitives or residual_penalty by validation needs at least 2 tasks; got {n}")
    short = [i for i in range(n) if _count(demos_per_task[i]) <= t]
    if short:
        raise ValidationError(f"choosing n_primitives or residual_penalty by validation transfers each held-out task from {t} "
                              f"demonstration(s) and scores it on the others: task {short[0]} has "
                              f"{_count(demos_per_task[short[0]])}; give every task at least {t + 1}")
    approx = search == "approx-loo"  # every task held out, by one Newton step from one fit (approximate_cv; no cv)
    folds = [np.arange(n)] if approx else task_folds(n, cv, learner.rng)
    k_max = min(_reward_dimension(learner, mdp, n), n - 1) if approx else max_primitives(learner, mdp, n, folds)
    n_train = n - max(len(f) for f in folds)  # the fewest training tasks of a fold
    progress = SearchProgress()
    progress.folds, progress.n_tasks = folds, n
    scores = progress.scores
    run = functools.partial(score_candidates, learner, mdp, demos_per_task, flat_rewards, n_transfer_demos=t,
                            score=score, candidate_max_iter=candidate_max_iter,
                            transfer_max_iter=transfer_max_iter, progress=progress)
    if approx:
        run = functools.partial(_approximate_run, learner, mdp, demos_per_task, flat_rewards, t, score,
                                candidate_max_iter, transfer_max_iter, progress)
    choice = functools.partial(_choice, share_level=share_level, rule=rule)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)  # budgets of the candidates: the final fit warns
            candidates = sharing_candidates(learner, k_max, k_grid, lam_grid)
            if search == "evidence":
                candidates = _evidence_candidates(learner, mdp, demos_per_task, flat_rewards, k_max, lam_grid, n_train)
            first = folds[:1] if search not in ("full", "evidence") and len(folds) > 1 else folds
            warm, reuse = search == "race-warm", search != "full"
            if search == "evidence" and len(candidates) == 1:  # nothing to compare it with: chosen unscored
                scores[candidates[0]] = []
            else:
                run(first, candidates, warm=warm, reuse=reuse)
            if len(first) < len(folds):
                lead = min(np.mean(v[0]) for v in scores.values())
                contenders = [c for c in candidates
                              if np.mean(scores[c][0]) <= lead + race_margin * abs(lead) or c[1] == 0.0]
                if len(contenders) > 1:  # else the flat model alone is left: it is the choice, scored on one fold
                    run(folds[1:], contenders, warm=warm, reuse=reuse)
            rows = score_rows(scores)
            best = choice(rows)
            while search == "evidence" and learner.n_primitives == AUTO and rows[best]["residual_penalty"] != 0.0:
                k, lam = rows[best]["n_primitives"], rows[best]["residual_penalty"]
                beyond = _beyond(k, [c[0] for c in scores if c[1] == lam], k_max)
                if not beyond:  # the chosen k is inside the tried ones: the bisection below refines it
                    break
                run(folds, [(beyond, lam)], warm=False, reuse=False)
                rows = score_rows(scores)
                best = choice(rows)
                if rows[best]["n_primitives"] == k:
                    break
            while learner.n_primitives == AUTO and rows[best]["residual_penalty"] != 0.0:
                k, lam = rows[best]["n_primitives"], rows[best]["residual_penalty"]
                between = bisection_midpoints(k, [c[0] for c in scores if c[1] == lam], k_max)
                if not between:
                    break
                run(folds, [(m, lam) for m in between], warm=False, reuse=False)
                rows = score_rows(scores)
                best = choice(rows)
                if rows[best]["n_primitives"] == k:
                    break
            if search == "evidence" and learner.n_primitives == AUTO and rows[best]["residual_penalty"] != 0.0:
                k, lam = rows[best]["n_primitives"], rows[best]["residual_penalty"]
                trio = [(m, lam) for m in confirmation_primitives(k, k_max, n_train)]
                if trio:  # the screen's scores of k - 1, k and k + 1 replaced by those of full fits
                    for pair in trio:
                        scores.pop(pair, None)
                    run(folds, trio, warm=False, reuse=False, candidate_max_iter=None)
                    rows = score_rows(scores)
                    confirmed = [r for r in range(len(rows)) if (rows[r]["n_primitives"], rows[r]["residual_penalty"]) in trio]
                    for r in confirmed:
                        rows[r]["confirmed"] = True
                    best = confirmed[choice([rows[r] for r in confirmed])]
    except KeyboardInterrupt as exc:
        cause: BaseException = exc
        while isinstance(cause, FitInterrupted) and cause.__cause__ is not None:
            cause = cause.__cause__
        raise FitInterrupted(progress.interrupted(), "the search of choose_sharing") from cause
    rows[best]["chosen"] = True
    return SearchResult(rows[best]["n_primitives"], rows[best]["residual_penalty"], rows, folds, scores, n)


class SearchProgress:
    """What a search of :func:`choose_sharing` has done so far: the ``result`` of the
    :class:`~factirl_opt.exceptions.FitInterrupted` it raises when interrupted.

    Attributes
    ----------
    scores : dict
        ``{(k, lambda): [array of per-task held-out scores, one per fold scored]}``.
    fits : dict
        ``{(k, lambda): FactIRL}``: each candidate's last fit (on the training tasks of the last
        fold it was scored on, ``train_tasks[(k, lambda)]``); a race's flat model, which takes
        another candidate's fit instead of one of its own, is not among them.
    train_tasks : dict
        ``{(k, lambda): array of int}``: the tasks each fit of ``fits`` was fitted on.
    last : tuple or None
        The candidate fitted last (or being fitted), its model and training tasks: ``((k,
        lambda), FactIRL, tasks)``; None before the first fit.
    rows : list of dict
        After an interrupt: the validation table of the candidates scored so far (as
        :func:`choose_sharing` returns it), the kept candidate's row ``chosen``.
    kept : tuple or None
        After an interrupt: ``((k, lambda), FactIRL, tasks)``, the fit kept: the fitted
        candidate of lowest mean score among those scored on the most folds (flat model aside,
        the rule of :func:`choose_sharing`); when none was scored, the last candidate's fit
        (complete, or as far as it got if it was interrupted); None when nothing was fitted.
    """

    def __init__(self) -> None:
        self.scores: dict = {}
        self.fits: dict = {}
        self.train_tasks: dict = {}
        self.last: tuple | None = None
        self.rows: list[dict] = []
        self.kept: tuple | None = None
        self.folds: list = []
        self.n_tasks = 0

    def result(self) -> SearchResult | None:
        """After an interrupt, the table so far as a :class:`SearchResult` (None when no candidate was scored)."""
        if not self.rows or self.kept is None:
            return None
        (k, lam), _, _ = self.kept
        return SearchResult(k, lam, self.rows, self.folds, self.scores, self.n_tasks)

    def interrupted(self) -> "SearchProgress":
        """Fill ``rows`` and ``kept`` from what was done; returns self."""
        fitted = {c: v for c, v in self.scores.items() if c in self.fits}
        if fitted:
            rows = score_rows(fitted)
            best = rows[_choice(rows)]
            pair = (best["n_primitives"], best["residual_penalty"])
            self.kept = (pair, self.fits[pair], self.train_tasks[pair])
            self.rows = score_rows(self.scores)
            for row in self.rows:
                row["chosen"] = (row["n_primitives"], row["residual_penalty"]) == pair
        elif self.last is not None and hasattr(self.last[1], "dictionary_"):
            self.kept = self.last
            self.rows = []
        return self


def score_rows(scores: dict) -> list[dict]:
    """The validation table of ``{(k, lambda): [per-task scores of each fold]}`` (as
    :func:`score_candidates` returns them), one row per candidate in the dict's order, as
    :func:`choose_row` takes it (a candidate chosen unscored, with no fold: NaN scores)."""
    return [{"n_primitives": k, "residual_penalty": lam,
             "score": float(np.mean(np.concatenate(per_fold))) if per_fold else np.nan,
             "score_std": float(np.std([np.mean(f) for f in per_fold])) if per_fold else np.nan,
             "fold_scores": [float(np.mean(f)) for f in per_fold],
             "task_scores": [float(v) for v in np.concatenate(per_fold)] if per_fold else [], "chosen": False}
            for (k, lam), per_fold in scores.items()]


def _evidence_candidates(learner: Any, mdp: Any, demos_per_task: Any, flat_rewards: Any, k_max: int,
                         lam_grid: Sequence[float], n_train: int) -> list[tuple[int, float]]:
    """The candidates of the ``"evidence"`` search: k from the evidence of the flat start's PCA
    (:func:`~factirl_opt.learners.evidence.flat_start_evidence`,
    :func:`~factirl_opt.learners.evidence.evidence_primitives`) at the penalties of
    :func:`~factirl_opt.learners.evidence.evidence_penalties`, then the flat model (k = 1); when
    the tasks share little (the evidence's k is 0, or a plausible k more than half the ``n_train``
    training tasks of a fold), the flat model alone (or k = 1 at a fixed lambda)."""
    if flat_rewards is None:
        raise ValidationError("search='evidence' chooses k from the flat start's rewards: give flat_rewards "
                              "(FactIRL.fit computes them with init='pca')")
    log_evidence, rank = flat_start_evidence(learner, mdp, demos_per_task, flat_rewards)
    ks = evidence_primitives(rank, k_max, n_train, largest_plausible=int(plausible_ranks(log_evidence)[-1]))
    lams = evidence_penalties(lam_grid)
    shared = [c for c in sharing_candidates(learner, k_max, ks, lams) if c[1] != 0.0] if ks else []
    flat = [c for c in sharing_candidates(learner, k_max, (1,), lams) if c[1] == 0.0]
    return shared + flat or sharing_candidates(learner, k_max, (1,), lams)[:1]


def _beyond(k: int, tried: Sequence[int], k_max: int) -> int | None:
    """The next k of the ``"evidence"`` search below the tried ones: half of ``k`` (rounded up) when it
    is the smallest tried, if within ``[1, k_max]`` and not tried; else None. Only down: the
    evidence of the flat rewards overestimates k with many tasks, and the held-out score of PCA
    starts favours large k (on the README's grid a walk up from (10, 1) ended at (17, 1), 13.55
    against 12.11; on the grid at 20 tasks, seed 0, at (12, 1), 12.58 against 11.96;
    ``results/which-learner/diagnostics/evidence/README.md``)."""
    step = (k + 1) // 2 if k == min(tried) else None
    return step if step is not None and step not in tried and 1 <= step <= k_max else None


def bisection_midpoints(k: int, tried: Sequence[int], k_max: int) -> list[int]:
    """The midpoints between ``k`` and its nearest tried neighbours, rounded down, not tried yet and
    at most ``k_max``: the next step of a bisection of the number of primitives around the chosen
    one (never beyond the tried range)."""
    below = [j for j in tried if j < k]
    above = [j for j in tried if j > k]
    mids = {(k + e) // 2 for e in ([max(below)] if below else []) + ([min(above)] if above else [])}
    return sorted(m for m in mids if m not in tried and 1 <= m <= k_max and m != k)


def choose_row(rows: list[dict], rule: str = DEFAULT_RULE, share_level: float = SHARE_LEVEL) -> int:
    """The index of the row a choice ``rule`` (:data:`RULES`) takes in a validation table (rows of
    :func:`choose_sharing`; ``task_scores`` paired over the same held-out tasks): the rule of
    :func:`search_sharing`, for a table already scored (e.g. to compare the rules on one search).

    Raises
    ------
    ValidationError
        An unknown ``rule``.
    """
    if rule not in RULES:
        raise ValidationError(f"rule must be one of {RULES}; got {rule!r}")
    return _choice(rows, share_level, rule)


def _choice(rows: list[dict], share_level: float = SHARE_LEVEL, rule: str = DEFAULT_RULE) -> int:
    """The chosen row: the lowest mean score among the rows with the most folds, unless the flat
    model (``lambda = 0``) is among them and the leader's gain over it, paired over the n held-out
    tasks, is within ``t_(n-1)(1 - share_level)`` standard errors
    (:func:`~factirl_opt.learners.intention_count.one_standard_error_choice`). With
    ``rule="share-within-noise"``, a sharing leader then gives way to the sharing row that shares
    most (largest lambda, then smallest k) among those whose paired difference with it is within
    the same number of standard errors; with ``rule="fewest-within-se"``, to the row of fewest
    primitives at the leader's lambda whose paired difference with it is within one standard
    error."""
    most = max(len(r["fold_scores"]) for r in rows)
    complete = [r for r in range(len(rows)) if len(rows[r]["fold_scores"]) == most]
    best = min(complete, key=lambda r: rows[r]["score"])
    flat = [r for r in complete if rows[r]["residual_penalty"] == 0.0]

    def within(a: int, b: int) -> bool:  # whether row a is within noise of row b (paired over the held-out tasks)
        pair = -np.array([rows[a]["task_scores"], rows[b]["task_scores"]])  # higher is better there
        n_se = t_dist.ppf(1.0 - share_level, pair.shape[1] - 1) if pair.shape[1] > 1 else 0.0
        return one_standard_error_choice(pair, n_se) == 0

    if flat and flat[0] != best and within(flat[0], best):
        return flat[0]
    if rule == "share-within-noise" and rows[best]["residual_penalty"] != 0.0:
        near = [r for r in complete if rows[r]["residual_penalty"] != 0.0 and (r == best or within(r, best))]
        return min(near, key=lambda r: (-rows[r]["residual_penalty"], rows[r]["n_primitives"]))
    if rule == "fewest-within-se" and rows[best]["residual_penalty"] != 0.0:
        same = sorted((r for r in complete if rows[r]["residual_penalty"] == rows[best]["residual_penalty"]),
                      key=lambda r: rows[r]["n_primitives"])
        return same[one_standard_error_choice(-np.array([rows[r]["task_scores"] for r in same]), 1.0)]
    return best


def score_candidates(learner: Any, mdp: Any, demos_per_task: Any, flat_rewards: Any, folds: Sequence[np.ndarray],
                     candidates: Sequence[tuple[int, float]], *, n_transfer_demos: int = N_TRANSFER_DEMOS,
                     score: str = DEFAULT_SCORE, warm: bool = False, reuse: bool = False,
                     candidate_max_iter: int | None = None, transfer_max_iter: int | None = None,
                     progress: SearchProgress | None = None) -> dict:
    """The held-out scores of ``candidates`` on ``folds``: for each fold and candidate, the
    candidate (:func:`fixed_learner`) fitted on the other folds' tasks, each held-out task
    transferred from its first ``n_transfer_demos`` demonstrations and scored on the others.

    Parameters
    ----------
    learner : FactIRL
        Its other hyper-parameters are used by every candidate fit.
    mdp, demos_per_task, flat_rewards
        As in :func:`choose_sharing` (every task's).
    folds : sequence of arrays of int
        The held-out tasks of each fold (:func:`task_folds`).
    candidates : sequence of (k, lambda)
    n_transfer_demos : int
    score : str
        :data:`SCORES`.
    warm : bool, default=False
        Each fold's candidate starts from its predecessor's fit (the candidate before it with
        the same k), with ``WARM_BUDGET * max_iter`` outer iterations.
    reuse : bool, default=False
        ``lambda = 0`` takes the fold's last fitted candidate instead of a fit of its own (its
        transfer, the flat learner's, does not use the dictionary).
    candidate_max_iter : int or None
        Outer iterations of each candidate fit, at most the learner's ``max_iter`` (None: that).
    transfer_max_iter : int or None
        Steps of each held-out task's transfer (None: the learner's ``transfer_max_iter``).
    progress : SearchProgress, optional
        Each score is appended to ``progress.scores`` as soon as it is computed, and each fit
        recorded, so an interrupt loses none of them.

    Returns
    -------
    dict
        ``{(k, lambda): [array of per-task scores, one per fold]}``.
    """
    tasks = task_set(mdp, demos_per_task, learner.features, learner.reward)
    n = tasks.n_tasks
    t = n_transfer_demos
    progress = SearchProgress() if progress is None else progress
    budget = learner.max_iter if candidate_max_iter is None else min(candidate_max_iter, learner.max_iter)
    scores: dict = {}
    for held in folds:
        train = np.setdiff1d(np.arange(n), held)
        sub_mdp, sub_features = _fit_inputs(tasks.subset(train), learner.features)
        fitted: dict = {}
        for k, lam in candidates:
            before = [c for c in fitted if c[0] == k]
            start = fitted[before[-1]] if before else None
            if reuse and lam == 0.0 and fitted:  # the flat model: the dictionary plays no part, no fit
                model = copy.copy(fitted[before[-1] if before else list(fitted)[-1]])
                model.residual_penalty = model.residual_penalty_ = 0.0
            else:
                start = start if warm else None
                model = fixed_learner(learner, k, lam, max_iter=budget)
                model.features = sub_features
                if start is not None:
                    model.init = (start.dictionary_, start.coefficients_)
                    model.max_iter = max(1, int(round(WARM_BUDGET * budget)))
                progress.last = ((k, lam), model, train)
                model.fit(sub_mdp, take_tasks(demos_per_task, train),
                          flat_rewards=None if flat_rewards is None else take_tasks(flat_rewards, train))
                progress.fits[k, lam], progress.train_tasks[k, lam] = model, train
            fitted[k, lam] = model
            value = _score(model, tasks, held, t, score, transfer_max_iter)
            scores.setdefault((k, lam), []).append(value)
            progress.scores.setdefault((k, lam), []).append(value)
    return scores


def _approximate_run(learner: Any, mdp: Any, demos_per_task: Any, flat_rewards: Any, t: int, score: str,
                     candidate_max_iter: int | None, transfer_max_iter: int | None, progress: SearchProgress,
                     folds: Any, candidates: Sequence[tuple[int, float]], **_: Any) -> dict:
    """:func:`score_candidates` of ``search="approx-loo"``: every task scored as held out, with the dictionary
    of one Newton step from one fit of each candidate on every task
    (:func:`~factirl_opt.learners.approximate_cv.leave_task_out_scores`; ``folds`` is the one fold of every task)."""
    tasks = task_set(mdp, demos_per_task, learner.features, learner.reward)
    return leave_task_out_scores(learner, mdp, demos_per_task, flat_rewards, candidates,
                                 lambda model, idx: _score(model, tasks, idx, t, score, transfer_max_iter),
                                 candidate_max_iter=candidate_max_iter, progress=progress)


def fixed_learner(learner: Any, k: int, lam: float, **params: Any) -> Any:
    """An unfitted, quiet clone of ``learner`` with fixed ``k`` and ``lambda`` (and ``params`` set).

    ``clone(learner).set_params(n_primitives=k, residual_penalty=lam, verbose=False,
    callback=None, **params)`` (:func:`~factirl_opt.learners.estimator.clone`).
    """
    return clone(learner).set_params(**{"n_primitives": k, "residual_penalty": lam, "verbose": False, "callback": None,
                                        **params})


def _reward_dimension(learner: Any, mdp: Any, n_tasks: int) -> int:
    """p, the reward parameters per task of ``learner``'s features on ``n_tasks`` tasks of ``mdp``
    (:attr:`~factirl_opt.tasks.task_set.TaskSet.n_params`; the demonstrations play no part)."""
    return task_set(mdp, [None] * n_tasks, learner.features, learner.reward).n_params


def flat_start_rewards(learner: Any, mdp: Any, demos_per_task: Any, solver: str, tol: float,
                       stol: float = 0.0) -> Any:
    """The flat learner of FactIRL's PCA start (its ``solver``, ``tol`` and saturation rule ``stol``,
    without the gradient rule, as FactIRL's own flat start) on every task at once (separable: each
    task's rewards are those of its own fit)."""
    flat = GradIRL(beta=learner.beta, features=learner.features, max_iter=learner.flat_max_iter, tol=tol, gtol=0.0,
                   stol=stol, solver=solver, objective=learner.objective, reward=learner.reward,
                   **Execution.of(learner).params())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)  # the PCA start's flat fit does not warn either
        return flat.fit(mdp, demos_per_task).rewards_


def cv_results(result: SearchResult) -> dict[str, Any]:
    """The table of a search, as ``GridSearchCV.cv_results_``: one entry per candidate in every array.

    Keys: ``param_n_primitives`` (int), ``param_residual_penalty`` (float), ``params`` (list of
    dicts), ``mean_test_score`` and ``std_test_score`` (the mean over the held-out tasks scored
    and the spread of the folds' means; lower scores are better), ``rank_test_score`` (1 the
    lowest mean among the candidates scored on the most folds, which alone are chosen from;
    the others after them; the ``"evidence"`` route's confirmed candidates, chosen from when
    there are any, first), ``split<f>_test_score`` (fold f's mean, NaN where the candidate was
    not scored on it: a race prunes), ``task<j>_test_score`` (task j's held-out score, NaN where
    not scored), ``n_splits_scored``, ``chosen`` (bool, exactly one True) and ``confirmed`` (bool: the
    candidate's scores are those of full fits, the ``"evidence"`` route's confirmation of k; the
    others' are the screen's).
    """
    rows, folds, n = result.rows, result.folds, result.n_tasks
    m = len(rows)
    out: dict[str, Any] = {
        "param_n_primitives": np.array([r["n_primitives"] for r in rows], dtype=np.int64),
        "param_residual_penalty": np.array([r["residual_penalty"] for r in rows], dtype=np.float64),
        "params": [{"n_primitives": int(r["n_primitives"]), "residual_penalty": float(r["residual_penalty"])} for r in rows],
        "mean_test_score": np.array([r["score"] for r in rows], dtype=np.float64),
        "std_test_score": np.array([r["score_std"] for r in rows], dtype=np.float64),
    }
    splits = np.full((m, len(folds)), np.nan)
    tasks = np.full((m, n), np.nan)
    for i, r in enumerate(rows):
        per_fold = result.scores[r["n_primitives"], r["residual_penalty"]]
        for f, values in enumerate(per_fold):
            splits[i, f] = float(np.mean(values))
            tasks[i, folds[f]] = values
    n_scored = np.array([len(r["fold_scores"]) for r in rows], dtype=np.int64)
    confirmed = np.array([bool(r.get("confirmed", False)) for r in rows])
    order = np.lexsort((out["mean_test_score"], -n_scored, ~confirmed))
    rank = np.empty(m, dtype=np.int64)
    rank[order] = np.arange(1, m + 1)
    out["rank_test_score"] = rank
    out.update({f"split{f}_test_score": splits[:, f] for f in range(len(folds))})
    out.update({f"task{j}_test_score": tasks[:, j] for j in range(n)})
    out["n_splits_scored"] = n_scored
    out["chosen"] = np.array([bool(r["chosen"]) for r in rows])
    out["confirmed"] = confirmed
    return out


def validation_rows(results: dict[str, Any]) -> list[dict]:
    """The former validation table (``FactIRL.validation_``, deprecated) of a ``cv_results_``:
    one dict per candidate with ``n_primitives``, ``residual_penalty``, ``score``, ``score_std``,
    ``fold_scores`` (the folds scored), ``task_scores`` (the tasks scored, by task index) and ``chosen``."""
    splits = sorted((k for k in results if k.startswith("split") and k.endswith("_test_score")),
                    key=lambda k: int(k[5:-11]))
    tasks = sorted((k for k in results if k.startswith("task") and k.endswith("_test_score")), key=lambda k: int(k[4:-11]))
    rows = []
    for i in range(len(results["param_n_primitives"])):
        folds = [float(results[k][i]) for k in splits if np.isfinite(results[k][i])]
        per_task = [float(results[k][i]) for k in tasks if np.isfinite(results[k][i])]
        rows.append({"n_primitives": int(results["param_n_primitives"][i]),
                     "residual_penalty": float(results["param_residual_penalty"][i]),
                     "score": float(results["mean_test_score"][i]), "score_std": float(results["std_test_score"][i]),
                     "fold_scores": folds, "task_scores": per_task, "chosen": bool(results["chosen"][i])})
    return rows


#: the keys every ``cv_results_`` has (:func:`cv_results`), each an array of one entry per candidate
CV_RESULTS_KEYS = ("param_n_primitives", "param_residual_penalty", "mean_test_score", "std_test_score",
                   "rank_test_score", "n_splits_scored", "chosen")
#: the keys of a row of the former validation table (:func:`validation_rows`)
ROW_KEYS = ("n_primitives", "residual_penalty", "score", "score_std", "fold_scores", "task_scores", "chosen")


def check_cv_results(results: Any, name: str = "cv_results_") -> None:
    """Refuse a ``cv_results_`` that is not a dict of equal-length arrays with :data:`CV_RESULTS_KEYS` (an edited table).

    Raises
    ------
    ValidationError
        Naming ``name`` and the missing key, or the key whose length differs.
    """
    if not isinstance(results, dict):
        raise ValidationError(f"{name} must be a dict of equal-length arrays (one entry per candidate); got {results!r:.80}")
    missing = [key for key in CV_RESULTS_KEYS if key not in results]
    if missing:
        raise ValidationError(f"{name} has no key {missing[0]!r}: a search's results have {list(CV_RESULTS_KEYS)}")
    m = len(results["param_n_primitives"])
    for key, value in results.items():
        if not hasattr(value, "__len__") or len(value) != m:
            raise ValidationError(f"{name}[{key!r}] must have one entry per candidate ({m}); got {value!r:.60}")
    if m == 0 or int(np.sum(np.asarray(results["chosen"], dtype=bool))) != 1:
        raise ValidationError(f"{name}['chosen'] must mark exactly one candidate; {int(np.sum(results['chosen']))} are")


def rows_cv_results(rows: Any, name: str = "validation_") -> dict[str, Any]:
    """A ``cv_results_`` of rows of the former validation table (a file of 0.1.0, or a table set by hand).

    ``fold_scores`` fill ``split<f>_test_score`` in order and ``task_scores`` (when present)
    ``task<j>_test_score`` in order (NaN beyond a row's own).

    Raises
    ------
    ValidationError
        Naming ``name``, the row and the missing key.
    """
    if not isinstance(rows, (list, tuple)) or not rows:
        raise ValidationError(f"{name} must be a non-empty list of rows (dicts); got {rows!r:.80}")
    for i, row in enumerate(rows):
        if not isinstance(row, dict):
            raise ValidationError(f"{name}[{i}] must be a dict with keys {list(ROW_KEYS)}; got {row!r:.80}")
        missing = [key for key in ROW_KEYS if key not in row and key != "task_scores"]
        if missing:
            raise ValidationError(f"{name}[{i}] has no key {missing[0]!r}: a row has {list(ROW_KEYS)}")
    n_folds = max(len(r["fold_scores"]) for r in rows)
    n_tasks = max(len(r.get("task_scores", [])) for r in rows)
    splits, tasks = np.full((len(rows), n_folds), np.nan), np.full((len(rows), n_tasks), np.nan)
    for i, r in enumerate(rows):
        splits[i, :len(r["fold_scores"])] = r["fold_scores"]
        tasks[i, :len(r.get("task_scores", []))] = r.get("task_scores", [])
    scored = np.array([len(r["fold_scores"]) for r in rows], dtype=np.int64)
    mean = np.array([r["score"] for r in rows], dtype=np.float64)
    order = np.lexsort((mean, -scored))
    rank = np.empty(len(rows), dtype=np.int64)
    rank[order] = np.arange(1, len(rows) + 1)
    return {"param_n_primitives": np.array([r["n_primitives"] for r in rows], dtype=np.int64),
            "param_residual_penalty": np.array([r["residual_penalty"] for r in rows], dtype=np.float64),
            "params": [{"n_primitives": int(r["n_primitives"]), "residual_penalty": float(r["residual_penalty"])}
                       for r in rows],
            "mean_test_score": mean, "std_test_score": np.array([r["score_std"] for r in rows], dtype=np.float64),
            "rank_test_score": rank, **{f"split{f}_test_score": splits[:, f] for f in range(n_folds)},
            **{f"task{j}_test_score": tasks[:, j] for j in range(n_tasks)}, "n_splits_scored": scored,
            "chosen": np.array([bool(r["chosen"]) for r in rows])}


def plot_validation(model: Any, ax: Any = None) -> Any:
    """Plot ``model.cv_results_``: mean held-out score (error bars: the folds' spread) against
    lambda, one line per k; the chosen candidate circled. Needs matplotlib.

    Returns
    -------
    matplotlib.axes.Axes

    Raises
    ------
    ValidationError
        The model has no ``cv_results_``, or it lacks a key the plot reads or its arrays differ
        in length (an edited table; :func:`check_cv_results`), naming the key.
    """
    if not hasattr(model, "cv_results_"):
        raise ValidationError("this model has no cv_results_: fit it with n_primitives='auto' or residual_penalty='auto'")
    check_cv_results(model.cv_results_)
    rows = validation_rows(model.cv_results_)
    import matplotlib.pyplot as plt

    if ax is None:
        ax = plt.figure().add_subplot()
    finite = [r["residual_penalty"] for r in rows if np.isfinite(r["residual_penalty"]) and r["residual_penalty"] > 0]
    lo = min(finite, default=1e-2) / 10.0
    hi = max(finite, default=1.0) * 10.0

    def x_of(lam):
        return hi if lam == np.inf else lo if lam == 0.0 else lam

    for k in sorted({r["n_primitives"] for r in rows}):
        mine = sorted((r for r in rows if r["n_primitives"] == k), key=lambda r: x_of(r["residual_penalty"]))
        ax.errorbar([x_of(r["residual_penalty"]) for r in mine], [r["score"] for r in mine],
                    yerr=[r["score_std"] for r in mine], marker="o", label=f"k = {k}")
    chosen = [r for r in rows if r["chosen"]]
    for r in chosen:
        ax.plot([x_of(r["residual_penalty"])], [r["score"]], "o", markersize=14, fillstyle="none", color="k")
    ax.set_xscale("log")
    ax.set_xlabel("residual penalty lambda (left end: 0, right end: inf)")
    ax.set_ylabel("held-out score (lower is better)")
    ax.legend()
    return ax

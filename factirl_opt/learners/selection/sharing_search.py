"""The search that chooses how much to share, as a component: :class:`SharingSearch`.

``FactIRL(n_primitives="auto", residual_penalty="auto", sharing_search=SharingSearch(...))``:
the folds over tasks (``cv``), the candidate grids, the route (how the candidates are fitted
and which folds each is scored on), the held-out score and the choice rule are the search's
parameters, and the results a ``cv_results_`` table in the manner of scikit-learn's
``GridSearchCV`` (a dict of equal-length arrays, one row per candidate, ready for
``pandas.DataFrame``). The engine is :func:`factirl_opt.learners.selection.search.search_sharing`, the routes those of
:mod:`~factirl_opt.learners.selection.routes`.

A parameter object and not a separate estimator (``LassoCV`` / ``GridSearchCV``): the
``"auto"`` values are FactIRL's own parameters, one of them may be fixed while the other is
searched, the search shares FactIRL's flat start between its candidates and the final fit,
and the fitted model is a FactIRL (``transfer``, ``save_model``) whatever chose its k. A
wrapper estimator would have to forward all of that; a parameter travels with ``clone``,
``get_params(deep=True)`` (``sharing_search__cv``), ``set_params`` and persistence. FactIRL's fit
with ``"auto"`` values is :func:`fit_auto`: the search, then the fit of the chosen pair on every task.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..._validation import check_int
from ...exceptions import FitInterrupted, ValidationError
from ...interruption import INTERRUPTED, raise_interrupted, warn_interrupted
from ...objectives.residuals import check_residual_penalty
from ...tasks.task_set import TaskSet
from ..estimator import Estimator
from .folds import N_FOLDS
from .results import SearchResult, cv_results
from .routes import AUTO, DEFAULT_ROUTE, K_CANDIDATES, LAMBDA_CANDIDATES, ROUTES, get_route, route_rule
from .rules import RULES, SHARE_LEVEL
from .scores import DEFAULT_SCORE, N_TRANSFER_DEMOS, SCORES
from .search import RACE_MARGIN, fixed_learner, own_flat_start_rewards, search_sharing

__all__ = ["SharingSearch", "fit_auto", "is_auto"]


def _is_default(value: Any, default: Any) -> bool:
    """Whether a search parameter's ``value`` is its (tuple or number) ``default``."""
    if isinstance(value, (list, tuple)):
        return tuple(value) == default
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        return False
    return bool(value == default)


class SharingSearch(Estimator):
    """How ``FactIRL`` chooses k and the residual penalty lambda for its ``"auto"`` values.

    K-fold over tasks: for each fold and candidate ``(k, lambda)`` a FactIRL with those values
    is fitted on the other folds' tasks, each held-out task is transferred from its first
    ``n_transfer_demos`` demonstrations and scored on the others (docs/maths.md §8a; the user
    guide's page on choosing how much to share).

    Parameters
    ----------
    cv : int, splitter or iterable, default=3
        The folds over tasks: a number of folds (a permutation of the tasks drawn from the
        learner's ``rng``), a scikit-learn splitter (``split(X)``; its test indices), or an
        iterable of ``(train, test)`` pairs or of held-out index arrays
        (:func:`~factirl_opt.learners.selection.task_folds`). Only an int is saved by ``save_model``.
    n_primitives_grid : tuple of int, default=(1, 2, 4, 8, 16)
        Candidate k (those up to the reward directions the features span and the training tasks
        of a fold); then k is bisected around a chosen shared candidate. The ``"evidence"`` route
        reads its candidates off the flat rewards' evidence instead, and refuses another grid
        (:data:`~factirl_opt.learners.selection.routes.ROUTE_UNREAD`: every route refuses a setting it does not read).
    residual_penalty_grid : tuple of float, default=(inf, 1.0, 0.01, 0.0)
        Candidate lambda, from the factorial model (inf) to the flat one (0).
    route : str, default="evidence"
        :data:`~factirl_opt.learners.selection.routes.ROUTES`: how candidates are fitted and on which folds they are scored.
    score : str, default="likelihood"
        The held-out score (:data:`~factirl_opt.learners.selection.SCORES`). ``"deviation"``: each
        held-out transfer's deviation (the benchmark's measure) under a reference reward of the
        task, the flat learner's reward of the demonstrations the transfer did not see, fitted
        once per search (:func:`~factirl_opt.learners.selection.held_out_deviation`); the other
        scores judge how the transferred reward explains those demonstrations.
    rule : str or None, default=None
        The choice rule (:data:`~factirl_opt.learners.selection.RULES`); None: the route's own
        (:func:`~factirl_opt.learners.selection.routes.route_rule`: ``"fewest-within-se"`` on the ``"evidence"`` route,
        ``"significant-gain"`` on the others), the one its benchmark figures were measured with.
    n_transfer_demos : int, default=1
        Demonstrations a held-out task is transferred from.
    race_margin : float, default=0.1
        A race keeps, after the first fold, the candidates within this fraction of the best
        (the ``"race"``, ``"race-warm"`` and ``"short"`` routes).
    share_level : float, default=0.05
        Level of the one-sided paired t-tests of the rule.
    """

    def __init__(self, cv: Any = N_FOLDS, *, n_primitives_grid: tuple = K_CANDIDATES,
                 residual_penalty_grid: tuple = LAMBDA_CANDIDATES, route: str = DEFAULT_ROUTE,
                 score: str = DEFAULT_SCORE, rule: str | None = None, n_transfer_demos: int = N_TRANSFER_DEMOS,
                 race_margin: float = RACE_MARGIN, share_level: float = SHARE_LEVEL) -> None:
        self.cv = cv
        self.n_primitives_grid = n_primitives_grid
        self.residual_penalty_grid = residual_penalty_grid
        self.route = route
        self.score = score
        self.rule = rule
        self.n_transfer_demos = n_transfer_demos
        self.race_margin = race_margin
        self.share_level = share_level

    def check(self) -> None:
        """Validate the parameters (``ValidationError`` naming the first bad one)."""
        route = get_route(self.route)
        if self.score not in SCORES:
            raise ValidationError(f"score must be one of {SCORES}; got {self.score!r}")
        if self.rule is not None and self.rule not in RULES:
            raise ValidationError(f"rule must be one of {RULES} or None; got {self.rule!r}")
        ks = list(self.n_primitives_grid) if isinstance(self.n_primitives_grid, (list, tuple)) else None
        if not ks or any(isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1 for k in ks):
            raise ValidationError(f"n_primitives_grid must be a non-empty tuple of integers >= 1; got {self.n_primitives_grid!r}")
        lams = list(self.residual_penalty_grid) if isinstance(self.residual_penalty_grid, (list, tuple)) else None
        if not lams or any(isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v) or v < 0 for v in lams):
            raise ValidationError(f"residual_penalty_grid must be a non-empty tuple of numbers >= 0 (inf allowed); got "
                                  f"{self.residual_penalty_grid!r}")
        for name in ("race_margin", "share_level"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < (1 if name == "share_level" else math.inf):
                raise ValidationError(f"{name} must be a number >= 0{' and < 1' if name == 'share_level' else ''}; got {value!r}")
        defaults = {"n_primitives_grid": tuple(K_CANDIDATES), "race_margin": RACE_MARGIN, "cv": N_FOLDS}
        for name, why in route.unread.items():
            value = getattr(self, name)
            if not _is_default(value, defaults[name]):
                readers = [r for r in ROUTES if name not in ROUTES[r].unread]
                raise ValidationError(f"{name}={value!r} is not read by the {self.route!r} route ({why}): leave it at "
                                      f"its default {defaults[name]!r}, or take a route that reads it: {readers}")

    @property
    def needs_flat_start(self) -> bool:
        """Whether the route's candidates are PCA starts of the flat rewards (no alternating fit),
        so that ``FactIRL.fit`` computes the flat rewards whatever its ``init``."""
        return get_route(self.route).candidate_max_iter == 0

    def search(self, learner: Any, tasks: TaskSet, flat_rewards: Any = None) -> SearchResult:
        """Choose ``(k, lambda)`` for ``learner`` (a FactIRL with ``"auto"`` values).

        Parameters
        ----------
        learner : FactIRL
        tasks : TaskSet
            Every task, as ``FactIRL.fit`` builds them (:func:`~factirl_opt.learners.fitting.learner_tasks`).
        flat_rewards : optional
            Every task's flat rewards, the PCA start of every candidate
            (:func:`~factirl_opt.learners.selection.flat_start_rewards`).

        Returns
        -------
        SearchResult
            Its :func:`cv_results` is the table ``FactIRL.cv_results_``.
        """
        self.check()
        return search_sharing(learner, tasks, flat_rewards, search=self.route, score=self.score, cv=self.cv,
                              k_grid=tuple(self.n_primitives_grid), lam_grid=tuple(self.residual_penalty_grid),
                              n_transfer_demos=self.n_transfer_demos, race_margin=self.race_margin,
                              share_level=self.share_level, rule=route_rule(self.route, self.rule))


def is_auto(value: Any) -> bool:
    """Whether a hyper-parameter asks for validation (:mod:`factirl_opt.learners.selection`)."""
    return isinstance(value, str) and value == AUTO


def fit_auto(learner: Any, tasks: TaskSet, flat_rewards: Any) -> Any:
    """``learner.fit`` (a FactIRL) with ``n_primitives`` and/or ``residual_penalty`` chosen by validation
    (its ``sharing_search``, :func:`~factirl_opt.learners.selection.search.search_sharing`), then the fit of
    the chosen pair on every task of ``tasks`` (the task set ``fit`` built); returns ``learner``, fitted,
    with ``cv_results_``."""
    if not is_auto(learner.n_primitives):
        check_int(learner.n_primitives, "n_primitives", minimum=1)
    check_residual_penalty(learner.residual_penalty)
    start = learner._group("start")
    if isinstance(start.init, tuple):
        raise ValidationError("n_primitives='auto' or residual_penalty='auto' fits candidates on subsets of the tasks and "
                              "with other k: init must be 'pca' or 'random', not a (D0, H0) tuple")
    if flat_rewards is not None:
        tasks.basis.start_points_from_rewards(flat_rewards, tasks.n_tasks)  # fit's check, before the folds split them
    for name in [a for a in vars(learner) if a.endswith("_") and not a.startswith("_")]:
        delattr(learner, name)  # a failed validation leaves no fitted state of an earlier fit
    search = SharingSearch() if learner.sharing_search is None else learner.sharing_search
    if not isinstance(search, SharingSearch):
        raise ValidationError(f"sharing_search must be a SharingSearch or None; got {type(search).__name__}")
    if flat_rewards is None and (start.init == "pca" or search.needs_flat_start):
        try:
            flat_rewards = own_flat_start_rewards(learner, tasks)
        except FitInterrupted as exc:
            warn_interrupted("FactIRL.fit", "in the flat fit that precedes the search of n_primitives or "
                             "residual_penalty, before any candidate: the model stays unfitted", exc.__cause__)
            raise_interrupted(exc, "FactIRL.fit")
    try:
        found = search.search(learner, tasks, flat_rewards)
    except FitInterrupted as exc:
        keep_search(learner, exc.result, tasks.n_tasks, exc.__cause__)
        raise_interrupted(exc, "FactIRL.fit")
    table = cv_results(found)
    execution = learner._group("execution")
    model = fixed_learner(learner, found.n_primitives, found.residual_penalty, execution=execution)
    try:
        model._fit_tasks(tasks, flat_rewards)
    except KeyboardInterrupt:  # the final fit warned and kept its best point: so does this model, with the table
        if adopt(learner, model):
            learner.cv_results_ = table
        raise
    adopt(learner, model)
    learner.cv_results_ = table
    return learner


def adopt(learner: Any, model: Any) -> bool:
    """Give ``learner`` the fitted state of ``model`` (a fixed-value fit of the search), if it has one; whether it had."""
    if not hasattr(model, "dictionary_"):
        return False
    for name, value in vars(model).items():
        if name.endswith("_") and not name.startswith("_"):
            setattr(learner, name, value)
    return True


def keep_search(learner: Any, progress: Any, n: int, cause: BaseException | None) -> None:
    """After an interrupt during the search: keep the best candidate's fit so far and the table so far, and warn."""
    if progress.kept is None:
        warn_interrupted("FactIRL.fit", "during the search of n_primitives or residual_penalty, before any "
                         "candidate was fitted: the model stays unfitted", cause)
        return
    (k, lam), model, train = progress.kept
    adopt(learner, model)
    learner.status_ = learner.stop_reason_ = INTERRUPTED
    if progress.rows:
        learner.cv_results_ = cv_results(progress.result())
        what = f"the fit of ({k}, {lam:g}), the best candidate scored so far"
    else:
        what = f"the fit of ({k}, {lam:g}), the last candidate fitted (none was scored yet)"
    warn_interrupted("FactIRL.fit", f"during the search of n_primitives or residual_penalty: kept {what}, "
                     f"fitted on {len(train)} of the {n} tasks (a fold's training tasks: rewards_ and "
                     f"coefficients_ are theirs), and the validation table so far", cause)

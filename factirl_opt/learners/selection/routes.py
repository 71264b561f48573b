"""The routes of the sharing search, one small class each, in one registry (:data:`ROUTES`).

A route says how the search of :func:`~factirl_opt.learners.selection.search.search_sharing` runs:
how it proposes its candidates, whether it races them over the folds, whether a candidate
warm-starts from its predecessor or a flat model takes another candidate's fit, the budgets of
its candidate fits and held-out transfers, where it steps k after a shared choice, whether it
confirms that choice by full fits, and the choice rule it was benchmarked with. The route names
are the one vocabulary of the search; :data:`DEFAULT_ROUTE` is the one default. The candidate pairs of a
learner's ``"auto"`` values (:func:`sharing_candidates`) are what the routes propose from.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np

from ...exceptions import ValidationError
from ...tasks.task_set import TaskSet
from ..fitting import resolve_step_solver
from ..solver_settings import estimator_solvers
from .evidence import (confirmation_primitives, evidence_penalties, evidence_primitives, flat_start_evidence,
                       plausible_ranks)
from .rules import DEFAULT_RULE, RULES

__all__ = ["AUTO", "K_CANDIDATES", "LAMBDA_CANDIDATES", "sharing_candidates", "max_primitives", "Route", "RaceRoute", "FullRoute", "RaceWarmRoute", "ShortRoute", "PCARoute", "EvidenceRoute", "ROUTES",
           "DEFAULT_ROUTE", "ROUTE_RULES", "ROUTE_UNREAD", "route_rule", "get_route", "SHORT_MAX_ITER",
           "SCREEN_TRANSFER_MAX_ITER"]

#: the value of ``n_primitives`` / ``residual_penalty`` that asks for validation
AUTO = "auto"
#: candidate numbers of primitives (those <= min(p, number of training tasks of a fold) are tried)
K_CANDIDATES = (1, 2, 4, 8, 16)
#: candidate residual penalties, from the factorial model (inf) to the flat one (0)
LAMBDA_CANDIDATES = (np.inf, 1.0, 1e-2, 0.0)

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


def max_primitives(tasks: TaskSet, folds: Sequence[np.ndarray]) -> int:
    """The largest k a candidate may have: the reward directions the task set's basis spans
    (:meth:`~factirl_opt.tasks.basis.RewardBasis.rank`, at most the reward dimension p), and the
    training tasks of the smallest fold's fit."""
    return min(tasks.basis.rank(tasks.n_tasks), min(tasks.n_tasks - len(f) for f in folds))


#: outer iterations of each candidate fit on the ``"short"`` route
SHORT_MAX_ITER = 10
#: steps of each held-out task's transfer on the ``"short"``, ``"pca"`` and ``"evidence"`` routes
#: (the learner's ``transfer_max_iter`` elsewhere): the tempered held-out likelihood judges the
#: transferred reward's direction, which the first steps set; from one demonstration the rest of a
#: transfer mostly grows the reward's scale toward the saturated policy
SCREEN_TRANSFER_MAX_ITER = 20
_EVERY_FOLD = "it scores every candidate on every fold"


class Route:
    """A route of the sharing search: its particulars as class attributes and methods.

    Attributes
    ----------
    name : str
        Its key in :data:`ROUTES`.
    races : bool
        Every candidate on the first fold, only the contenders (within ``race_margin`` of the
        best there, and the flat model) on the others.
    warm : bool
        A candidate starts from its predecessor's fit on the fold (the same k, the next larger
        lambda), with ``WARM_BUDGET * max_iter`` outer iterations.
    reuse : bool
        ``lambda = 0`` takes the fold's last fitted candidate instead of a fit of its own.
    score_alone : bool
        Whether a single candidate is scored (False: it is chosen unscored).
    candidate_max_iter, transfer_max_iter : int or None
        Budgets of each candidate fit and held-out transfer (None: the learner's).
    rule : str
        The choice rule taken when none is given (the one the route was benchmarked with).
    unread : dict
        The parameters of ``SharingSearch`` the route does not read, with why.
    """

    name: ClassVar[str] = ""
    races: ClassVar[bool] = False
    warm: ClassVar[bool] = False
    reuse: ClassVar[bool] = True
    score_alone: ClassVar[bool] = True
    candidate_max_iter: ClassVar[int | None] = None
    transfer_max_iter: ClassVar[int | None] = None
    rule: ClassVar[str] = DEFAULT_RULE
    unread: ClassVar[dict[str, str]] = {}

    def candidates(self, learner: Any, tasks: TaskSet, flat_rewards: Any, k_max: int,
                   k_grid: Sequence[int], lam_grid: Sequence[float], n_train: int) -> list[tuple[int, float]]:
        """The first candidates (:func:`sharing_candidates` of the grids)."""
        return sharing_candidates(learner, k_max, k_grid, lam_grid)

    def below(self, k: int, tried: Sequence[int], k_max: int) -> list[int]:
        """The k tried next below a shared choice of ``k``, before the bisection ([]: none)."""
        return []

    def confirmation(self, k: int, k_max: int, n_train: int) -> list[int]:
        """The k refitted in full around a shared choice of ``k``, their screen scores replaced ([]: none)."""
        return []

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class RaceRoute(Route):
    """``"race"``: every candidate on the first fold, the contenders on the others, each fitted with the learner's ``max_iter``."""

    name = "race"
    races = True


class FullRoute(Route):
    """``"full"``: every candidate on every fold."""

    name = "full"
    reuse = False
    unread = {"race_margin": _EVERY_FOLD}


class RaceWarmRoute(RaceRoute):
    """``"race-warm"``: the race, candidates warm-started along lambda."""

    name = "race-warm"
    warm = True


class ShortRoute(RaceRoute):
    """``"short"``: the race with candidate fits of ``SHORT_MAX_ITER`` outer iterations and held-out
    transfers of ``SCREEN_TRANSFER_MAX_ITER`` steps."""

    name = "short"
    candidate_max_iter = SHORT_MAX_ITER
    transfer_max_iter = SCREEN_TRANSFER_MAX_ITER


class PCARoute(FullRoute):
    """``"pca"``: every candidate on every fold, each its PCA start from the training tasks' flat
    rewards (no alternating fit), held-out transfers of ``SCREEN_TRANSFER_MAX_ITER`` steps."""

    name = "pca"
    candidate_max_iter = 0
    transfer_max_iter = SCREEN_TRANSFER_MAX_ITER


class EvidenceRoute(Route):
    """``"evidence"``: k from Minka's evidence of the flat rewards' PCA (:mod:`~factirl_opt.learners.selection.evidence`,
    no fit), then the ``"pca"`` route's cheap scores for that k, half and twice it (at lambda inf, 1
    and 0), then k halved below the smallest and bisected around a shared choice; the flat model
    chosen unscored when no direction is shared or more than half the training tasks of a fold; a
    shared k confirmed by full fits of k - 1, k and k + 1 when a fold has many training tasks per
    primitive (:func:`~factirl_opt.learners.selection.evidence.confirmation_primitives`). Needs the flat rewards."""

    name = "evidence"
    score_alone = False
    candidate_max_iter = 0
    transfer_max_iter = SCREEN_TRANSFER_MAX_ITER
    rule = "fewest-within-se"
    unread = {"n_primitives_grid": "it reads its candidate k off the evidence of the flat rewards' PCA",
              "race_margin": _EVERY_FOLD}

    def candidates(self, learner: Any, tasks: TaskSet, flat_rewards: Any, k_max: int,
                   k_grid: Sequence[int], lam_grid: Sequence[float], n_train: int) -> list[tuple[int, float]]:
        """k from the evidence of the flat start's PCA (:func:`~.evidence.flat_start_evidence`,
        :func:`~.evidence.evidence_primitives`) at the penalties of :func:`~.evidence.evidence_penalties`,
        then the flat model (k = 1); when the tasks share little (the evidence's k is 0, or a plausible
        k more than half the ``n_train`` training tasks of a fold), the flat model alone (or k = 1 at a
        fixed lambda). ``k_grid`` is not read."""
        if flat_rewards is None:
            raise ValidationError("search='evidence' chooses k from the flat start's rewards: give flat_rewards "
                                  "(FactIRL.fit computes them with init='pca')")
        log_evidence, rank = flat_start_evidence(tasks, flat_rewards)
        ks = evidence_primitives(rank, k_max, n_train, largest_plausible=int(plausible_ranks(log_evidence)[-1]))
        lams = evidence_penalties(lam_grid)
        shared = [c for c in sharing_candidates(learner, k_max, ks, lams) if c[1] != 0.0] if ks else []
        flat = [c for c in sharing_candidates(learner, k_max, (1,), lams) if c[1] == 0.0]
        return shared + flat or sharing_candidates(learner, k_max, (1,), lams)[:1]

    def below(self, k: int, tried: Sequence[int], k_max: int) -> list[int]:
        """Half of ``k`` (rounded up) when it is the smallest tried, if within ``[1, k_max]`` and not
        tried; else none. Only down: the evidence of the flat rewards overestimates k with many
        tasks, and the held-out score of PCA starts favours large k (on the README's grid a walk up
        from (10, 1) ended at (17, 1), 13.55 against 12.11; on the grid at 20 tasks, seed 0, at
        (12, 1), 12.58 against 11.96; ``results/which-learner/diagnostics/evidence/README.md``)."""
        step = (k + 1) // 2
        return [step] if k == min(tried) and step not in tried and 1 <= step <= k_max else []

    def confirmation(self, k: int, k_max: int, n_train: int) -> list[int]:
        """:func:`~factirl_opt.learners.selection.evidence.confirmation_primitives`."""
        return confirmation_primitives(k, k_max, n_train)


#: the routes of a search, by name: the one vocabulary of :func:`~.search.search_sharing` and
#: ``SharingSearch(route=...)``
ROUTES: dict[str, Route] = {route.name: route() for route in (
    RaceRoute, FullRoute, RaceWarmRoute, ShortRoute, PCARoute, EvidenceRoute)}
#: the route ``SharingSearch()`` takes: the cheapest that meets the which-learner benchmark's quality
#: (``results/which-learner/README.md``)
DEFAULT_ROUTE = "evidence"
#: the choice rule of each route whose own is not :data:`~.rules.DEFAULT_RULE`
ROUTE_RULES: dict[str, str] = {name: route.rule for name, route in ROUTES.items() if route.rule != DEFAULT_RULE}
#: the parameters of ``SharingSearch`` each route does not read, with why: on that route a value
#: other than the default is refused by name (a search never ignores a setting silently)
ROUTE_UNREAD: dict[str, dict[str, str]] = {name: dict(route.unread) for name, route in ROUTES.items() if route.unread}


def get_route(route: str) -> Route:
    """The route of that name in :data:`ROUTES`.

    Raises
    ------
    ValidationError
        An unknown ``route``.
    """
    if not isinstance(route, str) or route not in ROUTES:
        raise ValidationError(f"route must be one of {tuple(ROUTES)}; got {route!r}")
    return ROUTES[route]


def route_rule(route: str, rule: str | None = None) -> str:
    """The choice rule a search on ``route`` takes: ``rule`` if given, else the route's own
    (:data:`ROUTE_RULES`, else :data:`~factirl_opt.learners.selection.rules.DEFAULT_RULE`).

    Raises
    ------
    ValidationError
        An unknown ``route`` or ``rule``.
    """
    chosen = get_route(route).rule if rule is None else rule
    if chosen not in RULES:
        raise ValidationError(f"rule must be one of {RULES} or None; got {rule!r}")
    return chosen

"""The engine of the sharing search: candidates fitted on each fold's training tasks, each held-out task
transferred and scored (:func:`score_candidates`), on the folds its route says (:mod:`~.routes`), then
chosen by a rule (:mod:`~.rules`) and k bisected around a shared choice (:func:`search_sharing`).

Cost. The flat fit of the PCA start is computed once for all tasks and indexed by fold: the flat
learner is separable over tasks (:mod:`solvers.separable`), so a task's flat reward is the same
whichever tasks share the fit. A candidate then costs one alternating fit on ``(K-1)/K`` of the
tasks per fold and one transfer; ``lambda = 0`` (the flat model: the dictionary plays no part) is
tried once, with the smallest k, and may take the dictionary of another candidate.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..._deprecation import warn_once
from ..._validation import check_int, check_tol
from ...exceptions import ConvergenceWarning, FitInterrupted, ValidationError
from ...tasks.task_set import TaskSet
from ..estimator import clone
from ..fitting import learner_entry, learner_tasks
from ..gradirl import GradIRL
from ..solver_settings import SolverSettings
from ..start import flat_solver
from .folds import N_FOLDS, task_folds
from .results import SearchResult, _with_reasons, score_rows
from .routes import AUTO, DEFAULT_ROUTE, K_CANDIDATES, LAMBDA_CANDIDATES, ROUTES, max_primitives
from .rules import RULES, SHARE_LEVEL, _choice
from .scores import DEFAULT_SCORE, N_TRANSFER_DEMOS, SCORES, _score, needs_reference

__all__ = ["RACE_MARGIN", "WARM_BUDGET", "choose_sharing", "search_sharing", "SearchProgress", "score_candidates",
           "bisection_midpoints", "fixed_learner", "flat_start_rewards", "own_flat_start_rewards", "reference_rewards"]

#: a race keeps, after the first fold, the candidates whose score there is within this fraction of the best one's
RACE_MARGIN = 0.1
#: a warm-started candidate's outer iterations, as a fraction of ``max_iter`` (at least one)
WARM_BUDGET = 0.5


#: the engine's former vocabulary, retired: its routes are :data:`~.routes.ROUTES`, with one default
_RETIRED = {"SEARCHES": ("full", "race", "race-warm", "evidence"), "DEFAULT_SEARCH": "race"}


def __getattr__(name: str) -> Any:
    if name in _RETIRED:
        warn_once(f"name:selection.{name}", f"{name} is deprecated: the routes of the sharing search are "
                  "factirl_opt.learners.selection.ROUTES, with one default, DEFAULT_ROUTE", stacklevel=None)
        return _RETIRED[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def choose_sharing(learner: Any, mdp: Any, demos_per_task: Any, flat_rewards: Any = None,
                   search: str = "race", score: str = DEFAULT_SCORE, **options: Any) -> tuple[int, float, list[dict]]:
    """Deprecated: ``search_sharing(...).as_tuple()``, the search's ``(k, lambda, rows)``
    (:func:`search_sharing`, with the same arguments); the search as a component is
    :class:`~factirl_opt.learners.selection.SharingSearch`."""
    warn_once("adaptive.choose_sharing", "factirl_opt.learners.adaptive.choose_sharing is deprecated: "
                                         "search_sharing(...).as_tuple() gives its (k, lambda, rows); "
                                         "SharingSearch(route=..., score=...).search(...) is the search as a component")
    tasks = learner_tasks(learner, mdp, demos_per_task)
    return search_sharing(learner, tasks, flat_rewards, search=search, score=score, **options).as_tuple()


@learner_entry  # its candidates' fits and transfers plan with the caches of one fit (in FactIRL.fit: its own)
def search_sharing(learner: Any, tasks: TaskSet, flat_rewards: Any = None, *,
                   search: str = DEFAULT_ROUTE, score: str = DEFAULT_SCORE, cv: Any = N_FOLDS,
                   k_grid: Sequence[int] = K_CANDIDATES, lam_grid: Sequence[float] = LAMBDA_CANDIDATES,
                   n_transfer_demos: int = N_TRANSFER_DEMOS, race_margin: float = RACE_MARGIN,
                   share_level: float = SHARE_LEVEL, rule: str | None = None,
                   candidate_max_iter: int | None = None, transfer_max_iter: int | None = None) -> SearchResult:
    """Choose ``(k, lambda)`` for ``learner`` (a FactIRL with ``"auto"`` values) by K-fold over
    tasks, every setting of the search given, with the folds and scores.

    The route (:data:`~factirl_opt.learners.selection.routes.ROUTES`, one class each) says how the
    candidates are proposed and fitted and on which folds each is scored. In a race
    (:class:`~factirl_opt.learners.selection.routes.RaceRoute`) every candidate is scored on the first
    fold, and only those whose score there is at most ``(1 + race_margin)`` times the best one, and
    the flat model, on the others: a candidate far behind on one fold has no chance of the best mean
    (F-race, successive halving). The pruned candidates keep their first fold's scores; the choice is
    among the candidates scored on every fold. ``lambda = 0`` may take the fold's last fitted
    candidate instead of a fit of its own (its transfer, the flat learner's, does not use the
    dictionary). Measured (results/README.md): on the ``tiny`` grid the race cost 19-21x one fixed
    fit against 26-30x for the full search, with the same choice, on the ``quick`` grid 11.9x
    against 30.3x; the warm race 16-18x on ``tiny``, but its shortened fits moved the scores enough
    to change the choice on both seeds, to pairs that transferred worse.

    The choice: the ``rule`` (:mod:`~factirl_opt.learners.selection.rules`). Then, if k is ``"auto"`` and the choice shares (``lambda > 0``), a bisection of k at the
    chosen lambda: the midpoints between the chosen k and its nearest tried neighbours
    (:func:`bisection_midpoints`; 8 between 4 and 16 gives 6 and 12) are scored on every fold and the choice
    is made again over the whole table; while it moves to a midpoint, the step repeats around it.
    On the paper's grid with 100 tasks (seed 0) the race chose (8, 1) and transferred at 5.89,
    where k = 6 and k = 5 without residuals transfer at 5.06 and 4.87
    (``results/which-learner/README.md``).

    Parameters
    ----------
    learner : FactIRL
        Its other hyper-parameters are used by every candidate fit.
    tasks : TaskSet
        Every task, as ``FactIRL.fit`` built them; folds and held-out tasks are rows of it (``tasks.subset``).
    flat_rewards : optional
        The flat learner's rewards of every task (:func:`flat_start_rewards`), the PCA start of
        every candidate (``init="pca"``); None: each candidate fit runs its own flat fit.
    search : str, default=DEFAULT_ROUTE
        The route, a name of :data:`~factirl_opt.learners.selection.routes.ROUTES`. After the
        bisection, a route may confirm a shared choice (the ``"evidence"`` route: k - 1, k and
        k + 1 refitted with the learner's ``max_iter``, their screen scores replaced, and the rule
        chooses among them).
    score, cv, k_grid, lam_grid, n_transfer_demos, race_margin, share_level, rule
        As ``SharingSearch``'s ``score``, ``cv`` (an int's permutation drawn from ``learner.rng``),
        ``n_primitives_grid``, ``residual_penalty_grid``, ``n_transfer_demos``, ``race_margin``,
        ``share_level`` and ``rule`` (None: the route's own).
    candidate_max_iter : int or None
        Outer iterations of each candidate fit (0: the candidate is its PCA start, from the
        training tasks' flat rewards); None: the route's (the learner's ``max_iter`` on the routes
        that set none). The final fit of ``FactIRL.fit`` always has the learner's.
    transfer_max_iter : int or None
        Steps of each held-out task's transfer (None: the route's, else the learner's ``transfer_max_iter``).

    Returns
    -------
    SearchResult

    Raises
    ------
    ValidationError
        Fewer than 2 tasks, or a task with at most ``n_transfer_demos`` demonstrations (no
        demonstration left to score it on), or an unknown ``search``, ``score`` or ``rule``.
    """
    if not isinstance(search, str) or search not in ROUTES:
        raise ValidationError(f"search must be one of {tuple(ROUTES)}; got {search!r}")
    route = ROUTES[search]
    candidate_max_iter = route.candidate_max_iter if candidate_max_iter is None else candidate_max_iter
    transfer_max_iter = route.transfer_max_iter if transfer_max_iter is None else transfer_max_iter
    rule = route.rule if rule is None else rule
    if score not in SCORES:
        raise ValidationError(f"score must be one of {SCORES}; got {score!r}")
    if rule not in RULES:
        raise ValidationError(f"rule must be one of {RULES}; got {rule!r}")
    t = check_int(n_transfer_demos, "n_transfer_demos", minimum=1)
    if candidate_max_iter is not None:
        check_int(candidate_max_iter, "candidate_max_iter", minimum=0)
    if transfer_max_iter is not None:
        check_int(transfer_max_iter, "transfer_max_iter", minimum=0)
    n = tasks.n_tasks
    if n < 2:
        raise ValidationError(f"choosing n_primitives or residual_penalty by validation needs at least 2 tasks; got {n}")
    short = [i for i in range(n) if len(tasks.demos_per_task[i]) <= t]
    if short:
        raise ValidationError(f"choosing n_primitives or residual_penalty by validation transfers each held-out task from {t} "
                              f"demonstration(s) and scores it on the others: task {short[0]} has "
                              f"{len(tasks.demos_per_task[short[0]])}; give every task at least {t + 1}")
    folds = task_folds(n, cv, learner.rng)
    k_max = max_primitives(tasks, folds)
    n_train = n - max(len(f) for f in folds)  # the fewest training tasks of a fold
    progress = SearchProgress()
    progress.folds, progress.n_tasks = folds, n
    scores = progress.scores
    run = functools.partial(score_candidates, learner, tasks, flat_rewards, n_transfer_demos=t,
                            score=score, candidate_max_iter=candidate_max_iter,
                            transfer_max_iter=transfer_max_iter, progress=progress)
    choice = functools.partial(_choice, share_level=share_level, rule=rule)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)  # budgets of the candidates: the final fit warns
            candidates = route.candidates(learner, tasks, flat_rewards, k_max, k_grid, lam_grid, n_train)
            first = folds[:1] if route.races and len(folds) > 1 else folds
            warm, reuse = route.warm, route.reuse
            if not route.score_alone and len(candidates) == 1:  # nothing to compare it with: chosen unscored
                scores[candidates[0]] = []
            else:
                run(first, candidates, warm=warm, reuse=reuse)
            if not scores:
                raise _unfittable(progress.unscored)
            if len(first) < len(folds):
                lead = min(np.mean(v[0]) for v in scores.values())
                contenders = [c for c in candidates
                              if np.mean(scores[c][0]) <= lead + race_margin * abs(lead) or c[1] == 0.0]
                if len(contenders) > 1:  # else the flat model alone is left: it is the choice, scored on one fold
                    run(folds[1:], contenders, warm=warm, reuse=reuse)
            rows = score_rows(scores)
            best = choice(rows)
            for step in (route.below, bisection_midpoints):  # the route's steps down, then the bisection
                while learner.n_primitives == AUTO and rows[best]["residual_penalty"] != 0.0:
                    k, lam = rows[best]["n_primitives"], rows[best]["residual_penalty"]
                    more = step(k, [c[0] for c in scores if c[1] == lam], k_max)
                    if not more:
                        break
                    run(folds, [(m, lam) for m in more], warm=False, reuse=False)
                    rows = score_rows(scores)
                    best = choice(rows)
                    if rows[best]["n_primitives"] == k:
                        break
            if learner.n_primitives == AUTO and rows[best]["residual_penalty"] != 0.0:
                k, lam = rows[best]["n_primitives"], rows[best]["residual_penalty"]
                trio = [(m, lam) for m in route.confirmation(k, k_max, n_train)]
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
        raise FitInterrupted(progress.interrupted(), "the sharing search") from cause
    rows = _with_reasons(rows, progress.unscored)
    rows[best]["chosen"] = True
    return SearchResult(rows[best]["n_primitives"], rows[best]["residual_penalty"], rows, folds, scores, n,
                        dict(progress.unscored))


class SearchProgress:
    """What a search of :func:`search_sharing` has done so far: the ``result`` of the
    :class:`~factirl_opt.exceptions.FitInterrupted` it raises when interrupted.

    Attributes
    ----------
    scores : dict
        ``{(k, lambda): [array of per-task held-out scores, one per fold scored]}``.
    unscored : dict
        ``{(k, lambda): reason}``: the candidates that could not be fitted on a fold (scored no further).
    fits : dict
        ``{(k, lambda): FactIRL}``: each candidate's last fit (on the training tasks of the last
        fold it was scored on, ``train_tasks[(k, lambda)]``); a race's flat model, which takes
        another candidate's fit instead of one of its own, is not among them.
    train_tasks : dict
        ``{(k, lambda): array of int}``: the tasks each fit of ``fits`` was fitted on.
    references : list or None
        The reference rewards of every task of the search (:func:`reference_rewards`), fitted by
        the first score that needs them (``score="deviation"``), then shared by every fold and
        candidate; None until then.
    last : tuple or None
        The candidate fitted last (or being fitted), its model and training tasks: ``((k,
        lambda), FactIRL, tasks)``; None before the first fit.
    rows : list of dict
        After an interrupt: the validation table of the candidates scored so far (as
        :func:`search_sharing` returns it), the kept candidate's row ``chosen``.
    kept : tuple or None
        After an interrupt: ``((k, lambda), FactIRL, tasks)``, the fit kept: the fitted
        candidate of lowest mean score among those scored on the most folds (flat model aside,
        the rule of :func:`search_sharing`); when none was scored, the last candidate's fit
        (complete, or as far as it got if it was interrupted); None when nothing was fitted.
    """

    def __init__(self) -> None:
        self.scores: dict = {}
        self.unscored: dict = {}
        self.fits: dict = {}
        self.train_tasks: dict = {}
        self.references: Any = None
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
        return SearchResult(k, lam, self.rows, self.folds, self.scores, self.n_tasks, dict(self.unscored))

    def interrupted(self) -> "SearchProgress":
        """Fill ``rows`` and ``kept`` from what was done; returns self."""
        fitted = {c: v for c, v in self.scores.items() if c in self.fits}
        if fitted:
            rows = score_rows(fitted)
            best = rows[_choice(rows)]
            pair = (best["n_primitives"], best["residual_penalty"])
            self.kept = (pair, self.fits[pair], self.train_tasks[pair])
            self.rows = score_rows(self.scores, self.unscored)
            for row in self.rows:
                row["chosen"] = (row["n_primitives"], row["residual_penalty"]) == pair
        elif self.last is not None and hasattr(self.last[1], "dictionary_"):
            self.kept = self.last
            self.rows = []
        return self


def _unfittable(unscored: dict) -> ValidationError:
    """The error of a search none of whose candidates could be fitted."""
    reasons = "; ".join(f"(k={k}, lambda={lam}): {why}" for (k, lam), why in unscored.items())
    return ValidationError(f"no candidate of the sharing search could be fitted: {reasons}")


def bisection_midpoints(k: int, tried: Sequence[int], k_max: int) -> list[int]:
    """The midpoints between ``k`` and its nearest tried neighbours, rounded down, not tried yet and
    at most ``k_max``: the next step of a bisection of the number of primitives around the chosen
    one (never beyond the tried range)."""
    below = [j for j in tried if j < k]
    above = [j for j in tried if j > k]
    mids = {(k + e) // 2 for e in ([max(below)] if below else []) + ([min(above)] if above else [])}
    return sorted(m for m in mids if m not in tried and 1 <= m <= k_max and m != k)


@learner_entry
def score_candidates(learner: Any, tasks: TaskSet, flat_rewards: Any, folds: Sequence[np.ndarray],
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
    tasks, flat_rewards
        As in :func:`search_sharing` (every task's).
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
        Outer iterations of each candidate fit, at most the learner's ``max_iter`` (None: that);
        0: each candidate is its PCA start, whatever the learner's ``init``.
    transfer_max_iter : int or None
        Steps of each held-out task's transfer (None: the learner's ``transfer_max_iter``).
    progress : SearchProgress, optional
        Each score is appended to ``progress.scores`` as soon as it is computed, and each fit
        recorded, so an interrupt loses none of them; a score against a reference reward
        (``score="deviation"``) takes ``progress.references``, fitted here when None
        (:func:`reference_rewards`).

    Returns
    -------
    dict
        ``{(k, lambda): [array of per-task scores, one per fold]}``. A candidate whose fit on a
        fold's training tasks raises a ValidationError (e.g. more primitives than that fold's
        features span) is scored no further; ``progress.unscored`` holds its reason.
    """
    n = tasks.n_tasks
    t = n_transfer_demos
    progress = SearchProgress() if progress is None else progress
    if needs_reference(score) and progress.references is None:
        progress.references = reference_rewards(learner, tasks, t)
    budget = learner.max_iter if candidate_max_iter is None else min(candidate_max_iter, learner.max_iter)
    scores: dict = {}
    for held in folds:
        train = np.setdiff1d(np.arange(n), held)
        fitted: dict = {}
        for k, lam in [c for c in candidates if c not in progress.unscored]:
            before = [c for c in fitted if c[0] == k]
            start = fitted[before[-1]] if before else None
            if reuse and lam == 0.0 and fitted:  # the flat model: the dictionary plays no part, no fit
                model = copy.copy(fitted[before[-1] if before else list(fitted)[-1]])
                model.residual_penalty = model.residual_penalty_ = 0.0
            else:
                start = start if warm else None
                pca = {"start": dataclasses.replace(learner._group("start"), init="pca")} if budget == 0 else {}
                model = fixed_learner(learner, k, lam, max_iter=budget, **pca)
                if start is not None:
                    model.start = model._group("start").set_params(init=(start.dictionary_, start.coefficients_))
                    model.max_iter = max(1, int(round(WARM_BUDGET * budget)))
                progress.last = ((k, lam), model, train)
                try:
                    model._fit_tasks(tasks.subset(train), None if flat_rewards is None else [flat_rewards[i] for i in train])
                except ValidationError as exc:  # inputs were checked before the search: this candidate cannot be fitted here
                    fold = len(progress.scores.get((k, lam), []))  # folds are scored in order, across calls (a race's)
                    progress.unscored[k, lam] = f"cannot be fitted on the training tasks of fold {fold}: {exc}"
                    continue
                progress.fits[k, lam], progress.train_tasks[k, lam] = model, train
            fitted[k, lam] = model
            reference = None if progress.references is None else [progress.references[i] for i in held]
            value = _score(model, tasks, held, t, score, transfer_max_iter, reference)
            scores.setdefault((k, lam), []).append(value)
            progress.scores.setdefault((k, lam), []).append(value)
    return scores


def fixed_learner(learner: Any, k: int, lam: float, **params: Any) -> Any:
    """An unfitted, quiet clone of ``learner`` with fixed ``k`` and ``lambda`` (and ``params`` set).

    ``clone(learner).set_params(n_primitives=k, residual_penalty=lam, execution=quiet, **params)``
    (:func:`~factirl_opt.learners.estimator.clone`), ``quiet`` the learner's execution without
    progress bars or callback.
    """
    quiet = learner._group("execution").quiet()
    return clone(learner).set_params(**{"n_primitives": k, "residual_penalty": lam, "execution": quiet, **params})


@learner_entry
def flat_start_rewards(learner: Any, tasks: TaskSet, solver: Any, tol: float, stol: float = 0.0) -> Any:
    """The flat learner of FactIRL's PCA start (its ``solver``, a name or ``(name, options)``, ``tol``
    and saturation rule ``stol``, without the gradient rule, as FactIRL's own flat start) on every
    task of ``tasks`` at once (separable: each task's rewards are those of its own fit)."""
    solver = solver if isinstance(solver, tuple) else (solver, None)
    flat = GradIRL(beta=learner.beta, features=learner.features, max_iter=learner._group("start").flat_max_iter, tol=tol,
                   gtol=0.0, stol=stol, solver=SolverSettings(solver[0], solver[1]), objective=learner.objective,
                   reward=learner.reward, execution=learner._group("execution").quiet())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)  # the PCA start's flat fit does not warn either
        return flat._fit_tasks(tasks).rewards_


def own_flat_start_rewards(learner: Any, tasks: TaskSet) -> Any:
    """:func:`flat_start_rewards` with the learner's own flat start: its flat solver
    (:func:`~factirl_opt.learners.start.flat_solver`) and its start's ``flat_tol`` and ``flat_stol``,
    checked."""
    start = learner._group("start")
    return flat_start_rewards(learner, tasks, flat_solver(learner), check_tol(start.flat_tol, "flat_tol"),
                              check_tol(start.flat_stol, "flat_stol"))


@learner_entry
def reference_rewards(learner: Any, tasks: TaskSet, n_transfer_demos: int = N_TRANSFER_DEMOS) -> Any:
    """The reference reward of every task for ``score="deviation"``: the flat learner's reward of
    its scoring demonstrations (all but the first ``n_transfer_demos``, those a held-out transfer
    does not see), as FactIRL's flat start fits it (:func:`own_flat_start_rewards`).

    The flat learner is separable over tasks, so one fit on every task gives each task the reward
    it would have alone: a search fits it once, whatever its folds and candidates. Its cost on
    the paper's grid at 20 tasks: 0.75 s of CPU, against about 4 s for one candidate's fit on a
    fold (``results/which-learner/diagnostics/predicted/README.md``).

    Parameters
    ----------
    learner : FactIRL
    tasks : TaskSet
        Every task of the search; each has more than ``n_transfer_demos`` demonstrations.
    n_transfer_demos : int, default=N_TRANSFER_DEMOS

    Returns
    -------
    ndarray, shape (n, S, A), or list of n (S_i, A) arrays
        As ``GradIRL.rewards_``.

    Raises
    ------
    ValidationError
        A task with at most ``n_transfer_demos`` demonstrations.
    """
    t = check_int(n_transfer_demos, "n_transfer_demos", minimum=1)
    short = [i for i in range(tasks.n_tasks) if len(tasks.demos_per_task[i]) <= t]
    if short:
        raise ValidationError(f"the reference reward of a task is fitted to its demonstrations after the first {t}: task "
                              f"{short[0]} has {len(tasks.demos_per_task[short[0]])}; give every task at least {t + 1}")
    return own_flat_start_rewards(learner, tasks.episodes(t))

"""FactIRL's fit with ``"auto"`` values: the sharing search, then the fit of the chosen pair on every
task, and what an interrupt keeps (the best candidate's fit so far and the table so far)."""

from __future__ import annotations

from typing import Any

from ..._validation import check_int, check_tol
from ...exceptions import FitInterrupted, ValidationError
from ...interruption import INTERRUPTED, raise_interrupted, warn_interrupted
from ...objectives.residuals import check_residual_penalty
from ...tasks.task_set import task_set
from ..factorial_start import flat_solver
from .candidates import AUTO
from .results import cv_results
from .search import fixed_learner, flat_start_rewards
from .sharing_search import SharingSearch

__all__ = ["fit_auto", "is_auto"]


def is_auto(value: Any) -> bool:
    """Whether a hyper-parameter asks for validation (:mod:`factirl_opt.learners.selection`)."""
    return isinstance(value, str) and value == AUTO


def check_flat_rewards(tasks: Any, flat_rewards: Any) -> None:
    """The shape check of ``fit``'s PCA start, made before a search splits ``flat_rewards`` over folds."""
    tasks.basis.start_points_from_rewards(flat_rewards, tasks.n_tasks)


def fit_auto(learner: Any, mdp: Any, demos_per_task: Any, flat_rewards: Any) -> Any:
    """``learner.fit`` (a FactIRL) with ``n_primitives`` and/or ``residual_penalty`` chosen by validation
    (its ``sharing_search``, :func:`~factirl_opt.learners.selection.search.search_sharing`), then the fit of
    the chosen pair on every task; returns ``learner``, fitted, with ``cv_results_``."""
    if not is_auto(learner.n_primitives):
        check_int(learner.n_primitives, "n_primitives", minimum=1)
    check_residual_penalty(learner.residual_penalty)
    start = learner._group("start")
    if isinstance(start.init, tuple):
        raise ValidationError("n_primitives='auto' or residual_penalty='auto' fits candidates on subsets of the tasks and "
                              "with other k: init must be 'pca' or 'random', not a (D0, H0) tuple")
    tasks = task_set(mdp, demos_per_task, learner.features, learner.reward)
    if flat_rewards is not None:
        check_flat_rewards(tasks, flat_rewards)
    for name in [a for a in vars(learner) if a.endswith("_") and not a.startswith("_")]:
        delattr(learner, name)  # a failed validation leaves no fitted state of an earlier fit
    search = SharingSearch() if learner.sharing_search is None else learner.sharing_search
    if not isinstance(search, SharingSearch):
        raise ValidationError(f"sharing_search must be a SharingSearch or None; got {type(search).__name__}")
    if flat_rewards is None and (start.init == "pca" or search.needs_flat_start):
        try:
            flat_rewards = flat_start_rewards(learner, mdp, demos_per_task, flat_solver(learner),
                                              check_tol(start.flat_tol, "flat_tol"),
                                              check_tol(start.flat_stol, "flat_stol"))
        except FitInterrupted as exc:
            warn_interrupted("FactIRL.fit", "in the flat fit that precedes the search of n_primitives or "
                             "residual_penalty, before any candidate: the model stays unfitted", exc.__cause__)
            raise_interrupted(exc, "FactIRL.fit")
    try:
        found = search.search(learner, mdp, demos_per_task, flat_rewards)
    except FitInterrupted as exc:
        keep_search(learner, exc.result, len(tasks.demos_per_task), exc.__cause__)
        raise_interrupted(exc, "FactIRL.fit")
    table = cv_results(found)
    execution = learner._group("execution")
    model = fixed_learner(learner, found.n_primitives, found.residual_penalty, execution=execution)
    try:
        model.fit(mdp, demos_per_task, flat_rewards=flat_rewards)
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

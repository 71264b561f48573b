"""The folds of the sharing search: the held-out tasks of each fold (a fold's tasks are rows of the search's task set)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..._deprecation import warn_once
from ..._validation import as_rng
from ...exceptions import ValidationError
from ...mdp.tabular import TabularMDP
from ...tasks.task_set import per_task_features

__all__ = ["N_FOLDS", "task_folds"]

#: folds over tasks
N_FOLDS = 3


def _take_tasks(seq: Any, idx: Sequence[int] | np.ndarray) -> Any:  # the retired helpers of per-task inputs
    return seq[np.asarray(idx)] if isinstance(seq, np.ndarray) else [seq[i] for i in idx]


def _task_subset(mdp: Any, features: Any, idx: Sequence[int] | np.ndarray) -> tuple[Any, Any]:
    return (mdp if isinstance(mdp, TabularMDP) else _take_tasks(mdp, idx),
            _take_tasks(features, idx) if per_task_features(features) else features)


def _task_mdp(mdp: Any, i: int) -> Any:
    return mdp if isinstance(mdp, TabularMDP) else mdp[i]


def __getattr__(name: str) -> Any:
    if name not in ("take_tasks", "task_subset", "task_mdp"):
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    warn_once(f"name:selection.folds.{name}", f"{name} is deprecated: a fold's tasks are TaskSet.subset(rows)", stacklevel=None)
    return globals()["_" + name]


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

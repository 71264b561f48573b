"""Saving and loading demonstration sets of several tasks, ragged or not."""

from __future__ import annotations

from typing import IO

import numpy as np
from numpy.typing import NDArray

from ..exceptions import PersistenceError, ValidationError
from ..tasks.trajectories import parse_demonstrations
from .archive import Target, read_archive, require, write_archive

__all__ = ["save_demonstrations", "load_demonstrations"]


def save_demonstrations(demos_per_task: object, path: Target) -> str | IO[bytes]:
    """Save demonstrations of several tasks, ragged or not, to an ``.npz`` file.

    Parameters
    ----------
    demos_per_task : list of n task demonstrations, or ndarray (n, m, L, 2)
        Any layout the learners accept (:mod:`factirl_opt.tasks.trajectories`): each task an int
        array (m, L, 2) or a list of episodes, each (L_j, 2) pairs (lengths may differ) or a
        trajectory with integer ``obs`` and ``acts`` (saved as its (state, action) steps).
    path : str or os.PathLike or writable binary file
        Written as given (no ``.npz`` suffix is appended). A path is written atomically: on
        a failure (a full disk, Ctrl-C) the previous file stays intact and no partial file
        remains.

    Returns
    -------
    path : str or file
        The path written (as a string), or the file object.

    Raises
    ------
    ValidationError
        The demonstrations are not in an accepted layout, or hold a value that is not an
        integer >= 0 (the message names task, episode and step); or ``path`` is neither a
        path nor a writable file.
    PersistenceError
        The file cannot be written (a missing or read-only directory, a path that is a
        directory, a full disk): the message names the path and the cause, the ``OSError``
        is chained.
    """
    tasks = parse_demonstrations(demos_per_task)
    arrays = {
        "steps": np.concatenate([task.steps for task in tasks]),
        "episode_lengths": np.concatenate([task.lengths for task in tasks]),
        "task_n_episodes": np.array([len(task.lengths) for task in tasks], dtype=np.int64),
    }
    header = {"kind": "demonstrations", "n_tasks": len(tasks), "task_forms": [task.form for task in tasks]}
    return write_archive(path, header, arrays)


def _demonstration_arrays(header: dict, contents: dict[str, np.ndarray], label: str) -> tuple:
    """The task forms and the steps, episode lengths and episode counts, checked consistent."""
    forms = require(header, "task_forms", label, "the header", list)
    steps = require(contents, "steps", label, "the archive")
    lengths = require(contents, "episode_lengths", label, "the archive")
    counts = require(contents, "task_n_episodes", label, "the archive")
    for member, arr, ndim in (("steps", steps, 2), ("episode_lengths", lengths, 1), ("task_n_episodes", counts, 1)):
        if arr.ndim != ndim or arr.dtype.kind not in "iu":
            raise PersistenceError(f"{label}: member {member!r} must be a {ndim}-d integer array; got {arr.dtype} {arr.shape}")
    n_steps = len(steps)
    if (
        steps.shape[1:] != (2,)
        or len(forms) != len(counts)
        or np.any(lengths < 1)
        or np.any(lengths > n_steps)
        or np.any(counts < 1)
        or np.any(counts > len(lengths))
        or counts.sum() != len(lengths)
        or lengths.sum() != n_steps
    ):
        raise PersistenceError(
            f"{label} is inconsistent: {len(forms)} task forms, "
            f"{len(counts)} tasks with {int(counts.sum())} episodes, {len(lengths)} episode lengths summing to "
            f"{int(lengths.sum())}, {steps.shape} steps"
        )
    return forms, steps, lengths, counts


def load_demonstrations(path: Target) -> list[NDArray[np.int64] | list[NDArray[np.int64]]]:
    """Load demonstrations written by :func:`save_demonstrations`.

    Parameters
    ----------
    path : str or os.PathLike or readable binary file

    Returns
    -------
    demos_per_task : list of n task demonstrations
        Each in the form it was saved in: an int64 array (m, L, 2), or a list of int64
        episodes (L_j, 2). (A task saved by format version 1 as a single (L, 2) episode loads
        as a list of one episode.)

    Raises
    ------
    PersistenceError
        The file is corrupt (also a single corrupt compressed member), not a factirl-opt file,
        holds a model, lacks a member, is inconsistent, holds negative states or actions (the
        message names task, episode and step), or has a newer format version; or the file
        is missing or unreadable (the message names the path and the cause, the ``OSError``
        is chained).
    """
    header, contents, label = read_archive(path, "demonstrations")
    forms, steps, lengths, counts = _demonstration_arrays(header, contents, label)
    episodes = np.split(steps, np.cumsum(lengths)[:-1])
    bounds = np.concatenate([[0], np.cumsum(counts)])
    out: list = []
    for i, form in enumerate(forms):
        eps = episodes[bounds[i]:bounds[i + 1]]
        if form in ("list", "episode"):
            out.append(eps)
        elif form == "array" and len({len(ep) for ep in eps}) == 1:
            out.append(np.stack(eps))
        else:
            raise PersistenceError(f"{label} is inconsistent: task {i} has form {form!r:.40} with episode lengths {[len(e) for e in eps]}")
    try:
        parse_demonstrations(out)
    except ValidationError as exc:
        raise PersistenceError(f"{label} holds invalid demonstrations: {exc}") from None
    return [task.astype(np.int64) if isinstance(task, np.ndarray) else [ep.astype(np.int64) for ep in task] for task in out]

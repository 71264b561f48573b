"""Demonstration layouts: the one parser of every form demonstrations may take.

Used by :func:`~factirl_opt.empirical_statistics` (hence by every learner's ``fit`` and
``transfer``) and by :func:`~factirl_opt.save_demonstrations`, so a layout is accepted, and a
bad one refused with the same message, wherever demonstrations enter.

Layouts
-------
``demos_per_task`` holds the demonstrations of n tasks: a list (or tuple) with one entry per
task, or an int array of shape (n, m, L, 2). A **task** is

- an int array of shape (m, L, 2): m episodes of equal length L, or
- a list (or tuple) of episodes, of any lengths.

An **episode** is

- array-like of shape (L, 2), L >= 1: ``episode[t] = (state, action)`` at step t, integers
  (floats holding whole numbers are accepted), or
- a trajectory from another library (read by duck typing, nothing is imported): an object
  with attributes ``obs`` and ``acts`` (the layout of ``imitation``'s ``Trajectory``) or
  ``observations`` and ``actions`` (Minari's ``EpisodeData``), or a mapping (a dict, or an
  ``.npz`` file opened with ``numpy.load``) with keys ``obs`` or ``observations`` and
  ``acts`` or ``actions``. Observations must be integer states, one per step (a Discrete
  observation space); float, one-hot, image or dict observations are refused with a clear
  error: map them to state indices first. Actions must be integers. ``obs`` may hold one
  more entry than ``acts``, the observation reached after the last action, which is dropped
  (as in ``imitation``); with equally many, ``obs[t]`` is the state in which ``acts[t]`` was
  taken.

The nesting rule
----------------
The entries of ``demos_per_task`` are tasks, never episodes. A single episode in that
position (an (L, 2) array, a list of (state, action) pairs, a trajectory) is refused, because
``[ep0, ep1]`` could mean one task with two episodes, ``[[ep0, ep1]]``, or two tasks of one
episode each, ``[[ep0], [ep1]]``: the error shows both. Likewise an (m, L, 2) array given as
``demos_per_task`` could be one task (``[demos]``) or m tasks of one episode
(``list(demos[:, None])``), and is refused.

Only the (state, action) steps enter the empirical statistics of eq. (5); episode boundaries
are kept for saving (:func:`~factirl_opt.save_demonstrations`) and for the user.
"""

from __future__ import annotations

import collections.abc
import numbers
import os
import typing

import numpy as np
from numpy.typing import NDArray

from .._validation import check_mdp
from ..exceptions import PersistenceError, ValidationError

from ..mdp.tabular import TabularMDP  # at run time too: typing.get_type_hints resolves the annotations

__all__ = ["demonstrations_from_trajectories", "parse_demonstrations", "parse_episodes", "parse_task", "task_steps",
           "TaskDemonstrations"]

_COLUMNS = ("state", "action")
_OBS_KEYS = ("obs", "observations")
_ACT_KEYS = ("acts", "actions")
_INT64_LIMIT = 2**63  # states and actions must fit in int64


class TaskDemonstrations(typing.NamedTuple):
    """One task's demonstrations, validated.

    Attributes
    ----------
    steps : ndarray of int64, shape (N, 2)
        The (state, action) steps of all episodes, concatenated in order.
    lengths : ndarray of int64, shape (m,)
        Length of each episode (each >= 1, summing to N).
    form : {"array", "list"}
        How the task was given: one (m, L, 2) array, or a list of episodes.
    """

    steps: np.ndarray
    lengths: np.ndarray
    form: str

    def episodes(self) -> list[NDArray[np.int64]]:
        """The episodes as a list of int64 (L_j, 2) arrays (views of ``steps``)."""
        return np.split(self.steps, np.cumsum(self.lengths)[:-1])

    def episode_range(self, start: int, stop: int | None = None) -> TaskDemonstrations:
        """Episodes ``start:stop`` only (their steps a view of ``steps``), as a slice of the episodes given."""
        bounds = np.concatenate([[0], np.cumsum(self.lengths)])
        span = range(len(self.lengths))[start:stop]
        return TaskDemonstrations(self.steps[bounds[span.start]:bounds[span.stop]], self.lengths[start:stop], self.form)


# ----------------------------------------------------------------------------- values


def _value(v):
    return v.item() if isinstance(v, np.generic) else v


def _bad_entry(arr, index, where, problem):
    *lead, col = (int(i) for i in index)
    return ValidationError(f"{where(*lead)}: {_COLUMNS[col]} {_value(arr[tuple(index)])!r} {problem}")


def _first(mask):
    return tuple(np.argwhere(mask)[0])


def _object_integers(arr, where):
    """An object array of Python ints (any size), or the error naming the first non-integer."""
    out = np.empty(arr.shape, dtype=object)
    for index, v in np.ndenumerate(arr):
        if isinstance(v, numbers.Integral) and not isinstance(v, (bool, np.bool_)):
            out[index] = int(v)
        elif isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_)) and np.isfinite(v) and v == round(v):
            out[index] = int(v)
        else:
            raise _bad_entry(arr, index, where, "is not an integer")
    return out


def _as_indices(arr, where, n_states=None, n_actions=None):
    """(..., 2) (state, action) pairs as int64, checked to be integers in range.

    ``where(*leading_index)`` names the step of an entry in messages. States and actions
    must be >= 0, and below ``n_states`` / ``n_actions`` when given.
    """
    kind = arr.dtype.kind
    if kind == "O":
        arr = _object_integers(arr, where)
    elif kind == "f":
        bad = ~np.isfinite(arr)
        bad[~bad] = arr[~bad] != np.round(arr[~bad])
        if bad.any():
            raise _bad_entry(arr, _first(bad), where, "is not an integer")
    elif kind not in "iu":
        raise _bad_entry(arr, (0,) * arr.ndim, where, f"is not an integer (the pairs have dtype {arr.dtype})")
    bounds = (n_states, n_actions)
    for col in (0, 1):
        values = arr[..., col]
        hi = bounds[col]
        bad = (values < 0) | (values >= (_INT64_LIMIT if hi is None else hi))
        if np.any(bad):
            index = _first(np.asarray(bad, dtype=bool)) + (col,)
            problem = f"is out of range [0, {hi})" if hi is not None else "is not a valid index (states and actions are integers >= 0)"
            raise _bad_entry(arr, index, where, problem)
    return arr.astype(np.int64)


# ----------------------------------------------------------------------------- episodes


def _is_trajectory(x):
    """An episode read as a trajectory: any mapping (its keys are checked when read) or an object."""
    if isinstance(x, collections.abc.Mapping):
        return True
    return any(hasattr(x, o) and hasattr(x, a) for o, a in zip(_OBS_KEYS, _ACT_KEYS))


def _has_trajectory_keys(x):
    """A mapping holding an observations or an actions key (so it was meant as one trajectory)."""
    return isinstance(x, collections.abc.Mapping) and any(k in x for k in _OBS_KEYS + _ACT_KEYS)


def describe(x: object) -> str:
    """What a value is, for messages: its type with its shape, length or keys."""
    if isinstance(x, collections.abc.Mapping):
        keys = [repr(k) for k in list(x)[:6]]
        more = ", ..." if len(x) > 6 else ""
        return f"a {type(x).__name__} of {len(x)} entries with keys [{', '.join(keys)}{more}]"
    if isinstance(x, np.ndarray):
        return f"an array of shape {x.shape} and dtype {x.dtype}"
    if isinstance(x, (list, tuple)):
        return f"a {type(x).__name__} of length {len(x)}"
    return f"{type(x).__name__} {x!r}" if isinstance(x, (numbers.Number, str)) else type(x).__name__


def _trajectory_fields(x, where):
    """(observations, actions) of a trajectory object or mapping."""
    if not isinstance(x, collections.abc.Mapping):
        o, a = next((o, a) for o, a in zip(_OBS_KEYS, _ACT_KEYS) if hasattr(x, o) and hasattr(x, a))
        return getattr(x, o), getattr(x, a)
    obs = [k for k in _OBS_KEYS if k in x]
    acts = [k for k in _ACT_KEYS if k in x]
    if len(obs) != 1 or len(acts) != 1:
        raise ValidationError(
            f"{where} is a mapping but not a trajectory: it needs exactly one of the keys 'obs', 'observations' "
            f"and one of 'acts', 'actions'; got keys {sorted(map(str, x))}"
        )
    try:
        return x[obs[0]], x[acts[0]]
    except Exception as exc:  # e.g. an opened .npz with a damaged member, or one holding objects
        raise ValidationError(f"{where}: cannot read its observations or actions: {type(exc).__name__}: {exc}") from None


def _trajectory_pairs(x, where):
    """The (L, 2) steps of a trajectory; the final observation, if any, dropped."""
    obs, acts = _trajectory_fields(x, where)
    try:
        obs, acts = np.asarray(obs), np.asarray(acts)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{where}: its observations and actions must be arrays: {exc}") from None
    if acts.size == 0:
        raise ValidationError(f"{where} has no actions (observations of shape {obs.shape}); expected L >= 1 actions")
    if obs.ndim != 1 or obs.dtype.kind not in "iu":
        hint = " (one row per step: one-hot or feature vectors? np.argmax(obs, axis=1) gives the states of one-hot rows)" if obs.ndim == 2 else ""
        raise ValidationError(
            f"{where}: observations must be integer states, one per step (a Discrete observation space); got "
            f"{obs.dtype} observations of shape {obs.shape}{hint}. Float, one-hot, image or dict observations are "
            "not states: map them to state indices first"
        )
    if acts.ndim != 1 or acts.dtype.kind not in "iu":
        raise ValidationError(
            f"{where}: actions must be integers, one per step (a Discrete action space); got {acts.dtype} actions of shape {acts.shape}"
        )
    L = len(acts)
    if len(obs) not in (L, L + 1):
        raise ValidationError(
            f"{where} has {len(obs)} observations and {L} actions; expected L + 1 observations "
            "(the last one reached after the final action, as in imitation's Trajectory) or L"
        )
    return np.column_stack((obs[:L], acts))


def _open_rollout(path, where):
    """The observations and actions of an ``.npz`` rollout file (read with ``allow_pickle=False``)."""
    label = f"{where} ({os.fspath(path)})"
    try:
        loaded = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise
    except Exception as exc:  # damaged bytes: numpy's readers raise many types (see persistence._members)
        raise PersistenceError(f"{label} is not a readable .npz rollout: {type(exc).__name__}: {exc}") from None
    if not isinstance(loaded, np.lib.npyio.NpzFile):
        raise PersistenceError(f"{label} holds a single array, not an .npz rollout with observations and actions")
    with loaded as npz:
        if "__header__" in npz.files:
            raise PersistenceError(f"{label} is a factirl-opt file, not a rollout: read it with fo.load_demonstrations")
        keys = [k for k in _OBS_KEYS + _ACT_KEYS if k in npz.files]
        try:
            arrays = {k: npz[k] for k in keys}
        except Exception as exc:  # a damaged member
            raise PersistenceError(f"{label}: a member is corrupt or unreadable: {type(exc).__name__}: {exc}") from None
    return arrays


def _task_labels(i):
    """How messages name task i and its episode j (labelled demonstrations)."""
    return f"demonstrations of task {i}", lambda j: f"demonstrations of task {i}, episode {j}"


def _episode(ep, where, load_files):
    """An episode (any accepted form; ``where`` names it) as an (L, 2) array, L >= 1; values not checked yet."""
    if isinstance(ep, np.ndarray) and ep.ndim == 2 and ep.shape[1] == 2 and ep.shape[0] > 0:
        return ep  # the common case, first
    if isinstance(ep, (str, os.PathLike)):
        if not load_files:
            raise ValidationError(f"{where} is a file name ({ep!r}): read .npz rollout files with fo.demonstrations_from_trajectories")
        ep = _open_rollout(ep, where)
    if _is_trajectory(ep):
        return _trajectory_pairs(ep, where)
    try:
        arr = np.asarray(ep)
    except (TypeError, ValueError) as exc:  # e.g. pairs of different lengths: [[0, 1], [2]]
        raise ValidationError(f"{where} must be an array of (state, action) pairs of shape (L, 2); got {describe(ep)} "
                              f"that is not a rectangular array ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0:
        raise ValidationError(f"{where} must have shape (L, 2) with L >= 1; got {arr.shape} ({describe(ep)})")
    return arr


def _episodes_steps(episodes, episode_of, bounds):
    """The checked int64 steps of one task's (L_j, 2) episodes (``episode_of(j)`` names episode j), concatenated.

    Integer episodes are checked at once on their concatenation (a located error maps the
    step back to its episode); others one by one, so that each is read in its own dtype.
    """
    if all(ep.dtype.kind in "iu" for ep in episodes):
        starts = np.cumsum([0] + [len(ep) for ep in episodes])

        def where(g):
            j = int(np.searchsorted(starts, g, side="right")) - 1
            return f"{episode_of(j)}, step {g - starts[j]}"

        return _as_indices(np.concatenate(episodes), where, *bounds)
    parts = [_as_indices(ep, lambda t, j=j: f"{episode_of(j)}, step {t}", *bounds)
             for j, ep in enumerate(episodes)]
    return np.concatenate(parts)


# ----------------------------------------------------------------------------- tasks


def _is_pair(x):
    if isinstance(x, np.ndarray):
        return x.shape == (2,)
    return isinstance(x, (list, tuple)) and len(x) == 2 and all(isinstance(v, (numbers.Number, np.generic, str)) for v in x)


def _single_episode(entry, load_files):
    """How an episode standing where a task should be looks (for the message), or None."""
    if isinstance(entry, np.ndarray):
        return f"an array of shape {entry.shape}" if entry.ndim == 2 and entry.shape[1] == 2 else None
    if isinstance(entry, (list, tuple)):
        return "a list of (state, action) pairs" if entry and _is_pair(entry[0]) else None
    if load_files and isinstance(entry, (str, os.PathLike)):
        return f"a rollout file {os.fspath(entry)!r}"
    if isinstance(entry, collections.abc.Mapping):
        return f"a trajectory, {describe(entry)}" if _has_trajectory_keys(entry) else None
    return f"a trajectory, {type(entry).__name__}" if _is_trajectory(entry) else None


def _nesting_error(entries, i, what, name):
    n = len(entries)
    head = f"{name}[{i}] is a single episode ({what}), not a task: a task is an (m, L, 2) array or a list of episodes. "
    if n == 1:
        return ValidationError(head + f"Pass [{name}] (one task of one episode)")
    if all(_single_episode(e, True) for e in entries):
        return ValidationError(
            head + f"If the {n} entries of {name} are episodes of one task, pass [{name}] (1 task of {n} episodes); "
            f"if each is the only episode of its own task, pass [[episode] for episode in {name}] ({n} tasks of 1 episode)"
        )
    return ValidationError(head + f"If it is the only episode of task {i}, wrap it in a list: [episode]")


def _layout_hint(demos, name):
    """How to pass a single trajectory, a dict of tasks or an iterator as ``demos_per_task``."""
    if isinstance(demos, collections.abc.Mapping):
        if _has_trajectory_keys(demos):
            return f", a single trajectory: pass [[{name}]] for one task of one episode"
        return (f": a mapping of tasks is not accepted (the task order would be implicit); pass "
                f"list({name}.values()) for one task per entry, in the order of its keys")
    if _is_trajectory(demos):
        return f", a single trajectory: pass [[{name}]] for one task of one episode"
    if isinstance(demos, collections.abc.Iterable) and not isinstance(demos, (str, bytes)):
        return f": pass list({name}) if it yields one entry per task"
    return ""


def _task_entries(demos, name, load_files):
    """The entries of ``demos_per_task``, one per task, after the checks of the nesting rule."""
    rule = f"{name} must be a list with one entry per task (one task is a list of one), or a 4-d array (n, m, L, 2)"
    if isinstance(demos, np.ndarray):
        if demos.ndim == 4:
            return list(demos)
        if demos.ndim == 3 and demos.shape[2] == 2:
            m = demos.shape[0]
            raise ValidationError(
                f"{rule}; got an array of shape {demos.shape}, the layout of one task's episodes: pass [{name}] for "
                f"one task of {m} episodes, or list({name}[:, None]) for {m} tasks of one episode each"
            )
        raise ValidationError(f"{rule}; got {describe(demos)}")
    if not isinstance(demos, (list, tuple)):
        raise ValidationError(f"{rule}; got {describe(demos)}{_layout_hint(demos, name)}")
    if len(demos) == 0:
        raise ValidationError(f"{name} is empty: give the demonstrations of at least one task")
    for i, entry in enumerate(demos):
        what = _single_episode(entry, load_files)
        if what is not None:
            raise _nesting_error(demos, i, what, name)
    return list(demos)


def _parse_task(entry, bounds, load_files, owner, episode_of):
    """One task's episodes, an (m, L, 2) array or a list of episodes, as :class:`TaskDemonstrations`;
    ``owner`` names them in messages (``"demonstrations of task i"``), ``episode_of(j)`` episode j."""
    if isinstance(entry, np.ndarray) and entry.ndim == 3 and entry.shape[2] == 2:
        m, L, _ = entry.shape
        if m == 0:
            raise ValidationError(f"{owner} are empty: give at least one episode")
        if L == 0:
            raise ValidationError(f"{episode_of(0)} must have shape (L, 2) with L >= 1; got (0, 2)")
        steps = _as_indices(entry, lambda j, t: f"{episode_of(j)}, step {t}", *bounds)
        return TaskDemonstrations(steps.reshape(-1, 2), np.full(m, L, dtype=np.int64), "array")
    if isinstance(entry, (list, tuple)):
        if len(entry) == 0:
            raise ValidationError(f"{owner} are empty: give at least one episode")
        episodes = [_episode(ep, episode_of(j), load_files) for j, ep in enumerate(entry)]
        return TaskDemonstrations(_episodes_steps(episodes, episode_of, bounds), np.array([len(e) for e in episodes], dtype=np.int64), "list")
    hint = ""
    if isinstance(entry, collections.abc.Mapping):
        hint = " (a mapping of episodes is not accepted: pass list(episodes.values()), in the order of its keys)"
    raise ValidationError(
        f"{owner} must be an int array of shape (m, L, 2) or a list of episodes of shape (L_j, 2); "
        f"got {describe(entry)}{hint}"
    )


def parse_demonstrations(demos_per_task: typing.Any, n_states: int | None = None, n_actions: int | None = None,
                         name: str = "demos_per_task", load_files: bool = False) -> list[TaskDemonstrations]:
    """Every task's demonstrations, in any accepted layout, validated (see the module docstring).

    Parameters
    ----------
    demos_per_task : list of n tasks, or ndarray (n, m, L, 2)
        Each task an int array (m, L, 2) or a list of episodes; each episode (L_j, 2) pairs or
        a trajectory (object or mapping with observations and actions).
    n_states, n_actions : int, optional
        When given, states must lie in [0, n_states) and actions in [0, n_actions); states and
        actions are always integers >= 0.
    name : str
        The argument's name in messages.
    load_files : bool, default=False
        Accept paths of ``.npz`` rollout files as episodes (read with ``allow_pickle=False``).

    Returns
    -------
    tasks : list of n :class:`TaskDemonstrations`

    Raises
    ------
    ValidationError
        The message names the bad task, episode and step (``task i, episode j, step t``), the
        bad value, and for a layout that breaks the nesting rule the two layouts it could mean.
    PersistenceError
        A rollout file cannot be read (only with ``load_files``).
    """
    entries = _task_entries(demos_per_task, name, load_files)
    bounds = (n_states, n_actions)
    return [_parse_task(entry, bounds, load_files, *_task_labels(i)) for i, entry in enumerate(entries)]


def parse_episodes(episodes: typing.Any, n_states: int | None = None, n_actions: int | None = None,
                   name: str = "episodes") -> TaskDemonstrations:
    """Episodes without task labels (a list of episodes, or an (m, L, 2) array), validated.

    As one task of :func:`parse_demonstrations`, but messages name the episodes as given
    (``episodes[j], step t``), not as a task's; a single episode given in place of the list
    is refused with how to pass it.

    Returns
    -------
    TaskDemonstrations
        All the steps (N, 2) and the episodes' lengths (m,).

    Raises
    ------
    ValidationError
        Naming the bad episode, step and value.
    """
    what = _single_episode(episodes, False)
    if what is not None and not (isinstance(episodes, np.ndarray) and episodes.ndim == 3):
        raise ValidationError(f"{name} is a single episode ({what}), not a list of episodes: pass [{name}]")
    return _parse_task(episodes, (n_states, n_actions), False, name, lambda j: f"{name}[{j}]")


def parse_task(mdp: TabularMDP, task_demos: typing.Any, task: int = 0) -> TaskDemonstrations:
    """One task's demonstrations (an (m, L, 2) array or a list of episodes), validated on its MDP;
    ``task`` is its index in error messages."""
    check_mdp(mdp)
    return _parse_task(task_demos, (mdp.n_states, mdp.n_actions), False, *_task_labels(task))


def task_steps(mdp: TabularMDP, task_demos: typing.Any, task: int = 0) -> NDArray[np.int64]:
    """All (state, action) steps (N, 2) of one task's demonstrations, validated (:func:`parse_task`)."""
    return parse_task(mdp, task_demos, task).steps


def demonstrations_from_trajectories(trajectories_per_task: typing.Any,
                                     mdp: TabularMDP | None = None) -> list[list[NDArray[np.int64]]]:
    """Trajectories from other libraries as this library's demonstrations (one list of episodes per task).

    Reads, without importing those libraries, objects with ``obs`` and ``acts`` attributes
    (``imitation``'s ``Trajectory``: ``obs`` has one more entry than ``acts``, the final
    observation, which is dropped) or ``observations`` and ``actions`` (Minari's
    ``EpisodeData``), mappings with keys ``obs``/``observations`` and ``acts``/``actions``
    (dicts, ``numpy.load`` of an ``.npz``), and paths of such ``.npz`` files. Observations
    must be integer states (a Discrete observation space). The learners accept the same
    objects directly as ``demos_per_task``; this function reads files and gives plain arrays
    (to save, inspect or reuse).

    Parameters
    ----------
    trajectories_per_task : list with one entry per task
        Each entry a list of that task's trajectories (episodes). The library's own layouts
        are accepted too: an episode may be an (L, 2) array, a task an (m, L, 2) array. A
        trajectory in the place of a task is refused (nesting rule of the module docstring):
        one task of trajectories ``trajs`` is ``[trajs]``.
    mdp : TabularMDP, optional
        When given, states are checked to lie in [0, S) and actions in [0, A).

    Returns
    -------
    demos_per_task : list of n lists of ndarrays of int64, each of shape (L_j, 2)
        ``demos_per_task[i][j][t] = (state, action)`` at step t of episode j of task i.

    Raises
    ------
    ValidationError
        A trajectory has non-integer (float, one-hot, image) observations or actions,
        inconsistent lengths, out-of-range values, or the layout breaks the nesting rule.
    PersistenceError
        A rollout file is not a readable ``.npz`` archive.
    FileNotFoundError
        A rollout file does not exist.

    Examples
    --------
    >>> class Trajectory:                       # the layout of imitation's Trajectory
    ...     def __init__(self, obs, acts):
    ...         self.obs, self.acts = obs, acts
    >>> demos = demonstrations_from_trajectories([[Trajectory([0, 1, 3], [1, 2]), {"obs": [2], "acts": [0]}]])
    >>> [ep.tolist() for ep in demos[0]]
    [[[0, 1], [1, 2]], [[2, 0]]]
    """
    n_states, n_actions = (None, None) if mdp is None else (check_mdp(mdp).n_states, mdp.n_actions)
    tasks = parse_demonstrations(trajectories_per_task, n_states, n_actions, name="trajectories_per_task", load_files=True)
    return [[ep.copy() for ep in task.episodes()] for task in tasks]

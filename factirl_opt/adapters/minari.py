"""Logged data in Farama's Minari format: a local dataset as episodes and (s, a, s') transitions.

Minari is the Farama Foundation's standard format for offline reinforcement-learning data. A
dataset holds episodes; each has ``observations`` (L + 1 of them: the last one is reached after
the final action), ``actions`` (L), rewards and termination flags. :func:`read_minari` opens a
dataset from local storage and gives

- the episodes in the library's layout, (L, 2) arrays of (state, action) steps: one task's
  demonstrations, ``[logged.episodes]``, for the learners;
- the final state of each episode, so that :meth:`LoggedEpisodes.transitions` gives every
  (s, a, s') transition, the L-th included, for :func:`~factirl_opt.estimate_mdp` and
  :func:`~factirl_opt.mdp.transition_log_likelihood`.

States. With a ``Discrete(n)`` observation space (Gymnasium's toy-text environments) the
observation is the state and S = n. Other observations must be mapped to state indices by the
caller: ``observation_to_state`` receives one episode's observations (as stored by Minari: an
array, or a dict of arrays for a Dict space) and returns the L + 1 states, integers in
[0, n_states). MiniGrid and BabyAI datasets are refused with an explanation: their
observations (an egocentric 7x7 view, a direction, a mission) do not say which cell the agent
is in, so they cannot be mapped to the states of the enumerated MiniGrid model
(``fo.minigrid.from_minigrid``); a dataset that records the agent's state, e.g. through a wrapper whose
observation is that model's state index, is read with ``observation_to_state``. Actions must be
``Discrete(A)``.

Nothing is downloaded: a dataset id is looked up in Minari's local storage (the directory
``$MINARI_DATASETS_PATH``, by default ``~/.minari/datasets``); fetch remote datasets yourself
first (``minari download <id>``).

Minari is an optional dependency (Python >= 3.11): ``pip install "minari[hdf5]>=0.5"``, or
from a clone of factirl-opt ``pip install -e ".[minari]"`` (datasets stored in the arrow
format also need ``pyarrow``). It is imported only to open a dataset from its id; a dataset
object is read by duck typing (``observation_space``, ``action_space``,
``iterate_episodes``).
"""

from __future__ import annotations

import contextlib
import importlib
import os
from collections.abc import Callable, Iterable, Iterator
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import check_int
from ..exceptions import FactIRLError, MissingDependencyError, PersistenceError, ValidationError
from ..mdp.estimation import as_transitions

__all__ = ["read_minari", "LoggedEpisodes", "INSTALL_HINT"]

#: The install hint of the ``minari`` extra: works for any install of factirl-opt, and from a clone.
INSTALL_HINT = 'pip install "minari[hdf5]>=0.5" (or, in a clone of factirl-opt: pip install -e ".[minari]")'
_MINIGRID_PREFIXES = ("MiniGrid", "BabyAI")
_MINIGRID_KEYS = {"image", "direction", "mission"}


class LoggedEpisodes(NamedTuple):
    """Episodes read from logged data, in the library's layout.

    Attributes
    ----------
    episodes : list of m ndarrays of int64, each of shape (L_j, 2)
        ``episodes[j][t] = (state, action)`` at step t of episode j (L_j >= 1).
    final_states : ndarray of int64, shape (m,)
        The state reached after the last action of each episode.
    n_states, n_actions : int
        S and A: every state lies in [0, S), every action in [0, A).
    episode_ids : ndarray of int64, shape (m,)
        The dataset's id of each episode, in the order read.
    """

    episodes: list[NDArray[np.int64]]
    final_states: NDArray[np.int64]
    n_states: int
    n_actions: int
    episode_ids: NDArray[np.int64]

    def transitions(self) -> NDArray[np.int64]:
        """All (s, a, s') transitions, episode by episode, the last step's included.

        Returns
        -------
        transitions : ndarray of int64, shape (N, 3)
            ``N = sum_j L_j``; the layout of :func:`~factirl_opt.estimate_mdp`.
        """
        return as_transitions(list(zip(self.episodes, self.final_states.tolist())), self.n_states, self.n_actions)


def _import_minari() -> Any:
    try:
        return importlib.import_module("minari")
    except ImportError as exc:
        raise MissingDependencyError(f"opening a Minari dataset from its id needs minari, which is not installed: {INSTALL_HINT}") from exc


def _where(dataset: Any) -> str:
    """The dataset's id and directory, as error messages name it."""
    if isinstance(dataset, str):
        root = os.environ.get("MINARI_DATASETS_PATH") or os.path.join("~", ".minari", "datasets")
        return f"{dataset!r} ({os.path.join(root, dataset)})"
    spec = getattr(dataset, "spec", None)
    name, path = getattr(spec, "dataset_id", None), getattr(spec, "data_path", None)
    if name is None and path is None:
        return f"given ({type(dataset).__name__})"
    return f"{name!r}" + (f" ({path})" if path else "")


@contextlib.contextmanager
def _reading(where: str) -> Iterator[None]:
    """Every read of a dataset's files (opening, listing, iterating episodes) goes through here: an error of
    the storage or of minari (h5py, json, a missing or malformed file) becomes a :class:`PersistenceError`
    naming the dataset and its directory; the library's own errors and interrupts pass unchanged."""
    try:
        yield
    except FactIRLError:
        raise
    except Exception as exc:  # noqa: BLE001 - whatever minari, h5py, pyarrow or json raise on damaged files
        raise PersistenceError(
            f"the Minari dataset {where} cannot be read: {type(exc).__name__}: {exc}. Its files (metadata.json, the "
            "episodes' data file) are damaged, truncated or missing: record or download the dataset again"
        ) from exc


def _episodes(ds: Any, indices: list[int] | None, where: str) -> Iterator[Any]:
    """The dataset's episodes, each read inside :func:`_reading`."""
    with _reading(where):
        episodes = iter(ds.iterate_episodes() if indices is None else ds.iterate_episodes(indices))
    while True:
        with _reading(where):
            ep = next(episodes, None)
        if ep is None:
            return
        yield ep


def _check_indices(ds: Any, episode_indices: Iterable[int] | None, where: str) -> list[int] | None:
    """``episode_indices`` as a list of ints, each one of the dataset's episodes (when it says which it has)."""
    if episode_indices is None:
        return None
    if isinstance(episode_indices, (str, bytes)) or not isinstance(episode_indices, Iterable):
        raise ValidationError(f"episode_indices must be an iterable of episode indices; got {type(episode_indices).__name__}")
    indices = [check_int(i, "episode_indices[]") for i in episode_indices]
    with _reading(where):
        listed = getattr(ds, "episode_indices", None)
        if listed is None and getattr(ds, "total_episodes", None) is not None:
            listed = range(int(ds.total_episodes))
        if listed is None:  # the dataset does not say which it has: reading will
            return indices
        known = {int(i) for i in listed}
    missing = [i for i in indices if i not in known]
    if missing:
        span = f"indices {min(known)}..{max(known)}" if known else "none"
        raise ValidationError(f"episode_indices: episode {missing[0]} is not in the Minari dataset {where}, which has "
                              f"{len(known)} episodes ({span})")
    return indices


def _open(dataset: Any) -> Any:
    """A dataset object: opened from local storage for an id, else checked by duck typing."""
    if isinstance(dataset, str):
        minari = _import_minari()
        try:
            with _reading(_where(dataset)):
                return minari.load_dataset(dataset, download=False)
        except PersistenceError as exc:
            if not isinstance(exc.__cause__, FileNotFoundError):
                raise
            raise FileNotFoundError(
                f"the Minari dataset {dataset!r} is not in local storage ({exc.__cause__}); factirl-opt downloads nothing: "
                f"set MINARI_DATASETS_PATH to the directory holding it, or fetch it first with `minari download {dataset}`"
            ) from None
    missing = [name for name in ("observation_space", "action_space", "iterate_episodes") if not hasattr(dataset, name)]
    if missing:
        raise ValidationError(
            f"dataset must be a Minari dataset id (str) or a minari.MinariDataset; got {type(dataset).__name__} "
            f"without {', '.join(missing)}"
        )
    return dataset


def _discrete_size(space: Any, what: str) -> int | None:
    """n of a ``Discrete(n)`` space starting at 0, None for another kind of space."""
    n = getattr(space, "n", None)
    if n is None:
        return None
    start = int(getattr(space, "start", 0))
    if start != 0:
        raise ValidationError(f"the dataset's {what} space {space} starts at {start}; states and actions are indices from 0")
    return int(n)


def _env_id(dataset: Any) -> str:
    spec = getattr(dataset, "env_spec", None)
    return str(getattr(spec, "id", "") or "")


def _is_minigrid(dataset: Any) -> bool:
    subspaces = getattr(dataset.observation_space, "spaces", None)
    keys = set(subspaces) if isinstance(subspaces, dict) else set()
    return _env_id(dataset).startswith(_MINIGRID_PREFIXES) or _MINIGRID_KEYS <= keys


def _state_reader(dataset: Any, observation_to_state: Callable[[Any], ArrayLike] | None, n_states: int | None) -> tuple[Callable[[Any], Any], int]:
    """How to turn one episode's observations into states, and S."""
    if observation_to_state is not None:
        if not callable(observation_to_state):
            raise ValidationError(f"observation_to_state must be callable; got {type(observation_to_state).__name__}")
        if n_states is None:
            raise ValidationError("observation_to_state needs n_states, the number of states its indices range over")
        return observation_to_state, check_int(n_states, "n_states", minimum=1)
    if n_states is not None:
        raise ValidationError("n_states is only used with observation_to_state; a Discrete observation space gives S itself")
    space = dataset.observation_space
    if _is_minigrid(dataset):
        raise ValidationError(
            f"this is a MiniGrid/BabyAI dataset (env {_env_id(dataset) or 'unknown'}, observation space {space}): its "
            "observations, an egocentric view, a direction and a mission, do not identify the agent's cell, so they are not "
            "states of the enumerated model fo.minigrid.from_minigrid. Record the agent's state in the dataset (e.g. a wrapper whose "
            "observation is that model's state index) and pass observation_to_state and n_states"
        )
    n = _discrete_size(space, "observation")
    if n is None:
        raise ValidationError(
            f"the dataset's observation space {space} is not Discrete: its observations are not state indices; pass "
            "observation_to_state (one episode's observations -> its L + 1 states) and n_states"
        )
    return (lambda obs: obs), n


def _indices(values: Any, size: int, what: str, episode: int) -> NDArray[np.int64]:
    """A 1-d array of integers in [0, size), or the error naming the episode and the bad value."""
    try:
        arr = np.asarray(values)
    except (TypeError, ValueError):
        arr = np.asarray(None, dtype=object)
    if arr.ndim != 1 or arr.dtype.kind not in "iu":
        raise ValidationError(
            f"episode {episode}: {what} must be a 1-d array of integers; got {arr.dtype} values of shape {arr.shape}"
        )
    bad = (arr < 0) | (arr >= size)
    if np.any(bad):
        t = int(np.argmax(bad))
        raise ValidationError(f"episode {episode}: {what} {arr[t].item()!r} at step {t} is out of range [0, {size})")
    return arr.astype(np.int64)


def _episode_steps(ep: Any, states_of: Callable[[Any], Any], S: int, A: int) -> tuple[int, NDArray[np.int64], int]:
    """(episode id, (L, 2) steps, final state) of one Minari episode."""
    ep_id = int(getattr(ep, "id", -1))
    actions = _indices(ep.actions, A, "actions", ep_id)
    states = _indices(states_of(ep.observations), S, "states", ep_id)
    L = len(actions)
    if L == 0:
        raise ValidationError(f"episode {ep_id} has no actions: an episode needs L >= 1 steps")
    if len(states) != L + 1:
        raise ValidationError(f"episode {ep_id} has {len(states)} states (observations) and {L} actions; expected L + 1 = {L + 1}")
    return ep_id, np.column_stack((states[:L], actions)), int(states[L])


def read_minari(
    dataset: Any,
    episode_indices: Iterable[int] | None = None,
    observation_to_state: Callable[[Any], ArrayLike] | None = None,
    n_states: int | None = None,
) -> LoggedEpisodes:
    """Episodes and transitions of a local Minari dataset, with integer states and actions.

    Parameters
    ----------
    dataset : str or minari.MinariDataset
        A dataset id, opened from local storage (``$MINARI_DATASETS_PATH``, nothing is
        downloaded), or an opened dataset.
    episode_indices : iterable of int, optional
        The episodes to read (Minari's indices), by default all of them.
    observation_to_state : callable, optional
        For datasets whose observations are not ``Discrete`` state indices: maps one episode's
        observations (L + 1 of them, as Minari stores them) to an int array of L + 1 states in
        [0, n_states). The hook for models whose states the observations identify.
    n_states : int, optional
        S, required with ``observation_to_state`` (and only then).

    Returns
    -------
    LoggedEpisodes
        ``episodes`` ((L_j, 2) arrays), ``final_states``, ``n_states``, ``n_actions``,
        ``episode_ids``; ``.transitions()`` gives the (N, 3) transitions.

    Raises
    ------
    MissingDependencyError
        A dataset id was given and minari is not installed (the message gives the pip command).
    FileNotFoundError
        The dataset id is not in local storage.
    PersistenceError
        The dataset's files are damaged, truncated or incomplete (corrupt data file, missing
        or malformed ``metadata.json``): any error of minari or of the storage while reading,
        with the dataset's id and directory.
    ValidationError
        A MiniGrid/BabyAI dataset without ``observation_to_state`` (see the module docstring),
        a non-Discrete observation or action space, a dataset with no episodes, an
        ``episode_indices`` entry the dataset does not have, or an episode with no action,
        mismatched lengths or out-of-range states or actions (the message names the episode).
    """
    ds = _open(dataset)
    where = _where(dataset if isinstance(dataset, str) else ds)
    with _reading(where):
        action_space = ds.action_space
    A = _discrete_size(action_space, "action")
    if A is None:
        raise ValidationError(f"the dataset's action space {action_space} is not Discrete: actions must be indices 0..A-1")
    with _reading(where):
        states_of, S = _state_reader(ds, observation_to_state, n_states)
    indices = _check_indices(ds, episode_indices, where)
    read = [_episode_steps(ep, states_of, S, A) for ep in _episodes(ds, indices, where)]
    if not read:
        raise ValidationError("the dataset holds no episodes (or episode_indices selects none)")
    ids, steps, finals = zip(*read)
    return LoggedEpisodes(list(steps), np.array(finals, dtype=np.int64), S, A, np.array(ids, dtype=np.int64))

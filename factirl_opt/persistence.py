"""Saving and loading fitted models and demonstration sets.

File format (``FORMAT_VERSION`` 1). A file is an ``.npz`` archive (``numpy.savez_compressed``)
holding plain numeric arrays only, so it loads with ``allow_pickle=False``, plus one member
``__header__``: a 0-d unicode array holding a JSON object::

    {"format": "factirl-opt", "format_version": 1, "kind": "model" | "demonstrations",
     "library_version": "0.1.0", "numpy_version": "1.26.4", ...}

A **model** file adds ``"class"`` (``"GradIRL"`` or ``"FactIRL"``), ``"params"`` (the
constructor parameters), ``"array_params"`` (names of parameters stored as arrays:
``features``, or ``init`` given as a tuple ``(D0, H0)``) and ``"attributes"`` (learnt
attributes, the names ending in ``_``, that are not arrays: lists of losses, counts,
status strings). Arrays are stored as members ``param/<name>`` and ``attr/<name>``, exactly
(dtype and bits), so a loaded model transfers and scores bit-identically.

Parameters that do not fit in JSON:

- a solver given as an object rather than a registry name (``solver``, ``h_solver``) is
  refused with a :class:`PersistenceError`: give the solver by name with its options
  (``solver="armijo", solver_options={...}``), which are stored;
- ``rng`` given as a ``numpy.random.Generator`` is stored as its bit generator's state (the
  loaded model gets a new Generator in that state); a ``SeedSequence`` by its entropy and
  spawn key; an int or None as is;
- options dicts must be JSON-serialisable (tuples come back as lists).

A **demonstrations** file stores the ``(state, action)`` steps of all episodes concatenated
(member ``steps``, int64 (N, 2)), the length of each episode (``episode_lengths``) and the
number of episodes of each task (``task_n_episodes``); the header's ``"task_forms"`` records
whether each task was an (m, L, 2) array, a single (L, 2) episode array, or a list of
episodes, and :func:`load_demonstrations` gives back the same form. Lists of episodes of
different lengths are therefore saved as they are.
"""

import json
import os
import zipfile

import numpy as np

import solvers

from .demonstrations import check_episode
from .exceptions import PersistenceError, ValidationError
from .factirl import FactIRL
from .gradirl import GradIRL

__all__ = ["save_model", "load_model", "save_demonstrations", "load_demonstrations", "FORMAT_VERSION"]

#: Version of the file format written by this library; files with a larger one are refused.
FORMAT_VERSION = 1
_FORMAT = "factirl-opt"
_HEADER = "__header__"
_MODEL_CLASSES = {"GradIRL": GradIRL, "FactIRL": FactIRL}
_SOLVER_PARAMS = ("solver", "h_solver")


def _library_version():
    from . import __version__

    return __version__


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def _to_json(value, what):
    """``value`` as plain JSON data (numpy scalars converted); PersistenceError naming ``what``."""
    try:
        return json.loads(json.dumps(value, default=_json_default))
    except (TypeError, ValueError) as exc:
        raise PersistenceError(f"cannot save {what}: {exc}") from None


# ----------------------------------------------------------------------------- rng parameter


def _encode_rng(rng):
    if rng is None or (isinstance(rng, (int, np.integer)) and not isinstance(rng, bool)):
        return {"type": "seed", "value": None if rng is None else int(rng)}
    if isinstance(rng, np.random.Generator):
        state = rng.bit_generator.state
        return {"type": "generator", "bit_generator": state["bit_generator"], "state": _to_json(state, "rng state")}
    if isinstance(rng, np.random.SeedSequence):
        return {
            "type": "seed_sequence",
            "entropy": _to_json(rng.entropy, "rng entropy"),
            "spawn_key": list(rng.spawn_key),
            "pool_size": rng.pool_size,
            "n_children_spawned": rng.n_children_spawned,
        }
    raise PersistenceError(f"cannot save rng of type {type(rng).__name__}: give a seed, a Generator or a SeedSequence")


def _decode_rng(spec):
    kind = spec.get("type") if isinstance(spec, dict) else None
    try:
        if kind == "seed":
            return spec["value"]
        if kind == "generator":
            bitgen = getattr(np.random, spec["bit_generator"])()
            bitgen.state = spec["state"]
            return np.random.Generator(bitgen)
        if kind == "seed_sequence":
            return np.random.SeedSequence(
                spec["entropy"],
                spawn_key=tuple(spec["spawn_key"]),
                pool_size=spec["pool_size"],
                n_children_spawned=spec["n_children_spawned"],
            )
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise PersistenceError(f"the stored rng parameter is malformed: {exc!r}") from None
    raise PersistenceError(f"the stored rng parameter is malformed: {spec!r}")


# ----------------------------------------------------------------------------- reading/writing


def _write(path, header, arrays):
    header = {"format": _FORMAT, "format_version": FORMAT_VERSION, "library_version": _library_version(),
              "numpy_version": np.__version__, **header}
    members = {_HEADER: np.array(json.dumps(header, default=_json_default))}
    members.update(arrays)
    if hasattr(path, "write"):
        np.savez_compressed(path, **members)
        return path
    path = os.fspath(path)
    with open(path, "wb") as f:  # np.savez would append ".npz" to a name without it
        np.savez_compressed(f, **members)
    return path


def _read(path, kind):
    """The header and every array of a factirl-opt file of the given kind."""
    label = os.fspath(path) if isinstance(path, (str, os.PathLike)) else type(path).__name__
    try:
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):
            raise PersistenceError(f"{label} is not a factirl-opt file: it holds a single .npy array, not an .npz archive")
        with loaded as npz:
            contents = {name: npz[name] for name in npz.files}
    except (FileNotFoundError, PersistenceError):
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        raise PersistenceError(f"{label} is not a readable factirl-opt file (corrupt or not an .npz archive): {exc}") from None
    if _HEADER not in contents:
        raise PersistenceError(f"{label} is an .npz archive but not a factirl-opt file: it has no {_HEADER} member")
    raw = contents.pop(_HEADER)
    try:
        header = json.loads(str(raw[()]))
    except (ValueError, IndexError, TypeError) as exc:
        raise PersistenceError(f"{label}: the {_HEADER} member is not valid JSON: {exc}") from None
    if not isinstance(header, dict) or header.get("format") != _FORMAT:
        raise PersistenceError(f"{label} is not a factirl-opt file: its header does not say format {_FORMAT!r}")
    version = header.get("format_version")
    if not isinstance(version, int) or isinstance(version, bool):
        raise PersistenceError(f"{label}: the header's format_version is missing or not an integer: {version!r}")
    if version > FORMAT_VERSION:
        raise PersistenceError(
            f"{label} has format version {version}, written by factirl-opt {header.get('library_version', '?')}; "
            f"this is factirl-opt {_library_version()}, which reads versions up to {FORMAT_VERSION}: upgrade factirl-opt"
        )
    found = header.get("kind")
    if found != kind:
        loader = {"model": "load_model", "demonstrations": "load_demonstrations"}.get(found)
        hint = f"; use {loader}" if loader else ""
        raise PersistenceError(f"{label} holds {found!r} data, not {kind!r}{hint}")
    return header, contents, label


def _require(mapping, key, label, where, kind=None):
    if key not in mapping:
        raise PersistenceError(f"{label} is incomplete: {where} lacks {key!r}")
    value = mapping[key]
    if kind is not None and not isinstance(value, kind):
        raise PersistenceError(f"{label} is malformed: {key!r} in {where} must be a {kind.__name__}; got {type(value).__name__}")
    return value


# ----------------------------------------------------------------------------- models


def save_model(model, path):
    """Save a :class:`GradIRL` or :class:`FactIRL` (fitted or not) to an ``.npz`` file.

    Stores the constructor parameters and every learnt attribute (names ending in ``_``),
    arrays exactly; see the module docstring for the format.

    Parameters
    ----------
    model : GradIRL or FactIRL
    path : str or os.PathLike or writable binary file
        Written as given (no ``.npz`` suffix is appended).

    Returns
    -------
    path
        The path (or file) written.

    Raises
    ------
    PersistenceError
        The model has a solver given as an object, or a parameter or attribute that is neither
        an array nor JSON-serialisable (the message names it).
    ValidationError
        ``model`` is not a GradIRL or FactIRL.
    """
    cls = type(model)
    name = next((n for n, c in _MODEL_CLASSES.items() if cls is c), None)
    if name is None:
        raise ValidationError(f"model must be a GradIRL or FactIRL; got {cls.__name__}")
    params, arrays, array_params = {}, {}, []
    for key, value in vars(model).items():
        if key.startswith("_") or key.endswith("_"):
            continue
        if key in _SOLVER_PARAMS and not isinstance(value, str):
            raise PersistenceError(
                f"cannot save {name} with {key} given as a {type(value).__name__} object: construct it with the "
                f"solver's registry name and options instead, e.g. {key}={getattr(value, 'name', 'armijo')!r} "
                f"(registered: {', '.join(solvers.registered_solvers())})"
            )
        if key == "rng":
            params[key] = _encode_rng(value)
        elif key == "features" and value is not None:
            arrays["param/features"] = np.asarray(value)
            array_params.append(key)
        elif key == "init" and isinstance(value, tuple):
            if len(value) != 2:
                raise PersistenceError(f"cannot save {name} with init a tuple of length {len(value)}: expected (D0, H0)")
            arrays["param/init/0"], arrays["param/init/1"] = np.asarray(value[0]), np.asarray(value[1])
            array_params.append(key)
        else:
            params[key] = _to_json(value, f"{name} parameter {key}={value!r:.80}")
    attributes, array_attributes = {}, []
    for key, value in vars(model).items():
        if not key.endswith("_") or key.startswith("_"):
            continue
        if isinstance(value, np.ndarray):
            if value.dtype.hasobject:
                raise PersistenceError(f"cannot save {name} attribute {key}: it is an object array")
            arrays[f"attr/{key}"] = value
            array_attributes.append(key)
        else:
            attributes[key] = _to_json(value, f"{name} attribute {key}")
    header = {"kind": "model", "class": name, "params": params, "array_params": array_params, "attributes": attributes,
              "array_attributes": array_attributes}
    return _write(path, header, arrays)


def load_model(path):
    """Load a model written by :func:`save_model`.

    Parameters
    ----------
    path : str or os.PathLike or readable binary file

    Returns
    -------
    model : GradIRL or FactIRL
        With the saved parameters and learnt attributes: it transfers and scores exactly like
        the saved model.

    Raises
    ------
    PersistenceError
        The file is corrupt, not a factirl-opt file, holds demonstrations, lacks a member or
        header entry, or has a newer format version (the message says which).
    FileNotFoundError
        No such file.
    """
    header, contents, label = _read(path, "model")
    name = _require(header, "class", label, "the header", str)
    if name not in _MODEL_CLASSES:
        raise PersistenceError(f"{label} holds a model of unknown class {name!r}; known: {', '.join(_MODEL_CLASSES)}")
    cls = _MODEL_CLASSES[name]
    params = dict(_require(header, "params", label, "the header", dict))
    for key in _require(header, "array_params", label, "the header", list):
        if key == "init":
            params["init"] = (
                _require(contents, "param/init/0", label, "the archive"),
                _require(contents, "param/init/1", label, "the archive"),
            )
        else:
            params[key] = _require(contents, f"param/{key}", label, "the archive")
    if "rng" in params:
        params["rng"] = _decode_rng(params["rng"])
    try:
        model = cls(**params)
    except TypeError as exc:
        raise PersistenceError(f"{label}: the stored parameters do not fit {name}: {exc}") from None
    attributes = _require(header, "attributes", label, "the header", dict)
    array_attributes = _require(header, "array_attributes", label, "the header", list)
    for key in array_attributes:
        attributes[key] = _require(contents, f"attr/{key}", label, "the archive")
    for key, value in attributes.items():
        if not (isinstance(key, str) and key.isidentifier() and key.endswith("_") and not key.startswith("_")):
            raise PersistenceError(f"{label} is malformed: {key!r} is not a learnt attribute name")
        setattr(model, key, value)
    return model


# ----------------------------------------------------------------------------- demonstrations


def _episode(ep, where):
    arr = check_episode(ep, where)
    if np.any(arr < 0):
        raise ValidationError(f"{where} holds a negative state or action: {arr[np.any(arr < 0, axis=1)][0].tolist()}")
    return arr.astype(np.int64)


def save_demonstrations(demos_per_task, path):
    """Save demonstrations of several tasks, ragged or not, to an ``.npz`` file.

    Parameters
    ----------
    demos_per_task : list of n task demonstrations, or ndarray (n, m, L, 2)
        Each task an int array (m, L, 2), a single episode (L, 2), or a list of episodes of
        shapes (L_j, 2) (lengths may differ).
    path : str or os.PathLike or writable binary file
        Written as given (no ``.npz`` suffix is appended).

    Returns
    -------
    path

    Raises
    ------
    ValidationError
        An episode is not an (L, 2) array of nonnegative integers, or a task has no episode.
    """
    if isinstance(demos_per_task, np.ndarray) and demos_per_task.ndim == 4:
        demos_per_task = list(demos_per_task)
    if not isinstance(demos_per_task, (list, tuple)) or len(demos_per_task) == 0:
        raise ValidationError(
            "demos_per_task must be a non-empty list with one entry per task (or an array (n, m, L, 2)); "
            f"got {type(demos_per_task).__name__}"
        )
    forms, episodes, counts = [], [], []
    for i, task in enumerate(demos_per_task):
        where = f"demonstrations of task {i}"
        if isinstance(task, np.ndarray) and task.ndim == 3:
            forms.append("array")
            eps = list(task)
        elif isinstance(task, np.ndarray) and task.ndim == 2:
            forms.append("episode")
            eps = [task]
        elif isinstance(task, (list, tuple)):
            forms.append("list")
            eps = list(task)
        else:
            raise ValidationError(
                f"{where} must be an int array (m, L, 2) or a list of episodes (L_j, 2); "
                f"got {type(task).__name__} with shape {np.shape(task)}"
            )
        if not eps:
            raise ValidationError(f"{where} are empty: give at least one episode")
        episodes.extend(_episode(ep, f"episode {j} of {where}") for j, ep in enumerate(eps))
        counts.append(len(eps))
    arrays = {
        "steps": np.concatenate(episodes),
        "episode_lengths": np.array([len(ep) for ep in episodes], dtype=np.int64),
        "task_n_episodes": np.array(counts, dtype=np.int64),
    }
    return _write(path, {"kind": "demonstrations", "n_tasks": len(counts), "task_forms": forms}, arrays)


def load_demonstrations(path):
    """Load demonstrations written by :func:`save_demonstrations`.

    Parameters
    ----------
    path : str or os.PathLike or readable binary file

    Returns
    -------
    demos_per_task : list of n task demonstrations
        Each in the form it was saved in: an int64 array (m, L, 2), a single episode (L, 2),
        or a list of int64 episodes (L_j, 2).

    Raises
    ------
    PersistenceError
        The file is corrupt, not a factirl-opt file, holds a model, lacks a member, is
        inconsistent, or has a newer format version.
    FileNotFoundError
        No such file.
    """
    header, contents, label = _read(path, "demonstrations")
    forms = _require(header, "task_forms", label, "the header", list)
    steps = _require(contents, "steps", label, "the archive")
    lengths = _require(contents, "episode_lengths", label, "the archive")
    counts = _require(contents, "task_n_episodes", label, "the archive")
    for member, arr, ndim in (("steps", steps, 2), ("episode_lengths", lengths, 1), ("task_n_episodes", counts, 1)):
        if arr.ndim != ndim or arr.dtype.kind not in "iu":
            raise PersistenceError(f"{label}: member {member!r} must be a {ndim}-d integer array; got {arr.dtype} {arr.shape}")
    if (
        steps.shape[1:] != (2,)
        or len(forms) != len(counts)
        or counts.sum() != len(lengths)
        or lengths.sum() != len(steps)
        or np.any(lengths < 1)
        or np.any(counts < 1)
    ):
        raise PersistenceError(
            f"{label} is inconsistent: {len(forms)} task forms, "
            f"{len(counts)} tasks with {int(counts.sum())} episodes, {len(lengths)} episode lengths summing to "
            f"{int(lengths.sum())}, {steps.shape} steps"
        )
    episodes = np.split(steps, np.cumsum(lengths)[:-1])
    bounds = np.concatenate([[0], np.cumsum(counts)])
    out = []
    for i, form in enumerate(forms):
        eps = episodes[bounds[i]:bounds[i + 1]]
        if form == "list":
            out.append([np.array(ep) for ep in eps])
        elif form == "episode" and len(eps) == 1:
            out.append(np.array(eps[0]))
        elif form == "array" and len({len(ep) for ep in eps}) == 1:
            out.append(np.stack(eps))
        else:
            raise PersistenceError(f"{label} is inconsistent: task {i} has form {form!r} with episode lengths {[len(e) for e in eps]}")
    return out

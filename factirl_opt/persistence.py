"""Saving and loading fitted models and demonstration sets.

File format (``FORMAT_VERSION`` 2). A file is an ``.npz`` archive (``numpy.savez_compressed``)
holding plain numeric arrays only, so it loads with ``allow_pickle=False``, plus one member
``__header__``: a 0-d unicode array holding a JSON object::

    {"format": "factirl-opt", "format_version": 2, "kind": "model" | "demonstrations",
     "library_version": "0.1.0", "numpy_version": "1.26.4", ...}

A **model** file adds ``"class"`` (``"GradIRL"`` or ``"FactIRL"``), ``"params"`` (the
constructor parameters), ``"array_params"`` (names of parameters stored as arrays:
``features``, or ``init`` given as a tuple ``(D0, H0)``), ``"attributes"`` (learnt
attributes, the names ending in ``_``, that are not arrays: lists of losses, counts,
status strings, the MDP signature) and ``"array_attributes"``. Arrays are stored as members
``param/<name>`` and ``attr/<name>``, exactly (dtype and bits), so a loaded model transfers
and scores bit-identically.

The MDP signature. A fitted model carries ``mdp_signature_``, the
:meth:`~factirl_opt.TabularMDP.signature` of the MDP it was fitted on (S, A, gamma and a
SHA-256 of the transitions), so that it can refuse another MDP
(:func:`~factirl_opt.mdp.check_signature`); it is saved and loaded with the model. A file
holding learnt attributes but no signature (written by format version 1, or a model whose
attributes were set by hand) loads with ``mdp_signature_ = None``: such a model cannot
check the MDP it is used on.

Parameters that do not fit in JSON:

- a solver, objective or planner given as an object rather than a registry name (``solver``,
  ``h_solver``, ``d_solver``, ``objective``, ``planner``) is refused with a
  :class:`PersistenceError`: give it by name, a solver with its options
  (``solver="armijo", solver_options={...}``), which are stored;
- ``callback``, a function called during ``fit``, is not part of the model and is not saved:
  the loaded model has ``callback=None``;
- ``rng`` given as a ``numpy.random.Generator`` is stored as its bit generator's state (the
  loaded model gets a new Generator in that state); a ``SeedSequence`` by its entropy and
  spawn key; an int or None as is;
- options dicts must be JSON-serialisable (tuples come back as lists).

A **demonstrations** file stores the ``(state, action)`` steps of all episodes concatenated
(member ``steps``, int64 (N, 2)), the length of each episode (``episode_lengths``) and the
number of episodes of each task (``task_n_episodes``); the header's ``"task_forms"`` records
whether each task was an (m, L, 2) array (``"array"``) or a list of episodes (``"list"``),
and :func:`load_demonstrations` gives back the same form. Lists of episodes of different
lengths are therefore saved as they are; trajectories of other libraries are saved as their
(state, action) steps. (Format version 1 also wrote ``"episode"``, a task given as a single
(L, 2) array, which the nesting rule of :mod:`factirl_opt.trajectories` now refuses; such a
task loads as a list of one episode.)

Reading is defensive: a corrupt or truncated file, a corrupt compressed member, a header that
is not the expected JSON, a member of the wrong dtype or shape, non-finite values, negative
states or inconsistent lengths all raise :class:`PersistenceError` naming the file and, where
there is one, the member or attribute.
"""

import json
import os

import numpy as np

import solvers

from ._validation import check_int, check_real
from .exceptions import PersistenceError, ValidationError
from .factirl import FactIRL
from .gradirl import GradIRL
from .trajectories import parse_demonstrations

__all__ = ["save_model", "load_model", "save_demonstrations", "load_demonstrations", "FORMAT_VERSION"]

#: Version of the file format written by this library; files with a larger one are refused.
#: 2: models carry ``mdp_signature_``; demonstration tasks are "array" or "list".
FORMAT_VERSION = 2
_FORMAT = "factirl-opt"
_HEADER = "__header__"
_MODEL_CLASSES = {"GradIRL": GradIRL, "FactIRL": FactIRL}
#: Parameters given by registry name or as an object: only names can be saved (how to name one).
_NAMED_PARAMS = {
    "solver": "the solver's registry name and options",
    "h_solver": "the solver's registry name and options",
    "d_solver": "the solver's registry name and options",
    "objective": "a registered objective name (factirl_opt.objectives.register_objective, fo.available_objectives())",
    "planner": "a planner name (fo.available_planners())",
}
#: Parameters that are not part of the model and are not saved (the loaded model has the default).
_RUNTIME_PARAMS = ("callback",)
_ARRAY_PARAMS = ("features", "init")
_TASK_FORMS = ("array", "list", "episode")



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
            return None if spec["value"] is None else check_int(spec["value"], "the seed", minimum=0)
        if kind == "generator":
            bitgen_cls = getattr(np.random, str(spec["bit_generator"]), None)
            if not (isinstance(bitgen_cls, type) and issubclass(bitgen_cls, np.random.BitGenerator)):
                raise ValueError(f"{spec['bit_generator']!r} is not a numpy bit generator")
            bitgen = bitgen_cls()
            bitgen.state = spec["state"]
            return np.random.Generator(bitgen)
        if kind == "seed_sequence":
            return np.random.SeedSequence(
                spec["entropy"],
                spawn_key=tuple(spec["spawn_key"]),
                pool_size=spec["pool_size"],
                n_children_spawned=spec["n_children_spawned"],
            )
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:
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


def _members(path, label):
    """Every member of the .npz archive at ``path``, each read (and decompressed) on its own.

    numpy's .npz/.npy readers raise many types on damaged bytes (zipfile.BadZipFile,
    zlib.error, EOFError, NotImplementedError for a flipped compression method, RuntimeError
    for a flipped encryption flag, SyntaxError or tokenize.TokenError from the .npy header
    parser, MemoryError for a huge declared shape, ...): every one of them means the file is
    damaged, so both reading steps catch them all and name the file (and the member).
    """
    unreadable = f"{label} is not a readable factirl-opt file"
    try:
        loaded = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise
    except Exception as exc:  # damaged bytes, see the docstring
        raise PersistenceError(f"{unreadable} (corrupt or not an .npz archive): {type(exc).__name__}: {exc}") from None
    if not isinstance(loaded, np.lib.npyio.NpzFile):
        raise PersistenceError(f"{label} is not a factirl-opt file: it holds a single .npy array, not an .npz archive")
    contents = {}
    with loaded as npz:
        for name in npz.files:
            try:
                contents[name] = npz[name]
            except Exception as exc:  # damaged bytes, see the docstring
                raise PersistenceError(
                    f"{unreadable}: member {name!r} is corrupt or unreadable ({type(exc).__name__}: {exc})"
                ) from None
    return contents


def _read(path, kind):
    """The header and every array of a factirl-opt file of the given kind."""
    label = os.fspath(path) if isinstance(path, (str, os.PathLike)) else type(path).__name__
    contents = _members(path, label)
    if _HEADER not in contents:
        raise PersistenceError(f"{label} is an .npz archive but not a factirl-opt file: it has no {_HEADER} member")
    raw = contents.pop(_HEADER)
    try:
        header = json.loads(str(raw[()]))
    except (ValueError, IndexError, TypeError, RecursionError) as exc:
        raise PersistenceError(f"{label}: the {_HEADER} member is not valid JSON: {exc}") from None
    if not isinstance(header, dict) or header.get("format") != _FORMAT:
        raise PersistenceError(f"{label} is not a factirl-opt file: its header does not say format {_FORMAT!r}")
    version = header.get("format_version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise PersistenceError(f"{label}: the header's format_version is missing or not an integer >= 1: {version!r}")
    if version > FORMAT_VERSION:
        raise PersistenceError(
            f"{label} has format version {version}, written by factirl-opt {header.get('library_version', '?')}; "
            f"this is factirl-opt {_library_version()}, which reads versions up to {FORMAT_VERSION}: upgrade factirl-opt"
        )
    found = header.get("kind")
    if found != kind:
        loader = {"model": "load_model", "demonstrations": "load_demonstrations"}.get(found)
        hint = f"; use {loader}" if loader else ""
        raise PersistenceError(f"{label} holds {found!r:.40} data, not {kind!r}{hint}")
    return header, contents, label


def _require(mapping, key, label, where, kind=None):
    if key not in mapping:
        raise PersistenceError(f"{label} is incomplete: {where} lacks {key!r}")
    value = mapping[key]
    if kind is not None and not isinstance(value, kind):
        raise PersistenceError(f"{label} is malformed: {key!r} in {where} must be a {kind.__name__}; got {type(value).__name__}")
    return value


def _check_array(arr, what, context, ndim=None, kinds="biuf"):
    """A stored array: numeric of the given kinds and ndim, and finite; PersistenceError otherwise."""
    if arr.dtype.kind not in kinds or (ndim is not None and arr.ndim != ndim):
        rule = f"{ndim}-d " if ndim is not None else ""
        rule += "float" if kinds == "f" else "numeric"
        raise PersistenceError(f"{context}: {what} must be a {rule} array; got {arr.dtype} of shape {arr.shape}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise PersistenceError(f"{context}: {what} must be finite; found {arr[bad].item()!r} at index {bad}")
    return arr


# ----------------------------------------------------------------------------- learnt attributes

#: Learnt array attributes of the models and their ndim (float arrays, finite).
_ARRAY_ATTRIBUTES = {"weights_": 2, "dictionary_": 2, "coefficients_": 2, "transfer_coefficients_": 2,
                     "rewards_": 3, "transfer_rewards_": 3, "loss_": 1, "transfer_loss_": 1}
_COUNT_ATTRIBUTES = ("n_iter_", "n_evaluations_", "transfer_n_evaluations_")
_HISTORY_ATTRIBUTES = ("loss_history_", "transfer_loss_history_")
_TEXT_ATTRIBUTES = ("status_", "transfer_status_")
_SIGNATURE_KEYS = ("n_states", "n_actions", "gamma", "transitions_sha256")
#: (attribute, axis, attribute, axis): axes of learnt arrays that have the same length
_SHAPE_LINKS = (
    ("dictionary_", 1, "coefficients_", 1), ("dictionary_", 1, "transfer_coefficients_", 1),
    ("coefficients_", 0, "rewards_", 0), ("weights_", 0, "rewards_", 0), ("rewards_", 0, "loss_", 0),
    ("transfer_coefficients_", 0, "transfer_rewards_", 0), ("transfer_rewards_", 0, "transfer_loss_", 0),
    ("rewards_", 1, "transfer_rewards_", 1), ("rewards_", 2, "transfer_rewards_", 2),
)


def _check_signature(sig, context):
    """``mdp_signature_``: None or a :meth:`TabularMDP.signature` dict."""
    if sig is None:
        return
    if not isinstance(sig, dict) or sorted(sig) != sorted(_SIGNATURE_KEYS):
        raise PersistenceError(f"{context}: mdp_signature_ must be None or a dict with keys {list(_SIGNATURE_KEYS)}; got {sig!r:.120}")
    try:
        check_int(sig["n_states"], "mdp_signature_ n_states", minimum=1)
        check_int(sig["n_actions"], "mdp_signature_ n_actions", minimum=1)
        check_real(sig["gamma"], "mdp_signature_ gamma", 0.0, 1.0, high_open=True)
    except ValidationError as exc:
        raise PersistenceError(f"{context}: {exc}") from None
    digest = sig["transitions_sha256"]
    if not (isinstance(digest, str) and len(digest) == 64 and set(digest) <= set("0123456789abcdef")):
        raise PersistenceError(f"{context}: mdp_signature_ transitions_sha256 must be 64 hexadecimal digits; got {digest!r:.80}")


def _check_attribute(key, value, context):
    if not (isinstance(key, str) and key.isidentifier() and key.endswith("_") and not key.startswith("_")):
        raise PersistenceError(f"{context}: {key!r} is not a learnt attribute name")
    ndim = _ARRAY_ATTRIBUTES.get(key)
    if isinstance(value, np.ndarray):
        _check_array(value, f"attribute {key}", context, ndim, "f" if ndim else "biuf")
    elif ndim is not None:
        raise PersistenceError(f"{context}: attribute {key} must be a {ndim}-d float array; got {type(value).__name__} {value!r:.60}")
    elif key == "mdp_signature_":
        _check_signature(value, context)
    try:
        if key in _COUNT_ATTRIBUTES:
            check_int(value, f"attribute {key}", minimum=0)
        elif key in _HISTORY_ATTRIBUTES:
            if not isinstance(value, list):
                raise ValidationError(f"attribute {key} must be a list of finite numbers; got {type(value).__name__}")
            for t, v in enumerate(value):
                check_real(v, f"attribute {key}[{t}]")
        elif key in _TEXT_ATTRIBUTES and not isinstance(value, str):
            raise ValidationError(f"attribute {key} must be a string; got {value!r:.60}")
    except ValidationError as exc:
        raise PersistenceError(f"{context}: {exc}") from None


def _check_attributes(attributes, context):
    """Each learnt attribute of the right type, the arrays' shapes consistent with each other."""
    for key, value in attributes.items():
        _check_attribute(key, value, context)
    for a, i, b, j in _SHAPE_LINKS:
        x, y = attributes.get(a), attributes.get(b)
        if isinstance(x, np.ndarray) and isinstance(y, np.ndarray) and x.shape[i] != y.shape[j]:
            raise PersistenceError(f"{context}: attributes {a} of shape {x.shape} and {b} of shape {y.shape} disagree "
                                   f"(axis {i} of {a} and axis {j} of {b} must have the same length)")
    sig, R = attributes.get("mdp_signature_"), attributes.get("rewards_")
    if sig is not None and isinstance(R, np.ndarray) and R.shape[1:] != (sig["n_states"], sig["n_actions"]):
        raise PersistenceError(f"{context}: rewards_ of shape {R.shape} do not fit the MDP of mdp_signature_ "
                               f"(S, A) = ({sig['n_states']}, {sig['n_actions']})")


# ----------------------------------------------------------------------------- models


def _named_param_error(name, key, value):
    what = value.__name__ if isinstance(value, type) else type(value).__name__
    hint = _NAMED_PARAMS[key]
    if key.endswith("solver"):
        hint += f", e.g. {key}={getattr(value, 'name', 'armijo')!r} (registered: {', '.join(solvers.registered_solvers())})"
    return PersistenceError(f"cannot save {name} with {key} given as a {what} object: construct it with {hint} instead")


def _model_params(model, name):
    """The constructor parameters: JSON values, arrays, and the names of the array ones."""
    params, arrays, array_params = {}, {}, []
    for key, value in vars(model).items():
        if key.startswith("_") or key.endswith("_") or key in _RUNTIME_PARAMS:
            continue
        if key in _NAMED_PARAMS and not isinstance(value, str):
            raise _named_param_error(name, key, value)
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
    return params, arrays, array_params


def _model_attributes(model, name):
    """The learnt attributes (names ending in ``_``): JSON values and arrays, checked."""
    attributes, arrays = {}, {}
    for key, value in vars(model).items():
        if not key.endswith("_") or key.startswith("_"):
            continue
        if isinstance(value, np.ndarray):
            if value.dtype.hasobject:
                raise PersistenceError(f"cannot save {name} attribute {key}: it is an object array")
            arrays[key] = value
        else:
            attributes[key] = _to_json(value, f"{name} attribute {key}")
    _check_attributes({**attributes, **arrays}, f"cannot save {name}")
    return attributes, arrays


def save_model(model, path):
    """Save a :class:`GradIRL` or :class:`FactIRL` (fitted or not) to an ``.npz`` file.

    Stores the constructor parameters (except ``callback``, which is not saved) and every learnt
    attribute (names ending in ``_``, including ``mdp_signature_``, the signature of the MDP the
    model was fitted on), arrays exactly; see the module docstring for the format.

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
        The model has a solver, objective or planner given as an object, a parameter or
        attribute that is neither
        an array nor JSON-serialisable, or a learnt attribute of the wrong type, shape or with
        non-finite values (the message names it).
    ValidationError
        ``model`` is not a GradIRL or FactIRL.
    """
    cls = type(model)
    name = next((n for n, c in _MODEL_CLASSES.items() if cls is c), None)
    if name is None:
        raise ValidationError(f"model must be a GradIRL or FactIRL; got {cls.__name__}")
    params, arrays, array_params = _model_params(model, name)
    attributes, array_attributes = _model_attributes(model, name)
    arrays.update({f"attr/{key}": value for key, value in array_attributes.items()})
    header = {"kind": "model", "class": name, "params": params, "array_params": array_params, "attributes": attributes,
              "array_attributes": list(array_attributes)}
    return _write(path, header, arrays)


def _load_params(header, contents, label):
    params = dict(_require(header, "params", label, "the header", dict))
    context = f"{label} is malformed"
    for key in _RUNTIME_PARAMS:
        if key in params:
            raise PersistenceError(f"{context}: {key!r} is never saved, yet the header's parameters hold it")
    for key in _require(header, "array_params", label, "the header", list):
        if key not in _ARRAY_PARAMS:
            raise PersistenceError(f"{context}: {key!r} is not an array parameter (known: {', '.join(_ARRAY_PARAMS)})")
        if key == "init":
            params["init"] = tuple(
                _check_array(_require(contents, f"param/init/{i}", label, "the archive"), f"parameter init[{i}]", context, ndim=2)
                for i in (0, 1)
            )
        else:
            params[key] = _check_array(_require(contents, f"param/{key}", label, "the archive"), f"parameter {key}", context, ndim=2)
    if "rng" in params:
        try:
            params["rng"] = _decode_rng(params["rng"])
        except PersistenceError as exc:
            raise PersistenceError(f"{label}: {exc}") from None
    return params


def _load_attributes(header, contents, label):
    attributes = dict(_require(header, "attributes", label, "the header", dict))
    for key in _require(header, "array_attributes", label, "the header", list):
        if not isinstance(key, str):
            raise PersistenceError(f"{label} is malformed: array attribute names must be strings; got {key!r:.40}")
        if key in attributes:
            raise PersistenceError(f"{label} is malformed: attribute {key} is stored twice (in the header and as an array)")
        attributes[key] = _require(contents, f"attr/{key}", label, "the archive")
    _check_attributes(attributes, f"{label} is malformed")
    return attributes


def load_model(path):
    """Load a model written by :func:`save_model`.

    Parameters
    ----------
    path : str or os.PathLike or readable binary file

    Returns
    -------
    model : GradIRL or FactIRL
        With the saved parameters and learnt attributes: it transfers and scores exactly like
        the saved model. A file with learnt attributes but no ``mdp_signature_`` (format
        version 1, or attributes set by hand) gives ``mdp_signature_ = None``: such a model
        cannot check the MDP it is used on.

    Raises
    ------
    PersistenceError
        The file is corrupt (also a single corrupt compressed member), not a factirl-opt file,
        holds demonstrations, lacks a member or header entry, holds an array of the wrong
        dtype or shape or with non-finite values, or has a newer format version (the message
        names the file and what is wrong).
    FileNotFoundError
        No such file.
    """
    header, contents, label = _read(path, "model")
    name = _require(header, "class", label, "the header", str)
    if name not in _MODEL_CLASSES:
        raise PersistenceError(f"{label} holds a model of unknown class {name!r:.40}; known: {', '.join(_MODEL_CLASSES)}")
    params = _load_params(header, contents, label)
    attributes = _load_attributes(header, contents, label)
    try:
        model = _MODEL_CLASSES[name](**params)
    except TypeError as exc:
        raise PersistenceError(f"{label}: the stored parameters do not fit {name}: {exc}") from None
    for key, value in attributes.items():
        setattr(model, key, value)
    if attributes and "mdp_signature_" not in attributes:
        model.mdp_signature_ = None
    return model


# ----------------------------------------------------------------------------- demonstrations


def save_demonstrations(demos_per_task, path):
    """Save demonstrations of several tasks, ragged or not, to an ``.npz`` file.

    Parameters
    ----------
    demos_per_task : list of n task demonstrations, or ndarray (n, m, L, 2)
        Any layout the learners accept (:mod:`factirl_opt.trajectories`): each task an int
        array (m, L, 2) or a list of episodes, each (L_j, 2) pairs (lengths may differ) or a
        trajectory with integer ``obs`` and ``acts`` (saved as its (state, action) steps).
    path : str or os.PathLike or writable binary file
        Written as given (no ``.npz`` suffix is appended).

    Returns
    -------
    path

    Raises
    ------
    ValidationError
        The demonstrations are not in an accepted layout, or hold a value that is not an
        integer >= 0 (the message names task, episode and step).
    """
    tasks = parse_demonstrations(demos_per_task)
    arrays = {
        "steps": np.concatenate([task.steps for task in tasks]),
        "episode_lengths": np.concatenate([task.lengths for task in tasks]),
        "task_n_episodes": np.array([len(task.lengths) for task in tasks], dtype=np.int64),
    }
    header = {"kind": "demonstrations", "n_tasks": len(tasks), "task_forms": [task.form for task in tasks]}
    return _write(path, header, arrays)


def _demonstration_arrays(header, contents, label):
    """The task forms and the steps, episode lengths and episode counts, checked consistent."""
    forms = _require(header, "task_forms", label, "the header", list)
    steps = _require(contents, "steps", label, "the archive")
    lengths = _require(contents, "episode_lengths", label, "the archive")
    counts = _require(contents, "task_n_episodes", label, "the archive")
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


def load_demonstrations(path):
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
        message names task, episode and step), or has a newer format version.
    FileNotFoundError
        No such file.
    """
    header, contents, label = _read(path, "demonstrations")
    forms, steps, lengths, counts = _demonstration_arrays(header, contents, label)
    episodes = np.split(steps, np.cumsum(lengths)[:-1])
    bounds = np.concatenate([[0], np.cumsum(counts)])
    out = []
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

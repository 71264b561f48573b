"""The constructor parameters of a saved estimator: JSON values, arrays and the ``rng``.

Which parameters there are comes from the estimator (``get_params()``, its ``__init__``'s
signature: :class:`factirl_opt.learners.estimator.Estimator`), and how each is stored from the kind
its class declares in ``param_kinds`` (:data:`PARAM_KINDS`); a parameter not declared there
is a plain JSON value.
"""

from __future__ import annotations

from typing import Any

import numpy as np

import solvers

from .._validation import check_int
from ..exceptions import FactIRLError, PersistenceError
from ..tasks.task_set import per_task_features
from ..learners.solver_settings import SolverSettings
from ..learners.selection.sharing_search import SharingSearch
from .archive import check_array, require, to_json

__all__ = ["PARAM_KINDS", "ARRAY_KINDS", "param_kind", "encode_params", "decode_params", "encode_rng", "decode_rng"]

#: The kinds of parameters an estimator class declares in ``param_kinds``, and how each is stored.
PARAM_KINDS = {
    "json": "a plain JSON value (the default kind)",
    "solver": "a solver's registry name (with its options in their own parameter), a SolverSettings, or None",
    "objective": "a registered objective name (factirl_opt.objectives.register_objective, fo.available_objectives())",
    "planner": "a planner name (fo.available_planners())",
    "rng": "None, a seed, a numpy Generator (its bit generator's state) or a SeedSequence",
    "features": "None, an array (member param/<name>) or one array per task (members param/<name>/<i>)",
    "dictionary-start": "a name, or a tuple (D0, H0) of arrays (members param/<name>/0 and /1)",
    "responsibility-start": "a name, or an array of labels or responsibilities (member param/<name>)",
    "runtime": "not saved: how a fit is watched and where it runs (the loaded model has the default)",
    "sharing-search": "None or a SharingSearch with an int cv (its parameters as JSON)",
    "group": "a parameter group (Start, Execution, ...): each field as its own kind, under <group>__<field>",
}
#: The kinds that may be stored as archive members (listed in the header's ``"array_params"``).
ARRAY_KINDS = ("features", "dictionary-start", "responsibility-start")
#: The kinds given by registry name: an object cannot be saved (what to give instead).
_NAMED = {"solver": "the solver's registry name and options", "objective": PARAM_KINDS["objective"],
          "planner": PARAM_KINDS["planner"]}


def param_kind(cls: type, name: str) -> str:
    """The kind of parameter ``name`` of estimator class ``cls`` (``"json"`` when it declares none)."""
    return dict(getattr(cls, "param_kinds", {})).get(name, "json")


# ----------------------------------------------------------------------------- rng


def encode_rng(rng: Any) -> dict:
    """``rng`` (None, a seed, a Generator or a SeedSequence) as JSON data."""
    if rng is None or (isinstance(rng, (int, np.integer)) and not isinstance(rng, bool)):
        return {"type": "seed", "value": None if rng is None else int(rng)}
    if isinstance(rng, np.random.Generator):
        state = rng.bit_generator.state
        return {"type": "generator", "bit_generator": state["bit_generator"], "state": to_json(state, "rng state")}
    if isinstance(rng, np.random.SeedSequence):
        return {
            "type": "seed_sequence",
            "entropy": to_json(rng.entropy, "rng entropy"),
            "spawn_key": list(rng.spawn_key),
            "pool_size": rng.pool_size,
            "n_children_spawned": rng.n_children_spawned,
        }
    raise PersistenceError(f"cannot save rng of type {type(rng).__name__}: give a seed, a Generator or a SeedSequence")


def decode_rng(spec: Any) -> int | None | np.random.Generator | np.random.SeedSequence:
    """The ``rng`` stored by :func:`encode_rng`; only numpy's bit generators are looked up."""
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


# ----------------------------------------------------------------------------- parameters


def _named_param_error(name: str, key: str, kind: str, value: Any) -> PersistenceError:
    what = value.__name__ if isinstance(value, type) else type(value).__name__
    hint = _NAMED[kind]
    if kind == "solver":
        hint += f", e.g. {key}={getattr(value, 'name', 'armijo')!r} (registered: {', '.join(solvers.registered_solvers())})"
    return PersistenceError(f"cannot save {name} with {key} given as a {what} object: construct it with {hint} instead")


def _member(value: Any, name: str, key: str) -> np.ndarray:
    """A parameter given as an array, as an archive member: numbers only (no object arrays)."""
    arr = np.asarray(value)
    if arr.dtype.hasobject:
        raise PersistenceError(f"cannot save {name} parameter {key}: it is not a numeric array ({type(value).__name__})")
    return arr


def _encode_one(name: str, key: str, kind: str, value: Any, arrays: dict[str, np.ndarray]) -> tuple[Any, bool]:
    """Parameter ``key`` of kind ``kind``: its JSON value, and whether it went to ``arrays`` as members."""
    if kind in _NAMED and not (value is None or isinstance(value, str)):
        if kind == "solver" and isinstance(value, SolverSettings):
            objects = [(f, v) for f, v in value.fields().items() if not isinstance(v, str)]
            if objects:
                raise _named_param_error(name, f"{key}.{objects[0][0]}", kind, objects[0][1])
            return {"solver_settings": value.fields()}, False
        raise _named_param_error(name, key, kind, value)
    if kind == "rng":
        return encode_rng(value), False
    if kind == "sharing-search" and value is not None:
        if not isinstance(value, SharingSearch):
            raise PersistenceError(f"cannot save {name} with {key} a {type(value).__name__}: give a SharingSearch or None")
        sub = value.get_params(deep=False)
        if isinstance(sub["cv"], bool) or not isinstance(sub["cv"], (int, np.integer)):
            raise PersistenceError(f"cannot save {name} with {key}.cv={sub['cv']!r:.60}: only a number of folds is "
                                   "saved (a splitter or explicit folds are not)")
        return {"sharing_search": to_json(sub, f"{name} parameter {key}")}, False
    if kind == "features" and per_task_features(value):  # one matrix per task: members <key>/0, 1, ...
        arrays.update({f"param/{key}/{i}": _member(F, name, key) for i, F in enumerate(value)})
        return {"per_task": len(value)}, True
    if kind == "features" and value is not None:
        arrays[f"param/{key}"] = _member(value, name, key)
        return None, True
    if kind == "dictionary-start" and isinstance(value, tuple):
        if len(value) != 2:
            raise PersistenceError(f"cannot save {name} with {key} a tuple of length {len(value)}: expected (D0, H0)")
        arrays[f"param/{key}/0"], arrays[f"param/{key}/1"] = _member(value[0], name, key), _member(value[1], name, key)
        return None, True
    if kind == "responsibility-start" and not isinstance(value, str):
        arrays[f"param/{key}"] = _member(value, name, key)
        return None, True
    return to_json(value, f"{name} parameter {key}={value!r:.80}"), False


def encode_params(model: Any, name: str) -> tuple[dict, dict[str, np.ndarray], list[str]]:
    """The parameters of ``model.get_params()``, each as its class declares its kind.

    Returns the JSON values, the arrays (archive members) and the names of the parameters
    stored as arrays; ``"runtime"`` parameters are left out.
    """
    params: dict[str, Any] = {}
    arrays: dict[str, np.ndarray] = {}
    array_params: list[str] = []
    cls = type(model)
    for top, group in model.get_params(deep=False).items():
        pairs = [(top, group)]
        if param_kind(cls, top) == "group" and group is not None:  # its fields, each as its own kind
            kind = cls.param_groups[top]
            group = group if isinstance(group, kind) else kind.of(group)  # a group given by a name (a kind)
            pairs = [(f"{top}__{k}", v) for k, v in group.get_params().items()]
        for key, value in pairs:
            kind = param_kind(cls, key)
            if kind == "runtime":
                continue
            encoded, as_array = _encode_one(name, key, kind, value, arrays)
            if as_array:
                array_params.append(key)
            if not as_array or encoded is not None:
                params[key] = encoded
    return params, arrays, array_params


def _per_task_features(key: str, spec: dict, contents: dict[str, np.ndarray], label: str) -> list[np.ndarray]:
    """The per-task feature matrices stored as members ``param/<key>/i``."""
    n = spec.get("per_task")
    if sorted(spec) != ["per_task"] or isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise PersistenceError(f"{label} is malformed: the {key} parameter must be {{'per_task': n >= 1}}; got {spec!r:.80}")
    return [check_array(require(contents, f"param/{key}/{i}", label, "the archive"), f"parameter {key}[{i}]",
                        f"{label} is malformed", ndim=2) for i in range(n)]


def _decode_array(key: str, kind: str, stored: Any, contents: dict[str, np.ndarray], label: str) -> Any:
    """Parameter ``key`` of an array kind, from its members."""
    context = f"{label} is malformed"
    if kind == "dictionary-start":
        return tuple(check_array(require(contents, f"param/{key}/{i}", label, "the archive"), f"parameter {key}[{i}]",
                                 context, ndim=2) for i in (0, 1))
    if kind == "features" and isinstance(stored, dict):
        return _per_task_features(key, stored, contents, label)
    value = check_array(require(contents, f"param/{key}", label, "the archive"), f"parameter {key}", context,
                        ndim=2 if kind == "features" else None)
    if kind == "responsibility-start" and value.ndim not in (1, 2):
        raise PersistenceError(f"{context}: parameter {key} must be a 1-d (labels) or 2-d (responsibilities) array; "
                               f"got shape {value.shape}")
    return value


def _decode_solver(key: str, value: Any, label: str) -> Any:
    """A ``"solver"`` parameter: a name, None, or the fields of a SolverSettings."""
    if not isinstance(value, dict):
        return value
    fields = value.get("solver_settings")
    if sorted(value) != ["solver_settings"] or not isinstance(fields, dict):
        raise PersistenceError(f"{label} is malformed: parameter {key} must be a name or {{'solver_settings': {{...}}}}; "
                               f"got {value!r:.80}")
    try:
        return SolverSettings(**fields)
    except (TypeError, FactIRLError) as exc:  # a field unknown or invalid, or its solver not registered or installed here
        raise PersistenceError(f"{label}: the solver settings of parameter {key} are not valid here: {exc}") from None


def _decode_sharing_search(key: str, value: Any, label: str) -> SharingSearch:
    """A ``"sharing-search"`` parameter: the parameters of a SharingSearch, checked."""
    fields = value.get("sharing_search") if isinstance(value, dict) else None
    if not isinstance(value, dict) or sorted(value) != ["sharing_search"] or not isinstance(fields, dict):
        raise PersistenceError(f"{label} is malformed: parameter {key} must be {{'sharing_search': {{...}}}}; got {value!r:.80}")
    fields = {k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()}
    try:
        search = SharingSearch(**fields)
        search.check()
    except (TypeError, FactIRLError) as exc:
        raise PersistenceError(f"{label}: the sharing search of parameter {key} is not valid: {exc}") from None
    return search


def decode_params(cls: type, header: dict, contents: dict[str, np.ndarray], label: str) -> dict[str, Any]:
    """The parameters stored by :func:`encode_params` for estimator class ``cls``, checked.

    A parameter stored under a name the class has since renamed (``cls.deprecated_params``)
    is returned under its name now.
    """
    params = dict(require(header, "params", label, "the header", dict))
    context = f"{label} is malformed"
    renamed: dict[str, str] = dict(getattr(cls, "deprecated_params", {}))
    for old, new in renamed.items():  # a file of before a rename, or before the groups (a field's former name)
        if old in params and new not in params:
            params[new] = params.pop(old)
    for key in params:
        if param_kind(cls, key) == "runtime":
            raise PersistenceError(f"{context}: {key!r} is never saved, yet the header's parameters hold it")
    array_names = [key for key in dict(getattr(cls, "param_kinds", {})) if param_kind(cls, key) in ARRAY_KINDS]
    for stored in require(header, "array_params", label, "the header", list):
        if not isinstance(stored, str):
            raise PersistenceError(f"{context}: array parameter names must be strings; got {stored!r:.40}")
        key = renamed.get(stored, stored)
        kind = param_kind(cls, key)
        if kind not in ARRAY_KINDS:
            raise PersistenceError(f"{context}: {key!r:.40} is not an array parameter (known: {', '.join(array_names)})")
        params[key] = _decode_array(stored, kind, params.get(key), contents, label)
    for key, value in params.items():
        kind = param_kind(cls, key)
        if kind == "solver":
            params[key] = _decode_solver(key, value, label)
        elif kind == "sharing-search" and value is not None:
            params[key] = _decode_sharing_search(key, value, label)
        elif kind == "rng":
            try:
                params[key] = decode_rng(value)
            except PersistenceError as exc:
                raise PersistenceError(f"{label}: {exc}") from None
    return _grouped(cls, params, label)


def _grouped(cls: type, params: dict[str, Any], label: str) -> dict[str, Any]:
    """``params`` with the fields ``<group>__<field>`` of each group as the group's value."""
    fields: dict[str, dict[str, Any]] = {}
    for key in [k for k in params if "__" in k]:
        top, _, sub = key.partition("__")
        fields.setdefault(top, {})[sub] = params.pop(key)
    for top, sub_params in fields.items():
        if param_kind(cls, top) == "group" or top == "solver":
            group = params.get(top)
            try:
                kind = getattr(cls, "param_groups")[top]
                group = kind() if group is None else kind.of(group)
                params[top] = group.set_params(**sub_params)
            except (TypeError, AttributeError, FactIRLError) as exc:
                raise PersistenceError(f"{label}: the stored fields of parameter {top} are not valid: {exc}") from None
        else:
            raise PersistenceError(f"{label} is malformed: {top!r:.40} holds no fields ({', '.join(sub_params)})")
    return params

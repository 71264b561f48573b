"""The constructor parameters of a saved estimator: JSON values, arrays and the ``rng``."""

from __future__ import annotations

from typing import Any

import numpy as np

import solvers

from .._validation import check_int
from ..exceptions import PersistenceError
from ..learners.fitting import per_task_features
from .archive import check_array, require, to_json

__all__ = ["NAMED_PARAMS", "RUNTIME_PARAMS", "ARRAY_PARAMS", "encode_params", "decode_params", "encode_rng", "decode_rng"]

#: Parameters given by registry name or as an object: only names can be saved (how to name one).
NAMED_PARAMS = {
    "solver": "the solver's registry name and options",
    "h_solver": "the solver's registry name and options",
    "d_solver": "the solver's registry name and options",
    "objective": "a registered objective name (factirl_opt.objectives.register_objective, fo.available_objectives())",
    "planner": "a planner name (fo.available_planners())",
}
#: Parameters that are not part of the model and are not saved (the loaded model has the default):
#: how a fit is watched and where its evaluations run.
RUNTIME_PARAMS = ("callback", "n_jobs", "backend", "client", "planner_options")
#: Parameters stored as arrays when given as arrays.
ARRAY_PARAMS = ("features", "init")


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


def _named_param_error(name: str, key: str, value: Any) -> PersistenceError:
    what = value.__name__ if isinstance(value, type) else type(value).__name__
    hint = NAMED_PARAMS[key]
    if key.endswith("solver"):
        hint += f", e.g. {key}={getattr(value, 'name', 'armijo')!r} (registered: {', '.join(solvers.registered_solvers())})"
    return PersistenceError(f"cannot save {name} with {key} given as a {what} object: construct it with {hint} instead")


def encode_params(model: Any, name: str) -> tuple[dict, dict[str, np.ndarray], list[str]]:
    """The constructor parameters: JSON values, arrays (archive members) and the names of the array ones."""
    params, arrays, array_params = {}, {}, []
    for key, value in vars(model).items():
        if key.startswith("_") or key.endswith("_") or key in RUNTIME_PARAMS:
            continue
        if key in NAMED_PARAMS and not isinstance(value, str):
            raise _named_param_error(name, key, value)
        if key == "rng":
            params[key] = encode_rng(value)
        elif key == "features" and per_task_features(value):  # one matrix per task: members features/0, 1, ...
            params[key] = {"per_task": len(value)}
            arrays.update({f"param/features/{i}": np.asarray(F) for i, F in enumerate(value)})
            array_params.append(key)
        elif key == "features" and value is not None:
            arrays["param/features"] = np.asarray(value)
            array_params.append(key)
        elif key == "init" and isinstance(value, tuple):
            if len(value) != 2:
                raise PersistenceError(f"cannot save {name} with init a tuple of length {len(value)}: expected (D0, H0)")
            arrays["param/init/0"], arrays["param/init/1"] = np.asarray(value[0]), np.asarray(value[1])
            array_params.append(key)
        else:
            params[key] = to_json(value, f"{name} parameter {key}={value!r:.80}")
    return params, arrays, array_params


def _per_task_features(spec: dict, contents: dict[str, np.ndarray], label: str) -> list[np.ndarray]:
    """The per-task feature matrices stored as members ``param/features/i``."""
    n = spec.get("per_task")
    if sorted(spec) != ["per_task"] or isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise PersistenceError(f"{label} is malformed: the features parameter must be {{'per_task': n >= 1}}; got {spec!r:.80}")
    return [check_array(require(contents, f"param/features/{i}", label, "the archive"), f"parameter features[{i}]",
                        f"{label} is malformed", ndim=2) for i in range(n)]


def decode_params(header: dict, contents: dict[str, np.ndarray], label: str) -> dict[str, Any]:
    """The constructor parameters stored by :func:`encode_params`, checked."""
    params = dict(require(header, "params", label, "the header", dict))
    context = f"{label} is malformed"
    for key in RUNTIME_PARAMS:
        if key in params:
            raise PersistenceError(f"{context}: {key!r} is never saved, yet the header's parameters hold it")
    for key in require(header, "array_params", label, "the header", list):
        if key not in ARRAY_PARAMS:
            raise PersistenceError(f"{context}: {key!r} is not an array parameter (known: {', '.join(ARRAY_PARAMS)})")
        if key == "init":
            params["init"] = tuple(
                check_array(require(contents, f"param/init/{i}", label, "the archive"), f"parameter init[{i}]", context, ndim=2)
                for i in (0, 1)
            )
        elif key == "features" and isinstance(params.get("features"), dict):
            params["features"] = _per_task_features(params["features"], contents, label)
        else:
            params[key] = check_array(require(contents, f"param/{key}", label, "the archive"), f"parameter {key}", context, ndim=2)
    if "rng" in params:
        try:
            params["rng"] = decode_rng(params["rng"])
        except PersistenceError as exc:
            raise PersistenceError(f"{label}: {exc}") from None
    return params

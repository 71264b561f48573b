"""Saving and loading estimators (:class:`GradIRL`, :class:`FactIRL`, :class:`MultiIntentIRL`), fitted or not."""

from __future__ import annotations

from typing import IO, Any

import numpy as np

from ..exceptions import PersistenceError, ValidationError
from ..learners.factirl import FactIRL
from ..tasks.task_set import per_task_features
from ..learners.gradirl import GradIRL
from ..learners.multi_intent import MultiIntentIRL
from .archive import Target, read_archive, require, to_json, write_archive
from .learnt import check_features_digest, check_learnt, decode_learnt, check_task_features, fitted_features_sha256, learnt_attributes
from .params import decode_params, encode_params, param_kind
from .posterior import load_transfer_posterior, save_transfer_posterior
from .successor_features import load_successor_features, save_successor_features

__all__ = ["MODEL_CLASSES", "save_model", "load_model"]

#: The estimator classes a file can hold, by the name stored in its header.
MODEL_CLASSES: dict[str, type] = {cls.__name__: cls for cls in (GradIRL, FactIRL, MultiIntentIRL)}


def _base_features(cls: type, params: dict[str, Any]) -> Any:
    """The value of the class's parameter of kind ``"features"`` (the base features the learnt
    attributes are checked against), None if it declares none."""
    names = [key for key in dict(getattr(cls, "param_kinds", {})) if param_kind(cls, key) == "features"]
    return params.get(names[0]) if names else None


def _feature_columns(features: Any) -> int | None:
    """Columns of a features parameter (None without features, or if it is not a matrix); per-task: of the first."""
    if features is None:
        return None
    shape = np.shape(features[0]) if per_task_features(features) else np.shape(features)
    return int(shape[1]) if len(shape) == 2 else None


def _check(cls: type, attributes: dict[str, Any], features: Any, context: str) -> None:
    check_learnt(cls, attributes, context, _feature_columns(features))
    if not per_task_features(features):
        check_features_digest(attributes, None if features is None else np.asarray(features), context)
    elif attributes:
        check_task_features(attributes, list(features), context)


def _is_array_list(value: Any) -> bool:
    """A per-task list of arrays (environments of different sizes)."""
    return isinstance(value, list) and len(value) > 0 and all(isinstance(v, np.ndarray) for v in value)


def _encode_attributes(model: Any, cls: type) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The learnt attributes the class declares and the model has, as JSON values and arrays, checked.

    Any other attribute named as a learnt one (ending in ``_``) is refused rather than dropped
    (:func:`~.learnt.check_learnt`): the loaded model would silently lack it.
    """
    name = cls.__name__
    declared = learnt_attributes(cls)
    attributes, arrays = {}, {}
    present = {key: getattr(model, key) for key in declared  # a property (a deprecated alias) is not stored
               if not isinstance(getattr(type(model), key, None), property) and hasattr(model, key)}
    present.update({key: value for key, value in vars(model).items()
                    if key.endswith("_") and not key.startswith("_") and key not in declared})
    for key, value in present.items():
        if isinstance(value, np.ndarray):
            if value.dtype.hasobject:
                raise PersistenceError(f"cannot save {name} attribute {key}: it is an object array")
            arrays[key] = value
        elif _is_array_list(value):
            arrays[key] = value
        else:
            attributes[key] = to_json(value, f"{name} attribute {key}")
    _check(cls, {**attributes, **arrays}, _base_features(cls, model.get_params(deep=False)), f"cannot save {name}")
    return attributes, arrays


def save_model(model: GradIRL | FactIRL | MultiIntentIRL, path: Target) -> str | IO[bytes]:
    """Save a :class:`GradIRL`, :class:`FactIRL` or :class:`MultiIntentIRL` (fitted or not) to an ``.npz`` file.

    Stores the parameters of ``model.get_params()``, each as the class declares its kind in
    ``param_kinds`` (the execution settings ``callback``, ``n_jobs``, ``backend``, ``client``
    and ``planner_options`` are not saved), and the learnt attributes the class declares in
    ``learnt_attributes`` (arrays exactly), each checked against its declared kind; see
    :mod:`factirl_opt.persistence` for the format.
    A path is written atomically: on a failure (a full disk, Ctrl-C) the previous file stays
    intact and no partial file remains.

    Parameters
    ----------
    model : GradIRL, FactIRL or MultiIntentIRL
    path : str or os.PathLike or writable binary file
        Written as given (no ``.npz`` suffix is appended).

    Returns
    -------
    path : str or file
        The path written (as a string), or the file object.

    Raises
    ------
    PersistenceError
        The model has a solver, objective or planner given as an object, a parameter that is
        neither an array nor JSON-serialisable, a learnt attribute its class does not declare
        or of the wrong type, shape or with non-finite values, or a ``features_sha256_`` that
        is not the digest of its ``features`` (the message names it); or the file cannot be
        written (a missing or read-only directory, a path that is a directory, a full disk:
        the message names the path and the cause, the ``OSError`` is chained).
    ValidationError
        ``model`` is not a GradIRL, FactIRL or MultiIntentIRL, or ``path`` neither a path nor a
        writable file.
    """
    cls = type(model)
    if MODEL_CLASSES.get(cls.__name__) is not cls:
        raise ValidationError(f"model must be one of {', '.join(MODEL_CLASSES)}; got {cls.__name__}")
    params, arrays, array_params = encode_params(model, cls.__name__)
    attributes, array_attributes = _encode_attributes(model, cls)
    lists = {key: len(value) for key, value in array_attributes.items() if isinstance(value, list)}
    for key, value in array_attributes.items():
        if key in lists:
            arrays.update({f"attr/{key}/{i}": v for i, v in enumerate(value)})
        else:
            arrays[f"attr/{key}"] = value
    header = {"kind": "model", "class": cls.__name__, "params": params, "array_params": array_params,
              "attributes": attributes, "array_attributes": [key for key in array_attributes if key not in lists]}
    if lists:
        header["array_list_attributes"] = lists
    save_transfer_posterior(model, header, arrays)
    save_successor_features(model, header, arrays)
    return write_archive(path, header, arrays)


def _decode_attributes(cls: type, header: dict, contents: dict[str, np.ndarray], label: str, features: Any) -> dict[str, Any]:
    attributes = dict(require(header, "attributes", label, "the header", dict))
    for key in require(header, "array_attributes", label, "the header", list):
        if not isinstance(key, str):
            raise PersistenceError(f"{label} is malformed: array attribute names must be strings; got {key!r:.40}")
        if key in attributes:
            raise PersistenceError(f"{label} is malformed: attribute {key} is stored twice (in the header and as an array)")
        attributes[key] = require(contents, f"attr/{key}", label, "the archive")
    lists = header.get("array_list_attributes", {})
    if not isinstance(lists, dict):
        raise PersistenceError(f"{label} is malformed: 'array_list_attributes' in the header must be a dict")
    for key, n in lists.items():
        if key in attributes or isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise PersistenceError(f"{label} is malformed: array list attribute {key!r:.40} stored twice or with count {n!r:.20}")
        attributes[key] = [require(contents, f"attr/{key}/{i}", label, "the archive") for i in range(n)]
    _check(cls, attributes, features, f"{label} is malformed")
    described = {f"attr/{key}" for key in header["array_attributes"]}
    described.update(f"attr/{key}/{i}" for key, n in lists.items() for i in range(n))
    stray = sorted(name for name in contents if name.startswith("attr/") and name not in described)
    if stray:
        raise PersistenceError(f"{label} is malformed: the archive holds {stray[0]}, which the header does not describe "
                               "(array_attributes and the per-task counts of array_list_attributes)")
    return attributes


def load_model(path: Target) -> GradIRL | FactIRL | MultiIntentIRL:
    """Load a model written by :func:`save_model`.

    Parameters
    ----------
    path : str or os.PathLike or readable binary file

    Returns
    -------
    model : GradIRL, FactIRL or MultiIntentIRL
        With the saved parameters and learnt attributes: it transfers and scores exactly like
        the saved model. A parameter saved under a name since renamed (FactIRL's
        ``h_solver``, ``h_solver_options``) loads under its name now. Every declared attribute is optional, so files written before an
        attribute existed still load. A fitted model's file without ``mdp_signature_`` (format
        version 1, or attributes set by hand) loads with ``mdp_signature_ = None`` (unknown:
        such a model cannot check the MDP it is used on); one without ``features_sha256_``
        gets the digest of its saved ``features`` (None without features), as the model was
        fitted with them; another missing attribute is absent.

    Raises
    ------
    PersistenceError
        The file is missing or unreadable (the message names the path and the cause, the
        ``OSError`` is chained), corrupt (also a single corrupt compressed member), not a
        factirl-opt file, holds demonstrations, lacks a member or header entry, holds an
        attribute its class does not declare or one of the wrong kind, shape or with
        non-finite values, has features other than those of ``features_sha256_``, or has a
        newer format version (the message names the file and what is wrong).
    ValidationError
        ``path`` is neither a path nor a readable file.
    """
    header, contents, label = read_archive(path, "model")
    name = require(header, "class", label, "the header", str)
    if name not in MODEL_CLASSES:
        raise PersistenceError(f"{label} holds a model of unknown class {name!r:.40}; known: {', '.join(MODEL_CLASSES)}")
    cls = MODEL_CLASSES[name]
    params = decode_params(cls, header, contents, label)
    features = _base_features(cls, params)
    attributes = _decode_attributes(cls, header, contents, label, features)
    try:
        model = cls(**params)
    except TypeError as exc:
        raise PersistenceError(f"{label}: the stored parameters do not fit {name}: {exc}") from None
    for key, value in attributes.items():
        setattr(model, key, decode_learnt(learnt_attributes(cls).get(key), value))
    if attributes:
        _complete_old_file(model, cls, attributes, features, label)
    load_transfer_posterior(model, header, contents, label)
    load_successor_features(model, header, contents, label)
    return model


def _complete_old_file(model: Any, cls: type, attributes: dict[str, Any], features: Any, label: str) -> None:
    """A fitted model's file written before ``mdp_signature_`` or ``features_sha256_`` existed.

    The signature becomes None (unknown: not checked); the digest is computed from the saved
    features (None without features; S and A come from the signature or from ``rewards_``).
    """
    for key, kind in learnt_attributes(cls).items():
        if key in attributes:
            continue
        if kind == "mdp-signature":
            setattr(model, key, None)
        elif kind == "features-digest":
            setattr(model, key, fitted_features_sha256(attributes, features, f"{label} is malformed"))

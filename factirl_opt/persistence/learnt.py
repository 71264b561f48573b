"""The learnt attributes of an estimator, as its class declares them, and their checks.

Each estimator class declares the attributes ``fit`` (and ``transfer``) set, in the class
variable ``learnt_attributes``: a mapping from the attribute's name (ending in ``_``) to its
kind. :func:`~factirl_opt.persistence.save_model` stores exactly these and
:func:`~factirl_opt.persistence.load_model` checks each against its kind, so a new attribute
is saved and checked by declaring it, and an attribute that is not declared is refused.

A kind is either

- a tuple of axis names: a finite float array with one axis per name, e.g.
  ``("n", "S", "A")``. Axes with the same name have the same length across the attributes;
  ``S`` and ``A`` are the MDP's (from ``mdp_signature_``) and ``p``, the number of reward
  parameters, is the number of columns of the ``features`` parameter when there is one;
- a tuple ``("integers", *axes)``: an array of integers >= 0 on those axes (e.g. labels);
- or one of the strings of :data:`KINDS`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._validation import check_features, check_int, check_real
from ..exceptions import PersistenceError, ValidationError
from ..tasks.task_set import features_digest
from ..mdp.tabular import SIGNATURE_KEYS
from ..learners.selection.results import CV_RESULTS_KEYS, check_cv_results
from .archive import check_array

__all__ = ["KINDS", "INTEGERS", "SIGNATURE_KEYS", "Kind", "is_array_kind", "array_axes", "learnt_attributes",
           "check_learnt", "decode_learnt", "features_sha256", "fitted_features_sha256", "check_features_digest", "check_task_features"]


#: The keys of a row of a validation table (``FactIRL.validation_``, :mod:`factirl_opt.learners.selection.results`).
VALIDATION_KEYS = ("n_primitives", "residual_penalty", "score", "score_std", "fold_scores", "task_scores", "chosen")

#: The kinds of learnt attributes that are not arrays, and what each holds.
KINDS = {
    "count": "an integer >= 0",
    "number": "a finite number",
    "flag": "True or False",
    "history": "a list of finite numbers",
    "text": "a string",
    "mdp-signature": f"None or a dict with keys {list(SIGNATURE_KEYS)} (an MDP's signature), or a non-empty list "
                     "of such dicts (one per task, tasks in several environments)",
    "features-digest": "None (no features) or the features' SHA-256 (64 lowercase hexadecimal digits)",
    "penalty": "a number >= 0, or inf",
    "validation": f"a list of dicts with keys {list(VALIDATION_KEYS)} (a validation table)",
    "cv-results": f"a dict of equal-length lists with keys {list(CV_RESULTS_KEYS)} and more (a search's cv_results_)",
}

#: A declared kind: axis names of a float array, or a key of :data:`KINDS`.
Kind = tuple[str, ...] | str


#: The first item of an array kind of integers >= 0: ``("integers", "m")``.
INTEGERS = "integers"


def is_array_kind(kind: Kind) -> bool:
    return isinstance(kind, tuple)


def array_axes(kind: tuple[str, ...]) -> tuple[str, ...]:
    """The axis names of an array kind (without the ``"integers"`` mark)."""
    return kind[1:] if kind[:1] == (INTEGERS,) else kind


def learnt_attributes(cls: type) -> dict[str, Kind]:
    """The class's declaration ``cls.learnt_attributes`` (name -> kind)."""
    return dict(getattr(cls, "learnt_attributes", {}))


def _is_sha256(value: Any) -> bool:
    return isinstance(value, str) and len(value) == 64 and set(value) <= set("0123456789abcdef")


def _check_signature(sig: Any, context: str) -> None:
    """``mdp_signature_``: None, a :meth:`TabularMDP.signature` dict, or a list of one per task."""
    if sig is None:
        return
    if isinstance(sig, list) and sig:
        for one in sig:
            _check_signature(one, context)
            if not isinstance(one, dict):
                raise PersistenceError(f"{context}: mdp_signature_ must be {KINDS['mdp-signature']}; got a list holding {one!r:.60}")
        if len({one["n_actions"] for one in sig}) != 1:
            raise PersistenceError(f"{context}: the per-task MDP signatures of mdp_signature_ differ in their numbers of actions")
        return
    if not isinstance(sig, dict) or sorted(sig) != sorted(SIGNATURE_KEYS):
        raise PersistenceError(f"{context}: mdp_signature_ must be {KINDS['mdp-signature']}; got {sig!r:.120}")
    try:
        check_int(sig["n_states"], "mdp_signature_ n_states", minimum=1)
        check_int(sig["n_actions"], "mdp_signature_ n_actions", minimum=1)
        check_real(sig["gamma"], "mdp_signature_ gamma", 0.0, 1.0, high_open=True)
    except ValidationError as exc:
        raise PersistenceError(f"{context}: {exc}") from None
    if not _is_sha256(sig["transitions_sha256"]):
        raise PersistenceError(f"{context}: mdp_signature_ transitions_sha256 must be 64 hexadecimal digits; "
                               f"got {sig['transitions_sha256']!r:.80}")


def _check_penalty(value: Any, what: str) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
        raise ValidationError(f"{what} must be {KINDS['penalty']}; got {value!r:.60}")


def _check_validation(key: str, value: Any) -> None:
    """A validation table: a list of rows with the keys of :data:`VALIDATION_KEYS`, exactly one chosen."""
    if not isinstance(value, list) or not value:
        raise ValidationError(f"attribute {key} must be {KINDS['validation']}; got {value!r:.80}")
    for t, row in enumerate(value):
        if not isinstance(row, dict) or set(row) not in (set(VALIDATION_KEYS), set(VALIDATION_KEYS) - {"task_scores"}):
            raise ValidationError(f"attribute {key}[{t}] must be a dict with keys {list(VALIDATION_KEYS)}; got {row!r:.80}")
        check_int(row["n_primitives"], f"attribute {key}[{t}] n_primitives", minimum=1)
        _check_penalty(row["residual_penalty"], f"attribute {key}[{t}] residual_penalty")
        check_real(row["score"], f"attribute {key}[{t}] score")
        check_real(row["score_std"], f"attribute {key}[{t}] score_std", 0.0)
        for name in ("fold_scores", "task_scores"):  # task_scores: absent in files of 0.1.0 before 2026-11-26
            if name not in row:
                continue
            if not isinstance(row[name], list):
                raise ValidationError(f"attribute {key}[{t}] {name} must be a list of numbers; got {row[name]!r:.60}")
            for f, v in enumerate(row[name]):
                check_real(v, f"attribute {key}[{t}] {name}[{f}]")
        if not isinstance(row["chosen"], bool):
            raise ValidationError(f"attribute {key}[{t}] chosen must be true or false; got {row['chosen']!r:.60}")
    if sum(row["chosen"] for row in value) != 1:
        raise ValidationError(f"attribute {key} must mark exactly one row chosen; {sum(row['chosen'] for row in value)} are")


def _check_value(key: str, kind: str, value: Any, context: str) -> None:
    """One attribute of a non-array kind."""
    if isinstance(value, np.ndarray):
        raise PersistenceError(f"{context}: attribute {key} must be {KINDS[kind]}; got an array of shape {value.shape}")
    try:
        if kind == "count":
            check_int(value, f"attribute {key}", minimum=0)
        elif kind == "history":
            if not isinstance(value, list):
                raise ValidationError(f"attribute {key} must be a list of finite numbers; got {type(value).__name__}")
            for t, v in enumerate(value):
                check_real(v, f"attribute {key}[{t}]")
        elif kind == "text" and not isinstance(value, str):
            raise ValidationError(f"attribute {key} must be a string; got {value!r:.60}")
        elif kind == "number":
            check_real(value, f"attribute {key}")
        elif kind == "flag" and not isinstance(value, bool):
            raise ValidationError(f"attribute {key} must be True or False; got {value!r:.60}")
        elif kind == "features-digest" and not (value is None or _is_sha256(value)):
            raise ValidationError(f"attribute {key} must be {KINDS[kind]}; got {value!r:.80}")
        elif kind == "penalty":
            _check_penalty(value, f"attribute {key}")
        elif kind == "validation":
            _check_validation(key, value)
        elif kind == "cv-results":
            _check_cv_results_types(value, f"attribute {key}")
            check_cv_results(value, f"attribute {key}")
    except ValidationError as exc:
        raise PersistenceError(f"{context}: {exc}") from None
    if kind == "mdp-signature":
        _check_signature(value, context)


#: the columns of a stored ``cv_results_`` whose entries are integers (>= 0), or true/false
_CV_INTEGER_COLUMNS = ("param_n_primitives", "rank_test_score", "n_splits_scored")
_CV_FLAG_COLUMNS = ("chosen", "confirmed")


def _check_cv_results_types(results: dict[str, Any], name: str) -> None:
    """The entries of a stored ``cv_results_`` (lists, as JSON holds them) are of their column's type.

    Scores (``*_score`` columns other than the rank) are numbers, NaN for a candidate not scored
    there; ``param_residual_penalty`` a number >= 0 or inf; the counts and the rank integers
    >= 0; ``chosen`` and ``confirmed`` true or false; ``params`` dicts. Other columns a search
    adds (descriptive text) are kept as they are.

    Raises
    ------
    ValidationError
        Naming the column, the candidate's index and the value.
    """
    if not isinstance(results, dict):
        return  # check_cv_results says what the table must be
    for key, column in results.items():
        for i, v in enumerate(column if isinstance(column, list) else ()):
            where = f"{name}[{key!r}][{i}]"
            if key == "params":
                if not isinstance(v, dict):
                    raise ValidationError(f"{where} must be a dict of the candidate's parameters; got {v!r:.60}")
            elif key in _CV_FLAG_COLUMNS:
                if not isinstance(v, (bool, np.bool_)):
                    raise ValidationError(f"{where} must be true or false; got {v!r:.60}")
            elif key in _CV_INTEGER_COLUMNS:
                if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < 0:
                    raise ValidationError(f"{where} must be an integer >= 0; got {v!r:.60}")
            elif key == "param_residual_penalty":
                _check_penalty(v, where)
            elif key.endswith("_score"):
                if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)) or np.isinf(v):
                    raise ValidationError(f"{where} must be a finite number, or NaN for a candidate not scored "
                                          f"there; got {v!r:.60}")


def _check_axes(declared: dict[str, Kind], attributes: dict[str, Any], axes: dict[str, tuple[int, str]], context: str) -> None:
    """Axes of the same name have the same length; ``axes`` holds the lengths known beforehand."""
    for key, kind in declared.items():
        value = attributes.get(key)
        if is_array_kind(kind) and isinstance(value, list):  # per-task (S_i, A) arrays: their count and A
            value = np.empty((len(value), 0, value[0].shape[1]) if value else (0, 0, 0))
            kind = (kind[0], "S_i", kind[2])
        if not (isinstance(kind, tuple) and isinstance(value, np.ndarray)):
            continue
        for i, axis in enumerate(array_axes(kind)):
            length = value.shape[i]
            if axis not in axes:
                axes[axis] = (length, f"axis {i} of {key} (shape {value.shape})")
            elif axes[axis][0] != length:
                raise PersistenceError(
                    f"{context}: attribute {key} of shape {value.shape} disagrees with {axes[axis][1]}: axis {i} "
                    f"({axis}) has length {length}, not {axes[axis][0]}"
                )


def _check_task_shapes(declared: dict[str, Kind], attributes: dict[str, Any], context: str) -> None:
    """Per-task (S_i, A) arrays (tasks in environments of different sizes) agree with the saved signatures.

    On the fitted tasks (first axis ``n``), task i's array has the shape (S_i, A) of task i's
    MDP in ``mdp_signature_`` (one per task, or one for all); on any other per-task list
    (``n_new``: the transfer's tasks, whose MDPs are not saved), every array has the fitted
    MDPs' A. The count of the arrays is checked with the other axes (:func:`_check_axes`).
    """
    sig = attributes.get("mdp_signature_")
    for key, kind in declared.items():
        value = attributes.get(key)
        if not (is_array_kind(kind) and isinstance(value, list) and value):
            continue
        signatures = sig if isinstance(sig, list) else [sig] * len(value) if isinstance(sig, dict) else None
        for i, one in enumerate(value):
            if kind[0] == "n" and signatures is not None and i < len(signatures):
                expected = (signatures[i]["n_states"], signatures[i]["n_actions"])
                if one.shape != expected:
                    raise PersistenceError(f"{context}: attribute {key}[{i}] of shape {one.shape} contradicts task {i}'s saved "
                                           f"MDP signature in mdp_signature_: (S, A) = {expected}")
            actions = signatures[0]["n_actions"] if signatures else value[0].shape[1]
            if one.shape[1] != actions:
                raise PersistenceError(f"{context}: attribute {key}[{i}] of shape {one.shape} has {one.shape[1]} actions; the "
                                       f"model's MDPs have A = {actions}")


def check_task_features(attributes: dict[str, Any], features: list, context: str) -> None:
    """A per-task features parameter (one matrix per task) agrees with the per-task signatures:
    one matrix per saved task, task i's with S_i (state features) or S_i * A rows, all with
    the same number of columns."""
    sig = attributes.get("mdp_signature_")
    signatures = sig if isinstance(sig, list) else [sig] * len(features) if isinstance(sig, dict) else None
    if signatures is not None and len(features) != len(signatures):
        raise PersistenceError(f"{context}: the features parameter holds {len(features)} per-task matrices; mdp_signature_ "
                               f"saves {len(signatures)} tasks")
    p = np.shape(features[0])[1] if np.ndim(features[0]) == 2 else None
    for i, F in enumerate(features):
        shape = np.shape(F)
        if len(shape) != 2 or shape[1] != p:
            raise PersistenceError(f"{context}: per-task features[{i}] of shape {shape} must be a matrix with the "
                                   f"{p} columns of features[0]")
        if signatures is not None:
            S, A = signatures[i]["n_states"], signatures[i]["n_actions"]
            if shape[0] not in (S, S * A):
                raise PersistenceError(f"{context}: per-task features[{i}] of shape {shape} contradicts task {i}'s saved MDP "
                                       f"signature in mdp_signature_ (S, A) = ({S}, {A}): it needs S = {S} or S * A = {S * A} rows")


def _known_axes(attributes: dict[str, Any], n_feature_columns: int | None) -> dict[str, tuple[int, str]]:
    axes = {}
    sig = attributes.get("mdp_signature_")
    if isinstance(sig, dict):
        where = f"the MDP of mdp_signature_ (S, A) = ({sig['n_states']}, {sig['n_actions']})"
        axes["S"], axes["A"] = (sig["n_states"], where), (sig["n_actions"], where)
    elif isinstance(sig, list) and sig:  # one per task: n tasks with A actions (their S may differ)
        axes["n"] = (len(sig), f"the {len(sig)} per-task MDP signatures of mdp_signature_")
        axes["A"] = (sig[0]["n_actions"], f"the MDPs of mdp_signature_ (A = {sig[0]['n_actions']})")
        if len({s["n_states"] for s in sig}) == 1:
            axes["S"] = (sig[0]["n_states"], f"the MDPs of mdp_signature_ (S = {sig[0]['n_states']})")
    if n_feature_columns is not None:
        axes["p"] = (n_feature_columns, "the columns of the features parameter")
    return axes


def _unevaluated_loss(key: str, value: Any, attributes: dict[str, Any]) -> bool:
    """Whether ``value`` is the per-task loss of an interrupted fit, where NaN means "never evaluated".

    A fit stopped by Ctrl-C keeps every task's best point; a task the fit never evaluated
    keeps its start with a NaN loss (:class:`factirl_opt.interruption.BestRows`). Such a
    model is usable, so it is saved and loaded with those NaNs (infinities are still refused).
    """
    prefix = key[: -len("loss_")] if key.endswith("loss_") else None
    return (prefix is not None and attributes.get(f"{prefix}stop_reason_") == "interrupted"
            and isinstance(value, np.ndarray) and value.dtype.kind == "f")


def decode_learnt(kind: Any, value: Any) -> Any:
    """A learnt attribute as the model holds it, from its checked stored value: a ``cv-results``
    kind's lists as numpy arrays (``params`` stays a list of dicts), any other value as it is."""
    if kind != "cv-results":
        return value
    return {key: v if key == "params" else np.asarray(v, dtype=bool if key == "chosen" else None)
            for key, v in value.items()}


def check_learnt(cls: type, attributes: dict[str, Any], context: str, n_feature_columns: int | None = None) -> None:
    """Check learnt ``attributes`` against the declaration of ``cls``; PersistenceError naming the bad one.

    Every name must be declared; each value must be of its kind (an array kind's array
    finite, float, with the declared number of axes; the per-task loss of an interrupted fit
    may hold NaN for tasks never evaluated); axes of the same name must agree, with
    each other and with the MDP signature and ``n_feature_columns`` (the features
    parameter's columns, if any); per-task arrays of environments of different sizes
    must each have their task's saved (S_i, A). Declared attributes may be missing.
    """
    declared = learnt_attributes(cls)
    for key, value in attributes.items():
        if key not in declared:
            raise PersistenceError(f"{context}: {key!r:.60} is not a learnt attribute of {cls.__name__} "
                                   f"(declared in {cls.__name__}.learnt_attributes: {', '.join(declared)})")
        kind = declared[key]
        if isinstance(kind, tuple) and isinstance(value, list) and kind[1:] == ("S", "A"):  # per-task (S_i, A) arrays
            for i, v in enumerate(value):
                check_array(v, f"attribute {key}[{i}]", context, len(kind) - 1, "f")
        elif isinstance(kind, tuple) and kind[:1] == (INTEGERS,):
            check_array(value, f"attribute {key}", context, len(kind) - 1, "iu")
            if np.any(value < 0):
                raise PersistenceError(f"{context}: attribute {key} must hold integers >= 0; found {value.min()}")
        elif isinstance(kind, tuple):
            if _unevaluated_loss(key, value, attributes):
                value = np.where(np.isnan(value), 0.0, value)
            check_array(value, f"attribute {key}", context, len(kind), "f")
        else:
            _check_value(key, kind, value, context)
    _check_axes(declared, attributes, _known_axes(attributes, n_feature_columns), context)
    _check_task_shapes(declared, attributes, context)


def features_sha256(features: ArrayLike, n_states: int, n_actions: int) -> str:
    """SHA-256 (hex) of the base features a model is fitted with: ``features_sha256_``.

    The features are taken as the learners use them: float64 (S*A, p), state features (S, p)
    repeated over the actions (:func:`~factirl_opt._validation.check_features`); the digest
    covers the ``repr`` of that shape, then the values in C order. Two feature matrices have
    the same digest exactly when the learners see the same values, bit for bit.

    Raises
    ------
    ValidationError
        ``features`` is not a finite (S*A, p) or (S, p) matrix.
    """
    digest = features_digest(check_features(features, n_states * n_actions, n_states))
    assert digest is not None  # features are given here (check_features refuses None)
    return digest


def _mdp_shape(attributes: dict[str, Any]) -> tuple[int, int] | None:
    """(S, A) of the model's MDP: from ``mdp_signature_``, else from the shape of ``rewards_``."""
    sig, rewards = attributes.get("mdp_signature_"), attributes.get("rewards_")
    if isinstance(sig, dict):
        return sig["n_states"], sig["n_actions"]
    if isinstance(rewards, np.ndarray) and rewards.ndim == 3:
        return rewards.shape[1], rewards.shape[2]
    return None


def fitted_features_sha256(attributes: dict[str, Any], features: np.ndarray | None, context: str) -> str | None:
    """The digest of ``features`` on the model's MDP (S, A from ``mdp_signature_`` or ``rewards_``).

    None without features, or when S and A are unknown (state features cannot then be told
    from state-action ones).
    """
    shape = _mdp_shape(attributes)
    if features is None or shape is None:
        return None
    try:
        return features_sha256(features, *shape)
    except ValidationError as exc:
        raise PersistenceError(f"{context}: the features parameter does not fit the model's MDP (S, A) = {shape}: {exc}") from None


def check_features_digest(attributes: dict[str, Any], features: np.ndarray | None, context: str) -> None:
    """The stored ``features_sha256_`` must be the digest of the stored features parameter.

    Checked when both are there and S, A are known; a digest without features is refused.
    """
    digest = attributes.get("features_sha256_")
    if digest is None:
        return
    if features is None:
        raise PersistenceError(f"{context}: features_sha256_ records features, but the model has no features parameter")
    actual = fitted_features_sha256(attributes, features, context)
    if actual is not None and actual != digest:
        raise PersistenceError(f"{context}: the features parameter is not the one the model was fitted with "
                               f"(its SHA-256 {actual[:12]}... differs from features_sha256_ {digest[:12]}...)")

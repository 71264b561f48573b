"""A FactIRL model's cached GPI libraries in a model file: the header entry and the members ``sf/...``.

The header's ``"successor_features"`` is a list, one entry per cached library
(:func:`factirl_opt.learners.gpi.gpi_library`): ``{"key": digest, "labels": [...], "state": digest}``; its arrays
are the members ``sf/<i>/policies`` ((L, S) int or (L, S, A) float) and ``sf/<i>/psi``
((L, S, A, k)). A model that has built no library has neither. The key is the digest of what the
library depends on, so a loaded model uses an entry exactly when it would have built the same one.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..exceptions import PersistenceError
from ..learners.gpi import set_successor_feature_cache, successor_feature_cache

__all__ = ["save_successor_features", "load_successor_features", "HEADER_KEY", "PREFIX"]

HEADER_KEY = "successor_features"
PREFIX = "sf/"


def save_successor_features(model: Any, header: dict, arrays: dict[str, np.ndarray]) -> None:
    """Add the model's cached libraries (if any) to a file's header and arrays."""
    cache = model.__dict__.get("_successor_features")
    if not cache:
        return
    entries = []
    for i, (key, entry) in enumerate(cache.items()):
        entries.append({"key": key, "labels": list(entry["labels"]), "state": entry.get("state")})
        arrays[f"{PREFIX}{i}/policies"] = np.asarray(entry["policies"])
        arrays[f"{PREFIX}{i}/psi"] = np.asarray(entry["psi"])
    header[HEADER_KEY] = entries


def load_successor_features(model: Any, header: dict, contents: dict[str, np.ndarray], label: str) -> None:
    """Give a loaded model the cached libraries its file holds, if any.

    Raises
    ------
    PersistenceError
        The header's entry or the members are malformed or inconsistent.
    """
    members = {name for name in contents if name.startswith(PREFIX)}
    if HEADER_KEY not in header:
        if members:
            raise PersistenceError(f"{label} is malformed: the archive holds {sorted(members)[0]} but the header has no "
                                   f"{HEADER_KEY!r}")
        return
    spec = header[HEADER_KEY]
    if not isinstance(spec, list):
        raise PersistenceError(f"{label} is malformed: {HEADER_KEY!r} in the header must be a list")
    entries = {}
    for i, item in enumerate(spec):
        if not (isinstance(item, dict) and isinstance(item.get("key"), str) and isinstance(item.get("labels"), list)):
            raise PersistenceError(f"{label} is malformed: {HEADER_KEY!r}[{i}] must be a dict with a 'key' and 'labels'")
        names = (f"{PREFIX}{i}/policies", f"{PREFIX}{i}/psi")
        if any(name not in contents for name in names):
            raise PersistenceError(f"{label} is incomplete: the archive lacks {names[0]} or {names[1]}")
        policies, psi = contents[names[0]], contents[names[1]]
        L = len(item["labels"])
        if psi.ndim != 4 or psi.shape[0] != L or policies.shape[:2] != psi.shape[:2] or not np.all(np.isfinite(psi)):
            raise PersistenceError(f"{label} is malformed: successor features {i} do not describe {L} policies "
                                   f"(psi {psi.shape}, policies {policies.shape}) or are not finite")
        entries[item["key"]] = {"labels": [str(x) for x in item["labels"]], "policies": policies, "psi": psi,
                                "state": item.get("state")}
        members.difference_update(names)
    if members:
        raise PersistenceError(f"{label} is malformed: the archive holds {sorted(members)[0]}, which the header does not describe")
    set_successor_feature_cache(model, entries)

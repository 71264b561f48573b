"""``FactIRL.transfer_posterior_`` in a model file: the header entry and the members ``posterior/...``.

The header's ``"transfer_posterior"`` is None (the posterior is undefined for the model) or the
JSON part of :func:`~factirl_opt.learners.posterior.posterior_arrays`; its arrays (means,
covariances, likelihood scalings, the dictionary, each distinct MDP as successor lists and each
distinct feature matrix) are members ``posterior/<name>``. A model that has transferred no
tasks has neither.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..exceptions import PersistenceError, ValidationError
from ..learners.posterior import has_transfer_posterior, posterior_arrays, posteriors_from_arrays, set_transfer_posterior

__all__ = ["save_transfer_posterior", "load_transfer_posterior", "HEADER_KEY", "PREFIX"]

HEADER_KEY = "transfer_posterior"
PREFIX = "posterior/"


def save_transfer_posterior(model: Any, header: dict, arrays: dict[str, np.ndarray]) -> None:
    """Add the model's ``transfer_posterior_`` (built now if it was not yet) to a file's header and arrays."""
    if not has_transfer_posterior(model):
        return
    posts = model.transfer_posterior_
    if posts is None:
        header[HEADER_KEY] = None
        return
    spec, members = posterior_arrays(posts)
    header[HEADER_KEY] = spec
    arrays.update({PREFIX + key: value for key, value in members.items()})


def load_transfer_posterior(model: Any, header: dict, contents: dict[str, np.ndarray], label: str) -> None:
    """Give a loaded model the ``transfer_posterior_`` its file holds, if any.

    Raises
    ------
    PersistenceError
        The header's entry or the members are malformed.
    """
    if HEADER_KEY not in header:
        stray = sorted(name for name in contents if name.startswith(PREFIX))
        if stray:
            raise PersistenceError(f"{label} is malformed: the archive holds {stray[0]} but the header has no "
                                   f"{HEADER_KEY!r}")
        return
    spec = header[HEADER_KEY]
    if spec is None:
        set_transfer_posterior(model, None)
        return
    if not isinstance(spec, dict):
        raise PersistenceError(f"{label} is malformed: {HEADER_KEY!r} in the header must be null or a dict")
    members = {name[len(PREFIX):]: value for name, value in contents.items() if name.startswith(PREFIX)}
    try:
        posts = posteriors_from_arrays(spec, members)
    except ValidationError as exc:
        raise PersistenceError(f"{label} is malformed: {exc}") from None
    for post in posts:
        if not (np.all(np.isfinite(post.mean)) and np.all(np.isfinite(post.covariance))):
            raise PersistenceError(f"{label} is malformed: the transfer posterior holds non-finite values")
    set_transfer_posterior(model, posts)

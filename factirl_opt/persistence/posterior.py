"""``FactIRL.transfer_posterior_`` in a model file: the header entry and the members ``posterior/...``.

The header's ``"transfer_posterior"`` is None (the posterior is undefined for the model) or the
JSON part of :func:`posterior_arrays`; its arrays (means,
covariances, likelihood scalings, the dictionary, each distinct MDP as successor lists and each
distinct feature matrix) are members ``posterior/<name>``. A model that has transferred no
tasks has neither.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..exceptions import PersistenceError, ValidationError
from ..learners.posterior import LaplacePosterior, has_transfer_posterior, set_transfer_posterior
from ..mdp.tabular import from_successors, to_successors

__all__ = ["save_transfer_posterior", "load_transfer_posterior", "posterior_arrays", "posteriors_from_arrays", "HEADER_KEY",
           "PREFIX"]

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
    for post in [q for p in posts for q in (p, *p.members)]:
        if not (np.all(np.isfinite(post.mean)) and np.all(np.isfinite(post.covariance))):
            raise PersistenceError(f"{label} is malformed: the transfer posterior holds non-finite values")
    set_transfer_posterior(model, posts)


def posterior_arrays(posteriors: list[LaplacePosterior]) -> tuple[dict, dict[str, NDArray[Any]]]:
    """The posteriors as JSON and arrays for :func:`factirl_opt.save_model` (distinct MDPs and features once)."""
    mdps: list[Any] = []
    feats: list[Any] = []
    mdp_index: list[int] = []
    feat_index: list[int] = []
    for post in posteriors:
        for pool, index, obj in ((mdps, mdp_index, post.mdp), (feats, feat_index, post.features)):
            hit = [j for j, o in enumerate(pool) if o is obj]
            if not hit:
                pool.append(obj)
            index.append(hit[0] if hit else len(pool) - 1)
    arrays: dict[str, NDArray[Any]] = {"mean": np.stack([p.mean for p in posteriors]),
                                       "covariance": np.stack([p.covariance for p in posteriors]),
                                       "scaling": np.array([p.scaling for p in posteriors]),
                                       "n_pairs": np.array([p.n_pairs for p in posteriors]),
                                       "dictionary": posteriors[0].dictionary,
                                       "mdp_index": np.array(mdp_index, dtype=np.int64),
                                       "features_index": np.array(feat_index, dtype=np.int64)}
    gammas = []
    for j, m in enumerate(mdps):
        sa_s, sa_p = to_successors(m)
        arrays[f"mdp/{j}/successors"], arrays[f"mdp/{j}/probabilities"] = sa_s, sa_p
        gammas.append(m.gamma)
    tabular = []
    for j, F in enumerate(feats):
        tabular.append(F is None)
        if F is not None:
            arrays[f"features/{j}"] = F
    spec = {"n_tasks": len(posteriors), "gammas": gammas, "tabular": tabular}
    B = len(posteriors[0].members)
    if B:  # the dictionary ensemble's posteriors: the same B dictionaries for every task (member_posteriors)
        if any(len(p.members) != B for p in posteriors):
            raise ValidationError("the posteriors' members must be as many for every task to be saved")
        arrays["members/dictionaries"] = np.stack([m.dictionary for m in posteriors[0].members])
        arrays["members/mean"] = np.stack([np.stack([m.mean for m in p.members]) for p in posteriors])
        arrays["members/covariance"] = np.stack([np.stack([m.covariance for m in p.members]) for p in posteriors])
        arrays["members/scaling"] = np.array([[m.scaling for m in p.members] for p in posteriors])
        spec["n_members"] = B
    return spec, arrays


def posteriors_from_arrays(spec: dict, arrays: dict[str, NDArray[Any]]) -> list[LaplacePosterior]:
    """The posteriors that :func:`posterior_arrays` encoded.

    Raises
    ------
    ValidationError
        Arrays missing or of inconsistent shapes.
    """
    try:
        n = int(spec["n_tasks"])
        mean, cov = np.asarray(arrays["mean"], dtype=np.float64), np.asarray(arrays["covariance"], dtype=np.float64)
        D = np.asarray(arrays["dictionary"], dtype=np.float64)
        mdps = [from_successors(arrays[f"mdp/{j}/successors"], arrays[f"mdp/{j}/probabilities"], float(g))
                for j, g in enumerate(spec["gammas"])]
        feats = [None if tab else np.asarray(arrays[f"features/{j}"], dtype=np.float64)
                 for j, tab in enumerate(spec["tabular"])]
        mi, fi = np.asarray(arrays["mdp_index"]), np.asarray(arrays["features_index"])
        scaling = np.asarray(arrays["scaling"], dtype=np.float64)
        n_pairs = np.asarray(arrays["n_pairs"], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValidationError(f"the posteriors' arrays are incomplete or malformed: {exc}") from None
    if mean.shape[0] != n or cov.shape != (n, mean.shape[1], mean.shape[1]) or mi.shape != (n,) or fi.shape != (n,):
        raise ValidationError(f"the posteriors' arrays do not describe {n} tasks: mean {mean.shape}, covariance {cov.shape}")
    posts = [LaplacePosterior(mean[i], cov[i], D, feats[int(fi[i])], mdps[int(mi[i])], float(scaling[i]),
                              float(n_pairs[i])) for i in range(n)]
    B = int(spec.get("n_members", 0))
    if B:
        try:
            Ds = np.asarray(arrays["members/dictionaries"], dtype=np.float64)
            m_mean = np.asarray(arrays["members/mean"], dtype=np.float64)
            m_cov = np.asarray(arrays["members/covariance"], dtype=np.float64)
            m_scaling = np.asarray(arrays["members/scaling"], dtype=np.float64)
        except KeyError as exc:
            raise ValidationError(f"the posteriors' arrays are incomplete or malformed: {exc}") from None
        d = mean.shape[1]
        if Ds.shape != (B, *D.shape) or m_mean.shape != (n, B, d) or m_cov.shape != (n, B, d, d) or m_scaling.shape != (n, B):
            raise ValidationError(f"the posteriors' members do not describe {n} tasks x {B} dictionaries: dictionaries "
                                  f"{Ds.shape}, mean {m_mean.shape}, covariance {m_cov.shape}, scaling {m_scaling.shape}")
        for i, p in enumerate(posts):
            p.members = tuple(LaplacePosterior(m_mean[i, b], m_cov[i, b], Ds[b], p.features, p.mdp, float(m_scaling[i, b]),
                                               p.n_pairs) for b in range(B))
    return posts

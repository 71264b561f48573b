"""The choice rules of the sharing search: which row of a scored validation table is chosen."""

from __future__ import annotations

import numpy as np

from ...exceptions import ValidationError
from ..intention_count import one_standard_error_choice

__all__ = ["RULES", "DEFAULT_RULE", "SHARE_LEVEL", "choose_row"]

#: choice rules of :func:`search_sharing`: the candidate of best mean score, kept over the flat model only
#: when its paired gain is significant (``"significant-gain"``); the same, then, among the sharing
#: candidates whose paired difference with that leader is not significant, the one that shares most
#: (the largest lambda, then the smallest k; ``"share-within-noise"``); or, after the first test, the
#: fewest primitives at the leader's lambda within one standard error of its paired difference
#: with the leader (``"fewest-within-se"``, Breiman et al.'s one-standard-error rule on k)
RULES = ("significant-gain", "share-within-noise", "fewest-within-se")
#: the rule ``FactIRL.fit`` uses
DEFAULT_RULE = "significant-gain"
#: a sharing candidate replaces the flat model only if a one-sided paired t-test over the held-out
#: tasks finds its gain significant at this level
SHARE_LEVEL = 0.05


def choose_row(rows: list[dict], rule: str = DEFAULT_RULE, share_level: float = SHARE_LEVEL) -> int:
    """The index of the row a choice ``rule`` (:data:`RULES`) takes in a validation table (rows of
    :func:`search_sharing`; ``task_scores`` paired over the same held-out tasks): the rule of
    :func:`search_sharing`, for a table already scored (e.g. to compare the rules on one search).

    Raises
    ------
    ValidationError
        An unknown ``rule``.
    """
    if rule not in RULES:
        raise ValidationError(f"rule must be one of {RULES}; got {rule!r}")
    return _choice(rows, share_level, rule)


def _choice(rows: list[dict], share_level: float = SHARE_LEVEL, rule: str = DEFAULT_RULE) -> int:
    """The chosen row: the lowest mean score among the rows with the most folds, unless the flat
    model (``lambda = 0``) is among them and the leader's gain over it, paired over the n held-out
    tasks, is within ``t_(n-1)(1 - share_level)`` standard errors
    (:func:`~factirl_opt.learners.intention_count.one_standard_error_choice`). With
    ``rule="share-within-noise"``, a sharing leader then gives way to the sharing row that shares
    most (largest lambda, then smallest k) among those whose paired difference with it is within
    the same number of standard errors; with ``rule="fewest-within-se"``, to the row of fewest
    primitives at the leader's lambda whose paired difference with it is within one standard
    error."""
    most = max(len(r["fold_scores"]) for r in rows)
    complete = [r for r in range(len(rows)) if len(rows[r]["fold_scores"]) == most]
    best = min(complete, key=lambda r: rows[r]["score"])
    flat = [r for r in complete if rows[r]["residual_penalty"] == 0.0]

    def within(a: int, b: int) -> bool:  # whether row a is within noise of row b (paired over the held-out tasks)
        pair = -np.array([rows[a]["task_scores"], rows[b]["task_scores"]])  # higher is better there
        from scipy.stats import t as t_dist  # here: scipy.stats costs 0.3 s of every import of the library

        n_se = t_dist.ppf(1.0 - share_level, pair.shape[1] - 1) if pair.shape[1] > 1 else 0.0
        return one_standard_error_choice(pair, n_se) == 0

    if flat and flat[0] != best and within(flat[0], best):
        return flat[0]
    if rule == "share-within-noise" and rows[best]["residual_penalty"] != 0.0:
        near = [r for r in complete if rows[r]["residual_penalty"] != 0.0 and (r == best or within(r, best))]
        return min(near, key=lambda r: (-rows[r]["residual_penalty"], rows[r]["n_primitives"]))
    if rule == "fewest-within-se" and rows[best]["residual_penalty"] != 0.0:
        same = sorted((r for r in complete if rows[r]["residual_penalty"] == rows[best]["residual_penalty"]),
                      key=lambda r: rows[r]["n_primitives"])
        return same[one_standard_error_choice(-np.array([rows[r]["task_scores"] for r in same]), 1.0)]
    return best

"""Choosing the number of intentions K of :class:`factirl_opt.learners.multi_intent.MultiIntentIRL`.

Two criteria over a range of candidate K, both computed from EM fits:

- ``"held-out"``: the episodes are split at random into ``n_folds`` folds; for each K and
  each fold, EM is fitted on the other folds and the held-out episodes are scored by the
  mixture's log-likelihood ``sum_j log sum_c w_c prod_t pi_c(a_t | s_t)``
  (:func:`factirl_opt.learners.em.e_step`); the score of K is the sum over the folds (higher is
  better). It needs no count of parameters, which for rewards on states and actions
  overstates the effective dimension (many rewards give the same policy).
- ``"bic"``: the Bayesian information criterion of the fit on all episodes,
  ``-2 log L + n_free log N`` with N the number of demonstrated steps (lower is better) and
  :func:`free_parameters` counting the model's parameters. It costs one fit per K; with
  tabular rewards (p = S*A parameters per intention) its penalty is heavy and it tends to
  choose few intentions, so it suits rewards on a few features.

Plain functions: the estimator passes closures that fit EM on a
subset of the episodes and score a fitted run on another subset.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from ..exceptions import ValidationError

__all__ = ["SELECTIONS", "check_candidates", "free_parameters", "bic", "fold_assignment",
           "held_out_scores", "one_standard_error_choice", "bic_scores", "best_candidate"]

#: criteria of ``n_intentions="auto"``
SELECTIONS = ("held-out", "bic")


def check_candidates(n_intentions_range: Any, n_episodes: int, n_folds: int | None) -> NDArray[np.int64]:
    """Candidate K (m,) from ``n_intentions_range`` ``(low, high)`` (both included).

    Raises :class:`ValidationError` unless ``1 <= low <= high`` are integers and ``high`` is at
    most the number of episodes a fit sees: all of them, or (held-out) those outside the
    largest fold, ``n_episodes - ceil(n_episodes / n_folds)``.
    """
    try:
        low, high = n_intentions_range
        ok = all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (low, high))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValidationError(f"n_intentions_range must be a pair of integers (low, high); got {n_intentions_range!r}")
    if not 1 <= low <= high:
        raise ValidationError(f"n_intentions_range must satisfy 1 <= low <= high; got ({low}, {high})")
    fitted = n_episodes if n_folds is None else n_episodes - -(-n_episodes // n_folds)
    if high > fitted:
        where = "episodes" if n_folds is None else f"episodes outside the largest of {n_folds} held-out folds"
        raise ValidationError(f"n_intentions_range=({low}, {high}): high exceeds the {fitted} {where}")
    return np.arange(low, high + 1, dtype=np.int64)


def free_parameters(n_intentions: int, n_params: int, n_primitives: int | None) -> int:
    """Free parameters of a K-intention model with rewards of dimension p.

    Flat (``n_primitives=None``): ``K p`` reward parameters. Shared dictionary of k primitives:
    the K x p reward matrix ``H D^T`` has rank ``r = min(K, k, p)``, a manifold of dimension
    ``r (K + p - r)`` (``D -> D M``, ``H -> H M^-T`` leave it unchanged). Both add the ``K - 1``
    mixture weights.
    """
    K, p = n_intentions, n_params
    if n_primitives is None:
        rewards = K * p
    else:
        r = min(K, n_primitives, p)
        rewards = r * (K + p - r)
    return int(rewards + K - 1)


def bic(log_likelihood: float, n_free: int, n_steps: int) -> float:
    """``-2 log L + n_free log N`` (Schwarz 1978); lower is better."""
    return float(-2.0 * log_likelihood + n_free * np.log(n_steps))


def fold_assignment(n_episodes: int, n_folds: int, rng: np.random.Generator) -> NDArray[np.int64]:
    """A fold (n,) in ``[0, n_folds)`` for each episode, the folds' sizes differing by at most one."""
    return np.asarray(rng.permutation(n_episodes) % n_folds, dtype=np.int64)


def held_out_scores(fit: Callable[[NDArray[np.int64], int], Any],
                    score: Callable[[Any, NDArray[np.int64]], NDArray[np.float64]], candidates: Sequence[int],
                    folds: NDArray[np.int64]) -> NDArray[np.float64]:
    """Held-out log-likelihood (m, n) of each episode under each candidate K.

    Parameters
    ----------
    fit : callable
        ``fit(episode_indices, K)``: a fitted run on those episodes.
    score : callable
        ``score(run, episode_indices)``: the log-likelihoods of those episodes under the run.
    candidates : sequence of int, length m
    folds : ndarray of int, shape (n,)
        :func:`fold_assignment`; episode j is scored by the fit on the folds other than its own.
    """
    out = np.zeros((len(candidates), len(folds)))
    for i, K in enumerate(candidates):
        for f in np.unique(folds):
            test = np.flatnonzero(folds == f)
            out[i, test] = score(fit(np.flatnonzero(folds != f), int(K)), test)
    return out


def one_standard_error_choice(per_episode: NDArray[np.float64], n_se: float = 1.0) -> int:
    """Index of the smallest candidate within one standard error of the best held-out total.

    ``per_episode`` (m, n) holds each episode's held-out log-likelihood under each of the m
    candidates (in increasing K). With ``b`` the candidate of highest total, candidate i
    qualifies when ``total_b - total_i <= n_se sqrt(n) std_j(l_bj - l_ij)``, ``n_se`` times the
    standard error of the difference of totals over episodes (Breiman et al.'s one-standard-error
    rule for ``n_se = 1``): a larger K must beat a smaller one by more than the noise of the
    held-out sample. Any rows and columns will do: rows are candidates in order of preference,
    columns paired held-out units (episodes, tasks).
    """
    totals = per_episode.sum(axis=1)
    b = int(np.argmax(totals))
    n = per_episode.shape[1]
    diff = per_episode[b][None, :] - per_episode
    se = np.sqrt(n) * diff.std(axis=1, ddof=1) if n > 1 else np.zeros(len(totals))
    return int(np.flatnonzero(totals[b] - totals <= n_se * se)[0])


def bic_scores(fit: Callable[[NDArray[np.int64], int], Any], log_likelihood: Callable[[Any], float],
               n_free: Callable[[int], int], candidates: Sequence[int], n_episodes: int,
               n_steps: int) -> tuple[NDArray[np.float64], list]:
    """BIC (m,) of each candidate K fitted on all episodes, and the fitted runs (to keep the chosen one)."""
    everything = np.arange(n_episodes)
    runs = [fit(everything, int(K)) for K in candidates]
    scores = np.array([bic(log_likelihood(run), n_free(int(K)), n_steps) for K, run in zip(candidates, runs)])
    return scores, runs


def best_candidate(scores: NDArray[np.float64]) -> int:
    """Index of the lowest BIC (the first on ties)."""
    return int(np.argmin(scores))

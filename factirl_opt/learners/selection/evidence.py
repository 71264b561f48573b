"""The number of primitives from one decomposition: Minka's Laplace evidence for the rank of a PCA.

The factorial model writes every task's reward parameters as ``w_i = D h_i`` (k primitives), and
its PCA start takes D from the flat rewards' principal directions
(:func:`~factirl_opt.learners.dictionary.pca_dictionary`). Probabilistic PCA (Tipping & Bishop
1999) reads the same decomposition as a model, ``x_i = U h_i + noise`` with isotropic noise, and
Minka (2000) approximates its evidence ``p(X | k)`` by Laplace's method from the spectrum of the
data alone: one SVD scores every k, no fit and no held-out transfer (scikit-learn's
``PCA(n_components="mle")`` chooses its rank so). :func:`laplace_rank_evidence` is that
approximation on a spectrum, :func:`pca_rank_evidence` on a data matrix, and
:func:`flat_start_evidence` on the matrix FactIRL's PCA start decomposes (the flat rewards in the
basis' metric), the ``"evidence"`` route of :class:`~factirl_opt.learners.selection.SharingSearch`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import gammaln

from ..._validation import check_array, check_int
from ...exceptions import ValidationError
from ...tasks.task_set import TaskSet

__all__ = ["CONFIRM_TASKS_PER_PRIMITIVE", "MIN_TASKS_PER_PRIMITIVE", "confirmation_primitives", "PLAUSIBLE_LOG_BAYES_FACTOR", "laplace_rank_evidence", "plausible_ranks", "pca_rank_evidence", "flat_start_points",
           "flat_start_evidence", "evidence_primitives", "evidence_penalties"]

#: eigenvalues below this fraction of the largest are zero (the noise variance never falls below it)
_RELATIVE_FLOOR = 1e-12


def laplace_rank_evidence(spectrum: ArrayLike, n_samples: int, max_rank: int | None = None) -> NDArray[np.float64]:
    """Minka's Laplace approximation of the log evidence of probabilistic PCA for every rank k.

    For the eigenvalues ``l_1 >= ... >= l_d`` of the sample covariance of N points in d
    dimensions (Minka 2000: Laplace's method around the maximum-likelihood PPCA, the uniform
    prior on the subspace U):

    .. math::

        \\log p(X \\mid k) \\approx \\log p(U) - \\frac{N}{2} \\sum_{j=1}^{k} \\log l_j
        - \\frac{N (d - k)}{2} \\log v + \\frac{m + k}{2} \\log 2\\pi
        - \\frac{1}{2} \\log |A_Z| - \\frac{k}{2} \\log N

    with ``v = sum_(j > k) l_j / (d - k)`` the noise variance, ``m = d k - k (k + 1) / 2`` the
    dimension of the Stiefel manifold, ``log p(U) = -k log 2 + sum_(i=1)^k [log Gamma((d - i +
    1) / 2) - (d - i + 1) / 2 log pi]`` and ``log |A_Z| = sum_(i=1)^k sum_(j=i+1)^d log(N (l_i -
    l_j) (1 / l^_j - 1 / l^_i))``, ``l^_j = l_j`` for ``j <= k`` and ``v`` beyond. ``k = 0`` is
    the isotropic model, ``-N d / 2 log(mean l)``. Differences between ranks do not depend on
    the data's scale. The noise variance is floored at ``1e-12 l_1``, so exactly low-rank data
    have their rank as the best k.

    Parameters
    ----------
    spectrum : array_like, shape (d,)
        Eigenvalues of the sample covariance (the second moment, for a model without mean),
        non-negative, any order (sorted here); zeros where the N points span fewer than d
        dimensions.
    n_samples : int
        N >= 1.
    max_rank : int or None
        The largest k scored (at most ``d - 1``, the default).

    Returns
    -------
    ndarray, shape (max_rank + 1,)
        ``log p(X | k)`` for ``k = 0, ..., max_rank``; ``-inf`` for a k whose k-th eigenvalue
        is zero.

    Raises
    ------
    ValidationError
        A spectrum that is not a finite, non-negative vector of at least 2 values, not all zero,
        ``n_samples < 1`` or ``max_rank`` outside ``[0, d - 1]``.

    References
    ----------
    T. P. Minka, "Automatic choice of dimensionality for PCA", NIPS 13 (2000).
    """
    lam = check_array(spectrum, "spectrum", ndim=1)
    if lam.size < 2 or np.any(lam < 0) or not np.any(lam > 0):
        raise ValidationError(f"spectrum must hold at least 2 non-negative eigenvalues, not all zero; got {lam!r:.80}")
    n = check_int(n_samples, "n_samples", minimum=1)
    d = lam.size
    K = d - 1 if max_rank is None else check_int(max_rank, "max_rank", minimum=0, maximum=d - 1)
    lam = np.sort(lam)[::-1]
    floor = _RELATIVE_FLOOR * lam[0]
    out = np.full(K + 1, -np.inf)
    out[0] = -0.5 * n * d * np.log(max(float(lam.mean()), floor))
    i = np.arange(1, K + 1)
    log_pu = np.cumsum(gammaln((d - i + 1) / 2.0) - (d - i + 1) / 2.0 * np.log(np.pi)) - i * np.log(2.0)
    tail = np.cumsum(lam[::-1])[::-1]  # tail[k] = sum_(j >= k) l_j (0-based)
    for k in range(1, K + 1):
        if lam[k - 1] <= floor:
            break
        v = max(float(tail[k]) / (d - k), floor)
        m = d * k - k * (k + 1) / 2.0
        hat = np.concatenate([lam[:k], np.full(d - k, v)])
        li, hi = lam[:k, None], hat[:k, None]
        gap = (li - lam[None, :]) * (1.0 / hat[None, :] - 1.0 / hi)  # (k, d); the pairs j > i count
        upper = np.arange(d)[None, :] > np.arange(k)[:, None]
        log_az = float(np.sum(np.log(np.maximum(gap[upper], np.finfo(float).tiny)))) + upper.sum() * np.log(n)
        out[k] = (log_pu[k - 1] - 0.5 * n * np.sum(np.log(lam[:k])) - 0.5 * n * (d - k) * np.log(v)
                  + 0.5 * (m + k) * np.log(2.0 * np.pi) - 0.5 * log_az - 0.5 * k * np.log(n))
    return out


def pca_rank_evidence(X: ArrayLike, *, center: bool = False,
                      max_rank: int | None = None) -> tuple[NDArray[np.float64], int]:
    """The log evidence of every PCA rank of a data matrix, and the best rank (Minka 2000).

    The spectrum is that of the second moment ``X^T X / N`` (``center=False``: the factorial
    model and its PCA start have no mean) or of the covariance ``X_c^T X_c / (N - 1)``
    (``center=True``, as scikit-learn's ``PCA(n_components="mle")``); see
    :func:`laplace_rank_evidence`. With fewer samples than dimensions (fewer tasks than reward
    parameters) the sample covariance has at most N non-zero eigenvalues, so k is at most
    ``N - 1`` (``N - 2`` centred).

    Parameters
    ----------
    X : array_like, shape (N, d)
        One sample (a task's parameters) per row, N >= 2 (3 centred), d >= 2.
    center : bool, default=False
    max_rank : int or None
        The largest k scored; default and at most ``min(d, N) - 1`` (``min(d, N - 1) - 1`` centred).

    Returns
    -------
    log_evidence : ndarray, shape (max_rank + 1,)
        ``log p(X | k)`` for ``k = 0, ..., max_rank`` (k = 0: isotropic noise, nothing shared).
    rank : int
        The k of the largest evidence.

    Raises
    ------
    ValidationError
        X not a finite 2-d array with enough rows and at least 2 columns, all zero, or a bad
        ``max_rank``.
    """
    data = check_array(X, "X", ndim=2)
    N, d = data.shape
    if d < 2 or N < (3 if center else 2):
        raise ValidationError(f"X must have at least {3 if center else 2} rows (samples) and 2 columns; got {data.shape}")
    if center:
        data = data - data.mean(axis=0)
    s = np.linalg.svd(data, compute_uv=False)
    if not s.size or s[0] == 0:
        raise ValidationError(f"X is all zero{' (after centring)' if center else ''}: it has no spectrum to choose a rank from")
    spectrum = np.zeros(d)
    spectrum[:s.size] = s ** 2 / (N - 1 if center else N)
    # N points span at most N dimensions (N - 1 centred): a k that leaves no sample dimension to the
    # noise would see exactly zero noise whatever the data
    top = min(d, N - 1 if center else N) - 1
    if max_rank is not None:
        top = min(top, check_int(max_rank, "max_rank", minimum=0))
    evidence = laplace_rank_evidence(spectrum, N, top)
    return evidence, int(np.argmax(evidence))


def flat_start_points(tasks: TaskSet, flat_rewards: Any) -> NDArray[np.float64]:
    """The matrix FactIRL's PCA start decomposes, in the basis' metric: (n_tasks, d).

    The flat rewards' least-squares weights in the task set's basis
    (:meth:`~factirl_opt.tasks.basis.RewardBasis.start_points_from_rewards`), as the basis'
    :meth:`~factirl_opt.tasks.basis.RewardBasis.start_dictionary` hands them to the PCA: the
    rewards themselves for tabular rewards, ``W G^(1/2)`` in the features' mean Gram metric G
    otherwise (the principal directions of the rewards ``Phi_i w_i``).

    Parameters
    ----------
    tasks : TaskSet
        As ``FactIRL.fit`` builds them (its ``features`` and ``reward``; only the basis is read).
    flat_rewards : sequence of arrays, shape (S_i, A) each
        Every task's flat reward (:func:`~factirl_opt.learners.selection.search.flat_start_rewards`).

    Returns
    -------
    ndarray, shape (n_tasks, d)

    Raises
    ------
    ValidationError
        ``flat_rewards`` not one (S_i, A) array per task.
    """
    points = tasks.basis.start_points_from_rewards(flat_rewards, tasks.n_tasks)
    seen: list[NDArray[np.float64]] = []

    def capture(Y: NDArray[np.float64], k: int, rng: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        seen.append(np.array(Y, dtype=np.float64))
        return np.eye(Y.shape[1], k), np.zeros((Y.shape[0], k))

    tasks.basis.start_dictionary(points, 1, None, capture)
    return seen[0]


def flat_start_evidence(tasks: TaskSet, flat_rewards: Any,
                        max_rank: int | None = None) -> tuple[NDArray[np.float64], int]:
    """:func:`pca_rank_evidence` (uncentred) of :func:`flat_start_points`: the evidence of every
    number of primitives of the PCA start, and the best one (0: no direction shared by the tasks).

    Parameters
    ----------
    tasks, flat_rewards
        As in :func:`flat_start_points`.
    max_rank : int or None
        The largest k scored (default: as many as the tasks and the reward dimension allow).

    Returns
    -------
    log_evidence : ndarray, shape (K + 1,)
    rank : int
    """
    return pca_rank_evidence(flat_start_points(tasks, flat_rewards), max_rank=max_rank)


#: the ``"evidence"`` route keeps the flat model, unscored, when a plausible k of the evidence
#: exceeds the training tasks of a fold divided by this (:func:`evidence_primitives`)
MIN_TASKS_PER_PRIMITIVE = 2

#: ranks whose log evidence is within this of the best are plausible (:func:`plausible_ranks`): a
#: Bayes factor below e^3 (about 20), under Kass & Raftery's (1995) "strong" evidence
PLAUSIBLE_LOG_BAYES_FACTOR = 3.0


def plausible_ranks(log_evidence: ArrayLike, log_bayes_factor: float = PLAUSIBLE_LOG_BAYES_FACTOR) -> NDArray[np.intp]:
    """The ranks the evidence does not rule out against the best one.

    Those k whose log evidence is within ``log_bayes_factor`` of the largest: the evidence
    prefers the best rank to each of them by a Bayes factor below ``exp(log_bayes_factor)``
    (3: about 20, the threshold of "strong" evidence in Kass & Raftery 1995).

    Parameters
    ----------
    log_evidence : array_like, shape (K + 1,)
        ``log p(X | k)`` for ``k = 0, ..., K`` (:func:`pca_rank_evidence`), ``-inf`` allowed, at
        least one finite.
    log_bayes_factor : float, default=PLAUSIBLE_LOG_BAYES_FACTOR
        >= 0.

    Returns
    -------
    ndarray of int
        Sorted ranks; the best rank among them.

    Raises
    ------
    ValidationError
        ``log_evidence`` not a 1-d array with a finite value and no NaN or ``+inf``, or a negative
        or non-finite ``log_bayes_factor``.

    References
    ----------
    R. E. Kass and A. E. Raftery, "Bayes factors", JASA 90 (1995).
    """
    ev = np.asarray(log_evidence, dtype=np.float64)
    if ev.ndim != 1 or not ev.size or np.any(np.isnan(ev)) or np.any(ev == np.inf) or not np.any(np.isfinite(ev)):
        raise ValidationError(f"log_evidence must be a 1-d array of log evidences with a finite one, no NaN or +inf; "
                              f"got {ev!r:.80}")
    margin = float(log_bayes_factor)
    if not (math.isfinite(margin) and margin >= 0.0):
        raise ValidationError(f"log_bayes_factor must be a finite number >= 0; got {log_bayes_factor!r}")
    return np.flatnonzero(ev >= ev.max() - margin)


def evidence_primitives(rank: int, k_max: int, n_train: int | None = None, *,
                        largest_plausible: int | None = None) -> list[int]:
    """The numbers of primitives the ``"evidence"`` route scores for the evidence's best ``rank``.

    ``ceil(rank / 2)``, ``rank`` and ``2 rank``, each at most ``k_max`` and, given ``n_train``, at
    most ``n_train / MIN_TASKS_PER_PRIMITIVE`` (two training tasks a primitive): on the which-learner
    benchmark the evidence of the flat rewards misses the k that transfers best by up to a
    factor of 2 either way (``results/which-learner/diagnostics/evidence/``): 3 or 4 on the grid
    with 20 tasks (true k 5; (4, 1) to (8, 1) transfer best), 14 or 15 with 100 tasks (k = 5
    best), 9 to 11 with 20 Objectworld tasks (k = 4 or 5 best), the flat rewards' noise being
    neither isotropic nor Gaussian.

    None (the flat model is chosen without a held-out score) when the tasks share little:
    ``rank = 0`` (no direction shared), or, given ``n_train``, more directions than
    ``n_train / MIN_TASKS_PER_PRIMITIVE`` (each primitive of the flat rewards would rest on fewer
    than two of the tasks a candidate is fitted on) for ``largest_plausible``, the largest rank the
    evidence does not rule out (:func:`plausible_ranks`; a map per task at 5 and 20 tasks and
    BabyAI GoToLocal at 10 layouts have best ranks 1, 6 and 3 with ranks 2, 7 and 4 within a Bayes
    factor of 20, and flat transfers best on all of them). On the which-learner benchmark the latter
    holds at every BabyAI GoToLocal point, on every seed of one Objectworld map with 5 tasks and
    on two of three with a map per task and 5 tasks, where flat transfers best, and on one
    Objectworld map with 20 tasks, where the factorial model does (and where no route's held-out
    score finds it; ``results/which-learner/diagnostics/evidence/README.md``). A rule read off
    that benchmark, not derived.

    Parameters
    ----------
    rank : int
        >= 0 (:func:`flat_start_evidence`).
    k_max : int
        >= 1, the largest k a candidate may have.
    n_train : int or None
        >= 1, the fewest training tasks of a fold; None: no such limit.
    largest_plausible : int or None
        >= ``rank``, the largest plausible rank (:func:`plausible_ranks`), compared with
        ``n_train``; None: ``rank``.

    Returns
    -------
    list of int
        Sorted, distinct, in ``[1, k_max]``; empty when the tasks share little.
    """
    rank = check_int(rank, "rank", minimum=0)
    k_max = check_int(k_max, "k_max", minimum=1)
    widest = rank if largest_plausible is None else check_int(largest_plausible, "largest_plausible", minimum=rank)
    if n_train is not None and widest * MIN_TASKS_PER_PRIMITIVE > check_int(n_train, "n_train", minimum=1):
        return []
    if rank == 0:
        return []
    top = k_max if n_train is None else min(k_max, n_train // MIN_TASKS_PER_PRIMITIVE)
    return sorted({min(top, k) for k in ((rank + 1) // 2, rank, 2 * rank)})


#: the training tasks of a fold per primitive from which the ``"evidence"`` route confirms its
#: choice of k by fully fitted candidates (:func:`confirmation_primitives`)
CONFIRM_TASKS_PER_PRIMITIVE = 8


def confirmation_primitives(k: int, k_max: int, n_train: int) -> list[int]:
    """The numbers of primitives the ``"evidence"`` route rescores by fully fitted candidates
    around its choice ``k``: ``k - 1``, ``k`` and ``k + 1`` within ``[1, k_max]``, when a fold
    has at least ``CONFIRM_TASKS_PER_PRIMITIVE`` training tasks per primitive; else none.

    With many tasks per primitive the scores of PCA starts (and of candidates fitted for a few
    outer iterations) rank one primitive too many first, while the fitted models transfer the
    other way round: on the paper's grid at 100 tasks (66 training tasks a fold) the route's
    screen chose (6, inf) on every seed; on seed 1 it transfers at 4.71 against k = 5's 4.04, and
    there the held-out scores of fully fitted candidates tie 5 and 6 (0.7895 and 0.7890, 7 at
    0.832), so the fewest within one standard error is 5
    (``results/which-learner/diagnostics/evidence-budget/``). With few tasks per primitive (the
    grid at 20 or 30 tasks, 13 or 20 training tasks a fold) the screen's choices transfer well
    and full fits would cost more than the whole search (about 6 fits). A threshold read off
    that benchmark, not derived.

    Parameters
    ----------
    k : int
        >= 1, the screen's choice.
    k_max : int
        >= 1, the largest k a candidate may have.
    n_train : int
        >= 1, the fewest training tasks of a fold.

    Returns
    -------
    list of int
        Sorted; empty when the fold's tasks are too few per primitive.
    """
    k = check_int(k, "k", minimum=1)
    k_max = check_int(k_max, "k_max", minimum=1)
    if check_int(n_train, "n_train", minimum=1) < CONFIRM_TASKS_PER_PRIMITIVE * k:
        return []
    return [m for m in (k - 1, k, k + 1) if 1 <= m <= k_max]


def evidence_penalties(lam_grid: Sequence[float]) -> list[float]:
    """The residual penalties the ``"evidence"`` route scores, from a search's grid.

    The factorial model (inf), the residual model nearest it (the grid's largest finite
    positive penalty, 1 by default) and the flat model (0), those of them in the grid, in the
    grid's order: the held-out transfers of the residual candidates are the costly part of a
    search (``results/which-learner/diagnostics/routes/``), and no search of the which-learner
    benchmark chose the smaller penalty 0.01.

    Parameters
    ----------
    lam_grid : sequence of float
        Non-negative, inf allowed.

    Returns
    -------
    list of float
    """
    lams = [float(lam) for lam in lam_grid]
    finite = [lam for lam in lams if 0.0 < lam < math.inf]
    keep = {math.inf, 0.0} | ({max(finite)} if finite else set())
    return [lam for lam in lams if lam in keep]

"""Expectation-maximisation over intentions: the E-step, the weighted statistics, and the start.

Plain functions over arrays behind :class:`factirl_opt.learners.multi_intent.MultiIntentIRL`
(Babes-Vroman et al. 2011). ``n`` episodes, ``K`` intentions, episodes on the leading axis:

- :func:`episode_counts`: each episode's (state, action) counts, a sparse (n, S*A) matrix;
- :func:`log_policies`: each intention's action log-probabilities under the policy its
  objective models (:meth:`~factirl_opt.objectives.Objective.log_policy`: the Boltzmann
  policy of ``Q*`` for policy matching, eq. 7; the soft-optimal policy for maximum causal
  entropy, docs/maths.md §6), in log space;
- :func:`e_step`: the episodes' log-likelihoods under each intention, the responsibilities and
  the total log-likelihood, by log-sum-exp;
- :func:`weighted_statistics`: the responsibility-weighted empirical statistics (the hats of
  eq. 5) of each intention and its share of the demonstrated steps;
- :func:`agreement_clustering` (the default start): episodes that take the same action in a
  state they share are pulled together, episodes that take different ones pushed apart;
- :func:`kmeans`: k-means++ seeding and Lloyd iterations (the ``"frequencies"`` start).

The likelihood of an episode ``tau = ((s_0, a_0), ..., (s_{L-1}, a_{L-1}))`` under intention c
is ``prod_t pi_c(a_t | s_t)`` times the start and transition probabilities, which do not depend
on the intention and cancel in the responsibilities; the log-likelihoods here leave them out.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.special import logsumexp

from ..objectives import Objective, get_objective

__all__ = ["episode_counts", "log_policies", "e_step", "weighted_statistics", "kmeans", "kmeans_plus_plus",
           "agreement_clustering", "DISAGREEMENT_PENALTY"]

#: weight of a state where two episodes take different actions against one where they take the same
DISAGREEMENT_PENALTY = 3.0


def episode_counts(steps: NDArray[np.int64], lengths: NDArray[np.int64], n_states: int,
                   n_actions: int) -> sp.csr_matrix:
    """Each episode's (state, action) counts.

    Parameters
    ----------
    steps : ndarray of int, shape (N, 2)
        The (state, action) steps of all episodes, concatenated in order.
    lengths : ndarray of int, shape (n,)
        Episode lengths, summing to N.
    n_states, n_actions : int

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n, S*A)
        ``C[j, s * A + a]`` is the number of steps of episode j in state s taking action a.
    """
    n = len(lengths)
    rows = np.repeat(np.arange(n), lengths)
    cols = steps[:, 0] * n_actions + steps[:, 1]
    return sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n_states * n_actions))


def log_policies(planner: Any, rewards: NDArray[np.float64], beta: float,
                 objective: str | type[Objective]) -> NDArray[np.float64]:
    """Action log-probabilities ``log pi_c(a|s)`` (K, S, A) of each intention's rewards (K, S, A).

    The policy the objective models (:meth:`~factirl_opt.objectives.Objective.log_policy`):
    for ``"policy-matching"`` the Boltzmann policy of the optimal ``Q*``,
    ``log pi = beta Q* - log sum_a exp(beta Q*)`` (eq. 7); for ``"mce"`` the soft-optimal
    policy ``beta (Q - V)`` of the soft Bellman equation (docs/maths.md §6). Both stay finite
    for any finite rewards (no ``log(exp(.))``).
    """
    return (get_objective(objective) if isinstance(objective, str) else objective).log_policy(planner, rewards, beta)


def e_step(counts: Any, log_pi: NDArray[np.float64],
           mixture_weights: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Episodes' log-likelihoods, responsibilities and the total log-likelihood.

    Parameters
    ----------
    counts : sparse or ndarray, shape (n, S*A)
        :func:`episode_counts`.
    log_pi : ndarray, shape (K, S, A)
        :func:`log_policies`.
    mixture_weights : ndarray, shape (K,)
        Prior probability of each intention (nonnegative, summing to 1; a zero weight gives a
        zero responsibility).

    Returns
    -------
    log_likelihoods : ndarray, shape (n, K)
        ``sum_t log pi_c(a_t | s_t)`` of each episode under each intention.
    responsibilities : ndarray, shape (n, K)
        ``P(c | tau_j)``, rows summing to 1.
    total : float
        ``sum_j log sum_c w_c prod_t pi_c(a_t | s_t)``, the log-likelihood of the episodes'
        actions given their states (start and transition terms left out).
    """
    K = log_pi.shape[0]
    L = np.asarray(counts @ log_pi.reshape(K, -1).T)
    with np.errstate(divide="ignore"):
        joint = L + np.log(mixture_weights)[None, :]
    per_episode = logsumexp(joint, axis=1)
    return L, np.exp(joint - per_episode[:, None]), float(per_episode.sum())


def weighted_statistics(counts: Any, responsibilities: NDArray[np.float64], n_states: int,
                        n_actions: int) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Responsibility-weighted empirical statistics of each intention (the hats of eq. 5).

    The weighted pair counts ``c_c(s, a) = sum_j r_jc C_j(s, a)`` give, as for a labelled task
    (:func:`factirl_opt.empirical_statistics`), ``mu_c(s) = sum_a c_c(s, a) / N_c`` and
    ``pi_c(a|s) = c_c(s, a) / sum_a c_c(s, a)``, with ``N_c = sum_{s,a} c_c(s, a)`` the
    intention's expected number of steps. Hard responsibilities (0 or 1) give exactly the
    statistics of the episodes assigned to each intention. Since the objectives' losses are
    per-step averages (``J_c = -sum_{s,a} mu_c pi_c log pi`` for MCE), the expected
    complete-data log-likelihood of EM is ``-sum_c N_c J_c``: weight intention c by ``N_c``.

    An intention with no weight (``N_c = 0``) is given the statistics of all the episodes, so
    that they are defined; its weight ``N_c = 0`` keeps it out of the weighted loss.

    Parameters
    ----------
    counts : sparse or ndarray, shape (n, S*A)
    responsibilities : ndarray, shape (n, K)
    n_states, n_actions : int

    Returns
    -------
    mu : ndarray, shape (K, S)
    pi : ndarray, shape (K, S, A)
    steps : ndarray, shape (K,)
        ``N_c``.
    """
    S, A = n_states, n_actions
    pair = np.asarray((counts.T @ responsibilities).T if sp.issparse(counts) else responsibilities.T @ counts)
    steps = pair.sum(axis=1)
    empty = ~(steps > 0)
    if empty.any():
        pair[empty] = np.asarray(counts.sum(axis=0)).ravel()
    pair = pair.reshape(-1, S, A)
    visits = pair.sum(axis=2)
    mu = visits / visits.sum(axis=1, keepdims=True)
    pi = np.divide(pair, visits[:, :, None], out=np.zeros_like(pair), where=visits[:, :, None] > 0)
    return mu, pi, np.where(empty, 0.0, steps)


def kmeans_plus_plus(X: NDArray[np.float64], k: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """k-means++ seeding (Arthur & Vassilvitskii 2007): k rows of X (n, d) as centres (k, d).

    The first centre is a uniform draw; each next one is drawn with probability proportional
    to the squared distance to the nearest centre chosen (uniformly when all are zero).
    """
    n = X.shape[0]
    centres = [X[rng.integers(n)]]
    d2 = np.sum((X - centres[0]) ** 2, axis=1)
    for _ in range(1, k):
        total = d2.sum()
        j = rng.choice(n, p=d2 / total) if total > 0 else rng.integers(n)
        centres.append(X[j])
        d2 = np.minimum(d2, np.sum((X - X[j]) ** 2, axis=1))
    return np.array(centres)


def _assign(X, centres):
    d2 = (X * X).sum(axis=1)[:, None] - 2.0 * X @ centres.T + (centres * centres).sum(axis=1)[None, :]
    labels = np.argmin(d2, axis=1)
    return labels, np.maximum(d2[np.arange(len(X)), labels], 0.0)


def _lloyd(X, centres, max_iter):
    labels, d2 = _assign(X, centres)
    for _ in range(max_iter):
        for c in range(len(centres)):
            members = labels == c
            if members.any():
                centres[c] = X[members].mean(axis=0)
            else:  # an empty cluster takes the point farthest from its centre
                far = int(np.argmax(d2))
                centres[c], d2[far] = X[far], 0.0
        new, d2 = _assign(X, centres)
        if np.array_equal(new, labels):
            break
        labels = new
    return labels, float(d2.sum())


def kmeans(X: NDArray[np.float64], k: int, rng: np.random.Generator, n_seeds: int = 10,
           max_iter: int = 100) -> NDArray[np.int64]:
    """Labels (n,) of the best of ``n_seeds`` k-means runs (lowest inertia), each seeded by k-means++.

    Parameters
    ----------
    X : ndarray, shape (n, d)
    k : int
        Clusters, ``1 <= k <= n``.
    rng : numpy.random.Generator
    n_seeds : int
        Independent seedings.
    max_iter : int
        Lloyd iterations per seeding (stops earlier when the labels repeat).
    """
    best, best_inertia = None, np.inf
    for _ in range(n_seeds):
        labels, inertia = _lloyd(X, kmeans_plus_plus(X, k, rng), max_iter)
        if inertia < best_inertia:
            best, best_inertia = labels, inertia
    return np.asarray(best, dtype=np.int64)


def _merge_to(score, k):
    """Greedy agglomeration of a symmetric (n, n) score into k groups: merge the pair of largest total."""
    n = len(score)
    T = score.astype(np.float64).copy()
    np.fill_diagonal(T, -np.inf)
    alive = np.ones(n, dtype=bool)
    owner = np.arange(n)
    for _ in range(n - k):
        i, j = np.unravel_index(np.argmax(T), T.shape)
        i, j = min(i, j), max(i, j)
        owner[owner == j] = i
        T[i] += T[j]
        T[:, i] += T[:, j]
        T[i, i] = -np.inf
        T[j], T[:, j], alive[j] = -np.inf, -np.inf, False
    return np.searchsorted(np.flatnonzero(alive), owner)


def agreement_clustering(counts: Any, n_states: int, n_actions: int, k: int, rng: np.random.Generator,
                         penalty: float = DISAGREEMENT_PENALTY) -> NDArray[np.int64]:
    """Labels (n,) from the actions episodes take in the states they share.

    An expert acting on one intention takes the same action whenever it visits a state (a
    deterministic greedy policy exactly, a Boltzmann one mostly), so two of its episodes agree
    wherever their states overlap; episodes of different intentions often disagree. The score
    of a pair is the number of states where they take a common action minus ``penalty`` times
    the number of shared states where they do not; the groups are merged greedily, the pair of
    groups of largest total score first, down to k. Pairs that share no state score 0; ``rng``
    shuffles the episodes first, which breaks the ties among them (so restarts differ).
    Cost O(n^3) for n episodes.

    Parameters
    ----------
    counts : sparse or ndarray, shape (n, S*A)
        :func:`episode_counts`.
    n_states, n_actions : int
    k : int
        Groups, ``1 <= k <= n``.
    rng : numpy.random.Generator
    penalty : float
        Weight of a disagreement.
    """
    n = counts.shape[0]
    B = sp.csr_matrix(counts, dtype=np.float64)
    B.data[:] = 1.0
    V = sp.csr_matrix(B.toarray().reshape(n, n_states, n_actions).sum(axis=2) > 0, dtype=np.float64)
    agree = np.asarray((B @ B.T).todense())
    disagree = np.asarray((V @ V.T).todense()) - agree
    order = rng.permutation(n)
    score = (agree - penalty * disagree)[np.ix_(order, order)]
    labels = np.empty(n, dtype=np.int64)
    labels[order] = _merge_to(score, k)
    return labels

"""Successor features of fixed policies and generalised policy improvement (docs/maths.md §11).

Rewards linear in k reward features, ``R_h(s, a) = phi(s, a)^T h`` with ``phi`` (k, S, A) (for a
factorial model the primitive rewards ``Phi D``), have, for any fixed policy ``pi``, action
values linear in ``h`` too: ``Q^pi_h = psi^pi h`` with the *successor features*

    psi^pi(s, a) = phi(s, a) + gamma sum_s' P(s'|s, a) psi^pi_V(s'),
    (I - gamma P_pi) psi^pi_V = phi_pi,   phi_pi(s) = sum_a pi(a|s) phi(s, a),

(Barreto et al. 2017, eq. 4): the discounted expected sum of ``phi`` under ``pi``. They are
computed exactly, one linear system per policy with k right-hand sides, by the engine's
forward-mode derivative (:func:`~factirl_opt.planning.engine.tangent`: ``psi^pi`` is the
derivative of ``Q^pi`` along the k reward directions ``phi``), on the planner's factorisation
of ``I - gamma P_pi``: the sparse LU, solved once per policy for all k columns.

Generalised policy improvement (GPI; Barreto et al. 2017, Theorem 1): for a library of
policies ``pi_1..pi_L`` and a task ``h``, the policy greedy on ``max_l psi^{pi_l}(s, a)^T h``
has ``Q^{GPI}_h >= max_l Q^{pi_l}_h`` in every state and action (:func:`gpi_actions`). One
exact policy-improvement step (:func:`improve_policies`) evaluates a policy on the task's
reward and acts greedily on its action values: at least as good again (Howard).

Layout: libraries keep policies on the leading axis, ``psi`` (L, S, A, k); tasks' coefficients
are (n, k); deterministic policies (n, S) of action indices, stochastic ones (n, S, A).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._threads import blas_limited
from .._validation import check_array, check_mdp, check_policy, check_stochastic_policy
from ..exceptions import ValidationError
from .base import Planner
from .engine import greedy_values, tangent
from .registry import get_planner

__all__ = ["successor_features", "policy_successor_features", "gpi_actions", "library_values", "improve_policies",
           "GPI_BLOCK_BYTES", "GPI_TASK_CHUNK"]

#: memory of one block of action values in :func:`gpi_actions` (states x actions x tasks floats)
GPI_BLOCK_BYTES = 512 * 2**10
#: tasks whose GPI actions :func:`gpi_actions` computes together
GPI_TASK_CHUNK = 1024


def policy_successor_features(planner: Planner, phi: NDArray[np.float64], policy: NDArray[Any]) -> NDArray[np.float64]:
    """Successor features of L policies (unvalidated kernel of :func:`successor_features`).

    Parameters
    ----------
    planner : Planner
    phi : ndarray, shape (S, A, k)
        The reward features, features on the last axis.
    policy : ndarray, (L, S) int or (L, S, A) float

    Returns
    -------
    psi : ndarray, shape (L, S, A, k)
        ``psi[l] = phi + gamma P (I - gamma P_pi_l)^-1 phi_pi_l``: one factorisation of each
        policy's system (:meth:`Planner.system`), solved for the k columns at once.
    """
    L = policy.shape[0]
    S, A, k = phi.shape
    if L == 0:
        return np.empty((0, S, A, k))
    system = planner.system(policy)
    return tangent(planner, system, policy, np.broadcast_to(phi, (L, S, A, k)))


@blas_limited
def successor_features(mdp: Any, features: ArrayLike, policy: ArrayLike, planner: str | Planner = "auto") -> NDArray[np.float64]:
    """Exact successor features ``psi^pi`` of fixed policies for k reward features (Barreto et al. 2017).

    For every reward ``R_h = sum_j h_j features[j]`` the action values of ``pi`` are
    ``Q^pi_h(s, a) = psi^pi(s, a) @ h``, so one solve per policy (k right-hand sides on one
    factorisation of ``I - gamma P_pi``) gives them for every ``h``.

    Parameters
    ----------
    mdp : TabularMDP
    features : array_like, shape (k, S, A) or (k, S)
        The reward features ``phi_j``, one reward per row (state rewards repeated over the
        actions); for a factorial model its primitive rewards ``Phi D``.
    policy : array_like
        Deterministic: int actions (S,) or (L, S). Stochastic: probabilities ``pi(a|s)``,
        float (S, A) or (L, S, A), rows summing to 1.
    planner : str, default="auto"
        See :func:`~factirl_opt.available_planners`.

    Returns
    -------
    psi : ndarray, shape (S, A, k) or (L, S, A, k)
        ``psi[l, s, a, j]``: the expected discounted sum of ``features[j]`` from ``(s, a)``
        following policy ``l`` afterwards.

    Raises
    ------
    ValidationError
        Features or policies of the wrong shape or values.
    """
    check_mdp(mdp)
    phi = check_array(features, "features")
    S, A = mdp.n_states, mdp.n_actions
    if phi.ndim == 2 and phi.shape[1] == S and not (phi.shape == (S, A) and S != A):
        phi = np.repeat(phi[:, :, None], A, axis=2)
    if phi.ndim != 3 or phi.shape[1:] != (S, A):
        raise ValidationError(f"features must have shape (k, {S}, {A}) or (k, {S}) (one reward per row); got {np.shape(features)}")
    arr = np.asarray(policy)
    stochastic = arr.dtype.kind == "f"
    single = arr.ndim == (2 if stochastic else 1)
    n = 1 if single else (arr.shape[0] if arr.ndim else 0)
    pol = check_stochastic_policy(mdp, arr, n) if stochastic else check_policy(mdp, arr, n)
    psi = policy_successor_features(get_planner(mdp, planner), np.ascontiguousarray(np.moveaxis(phi, 0, 2)), pol)
    return psi[0] if single else psi


def _policy_rows(psi: NDArray[np.float64], policy: NDArray[Any]) -> NDArray[np.float64]:
    """``psi_V[l, s] = sum_a pi_l(a|s) psi[l, s, a]`` (L, S, k): the successor features of the states."""
    if policy.ndim == 2:
        return np.take_along_axis(psi, policy[:, :, None, None], axis=2)[:, :, 0]
    return np.einsum("lsa,lsak->lsk", policy, psi)


def library_values(psi: NDArray[np.float64], policy: NDArray[Any], coefficients: NDArray[np.float64],
                   start: NDArray[np.float64]) -> NDArray[np.float64]:
    """Values ``rho^T V^{pi_l}_h`` of every library policy on every task, from the successor features.

    ``V^{pi_l}_h(s) = sum_a pi_l(a|s) psi_l(s, a) h``: no solve.

    Parameters
    ----------
    psi : ndarray, shape (L, S, A, k)
    policy : ndarray, (L, S) int or (L, S, A) float
        The library's policies (those of ``psi``).
    coefficients : ndarray, shape (n, k)
    start : ndarray, shape (S,) or (n, S)
        The start distribution ``rho``, one for every task or one per task.

    Returns
    -------
    ndarray, shape (n, L)
    """
    rows = _policy_rows(psi, policy)  # (L, S, k)
    if start.ndim == 1:
        return coefficients @ np.einsum("s,lsk->lk", start, rows).T
    L, S, k = rows.shape
    per_task = (start @ np.moveaxis(rows, 1, 0).reshape(S, L * k)).reshape(-1, L, k)  # (n, L, k)
    return np.einsum("nlk,nk->nl", per_task, coefficients)


def gpi_actions(psi: NDArray[np.float64], coefficients: NDArray[np.float64],
                block_bytes: int = GPI_BLOCK_BYTES) -> NDArray[np.intp]:
    """Greedy actions of generalised policy improvement: ``argmax_a max_l psi_l(s, a) @ h``.

    Barreto et al. 2017, Theorem 1: the policy's action values on task ``h`` are at least
    ``max_l Q^{pi_l}_h`` everywhere. Ties go to the first maximising action.

    The action values of a block of states for a chunk of up to :data:`GPI_TASK_CHUNK` tasks
    (``block_bytes``, sized to stay in the processor's cache) are formed policy by policy and
    reduced by a running maximum: 3x less CPU at S = 10,000 than whole (S * A, tasks) arrays,
    whose passes through memory dominate.

    Parameters
    ----------
    psi : ndarray, shape (L, S, A, k), L >= 1
    coefficients : ndarray, shape (n, k)
    block_bytes : int
        Memory of one block of action values (rows ``s * A + a`` x tasks).

    Returns
    -------
    ndarray of intp, shape (n, S)
    """
    L, S, A, k = psi.shape
    n = coefficients.shape[0]
    flat = psi.reshape(L, S * A, k)
    out = np.empty((n, S), dtype=np.intp)
    for lo in range(0, n, GPI_TASK_CHUNK):
        Ht = np.ascontiguousarray(coefficients[lo:lo + GPI_TASK_CHUNK].T)  # (k, c)
        c = Ht.shape[1]
        states = max(1, block_bytes // (8 * A * c))
        best = np.empty((states * A, c))
        q = np.empty_like(best)
        for s0 in range(0, S, states):
            s1 = min(S, s0 + states)
            rows = slice(s0 * A, s1 * A)
            b, qb = best[:(s1 - s0) * A], q[:(s1 - s0) * A]
            np.matmul(flat[0, rows], Ht, out=b)
            for l in range(1, L):
                np.matmul(flat[l, rows], Ht, out=qb)
                np.maximum(b, qb, out=b)
            out[lo:lo + c, s0:s1] = np.argmax(b.reshape(s1 - s0, A, c), axis=1).T
    return out


def improve_policies(planner: Planner, R: NDArray[np.float64], policy: NDArray[np.intp]
                     ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """One exact policy-improvement step: evaluate ``policy`` on ``R``, act greedily on its ``Q``.

    As a sweep of :func:`~factirl_opt.planning.engine.plan`: a state keeps its action unless
    another is better by more than a relative 1e-12 (so an optimal policy is returned as is).

    Parameters
    ----------
    planner : Planner
    R : ndarray, shape (n, S, A)
    policy : ndarray of intp, shape (n, S)

    Returns
    -------
    improved : ndarray of intp, shape (n, S)
    V : ndarray, shape (n, S)
        The exact values of ``policy`` on ``R`` (before the step).
    """
    V, _ = greedy_values(planner, R, policy)
    Q = planner.q_from_values(R, V)
    best = np.argmax(Q, axis=2)
    q_cur = np.take_along_axis(Q, policy[:, :, None], axis=2)[:, :, 0]
    q_best = np.take_along_axis(Q, best[:, :, None], axis=2)[:, :, 0]
    tol = 1e-12 * np.maximum(1.0, np.abs(Q).max(axis=(1, 2)))[:, None]
    return np.where(q_best > q_cur + tol, best, policy), V

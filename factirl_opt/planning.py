"""Exact planning: Q* by warm-started policy iteration, policy evaluation, Boltzmann policies.

All functions take a batch of tasks on the leading axis: rewards (n, S, A), values (n, S),
deterministic policies (n, S) of action indices. A single (S, A) reward is accepted where
documented and gives unbatched outputs.
"""

import numpy as np

from ._threads import blas_limited
from ._validation import check_beta, check_mdp, check_policy, check_rewards
from .exceptions import FactIRLError, ValidationError

__all__ = ["optimal_q", "policy_evaluation", "boltzmann_policy", "value_iteration", "q_from_values"]


def _solve_policy_values(mdp, R, policy):
    """Values of deterministic policies: solve (I - gamma P_pi) V = R_pi, batched.

    R (n, S, A), policy (n, S) -> V (n, S).
    """
    S = mdp.n_states
    idx = np.arange(S)
    P_pi = mdp.transitions[idx[None, :], policy]  # (n, S, S)
    R_pi = np.take_along_axis(R, policy[:, :, None], axis=2)[:, :, 0]  # (n, S)
    M = np.eye(S)[None] - mdp.gamma * P_pi
    return np.linalg.solve(M, R_pi[:, :, None])[:, :, 0]


def q_from_values(mdp, R, V):
    """``Q = R + gamma P V`` for batches: R (n, S, A), V (n, S) -> Q (n, S, A)."""
    n, S, A = R.shape
    return R + mdp.gamma * (V @ mdp.transitions_flat.T).reshape(n, S, A)


@blas_limited
def policy_evaluation(mdp, rewards, policy):
    """Exact value of deterministic policies (Bellman equation, paper eq. 1).

    Parameters
    ----------
    mdp : TabularMDP
    rewards : array_like, shape (S, A) or (n, S, A)
    policy : array_like of int, shape (S,) or (n, S)
        Action taken in each state.

    Returns
    -------
    V : ndarray, shape (S,) or (n, S)
        ``V = (I - gamma P_pi)^-1 R_pi``.
    """
    check_mdp(mdp)
    R, single = check_rewards(mdp, rewards)
    pol = check_policy(mdp, policy, R.shape[0])
    if pol is None:
        raise ValidationError("policy must be given (shape (S,) or (n, S))")
    V = _solve_policy_values(mdp, R, pol)
    return V[0] if single else V


@blas_limited
def optimal_q(mdp, rewards, policy=None, max_iter=1000):
    """Exact optimal action values Q* and a greedy policy, by policy iteration.

    Policy iteration (Howard) evaluates each policy exactly, so the result is exact up to
    floating point; warm-started from ``policy`` (e.g. the greedy policy of a nearby reward,
    as in a line search) it usually converges in one or two evaluations. Ties in the greedy
    step keep the current action unless another is better by more than a relative 1e-12,
    so the iteration cannot cycle.

    Parameters
    ----------
    mdp : TabularMDP
    rewards : array_like, shape (S, A) or (n, S, A)
        One reward or a batch of rewards (tasks on the leading axis).
    policy : array_like of int, shape (S,) or (n, S), optional
        Initial deterministic policy (warm start). Default: greedy on the immediate reward.
    max_iter : int, default=1000
        Maximum policy-iteration sweeps (never reached in practice: the number of policies
        is finite and each sweep strictly improves).

    Returns
    -------
    Q : ndarray, shape (S, A) or (n, S, A)
        ``Q*`` (paper eq. 3).
    policy : ndarray of intp, shape (S,) or (n, S)
        A greedy policy on ``Q*``.
    """
    check_mdp(mdp)
    R, single = check_rewards(mdp, rewards)
    pol = check_policy(mdp, policy, R.shape[0])
    Q, pol, _ = _optimal_q(mdp, R, pol, max_iter)
    if single:
        return Q[0], pol[0]
    return Q, pol


def _optimal_q(mdp, R, policy=None, max_iter=1000):
    """Unvalidated batched policy iteration. Returns (Q, policy, V), all batched."""
    n, S, A = R.shape
    pol = np.argmax(R, axis=2) if policy is None else np.array(policy, dtype=np.intp, copy=True)
    Q = np.empty_like(R)
    V = np.empty((n, S))
    active = np.arange(n)
    for _ in range(max_iter):
        Ra, pa = R[active], pol[active]
        Va = _solve_policy_values(mdp, Ra, pa)
        Qa = q_from_values(mdp, Ra, Va)
        best = np.argmax(Qa, axis=2)
        q_cur = np.take_along_axis(Qa, pa[:, :, None], axis=2)[:, :, 0]
        q_best = np.take_along_axis(Qa, best[:, :, None], axis=2)[:, :, 0]
        tol = 1e-12 * np.maximum(1.0, np.abs(Qa).max(axis=(1, 2)))[:, None]
        improve = q_best > q_cur + tol
        Q[active], V[active] = Qa, Va
        changed = improve.any(axis=1)
        new_pol = np.where(improve, best, pa)
        pol[active] = new_pol
        if not changed.any():
            return Q, pol, V
        active = active[changed]
    raise FactIRLError(f"policy iteration did not converge in {max_iter} sweeps")


def boltzmann_policy(Q, beta):
    """Boltzmann (softmax) policy ``pi(a|s) ∝ exp(beta Q(s, a))`` (paper eq. 7).

    Numerically stable: the maximum over actions is subtracted before exponentiating, so no
    overflow occurs for any finite ``beta * Q``.

    Parameters
    ----------
    Q : array_like, shape (..., S, A)
    beta : float
        Inverse temperature, >= 0.

    Returns
    -------
    pi : ndarray, shape (..., S, A)
        Rows sum to 1.
    """
    Q = np.asarray(Q, dtype=np.float64)
    if Q.ndim < 1:
        raise ValidationError(f"Q must have an action axis; got shape {Q.shape}")
    beta = check_beta(beta)
    z = beta * (Q - Q.max(axis=-1, keepdims=True))
    np.exp(z, out=z)
    z /= z.sum(axis=-1, keepdims=True)
    return z


@blas_limited
def value_iteration(mdp, rewards, tol=1e-12, max_iter=100000):
    """Q* by value iteration (paper eq. 3): a slow, simple reference for tests.

    Parameters
    ----------
    mdp : TabularMDP
    rewards : array_like, shape (S, A) or (n, S, A)
    tol : float
        Stop when the sup-norm change of Q is below ``tol``.

    Returns
    -------
    Q : ndarray, shape (S, A) or (n, S, A)
    """
    check_mdp(mdp)
    R, single = check_rewards(mdp, rewards)
    Q = R.copy()
    for _ in range(max_iter):
        Q_new = q_from_values(mdp, R, Q.max(axis=2))
        if np.max(np.abs(Q_new - Q)) < tol:
            Q = Q_new
            break
        Q = Q_new
    return Q[0] if single else Q

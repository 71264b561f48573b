"""The policy-matching loss of eq. (5), its gradient, and the Gauss-Newton Jacobian.

Notation (DESIGN section 3), batched over tasks on the leading axis:

- ``Q = Q*_R`` (n, S, A) and a greedy policy ``pi*`` (n, S); ``pi = softmax(beta Q)``;
- loss per task ``J = sum_s mu(s) sum_a (pi(a|s) - pi_hat(a|s))^2`` (eq. 5);
- ``g = dJ/dQ = beta pi (e - sum_a pi e)`` with ``e = 2 mu (pi - pi_hat)`` (eqs. 7-8, with the
  factor ``beta`` that eq. 8 leaves out);
- ``y = dJ/dR`` by the adjoint: solve ``(I - gamma P_pi^T) z = P^T g`` (one S x S system per
  task) and add ``gamma z[s]`` at the greedy action of each state.

The paper's own route, eq. (9), builds ``phi = dQ*/dtheta`` explicitly (d right-hand sides);
:func:`dq_dtheta` and :func:`policy_matching_grad_reference` keep it as the reference that the
tests and the benchmark compare the adjoint with.
"""

from dataclasses import dataclass

import numpy as np

from ._threads import blas_limited
from ._validation import check_beta, check_mdp, check_policy, check_rewards, check_statistics
from .exceptions import FactIRLError, ValidationError
from .planning import _optimal_q, boltzmann_policy

__all__ = [
    "policy_matching_loss",
    "policy_matching_grad_reference",
    "dq_dtheta",
    "residual_jacobian",
    "PolicyMatchingObjective",
]


def _policy_matrix(mdp, policy):
    """``P_pi[n, s, s'] = P[s, pi(s), s']`` for deterministic policies (n, S)."""
    return mdp.transitions[np.arange(mdp.n_states)[None, :], policy]


def _forward(mdp, R, mu, pi_hat, beta, policy=None):
    """Q*, greedy policy, Boltzmann policy and loss per task (eq. 5)."""
    Q, pol, _ = _optimal_q(mdp, R, policy)
    pi = boltzmann_policy(Q, beta)
    diff = pi - pi_hat
    loss = np.einsum("ns,nsa->n", mu, diff * diff)
    return pol, pi, diff, loss


def _dj_dq(pi, diff, mu, beta):
    """``g = dJ/dQ`` (n, S, A) through the Boltzmann policy (eqs. 7-8)."""
    e = 2.0 * mu[:, :, None] * diff
    return beta * pi * (e - np.sum(pi * e, axis=2, keepdims=True))


def _adjoint(mdp, policy, g):
    """``y = dJ/dR`` from ``g = dJ/dQ`` with one S x S solve per task (DESIGN section 3)."""
    n, S, A = g.shape
    Ptg = g.reshape(n, S * A) @ mdp.transitions_flat  # (n, S): sum_{s,a} P[s,a,s'] g[s,a]
    M = np.eye(S)[None] - mdp.gamma * _policy_matrix(mdp, policy)
    z = np.linalg.solve(np.swapaxes(M, 1, 2), Ptg[:, :, None])[:, :, 0]
    y = g.copy()
    y[np.arange(n)[:, None], np.arange(S)[None, :], policy] += mdp.gamma * z
    return y


@blas_limited
def policy_matching_loss(mdp, rewards, mu_hat, pi_hat, beta=5.0, policy=None):
    """Policy-matching loss (eq. 5) per task and its gradient dJ/dR by the adjoint method.

    Parameters
    ----------
    mdp : TabularMDP
    rewards : array_like, shape (S, A) or (n, S, A)
        Rewards ``R[i, s, a]`` (a tabular ``theta`` reshaped).
    mu_hat : array_like, shape (S,) or (n, S)
        Empirical state frequencies (see :func:`empirical_statistics`).
    pi_hat : array_like, shape (S, A) or (n, S, A)
        Empirical policies.
    beta : float, default=5.0
        Boltzmann inverse temperature (eq. 7).
    policy : array_like of int, shape (n, S), optional
        Warm start for the policy iteration computing Q*.

    Returns
    -------
    loss : ndarray, shape (n,)
        ``J_i`` (eq. 5) for each task.
    grad : ndarray, shape (n, S, A)
        ``dJ_i / dR_i`` (eqs. 8-9, computed by the adjoint route of DESIGN section 3).
    """
    check_mdp(mdp)
    R, _ = check_rewards(mdp, rewards)
    mu, pi_hat = check_statistics(mdp, mu_hat, pi_hat, n=R.shape[0])
    beta = check_beta(beta)
    pol = check_policy(mdp, policy, R.shape[0])
    pol, pi, diff, loss = _forward(mdp, R, mu, pi_hat, beta, pol)
    return loss, _adjoint(mdp, pol, _dj_dq(pi, diff, mu, beta))


def dq_dtheta(mdp, policy, features=None, route="direct", tol=1e-13, max_iter=100000):
    """``phi = dQ*/dtheta`` of one task, the fixed point of eq. (9).

    ``phi(x, a) = dR(x, a)/dtheta + gamma sum_y P(y|x, a) phi(y, pi*(y))`` for the greedy
    policy ``pi*``. This builds the whole (S*A, p) matrix: the reference route.

    Parameters
    ----------
    mdp : TabularMDP
    policy : array_like of int, shape (S,)
        Greedy policy on Q*.
    features : array_like, shape (S*A, p), optional
        ``dR/dtheta`` for rewards ``R = F w``; default the identity (tabular, p = S*A).
    route : {"direct", "fixed_point"}
        ``"fixed_point"`` iterates eq. (9) like dynamic programming, as the paper describes;
        ``"direct"`` solves ``(I - gamma P_pi) Phi_V = F[greedy rows]`` with p right-hand sides
        (forward mode).
    tol : float
        Sup-norm stopping tolerance of the fixed-point iteration.

    Returns
    -------
    phi : ndarray, shape (S*A, p)
    """
    check_mdp(mdp)
    S, A = mdp.n_states, mdp.n_actions
    pol = check_policy(mdp, policy, 1)[0]
    F = np.eye(S * A) if features is None else np.asarray(features, dtype=np.float64)
    if F.ndim != 2 or F.shape[0] != S * A:
        raise ValidationError(f"features must have shape (S*A, p) = ({S * A}, p); got {F.shape}")
    greedy_rows = np.arange(S) * A + pol
    P2 = mdp.transitions_flat
    if route == "direct":
        M = np.eye(S) - mdp.gamma * mdp.transitions[np.arange(S), pol]
        return F + mdp.gamma * (P2 @ np.linalg.solve(M, F[greedy_rows]))
    if route == "fixed_point":
        phi = F.copy()
        for _ in range(max_iter):
            new = F + mdp.gamma * (P2 @ phi[greedy_rows])
            delta = np.max(np.abs(new - phi))
            phi = new
            if delta < tol:
                return phi
        raise FactIRLError(f"eq. (9) fixed-point iteration did not converge in {max_iter} sweeps")
    raise ValidationError(f"route must be 'direct' or 'fixed_point'; got {route!r}")


@blas_limited
def policy_matching_grad_reference(mdp, rewards, mu_hat, pi_hat, beta=5.0, features=None, route="fixed_point"):
    """Gradient of eq. (5) through the explicit ``dQ*/dtheta`` of eq. (9) (reference route).

    Computes ``phi`` for each task with :func:`dq_dtheta`, then
    ``dJ/dtheta = sum_{s,a} g(s, a) phi(s, a, :)`` with ``g = dJ/dQ``. Slow by design:
    it is what the adjoint route (:func:`policy_matching_loss`) is checked against.

    Parameters
    ----------
    rewards : array_like, shape (S, A) or (n, S, A)
        The rewards at which to differentiate (for features, ``R = F w`` already formed).
    features : array_like, shape (S*A, p), optional
        Differentiate with respect to feature weights ``w``; default tabular ``theta``.
    route : {"fixed_point", "direct"}

    Returns
    -------
    loss : ndarray, shape (n,)
    grad : ndarray, shape (n, p)
        ``p = S*A`` for tabular rewards.
    """
    check_mdp(mdp)
    R, _ = check_rewards(mdp, rewards)
    mu, pi_hat = check_statistics(mdp, mu_hat, pi_hat, n=R.shape[0])
    beta = check_beta(beta)
    pol, pi, diff, loss = _forward(mdp, R, mu, pi_hat, beta)
    g = _dj_dq(pi, diff, mu, beta).reshape(R.shape[0], -1)
    grads = [g[i] @ dq_dtheta(mdp, pol[i], features, route=route) for i in range(R.shape[0])]
    return loss, np.array(grads)


def _jacobian(mdp, policy, pi, mu, beta, features):
    """Gauss-Newton Jacobian ``d r / d w`` (n, S*A, k) for ``R = F w`` (forward mode, k RHS)."""
    n, S, A = pi.shape
    k = features.shape[1]
    greedy = np.arange(S)[None, :] * A + policy  # (n, S)
    M = np.eye(S)[None] - mdp.gamma * _policy_matrix(mdp, policy)
    phi_v = np.linalg.solve(M, features[greedy])  # (n, S, k)
    phi = features[None] + mdp.gamma * (mdp.transitions_flat @ phi_v)  # (n, S*A, k)
    phi = phi.reshape(n, S, A, k)
    dpi = beta * pi[..., None] * (phi - np.sum(pi[..., None] * phi, axis=2, keepdims=True))
    return (np.sqrt(mu)[:, :, None, None] * dpi).reshape(n, S * A, k)


@blas_limited
def residual_jacobian(mdp, rewards, mu_hat, pi_hat, beta, features, policy=None):
    """Residuals of eq. (5) and their Jacobian for rewards linear in parameters.

    With ``r_i = sqrt(mu_i) (pi_i - pi_hat_i)`` flattened, ``J_i = ||r_i||^2``. For
    ``R_i = F w_i`` the Jacobian ``dr_i/dw_i = sqrt(mu_i) dpi_i/dw`` comes from forward mode
    with p right-hand sides: ``Phi_V = (I - gamma P_pi)^-1 F[greedy rows]``,
    ``dQ*/dw = F + gamma P Phi_V``, ``dpi/dw = beta pi (dQ/dw - sum_a pi dQ/dw)``
    (DESIGN section 3, Gauss-Newton H-step).

    Parameters
    ----------
    rewards : array_like, shape (n, S, A)
        Current rewards ``F w_i`` reshaped.
    features : array_like, shape (S*A, p)
        ``F`` (the dictionary D in FactIRL's H-step).

    Returns
    -------
    loss : ndarray, shape (n,)
    residual : ndarray, shape (n, S*A)
    jacobian : ndarray, shape (n, S*A, p)
    """
    check_mdp(mdp)
    R, _ = check_rewards(mdp, rewards)
    mu, pi_hat = check_statistics(mdp, mu_hat, pi_hat, n=R.shape[0])
    beta = check_beta(beta)
    F = np.asarray(features, dtype=np.float64)
    if F.ndim != 2 or F.shape[0] != mdp.n_params:
        raise ValidationError(f"features must have shape (S*A, p) = ({mdp.n_params}, p); got {F.shape}")
    pol = check_policy(mdp, policy, R.shape[0])
    pol, pi, diff, loss = _forward(mdp, R, mu, pi_hat, beta, pol)
    r = (np.sqrt(mu)[:, :, None] * diff).reshape(R.shape[0], -1)
    return loss, r, _jacobian(mdp, pol, pi, mu, beta, F)


@dataclass
class Evaluation:
    """One batched evaluation of eq. (5) (internal to the learners)."""

    loss: np.ndarray  # (r,)
    grad: np.ndarray | None = None  # dJ/dR, (r, S, A)
    residual: np.ndarray | None = None  # (r, S*A)
    jacobian: np.ndarray | None = None  # (r, S*A, p)


class PolicyMatchingObjective:
    """Eq. (5) over a fixed set of tasks, with warm-started planning and an evaluation count.

    The learners build this once per ``fit``; the step solvers never see it directly, only the
    callables of a :class:`solvers.StepProblem` built on top of it.

    Parameters
    ----------
    mdp : TabularMDP
    mu_hat : ndarray, shape (n, S)
    pi_hat : ndarray, shape (n, S, A)
    beta : float

    Attributes
    ----------
    n_evaluations : int
        Number of batched Q* evaluations so far (each solves the planning problem of every
        task it is asked about at once; a repeated call at the same rewards is served from a
        cache and not counted).
    policy : ndarray of intp, shape (n, S)
        Last greedy policy of each task, used to warm-start the next policy iteration.
    """

    def __init__(self, mdp, mu_hat, pi_hat, beta):
        self.mdp = check_mdp(mdp)
        self.mu, self.pi_hat = check_statistics(mdp, mu_hat, pi_hat)
        self.beta = check_beta(beta)
        self.n_tasks = self.mu.shape[0]
        self.n_evaluations = 0
        self.policy = np.zeros((self.n_tasks, mdp.n_states), dtype=np.intp)
        self._warm = False
        # per-task cache of the last loss and dJ/dR, keyed on the exact rewards
        self._last_R = np.full((self.n_tasks, mdp.n_states, mdp.n_actions), np.nan)
        self._last_loss = np.zeros(self.n_tasks)
        self._last_grad = np.zeros((self.n_tasks, mdp.n_states, mdp.n_actions))

    def evaluate(self, rewards, rows=None, grad=True, features=None):
        """Loss (and dJ/dR, or residuals and Jacobian w.r.t. weights of ``features``).

        Parameters
        ----------
        rewards : ndarray, shape (r, S, A)
            Rewards of the tasks ``rows``.
        rows : ndarray of int, shape (r,), optional
            Which tasks (default all).
        grad : bool, default=True
            With ``features``: also compute ``dJ/dR`` (adjoint). Without ``features`` the
            gradient is always computed (one extra S x S solve per task) and cached, since
            every caller of a loss-only evaluation goes on to need it.
        features : ndarray, shape (S*A, p), optional
            Also compute the Gauss-Newton residuals and Jacobian for ``R = F w``.

        Returns
        -------
        Evaluation
            When every requested task was last evaluated (with its gradient) at exactly
            these rewards, loss and gradient are served from a per-task cache and no Q*
            evaluation is counted.
        """
        rows = np.arange(self.n_tasks) if rows is None else np.asarray(rows)
        rewards = np.asarray(rewards, dtype=np.float64)
        if features is None and np.array_equal(self._last_R[rows], rewards):
            return Evaluation(loss=self._last_loss[rows].copy(), grad=self._last_grad[rows].copy())
        mu, pi_hat = self.mu[rows], self.pi_hat[rows]
        warm = self.policy[rows] if self._warm else None
        pol, pi, diff, loss = _forward(self.mdp, rewards, mu, pi_hat, self.beta, warm)
        self.n_evaluations += 1
        self._warm = True
        self.policy[rows] = pol
        out = Evaluation(loss=loss)
        if grad or features is None:
            out.grad = _adjoint(self.mdp, pol, _dj_dq(pi, diff, mu, self.beta))
            self._last_R[rows] = rewards
            self._last_loss[rows] = loss
            self._last_grad[rows] = out.grad
        if features is not None:
            out.residual = (np.sqrt(mu)[:, :, None] * diff).reshape(len(rows), -1)
            out.jacobian = _jacobian(self.mdp, pol, pi, mu, self.beta, features)
        return out

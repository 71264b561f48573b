"""The maximum causal entropy likelihood: soft values, the loss and its adjoint gradient.

Infinite-horizon, discounted maximum causal entropy IRL (Ziebart et al. 2008, 2010), fitted by
maximum likelihood of the demonstrated pairs (MLIRL, Babes-Vroman et al. 2011; docs/maths.md
§6). Batched over tasks on the leading axis, rewards ``R`` (n, S, A):

- soft Bellman equation ``Q = R + gamma P V``, ``V(s) = (1/beta) log sum_a exp(beta Q(s, a))``
  (the fixed point ``V = T V`` of the soft Bellman operator ``T``), soft-optimal policy
  ``pi(a|s) = exp(beta (Q(s, a) - V(s)))``; ``log pi`` is computed as ``beta (Q - V)`` with the
  maximum over actions subtracted first (log-sum-exp), never as ``log(exp(.))``;
- loss per task, the mean negative log-likelihood of the demonstrated (state, action) pairs,
  ``J = -sum_{s,a} c(s, a) log pi(a|s)`` with pair frequencies ``c(s, a) = mu_hat(s) pi_hat(a|s)``.

Soft values by Newton's method (soft policy iteration). ``T`` is differentiable with
``dT/dV = gamma P_pi``, where ``P_pi[s, s'] = sum_a pi(a|s) P(s'|s, a)`` and ``pi`` is the
soft-greedy policy of ``V`` (the gradient of log-sum-exp is the softmax). The Newton step on
``F(V) = V - T V = 0`` is ``(I - gamma P_pi)(V_new - V) = T V - V``. Since
``T V = sum_a pi (Q - (1/beta) log pi)`` (average ``Q - (1/beta) log pi = T V`` over ``pi``),
``T V - gamma P_pi V = sum_a pi (R - (1/beta) log pi)``, and the step reads

    (I - gamma P_pi) V_new = sum_a pi(a|s) (R(s, a) - (1/beta) log pi(a|s)),

i.e. ``V_new`` is the soft value (reward plus entropy bonus) of the policy ``pi``: one solve
with the stochastic policy's system per step (:meth:`factirl_opt.planning.Planner.system`).
The soft value of any policy is a sub-solution (``T V >= V``) below ``V*``, and from a
sub-solution the iterates rise monotonically to ``V*`` with the error contracting at least by
``gamma`` per step (quadratically near the solution): from a cold or warm start, 2-12 steps on
the 10x10 grid at gamma 0.9 and 0.99, beta up to 1e3, rewards up to 1e3. The residual
``||T V - V||`` is *not* monotone along these iterates (guarding on its decrease, measured,
replaced up to 4800 Newton steps by value-iteration sweeps and took 20x more iterations at
gamma 0.99), so the guard checks what Newton guarantees instead: the new iterate must be
finite, a sub-solution (``T V_new >= V_new - eps``), and, when the current iterate is one,
not below it (``V_new >= V - eps``), with ``eps = 1e-9 max(1, ||V||_inf)``. A task whose step
fails these (a failed solve) takes the value-iteration sweep ``V <- T V`` instead, which keeps
a sub-solution one and contracts the error by ``gamma``. Stop when
``||T V - V||_inf <= 1e-12 max(1, ||V||_inf)`` per task; warm-started from the last values.

Gradient by one adjoint solve per task. With ``g = dlogL/dQ = beta (c - c(s) pi)``
(``c(s) = sum_a c(s, a)``) and ``dV(s) = sum_a pi(a|s) dQ(s, a)`` on the soft Bellman equation,
``dQ = (I - gamma P Pi)^-1 dR``, so ``dlogL/dR = g + gamma pi(a|s) z(s)`` with
``(I - gamma P_pi^T) z = P^T g`` (:func:`factirl_opt.planning.adjoint` with the stochastic
policy); ``dJ/dR = -(that)``.

Potential shaping ``R + gamma P phi - phi`` shifts ``Q`` and ``V`` by ``-phi(s)`` and leaves
``pi``, hence the loss, unchanged. The objective is not a least-squares one: the Gauss-Newton
step solvers do not apply, gradient solvers (``armijo``, ``armijo-nonneg``, ``lbfgs``) do.
"""

import numpy as np
from scipy.special import entr

from .._threads import blas_limited
from .._validation import check_beta, check_int, check_mdp, check_rewards, check_statistics, check_stochastic_policy
from ..exceptions import FactIRLError
from ..planning import adjoint, get_planner
from ._base import Objective

__all__ = ["MCEObjective", "mce_loss", "soft_values"]

#: relative tolerance of the soft values: ``||T V - V||_inf <= SOFT_TOL * max(1, ||V||_inf)``
SOFT_TOL = 1e-12
#: Newton (or guard) iterations allowed before :class:`FactIRLError`
SOFT_MAX_ITER = 1000
#: relative slack of the Newton guard's inequalities (far above rounding, far below a failed solve)
GUARD_SLACK = 1e-9


def soft_backup(planner, R, V, beta):
    """One application of the soft Bellman operator, and the soft-greedy policy's logarithm.

    Parameters
    ----------
    planner : Planner
    R : ndarray, shape (n, S, A)
    V : ndarray, shape (n, S)
    beta : float

    Returns
    -------
    Q : ndarray, shape (n, S, A)
        ``R + gamma P V``.
    TV : ndarray, shape (n, S)
        ``(1/beta) log sum_a exp(beta Q)``, with the maximum over actions subtracted first.
    log_pi : ndarray, shape (n, S, A)
        ``beta (Q - TV)``, computed as ``beta (Q - max Q) - log sum_a exp(beta (Q - max Q))``.
    """
    Q = planner.q_from_values(R, V)
    m = Q.max(axis=2, keepdims=True)
    z = beta * (Q - m)
    lse = np.log(np.exp(z).sum(axis=2, keepdims=True))  # in [0, log A]: the max term is exp(0)
    return Q, (m + lse / beta)[:, :, 0], z - lse


def _scale(V):
    return np.maximum(1.0, np.abs(V).max(axis=1))


def _newton_step(planner, R, V, TV, log_pi, beta):
    """One guarded Newton step for a batch of tasks: new V and its backup (Q, TV, log_pi).

    Newton's iterate is accepted where it is finite, a sub-solution, and not below a current
    sub-solution (module docstring); elsewhere the sweep ``V <- T V`` is taken.
    """
    pi = np.exp(log_pi)
    V_new = planner.system(pi).solve(np.sum(pi * (R - log_pi / beta), axis=2))
    Q, TV_new, lp = soft_backup(planner, R, V_new, beta)
    eps = (GUARD_SLACK * _scale(V))[:, None]
    sub = np.all(TV >= V - eps, axis=1)
    ok = np.all(np.isfinite(TV_new), axis=1) & np.all(TV_new >= V_new - eps, axis=1)
    ok &= ~sub | np.all(V_new >= V - eps, axis=1)
    if not ok.all():
        bad = ~ok
        V_new[bad] = TV[bad]
        Q[bad], TV_new[bad], lp[bad] = soft_backup(planner, R[bad], V_new[bad], beta)
    return V_new, Q, TV_new, lp


def soft_values(planner, R, beta, V0=None, tol=SOFT_TOL, max_iter=SOFT_MAX_ITER):
    """Soft values of every task by guarded Newton iteration (soft policy iteration).

    Unvalidated kernel (see the module docstring for the step and the guard).

    Parameters
    ----------
    planner : Planner
    R : ndarray, shape (n, S, A)
    beta : float
    V0 : ndarray, shape (n, S), optional
        Warm start (e.g. the values of a nearby reward); default zeros.
    tol : float
        Relative sup-norm tolerance on the soft Bellman residual.
    max_iter : int
        Iterations allowed; a task not converged by then raises :class:`FactIRLError`.

    Returns
    -------
    Q : ndarray, shape (n, S, A)
        ``R + gamma P V`` at the last iterate ``V``.
    V : ndarray, shape (n, S)
        ``T V`` (one more soft backup of the last iterate).
    log_pi : ndarray, shape (n, S, A)
        ``beta (Q - V)``: the soft-optimal policy's logarithm, exactly normalised against ``Q``.
    """
    n, S, _ = R.shape
    V = np.zeros((n, S)) if V0 is None else np.array(V0, dtype=np.float64)
    Q, TV, log_pi = soft_backup(planner, R, V, beta)
    res = np.abs(TV - V).max(axis=1)
    active = np.flatnonzero(~(res <= tol * _scale(V)))
    for _ in range(max_iter):
        if active.size == 0:
            break
        a = active
        V[a], Q[a], TV[a], log_pi[a] = _newton_step(planner, R[a], V[a], TV[a], log_pi[a], beta)
        res[a] = np.abs(TV[a] - V[a]).max(axis=1)
        active = a[~(res[a] <= tol * _scale(V[a]))]  # a NaN residual stays active
    if active.size:
        i = int(active[np.argmax(res[active])])
        raise FactIRLError(
            f"the soft Bellman equation did not converge in {max_iter} iterations: task {i} has residual "
            f"{res[i]:.3g} (tolerance {tol:g} x max(1, |V|)); beta * rewards may be too large to represent"
        )
    if not (np.all(np.isfinite(TV)) and np.all(np.isfinite(log_pi))):
        raise FactIRLError("the soft values are not finite: beta * rewards overflow float64; rescale the rewards")
    return Q, TV, log_pi


class _Point:
    """Forward pass of the MCE likelihood at some rewards (internal)."""

    def __init__(self, Q, V, log_pi, counts, beta):
        self.Q, self.V, self.log_pi, self.counts, self.beta = Q, V, log_pi, counts, beta
        self.pi = np.exp(log_pi)
        self.loss = -np.einsum("nsa,nsa->n", counts, log_pi)


def _forward(planner, R, mu, pi_hat, beta, V0=None, max_iter=SOFT_MAX_ITER):
    Q, V, log_pi = soft_values(planner, R, beta, V0, max_iter=max_iter)
    return _Point(Q, V, log_pi, mu[:, :, None] * pi_hat, beta)


def _gradient(planner, point):
    """``dJ/dR`` (n, S, A): one transposed solve per task with the soft-optimal policy's system."""
    pi, c = point.pi, point.counts
    g = point.beta * (c - c.sum(axis=2, keepdims=True) * pi)  # dlogL/dQ
    return -adjoint(planner, planner.system(pi), pi, g)


def soft_policy_values(planner, R, policy, beta):
    """Soft value of fixed stochastic policies: ``(I - gamma P_pi) V = sum_a pi R + H(pi) / beta``.

    ``H(pi)(s) = -sum_a pi log pi`` (``0 log 0 = 0``). Used to warm-start from a policy.
    """
    return planner.system(policy).solve(np.sum(policy * R, axis=2) + entr(policy).sum(axis=2) / beta)


class MCEObjective(Objective):
    """The MCE negative log-likelihood over a fixed set of tasks (see :class:`Objective`).

    Not least squares: use it with gradient step solvers (``armijo``, ``armijo-nonneg``, ``lbfgs``).
    Warm start: each task's last soft values start its next Newton iteration.
    """

    name = "mce"
    least_squares = False

    @classmethod
    def log_policy(cls, planner, rewards, beta):
        """The soft-optimal policy ``beta (Q - V)`` of the soft Bellman equation (docs/maths.md §6), (n, S, A)."""
        return soft_values(planner, rewards, beta)[2]

    def _forward(self, R, rows, warm):
        return _forward(self.planner, R, self.mu[rows], self.pi_hat[rows], self.beta, warm)

    def _warm_start(self, point):
        return point.V

    def _grad(self, point):
        return _gradient(self.planner, point)


@blas_limited
def mce_loss(mdp, rewards, mu_hat, pi_hat, beta, policy=None, planner="auto", max_iter=SOFT_MAX_ITER):
    """Maximum causal entropy negative log-likelihood per task and its gradient dJ/dR.

    Parameters
    ----------
    mdp : TabularMDP
    rewards : array_like, shape (S, A) or (n, S, A)
        Rewards ``R[i, s, a]``.
    mu_hat : array_like, shape (S,) or (n, S)
        Empirical state frequencies (see :func:`empirical_statistics`).
    pi_hat : array_like, shape (S, A) or (n, S, A)
        Empirical policies; the demonstrated pair frequencies are ``mu_hat(s) pi_hat(a|s)``.
    beta : float
        Inverse temperature of the soft Bellman equation (> 0).
    policy : array_like of float, shape (S, A) or (n, S, A), optional
        Warm start: a stochastic policy ``pi(a|s)`` (rows summing to 1), e.g. the soft-optimal
        policy of a nearby reward; the Newton iteration starts from its soft value. Default:
        start from ``V = 0``. The result does not depend on it (beyond 1e-12).
    planner : str, default="auto"
        See :func:`factirl_opt.available_planners`.
    max_iter : int
        Newton iterations allowed (each one solve per task); :class:`FactIRLError` beyond.

    Returns
    -------
    loss : ndarray, shape (n,)
        ``J_i = -sum_s mu_hat(s) sum_a pi_hat(a|s) log pi_i(a|s)``, ``pi_i`` soft-optimal for
        ``R_i``.
    grad : ndarray, shape (n, S, A)
        ``dJ_i / dR_i`` by the adjoint route (module docstring; docs/maths.md §6).
    """
    check_mdp(mdp)
    R, _ = check_rewards(mdp, rewards)
    mu, pi_hat = check_statistics(mdp, mu_hat, pi_hat, n=R.shape[0])
    beta = check_beta(beta)
    max_iter = check_int(max_iter, "max_iter", minimum=1)
    pl = get_planner(mdp, planner)
    V0 = None if policy is None else soft_policy_values(pl, R, check_stochastic_policy(mdp, policy, R.shape[0]), beta)
    point = _forward(pl, R, mu, pi_hat, beta, V0, max_iter)
    return point.loss, _gradient(pl, point)

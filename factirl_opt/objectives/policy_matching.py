"""The policy-matching loss of eq. (5), its gradient, and its Gauss-Newton derivatives.

Notation (docs/maths.md §3 and §5), batched over tasks on the leading axis:

- ``Q = Q*_R`` (n, S, A) and a greedy policy ``pi*`` (n, S); ``pi = softmax(beta Q)``;
- loss per task ``J = sum_s mu(s) sum_a (pi(a|s) - pi_hat(a|s))^2`` (eq. 5), i.e.
  ``J = ||r||^2`` with residuals ``r = sqrt(mu) (pi - pi_hat)`` flattened to (S*A,);
- ``g = dJ/dQ = beta pi (e - sum_a pi e)`` with ``e = 2 mu (pi - pi_hat)`` (eqs. 7-8, with the
  factor ``beta`` that eq. 8 leaves out);
- ``y = dJ/dR`` by the adjoint (:func:`factirl_opt.planning.adjoint`): one transposed
  S x S solve per task.

The paper's own route, eq. (9), builds ``phi = dQ*/dtheta`` explicitly (d right-hand sides);
:func:`dq_dtheta` and :func:`policy_matching_grad_reference` keep it as the dense reference
that the tests and the benchmark compare the adjoint with.
"""

import contextlib
import contextvars

import numpy as np
from scipy.special import log_softmax

from .._threads import blas_limited
from .._validation import check_beta, check_features, check_mdp, check_policy, check_rewards, check_statistics
from ..exceptions import FactIRLError, ValidationError
from ..planning import adjoint, boltzmann_policy, get_planner, plan, tangent
from solvers import Linearization

from ..tasks.task_set import parameter_matrix, reward_dimension
from ._base import Objective

__all__ = [
    "PolicyMatchingObjective",
    "policy_matching_loss",
    "policy_matching_grad_reference",
    "residual_jacobian",
    "dq_dtheta",
    "jacobian_mode",
    "JACOBIAN_MODES",
]

#: largest S*A for which the dense eq. (9) reference routes build their (S*A, d) matrices
REFERENCE_MAX_PARAMS = 5_000


def softmax_vjp(pi, E, beta):
    """``(dpi/dQ)^T E`` of the Boltzmann policy, per state: ``beta pi (E - sum_a pi E)``.

    The softmax Jacobian is symmetric, so this is also the forward product ``(dpi/dQ) dQ``
    with ``E = dQ``. ``E`` is (n, S, A) or (n, S, A, k).
    """
    if E.ndim == pi.ndim + 1:
        pi = pi[..., None]
    return beta * pi * (E - np.sum(pi * E, axis=2, keepdims=True))


class _Point:
    """Forward pass of eq. (5) at some rewards (internal)."""

    def __init__(self, plan_result, pi, diff, mu, beta):
        self.plan, self.pi, self.diff, self.mu, self.beta = plan_result, pi, diff, mu, beta
        self.loss = np.einsum("ns,nsa->n", mu, diff * diff)


def forward_point(planner, R, mu, pi_hat, beta, policy=None):
    """Exact Q*, Boltzmann policy and eq. (5) loss at rewards R (n, S, A): a point to differentiate at."""
    res = plan(planner, R, policy)
    pi = boltzmann_policy(res.Q, beta)
    return _Point(res, pi, pi - pi_hat, mu, beta)


def gradient_at(planner, point):
    """``dJ/dR`` (n, S, A) at a :func:`forward_point`, by the adjoint route."""
    g = softmax_vjp(point.pi, 2.0 * point.mu[:, :, None] * point.diff, point.beta)
    return adjoint(planner, point.plan.system, point.plan.policy, g)


def _residual(point):
    return (np.sqrt(point.mu)[:, :, None] * point.diff).reshape(point.diff.shape[0], -1)


def _jvp(planner, point, dR):
    """``dr = sqrt(mu) dpi/dQ dQ`` along dR (n, S, A) or k directions (n, S, A, k); rows flattened."""
    dQ = tangent(planner, point.plan.system, point.plan.policy, dR)
    sq = np.sqrt(point.mu)[:, :, None]
    dr = (sq[..., None] if dQ.ndim == 4 else sq) * softmax_vjp(point.pi, dQ, point.beta)
    n, S, A = point.pi.shape
    return dr.reshape(n, S * A, *dQ.shape[3:])


def _vjp(planner, point, U):
    """``J^T U`` (n, S, A) for U (n, S*A): the adjoint route with ``e = sqrt(mu) U``."""
    n, S, A = point.pi.shape
    e = np.sqrt(point.mu)[:, :, None] * U.reshape(n, S, A)
    return adjoint(planner, point.plan.system, point.plan.policy, softmax_vjp(point.pi, e, point.beta))


#: how :func:`residual_jacobian` and the objective build the Jacobian: ``"forward"`` (p tangent
#: right-hand sides), ``"reverse"`` (one adjoint right-hand side per residual row of a visited
#: state) or ``"auto"`` (reverse where a task batch has fewer such rows than p)
JACOBIAN_MODES = ("auto", "forward", "reverse")


_MODE = contextvars.ContextVar("factirl_opt_jacobian_mode", default="auto")


def _check_jacobian_mode(mode):
    if not (isinstance(mode, str) and mode in JACOBIAN_MODES):
        raise ValidationError(f"jacobian mode must be one of {', '.join(map(repr, JACOBIAN_MODES))}; got {mode!r}")
    return mode


@contextlib.contextmanager
def jacobian_mode(mode):
    """Context manager: policy-matching objectives evaluated inside the block (in this thread or
    asyncio task) build the Jacobian of their residuals in ``mode`` (:data:`JACOBIAN_MODES`).

    The Jacobian is the same to round-off in every mode; only its cost differs. Outside any
    block the mode is ``"auto"``; an objective whose own ``jacobian_mode`` is set keeps it.
    Example: ``with jacobian_mode("forward"): model.transfer(mdp, demos)``.

    Raises
    ------
    ValidationError
        For a mode not in :data:`JACOBIAN_MODES`.
    """
    token = _MODE.set(_check_jacobian_mode(mode))
    try:
        yield mode
    finally:
        _MODE.reset(token)


def _visited(point):
    """Each task's visited states first (n, c) and which of them are visited (n, c): c is the
    largest number of visited states of a task (at least 1), the other tasks padded with unvisited ones."""
    live = point.mu > 0
    c = max(int(live.sum(axis=1).max(initial=0)), 1)
    states = np.argsort(~live, axis=1, kind="stable")[:, :c]
    return states, np.take_along_axis(live, states, axis=1)


def _features_jacobian(planner, point, F, mode="auto"):
    """Gauss-Newton Jacobian ``dr/dw`` (n, S*A, p) for ``R = F w``.

    Only the rows of visited states (``mu > 0``) are nonzero. Forward mode solves with p
    right-hand sides per task (:func:`_jvp`); reverse mode with one per row of a visited state
    (:func:`_reverse_features_jacobian`); ``"auto"`` takes reverse where those rows are fewer than p.
    """
    n, S, A = point.pi.shape
    p = F.shape[1]
    if mode == "auto":
        mode = "reverse" if _visited(point)[0].shape[1] * A < p else "forward"
    if mode == "reverse":
        return _reverse_features_jacobian(planner, point, F)
    dR = np.broadcast_to(F.reshape(1, S, A, -1), (n, S, A, p))
    return _jvp(planner, point, dR)


def _reverse_features_jacobian(planner, point, F):
    """:func:`_features_jacobian` in reverse mode: ``q = c A`` adjoint right-hand sides per task.

    The rows of ``dQ/dw`` at a visited state's actions, ``e_j^T (I + gamma P M^-1 W_pi) F``
    (``M = I - gamma P_pi``, ``W_pi`` the policy's weights), are ``F_j + gamma z_j^T F_pi`` with
    ``M^T z_j = P^T e_j``: one transposed solve with q right-hand sides (the adjoint route of
    :func:`~factirl_opt.planning.adjoint` on the unit residual directions of those rows),
    then the softmax's Jacobian within each visited state and ``sqrt(mu)``, as in forward mode.
    """
    n, S, A = point.pi.shape
    p = F.shape[1]
    F3 = F.reshape(S, A, p)
    states, live = _visited(point)  # (n, c)
    c = states.shape[1]
    q = c * A
    unit = np.zeros((n, c, A, S, A))  # e_j for every row j = (state, action) of the visited states
    ii, jj, aa = np.meshgrid(np.arange(n), np.arange(c), np.arange(A), indexing="ij")
    unit[ii, jj, aa, states[:, :, None], aa] = 1.0
    PtE = planner.pullback(unit.reshape(n * q, S, A)).reshape(n, q, S)  # rows j of P
    z = point.plan.system.solve_transpose(np.ascontiguousarray(np.swapaxes(PtE, 1, 2)))  # (n, S, q)
    policy = point.plan.policy
    if policy.ndim == 2:
        F_pi = F3[np.arange(S)[None, :], policy]  # (n, S, p)
    else:
        F_pi = np.einsum("nsa,sap->nsp", policy, F3)
    dQ = F3[states] + planner.gamma * np.matmul(np.swapaxes(z, 1, 2), F_pi).reshape(n, c, A, p)  # (n, c, A, p)
    pi = np.take_along_axis(point.pi, states[:, :, None], axis=1)  # (n, c, A)
    sq = np.sqrt(np.take_along_axis(point.mu, states, axis=1) * live)
    rows = sq[:, :, None, None] * softmax_vjp(pi, dQ, point.beta)
    J = np.zeros((n, S, A, p))
    J[np.arange(n)[:, None], states] = rows
    return J.reshape(n, S * A, p)


class PolicyMatchingObjective(Objective):
    """Eq. (5) over a fixed set of tasks, with warm-started policy iteration (see :class:`Objective`).

    Warm start: each task's last greedy policy starts its next policy iteration.
    """

    name = "policy-matching"
    least_squares = True
    #: how the Jacobian of the residuals is built (:data:`JACOBIAN_MODES`; the same Jacobian to
    #: round-off): ``"auto"`` takes reverse mode where a batch of tasks has fewer residual rows
    #: at visited states than reward parameters (one demonstration of a transfer), else forward;
    #: None (default): the mode of the innermost :func:`jacobian_mode` block, else ``"auto"``
    jacobian_mode = None

    @classmethod
    def log_policy(cls, planner, rewards, beta):
        """``log pi = beta Q* - log sum_a exp(beta Q*)``, the Boltzmann policy of the optimal ``Q*`` (eq. 7), (n, S, A)."""
        return cls.log_policy_and_values(planner, rewards, beta)[0]

    @classmethod
    def log_policy_and_values(cls, planner, rewards, beta):
        """:meth:`log_policy` and ``V*`` (n, S) from one plan of the rewards."""
        optimal = plan(planner, rewards)
        return log_softmax(beta * optimal.Q, axis=2), optimal.V

    def _forward(self, R, rows, warm):
        return forward_point(self.planner, R, self.mu[rows], self.pi_hat[rows], self.beta, warm)

    def _warm_start(self, point):
        return point.plan.policy

    def _grad(self, point):
        return gradient_at(self.planner, point)

    def _linearize(self, point):
        return Linearization(point.loss, _residual(point), lambda dR: _jvp(self.planner, point, dR),
                             lambda U: _vjp(self.planner, point, U))

    def _jacobian(self, point, features):
        return _features_jacobian(self.planner, point, features, self.jacobian_mode or _MODE.get())


def _validated(mdp, rewards, mu_hat, pi_hat, beta):
    check_mdp(mdp)
    R, _ = check_rewards(mdp, rewards)
    mu, pi_hat = check_statistics(mdp, mu_hat, pi_hat, n=R.shape[0])
    return R, mu, pi_hat, check_beta(beta)


@blas_limited
def policy_matching_loss(mdp, rewards, mu_hat, pi_hat, beta=5.0, policy=None, planner="auto"):
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
    planner : str, default="auto"
        See :func:`factirl_opt.available_planners`.

    Returns
    -------
    loss : ndarray, shape (n,)
        ``J_i`` (eq. 5) for each task.
    grad : ndarray, shape (n, S, A)
        ``dJ_i / dR_i`` (eqs. 8-9, computed by the adjoint route of docs/maths.md §3).
    """
    R, mu, pi_hat, beta = _validated(mdp, rewards, mu_hat, pi_hat, beta)
    pl = get_planner(mdp, planner)
    point = forward_point(pl, R, mu, pi_hat, beta, check_policy(mdp, policy, R.shape[0]))
    return point.loss, gradient_at(pl, point)


@blas_limited
def residual_jacobian(mdp, rewards, mu_hat, pi_hat, beta, features, policy=None, planner="auto", mode="auto"):
    """Residuals of eq. (5) and their Jacobian for rewards linear in parameters.

    With ``r_i = sqrt(mu_i) (pi_i - pi_hat_i)`` flattened, ``J_i = ||r_i||^2``. For
    ``R_i = F w_i`` the Jacobian ``dr_i/dw_i = sqrt(mu_i) dpi_i/dw`` comes from forward mode
    with p right-hand sides: ``Phi_V = (I - gamma P_pi)^-1 F[greedy rows]``,
    ``dQ*/dw = F + gamma P Phi_V``, ``dpi/dw = beta pi (dQ/dw - sum_a pi dQ/dw)``
    (docs/maths.md §5, Gauss-Newton H-step). Only the rows of visited states (``mu_i > 0``) are
    nonzero; reverse mode builds them with one adjoint right-hand side per such row instead:
    ``dQ*/dw`` at row ``j`` is ``F_j + gamma z_j^T F[greedy rows]`` with
    ``(I - gamma P_pi)^T z_j = P^T e_j``.

    Parameters
    ----------
    rewards : array_like, shape (n, S, A)
        Current rewards ``F w_i`` reshaped.
    features : array_like, shape (S*A, p)
        ``F`` (the dictionary D in FactIRL's H-step).
    mode : {"auto", "forward", "reverse"}, default="auto"
        Forward mode (p right-hand sides per task), reverse mode (one per residual row of a
        visited state), or reverse where those rows are fewer than p. The same Jacobian to round-off.

    Returns
    -------
    loss : ndarray, shape (n,)
    residual : ndarray, shape (n, S*A)
    jacobian : ndarray, shape (n, S*A, p)
    """
    R, mu, pi_hat, beta = _validated(mdp, rewards, mu_hat, pi_hat, beta)
    F = check_features(features, mdp.n_params)
    mode = _check_jacobian_mode(mode)
    pl = get_planner(mdp, planner)
    point = forward_point(pl, R, mu, pi_hat, beta, check_policy(mdp, policy, R.shape[0]))
    return point.loss, _residual(point), _features_jacobian(pl, point, F, mode)


def dq_dtheta(mdp, policy, features=None, route="direct", tol=1e-13, max_iter=100000):
    """``phi = dQ*/dtheta`` of one task, the fixed point of eq. (9) (dense reference route).

    ``phi(x, a) = dR(x, a)/dtheta + gamma sum_y P(y|x, a) phi(y, pi*(y))`` for the greedy
    policy ``pi*``. This builds the whole (S*A, p) matrix; it refuses models with more than
    ``REFERENCE_MAX_PARAMS`` state-action pairs instead of running out of memory.

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
    if mdp.n_params > REFERENCE_MAX_PARAMS:
        raise ValidationError(
            f"the eq. (9) reference route builds dense (S*A, d) matrices; S*A = {mdp.n_params} exceeds "
            f"{REFERENCE_MAX_PARAMS}: use policy_matching_loss (adjoint route)"
        )
    pol = check_policy(mdp, policy, 1)[0]
    F = parameter_matrix(mdp, features)
    if route == "direct":  # forward mode with p right-hand sides: the engine's tangent kernel
        planner = get_planner(mdp)
        dQ = tangent(planner, planner.system(pol[None]), pol[None], F.reshape(1, S, A, -1))
        return dQ.reshape(S * A, -1)
    greedy_rows = np.arange(S) * A + pol
    P2 = mdp.transitions.reshape(S * A, S)
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
    R, mu, pi_hat, beta = _validated(mdp, rewards, mu_hat, pi_hat, beta)
    if R.shape[0] == 0:  # no tasks: empty loss and gradient, as policy_matching_loss returns
        p = reward_dimension(mdp, features)
        return np.zeros(0), np.zeros((0, p))
    point = forward_point(get_planner(mdp), R, mu, pi_hat, beta)
    g = softmax_vjp(point.pi, 2.0 * mu[:, :, None] * point.diff, beta).reshape(R.shape[0], -1)
    grads = [g[i] @ dq_dtheta(mdp, point.plan.policy[i], features, route=route) for i in range(R.shape[0])]
    return point.loss, np.array(grads)

"""The planning engine: the one place that solves Bellman systems (DESIGN sections 3 and 7).

Everything that plans goes through a *planner* bound to an MDP: exact ``Q*`` and a greedy policy
by policy iteration (:func:`optimal_q`), policy evaluation for deterministic and stochastic
policies (:func:`policy_evaluation`), and, for the objectives, the systems
``M = I - gamma P_pi`` of a batch of policies, solved with one or many right-hand sides and
transposed (adjoints). Batches keep tasks on the leading axis: rewards (n, S, A), values (n, S),
deterministic policies (n, S) of action indices, stochastic policies (n, S, A).

Planners (``planner=`` by name everywhere; :func:`available_planners`):

``"dense"``
    Batched dense LU (``numpy.linalg.solve`` on (n, S, S) systems, built in chunks of tasks
    that fit in 256 MiB). Best for small S; refuses models whose dense copy would not fit.
``"sparse-lu"``
    One sparse LU (SuperLU, ``scipy.sparse.linalg.splu``) per task, built once per policy and
    reused for the policy's values, the transposed (adjoint) solve and the Jacobian's
    right-hand sides. Bellman backups are one sparse x dense product for all tasks.
``"auto"`` (default)
    ``"dense"`` up to :data:`AUTO_DENSE_MAX_STATES` states, ``"sparse-lu"`` above (the measured
    crossover, see the README's planning benchmark).

Both are direct solvers: relative residuals are at the level of floating point (~1e-15), well
below the 1e-12 the library promises.
"""

import dataclasses

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ._threads import blas_limited
from ._validation import check_array, check_beta, check_stochastic_policy, check_int, check_mdp, check_policy, check_real, check_rewards
from .exceptions import FactIRLError, ValidationError

__all__ = [
    "available_planners",
    "get_planner",
    "optimal_q",
    "policy_evaluation",
    "boltzmann_policy",
    "value_iteration",
    "PlanResult",
    "plan",
    "adjoint",
    "tangent",
    "AUTO_DENSE_MAX_STATES",
]

#: ``planner="auto"`` uses the dense planner up to this many states (measured crossover)
AUTO_DENSE_MAX_STATES = 256
#: memory for one chunk of dense (c, S, S) systems
DENSE_CHUNK_BYTES = 256 * 2**20


class PolicySystem:
    """``M = I - gamma P_pi`` for a batch of n policies: solve ``M X = B`` and ``M^T X = B``.

    Right-hand sides ``B`` are (n, S) or (n, S, k). Built by :meth:`Planner.system`.
    """

    n: int

    def solve(self, B):  # pragma: no cover - interface
        raise NotImplementedError

    def solve_transpose(self, B):  # pragma: no cover - interface
        raise NotImplementedError


class _DenseSystem(PolicySystem):
    """Dense systems built chunk by chunk from the policies (never all n (S, S) at once)."""

    def __init__(self, planner, policy):
        self.planner, self.policy, self.n = planner, policy, policy.shape[0]

    def _solve(self, B, transpose):
        S = self.planner.S
        chunk = max(1, DENSE_CHUNK_BYTES // (8 * S * S))
        out = np.empty_like(B, dtype=np.float64)
        for lo in range(0, self.n, chunk):
            sl = slice(lo, lo + chunk)
            M = np.eye(S)[None] - self.planner.gamma * self.planner.policy_matrix(self.policy[sl])
            b = B[sl]
            x = np.linalg.solve(np.swapaxes(M, 1, 2) if transpose else M, b[..., None] if b.ndim == 2 else b)
            out[sl] = x[..., 0] if b.ndim == 2 else x
        return out

    def solve(self, B):
        return self._solve(B, False)

    def solve_transpose(self, B):
        return self._solve(B, True)


class _FactorSystem(PolicySystem):
    """One sparse LU factorisation per task, reused for every solve."""

    def __init__(self, factors):
        self.factors, self.n = factors, len(factors)

    def _solve(self, B, trans):
        return np.stack([lu.solve(np.ascontiguousarray(b), trans=trans) for lu, b in zip(self.factors, B)])

    def solve(self, B):
        return self._solve(B, "N")

    def solve_transpose(self, B):
        return self._solve(B, "T")


class Planner:
    """Base class: a planner bound to one MDP. Use :func:`get_planner`.

    Attributes
    ----------
    name : str
    S, A : int
    gamma : float
    """

    name = "base"

    def __init__(self, mdp):
        self.mdp, self.S, self.A, self.gamma = mdp, mdp.n_states, mdp.n_actions, mdp.gamma

    def backup(self, V):
        """``(P V)[n, s, a] = sum_s' P(s'|s, a) V[n, s']``: (n, S) -> (n, S, A).

        With k directions, (n, S, k) -> (n, S*A, k) (row ``s * A + a``).
        """
        raise NotImplementedError  # pragma: no cover

    def pullback(self, G):
        """``(P^T G)[n, s'] = sum_{s,a} P(s'|s, a) G[n, s, a]``: (n, S, A) -> (n, S)."""
        raise NotImplementedError  # pragma: no cover

    def system(self, policy):
        """:class:`PolicySystem` of deterministic (n, S) int or stochastic (n, S, A) policies."""
        raise NotImplementedError  # pragma: no cover

    def q_from_values(self, R, V):
        """``Q = R + gamma P V``: R (n, S, A), V (n, S) -> (n, S, A)."""
        return R + self.gamma * self.backup(V)


class DensePlanner(Planner):
    """Batched dense LU on (n, S, S) systems (today's planner; best for small S)."""

    name = "dense"

    def __init__(self, mdp):
        super().__init__(mdp)
        if mdp.is_sparse and 8 * self.S * self.S * self.A > DENSE_CHUNK_BYTES * 2:
            raise ValidationError(
                f"the dense planner needs the (S, A, S) = ({self.S}, {self.A}, {self.S}) transitions "
                f"({8 * self.S * self.S * self.A / 2**30:.2f} GiB) of this sparse model; use planner='sparse-lu' or 'auto'"
            )
        self.P3 = mdp.transitions
        self.P2 = self.P3.reshape(self.S * self.A, self.S)

    def backup(self, V):
        if V.ndim == 3:  # k directions: (n, S, k) -> (n, S*A, k)
            return self.P2 @ V
        return (V @ self.P2.T).reshape(V.shape[0], self.S, self.A)

    def pullback(self, G):
        return G.reshape(G.shape[0], self.S * self.A) @ self.P2

    def policy_matrix(self, policy):
        """``P_pi`` (n, S, S) of deterministic (n, S) or stochastic (n, S, A) policies."""
        if policy.ndim == 2:
            return self.P3[np.arange(self.S)[None, :], policy]
        return np.einsum("nsa,sat->nst", policy, self.P3)

    def system(self, policy):
        return _DenseSystem(self, policy)


class SparseLUPlanner(Planner):
    """One sparse LU per task (SuperLU), reused for values, adjoint and Jacobian solves."""

    name = "sparse-lu"

    def __init__(self, mdp):
        super().__init__(mdp)
        self.P = mdp.csr()
        self.PT = self.P.T.tocsr()
        self._eye = sp.identity(self.S, format="csr")
        self._pi_rows = np.repeat(np.arange(self.S), self.A)
        self._pi_cols = np.arange(self.S * self.A)

    def backup(self, V):
        if V.ndim == 3:  # k directions: (n, S, k) -> (n, S*A, k)
            n, _, k = V.shape
            out = self.P @ np.moveaxis(V, 0, 1).reshape(self.S, n * k)
            return np.moveaxis(out.reshape(self.S * self.A, n, k), 1, 0)
        return np.asarray(self.P @ V.T).T.reshape(V.shape[0], self.S, self.A)

    def pullback(self, G):
        return np.asarray(self.PT @ G.reshape(G.shape[0], self.S * self.A).T).T

    def policy_matrix(self, policy_i):
        """``P_pi`` (S, S) CSR of one deterministic (S,) or stochastic (S, A) policy."""
        if policy_i.ndim == 1:
            return self.P[np.arange(self.S) * self.A + policy_i]
        Pi = sp.csr_matrix((policy_i.ravel(), (self._pi_rows, self._pi_cols)), shape=(self.S, self.S * self.A))
        return Pi @ self.P

    def system(self, policy):
        factors = []
        for pol in policy:
            M = (self._eye - self.gamma * self.policy_matrix(pol)).tocsc()
            try:
                factors.append(spla.splu(M, permc_spec="COLAMD"))
            except RuntimeError as exc:  # singular: impossible for gamma < 1 and a stochastic P
                raise FactIRLError(f"sparse LU of I - gamma P_pi failed: {exc}") from None
        return _FactorSystem(factors)


PLANNERS = {"dense": DensePlanner, "sparse-lu": SparseLUPlanner}


def available_planners():
    """Names accepted by ``planner=``: ``"auto"`` and every registered planner."""
    return ["auto", *PLANNERS]


def get_planner(mdp, planner="auto"):
    """The planner named ``planner`` bound to ``mdp`` (cached on the MDP), or a Planner as is."""
    if isinstance(planner, Planner):
        if planner.mdp is not mdp:
            raise ValidationError("this planner is bound to another MDP")
        return planner
    if not isinstance(planner, str) or planner not in available_planners():
        raise ValidationError(f"unknown planner {planner!r}; available: {', '.join(available_planners())}")
    if planner == "auto":
        planner = "dense" if mdp.n_states <= AUTO_DENSE_MAX_STATES else "sparse-lu"
    cache = mdp.__dict__.setdefault("_planners", {})
    if planner not in cache:
        cache[planner] = PLANNERS[planner](mdp)
    return cache[planner]


@dataclasses.dataclass
class PlanResult:
    """Exact optimal planning of a batch of tasks (internal to the engine's users).

    Attributes
    ----------
    Q : ndarray, shape (n, S, A)
    policy : ndarray of intp, shape (n, S)
        Greedy on ``Q``.
    V : ndarray, shape (n, S)
    system : PolicySystem
        ``I - gamma P_pi`` of ``policy``, ready for more solves (adjoint, Jacobian).
    """

    Q: np.ndarray
    policy: np.ndarray
    V: np.ndarray
    system: PolicySystem


def _greedy_values(planner, R, policy):
    """Values of deterministic policies and their system: solve (I - gamma P_pi) V = R_pi."""
    system = planner.system(policy)
    R_pi = np.take_along_axis(R, policy[:, :, None], axis=2)[:, :, 0]
    return system.solve(R_pi), system


def plan(planner, R, policy=None, max_iter=1000):
    """Exact ``Q*`` of every task by policy iteration (unvalidated; see :func:`optimal_q`).

    Returns
    -------
    PlanResult
    """
    n, S, A = R.shape
    pol = np.argmax(R, axis=2) if policy is None else np.array(policy, dtype=np.intp, copy=True)
    Q, V = np.empty_like(R), np.empty((n, S))
    active, systems = np.arange(n), [None] * n
    for _ in range(max_iter):
        Ra, pa = R[active], pol[active]
        Va, sys_a = _greedy_values(planner, Ra, pa)
        Qa = planner.q_from_values(Ra, Va)
        best = np.argmax(Qa, axis=2)
        q_cur = np.take_along_axis(Qa, pa[:, :, None], axis=2)[:, :, 0]
        q_best = np.take_along_axis(Qa, best[:, :, None], axis=2)[:, :, 0]
        tol = 1e-12 * np.maximum(1.0, np.abs(Qa).max(axis=(1, 2)))[:, None]
        improve = q_best > q_cur + tol
        Q[active], V[active] = Qa, Va
        changed = improve.any(axis=1)
        pol[active] = np.where(improve, best, pa)
        if isinstance(sys_a, _FactorSystem):
            for j, i in enumerate(active):
                systems[i] = sys_a.factors[j]
        if not changed.any():
            system = _FactorSystem(systems) if isinstance(sys_a, _FactorSystem) else planner.system(pol)
            return PlanResult(Q, pol, V, system)
        active = active[changed]
    raise FactIRLError(f"policy iteration did not converge in {max_iter} sweeps")


def _policy_weights(policy, shape):
    """``w[n, s, a]`` = 1[a = pi(s)] for deterministic (n, S) policies, ``pi(a|s)`` for stochastic ones."""
    if policy.ndim == 3:
        return policy
    w = np.zeros(shape)
    np.put_along_axis(w, policy[:, :, None], 1.0, axis=2)
    return w


def adjoint(planner, system, policy, G):
    """``dL/dR`` from ``G = dL/dQ`` for ``Q = R + gamma P V``, ``V`` the values of ``policy``.

    For a greedy (deterministic) policy ``V(s) = Q(s, pi(s))`` (``Q*``, DESIGN section 3); for a
    stochastic one ``dV(s) = sum_a pi(a|s) dQ(s, a)`` (the soft Bellman equation, section 9).
    One transposed solve per task: ``(I - gamma P_pi^T) z = P^T G``, then
    ``dL/dR = G + gamma w z`` with ``w`` the policy's weights (``w[s, pi(s)] = 1``).

    Parameters
    ----------
    planner : Planner
    system : PolicySystem
        Of ``policy`` (e.g. ``PlanResult.system``).
    policy : ndarray, (n, S) int or (n, S, A) float
    G : ndarray, shape (n, S, A)

    Returns
    -------
    ndarray, shape (n, S, A)
    """
    z = system.solve_transpose(planner.pullback(G))
    if policy.ndim == 3:
        return G + planner.gamma * policy * z[:, :, None]
    y = G.copy()
    n, S = policy.shape
    y[np.arange(n)[:, None], np.arange(S)[None, :], policy] += planner.gamma * z
    return y


def tangent(planner, system, policy, dR):
    """Forward-mode derivative ``dQ`` of ``Q = R + gamma P V^pi`` along ``dR`` (policy fixed).

    ``dV = (I - gamma P_pi)^-1 dR_pi`` with ``dR_pi(s) = sum_a w(a|s) dR(s, a)``, then
    ``dQ = dR + gamma P dV`` (eq. 9 in forward mode; DESIGN sections 3 and 10).

    Parameters
    ----------
    dR : ndarray, shape (n, S, A) or, for k directions at once, (n, S, A, k)

    Returns
    -------
    dQ : ndarray, shape (n, S, A) or (n, S, A, k)
    """
    n, S, A = dR.shape[:3]
    w = _policy_weights(policy, (n, S, A))
    if dR.ndim == 3:
        dV = system.solve(np.einsum("nsa,nsa->ns", w, dR))
        return dR + planner.gamma * planner.backup(dV)
    if policy.ndim == 2:  # pick the greedy rows (no product with zeros)
        dR_pi = np.take_along_axis(dR, policy[:, :, None, None], axis=2)[:, :, 0]
    else:
        dR_pi = np.einsum("nsa,nsak->nsk", w, dR)
    dV = system.solve(dR_pi)
    return dR + planner.gamma * planner.backup(dV).reshape(dR.shape)


@blas_limited
def policy_evaluation(mdp, rewards, policy, planner="auto"):
    """Exact value of deterministic or stochastic policies (Bellman equation, paper eq. 1).

    Parameters
    ----------
    mdp : TabularMDP
    rewards : array_like, shape (S, A) or (n, S, A)
    policy : array_like
        Deterministic: int actions (S,) or (n, S). Stochastic: probabilities ``pi(a|s)``,
        float (S, A) or (n, S, A), rows summing to 1.
    planner : str, default="auto"
        See :func:`available_planners`.

    Returns
    -------
    V : ndarray, shape (S,) or (n, S)
        ``V = (I - gamma P_pi)^-1 R_pi`` with ``R_pi(s) = sum_a pi(a|s) R(s, a)``.
    """
    check_mdp(mdp)
    R, single = check_rewards(mdp, rewards)
    if policy is None:
        raise ValidationError("policy must be given (deterministic (S,)/(n, S) or stochastic (S, A)/(n, S, A))")
    pl = get_planner(mdp, planner)
    arr = np.asarray(policy)
    stochastic = arr.dtype.kind == "f" and arr.ndim in (2, 3) and arr.shape[-2:] == (mdp.n_states, mdp.n_actions)
    if not stochastic:
        V, _ = _greedy_values(pl, R, check_policy(mdp, policy, R.shape[0]))
    else:
        pi = check_stochastic_policy(mdp, policy, R.shape[0])
        V = pl.system(pi).solve(np.sum(pi * R, axis=2))
    return V[0] if single else V


@blas_limited
def optimal_q(mdp, rewards, policy=None, max_iter=1000, planner="auto"):
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
    planner : str, default="auto"
        See :func:`available_planners`.

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
    res = plan(get_planner(mdp, planner), R, pol, check_int(max_iter, "max_iter", minimum=1))
    if single:
        return res.Q[0], res.policy[0]
    return res.Q, res.policy


def boltzmann_policy(Q, beta):
    """Boltzmann (softmax) policy ``pi(a|s) ∝ exp(beta Q(s, a))`` (paper eq. 7).

    Numerically stable: the maximum over actions is subtracted before exponentiating, so no
    overflow occurs for any finite ``beta * Q``.

    Parameters
    ----------
    Q : array_like, shape (..., S, A)
        Finite action values.
    beta : float
        Inverse temperature, > 0.

    Returns
    -------
    pi : ndarray, shape (..., S, A)
        Rows sum to 1.
    """
    Q = check_array(Q, "Q")
    if Q.ndim < 1:
        raise ValidationError(f"Q must have an action axis; got shape {Q.shape}")
    beta = check_beta(beta)
    z = beta * (Q - Q.max(axis=-1, keepdims=True))
    np.exp(z, out=z)
    z /= z.sum(axis=-1, keepdims=True)
    return z


@blas_limited
def value_iteration(mdp, rewards, tol=1e-12, max_iter=100000, planner="auto"):
    """Q* by value iteration (paper eq. 3): a slow, simple reference for tests.

    Parameters
    ----------
    mdp : TabularMDP
    rewards : array_like, shape (S, A) or (n, S, A)
    tol : float
        Stop when the sup-norm change of Q is below ``tol``.
    max_iter : int
        Sweeps allowed; reaching it without meeting ``tol`` raises :class:`FactIRLError` (the
        error of an unconverged Q can be large: at gamma 0.9999 it needs ~3e5 sweeps for 1e-12).

    Returns
    -------
    Q : ndarray, shape (S, A) or (n, S, A)
    """
    check_mdp(mdp)
    R, single = check_rewards(mdp, rewards)
    tol = check_real(tol, "tol", low=0.0, low_open=True)
    max_iter = check_int(max_iter, "max_iter", minimum=1)
    pl = get_planner(mdp, planner)
    Q = R.copy()
    for _ in range(max_iter):
        Q_new = pl.q_from_values(R, Q.max(axis=2))
        delta = np.max(np.abs(Q_new - Q))
        Q = Q_new
        if delta < tol:
            return Q[0] if single else Q
    raise FactIRLError(f"value iteration did not reach tol={tol:g} in {max_iter} sweeps (last change {delta:.3g}); "
                       "raise max_iter or use optimal_q (exact policy iteration)")

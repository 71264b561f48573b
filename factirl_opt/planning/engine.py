"""The planning engine: policy iteration, exact policy values, adjoints and tangents (docs/maths.md §2-§3).

Everything that plans goes through a *planner* bound to an MDP
(:class:`~factirl_opt.planning.base.Planner`, by name through
:func:`~factirl_opt.planning.registry.get_planner`): exact ``Q*`` and a greedy policy by policy
iteration (:func:`optimal_q`, :func:`plan`), policy evaluation for deterministic and stochastic
policies (:func:`policy_evaluation`), and, for the objectives, the derivatives through planning
(:func:`adjoint`, :func:`tangent`) on the systems ``M = I - gamma P_pi`` of a batch of policies.
Batches keep tasks on the leading axis: rewards (n, S, A), values (n, S), deterministic
policies (n, S) of action indices, stochastic policies (n, S, A).

Both planners are direct solvers: relative residuals are at the level of floating point
(~1e-15), below the 1e-12 the library promises; the sparse planner's low-rank updates check
every solve's residual against the policy's own matrix.

What depends on the planner. ``Q*``, policy values, losses and gradients at given rewards agree
between planners to floating-point accuracy, growing with ``1 / (1 - gamma)`` for the values
(about 2e-15 relative at gamma 0.9, 1e-13 at 0.999) and up to ``1 / (1 - gamma)^2`` for the losses
and gradients, which depend on differences of ``Q`` between actions (3e-14 at gamma 0.9, 3e-10 at
0.999 on the 10x10 grid); the tests hold values to ``1e-13 / (1 - gamma)`` and losses to
``max(1e-13 / (1 - gamma), 1e-15 / (1 - gamma)^2)``. Both planners are then as close to the exact
values as the conditioning allows (``results/planners/accuracy.json``). The greedy policy returned
is the same except where two actions tie within a relative 1e-12 (both optimal; each planner
keeps the action its policy iteration reached). A fit chains many evaluations and amplifies such
rounding-level differences along directions in which the loss hardly changes, so fitted rewards
agree between planners only approximately (the same happens with a 1e-15 perturbation of the
start with one planner); a fit with one planner is repeatable bit for bit, also in threads, from
the same state of the sparse planner's per-thread factorisation cache (a reused or low-rank
updated factorisation rounds differently from a fresh one, at the 1e-12 level). See
the user guide, "Large MDPs: sparse dynamics and planners".
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._threads import blas_limited
from .._validation import check_array, check_beta, check_int, check_mdp, check_policy, check_real, check_rewards, check_stochastic_policy
from ..exceptions import FactIRLError, ValidationError
from ..mdp.environments import (
    assemble, by_environment, check_environments, is_environment_sequence, per_task_values,
    check_task_rewards,
)
from .base import Planner, PolicySystem
from .registry import get_planner

__all__ = ["PlanResult", "plan", "adjoint", "tangent", "policy_evaluation", "optimal_q", "value_iteration",
           "boltzmann_policy", "greedy_values"]


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

    Q: NDArray[np.float64]
    policy: NDArray[np.intp]
    V: NDArray[np.float64]
    system: PolicySystem


def greedy_values(planner: Planner, R: NDArray[np.float64], policy: NDArray[np.intp],
                  hints: list[Any] | None = None) -> tuple[NDArray[np.float64], PolicySystem]:
    """Values of deterministic policies and their system: solve (I - gamma P_pi) V = R_pi."""
    system = planner.system(policy, hints)
    R_pi = np.take_along_axis(R, policy[:, :, None], axis=2)[:, :, 0]
    return system.solve(R_pi), system


def plan(planner: Planner, R: NDArray[np.float64], policy: ArrayLike | None = None, max_iter: int = 1000) -> PlanResult:
    """Exact ``Q*`` of every task by policy iteration (unvalidated; see :func:`optimal_q`).

    Each sweep evaluates the active tasks' policies exactly; a sparse planner is handed each
    task's previous solver as a hint (:meth:`Planner.system`).

    Returns
    -------
    PlanResult
    """
    n, S, A = R.shape
    pol = planner.initial_policy(R) if policy is None else np.array(policy, dtype=np.intp, copy=True)
    Q, V = np.empty_like(R), np.empty((n, S))
    active, solvers = np.arange(n), [None] * n
    for _ in range(max_iter):
        Ra, pa = R[active], pol[active]
        Va, sys_a = greedy_values(planner, Ra, pa, [solvers[i] for i in active])
        Qa = planner.q_from_values(Ra, Va)
        best = np.argmax(Qa, axis=2)
        q_cur = np.take_along_axis(Qa, pa[:, :, None], axis=2)[:, :, 0]
        q_best = np.take_along_axis(Qa, best[:, :, None], axis=2)[:, :, 0]
        tol = 1e-12 * np.maximum(1.0, np.abs(Qa).max(axis=(1, 2)))[:, None]
        improve = q_best > q_cur + tol
        Q[active], V[active] = Qa, Va
        changed = improve.any(axis=1)
        pol[active] = np.where(improve, best, pa)
        if sys_a.solvers is not None:
            for j, i in enumerate(active):
                solvers[i] = sys_a.solvers[j]
        if not changed.any():
            system = planner.system(pol) if sys_a.solvers is None else planner.solver_system(solvers)
            return PlanResult(Q, pol, V, system)
        pol[active[changed]] = planner.refine_policy(Ra[changed], Qa[changed], pol[active[changed]], pa[changed])
        active = active[changed]
    raise FactIRLError(f"policy iteration did not converge in {max_iter} sweeps")


def _policy_weights(policy: NDArray[Any], shape: tuple[int, int, int]) -> NDArray[np.float64]:
    """``w[n, s, a]`` = 1[a = pi(s)] for deterministic (n, S) policies, ``pi(a|s)`` for stochastic ones."""
    if policy.ndim == 3:
        return policy
    w = np.zeros(shape)
    np.put_along_axis(w, policy[:, :, None], 1.0, axis=2)
    return w


def adjoint(planner: Planner, system: PolicySystem, policy: NDArray[Any], G: NDArray[np.float64]) -> NDArray[np.float64]:
    """``dL/dR`` from ``G = dL/dQ`` for ``Q = R + gamma P V``, ``V`` the values of ``policy``.

    For a greedy (deterministic) policy ``V(s) = Q(s, pi(s))`` (``Q*``, docs/maths.md §3); for a
    stochastic one ``dV(s) = sum_a pi(a|s) dQ(s, a)`` (the soft Bellman equation, docs/maths.md §6).
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


def tangent(planner: Planner, system: PolicySystem, policy: NDArray[Any], dR: NDArray[np.float64]) -> NDArray[np.float64]:
    """Forward-mode derivative ``dQ`` of ``Q = R + gamma P V^pi`` along ``dR`` (policy fixed).

    ``dV = (I - gamma P_pi)^-1 dR_pi`` with ``dR_pi(s) = sum_a w(a|s) dR(s, a)``, then
    ``dQ = dR + gamma P dV`` (eq. 9 in forward mode; docs/maths.md §3).

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
def policy_evaluation(mdp: Any, rewards: ArrayLike, policy: ArrayLike, planner: str | Planner = "auto") -> NDArray[np.float64]:
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
        V, _ = greedy_values(pl, R, check_policy(mdp, policy, R.shape[0]))
    else:
        pi = check_stochastic_policy(mdp, policy, R.shape[0])
        V = pl.system(pi).solve(np.sum(pi * R, axis=2))
    return V[0] if single else V


def _optimal_q_per_environment(mdps: Any, rewards: Any, policy: Any, **kwargs: Any) -> tuple[Any, Any]:
    """:func:`optimal_q` over tasks in many environments, one call per distinct MDP."""
    envs = check_environments(mdps)
    per_task = {"rewards": check_task_rewards(envs, rewards, "rewards"), "policy": per_task_values(envs, policy, "policy")}
    out = by_environment(envs, lambda m, **args: optimal_q(m, **args, **kwargs), per_task)
    return assemble(envs, [q for q, _ in out]), assemble(envs, [p for _, p in out])


@blas_limited
def optimal_q(mdp: Any, rewards: ArrayLike, policy: ArrayLike | None = None,
              max_iter: int = 1000, planner: str | Planner = "auto") -> tuple[Any, Any]:
    """Exact optimal action values Q* and a greedy policy, by policy iteration.

    Policy iteration (Howard) evaluates each policy exactly, so the result is exact up to
    floating point; warm-started from ``policy`` (e.g. the greedy policy of a nearby reward,
    as in a line search) it usually converges in one or two evaluations. Ties in the greedy
    step keep the current action unless another is better by more than a relative 1e-12,
    so the iteration cannot cycle.

    ``Q`` agrees between planners to floating-point accuracy (relative ~1e-15 at gamma 0.9,
    growing with ``1 / (1 - gamma)``); the
    greedy policy too, except in states where actions tie within 1e-12 (see the module
    docstring for what a fit's result depends on).

    Tasks in many environments: with a sequence of MDPs, tasks given the same MDP object are
    planned as one batch (:mod:`factirl_opt.mdp.environments`), with the results of one call
    per distinct MDP put back in task order.

    Parameters
    ----------
    mdp : TabularMDP or sequence of n TabularMDP
        One MDP for every task, or one per task (the same number of actions).
    rewards : array_like, shape (S, A) or (n, S, A)
        One reward or a batch of rewards (tasks on the leading axis). With a sequence of MDPs:
        a list of n arrays, task ``i``'s (S_i, A) or (S_i,) state reward, or a stacked
        (n, S, A) or (n, S) array when every ``S_i`` is S.
    policy : array_like of int, shape (S,) or (n, S), optional
        Initial deterministic policy (warm start). Default: greedy on the immediate reward.
        With a sequence of MDPs: one per task (a list of (S_i,) arrays, or stacked (n, S)).
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
        A greedy policy on ``Q*``. With a sequence of MDPs: ``Q`` (n, S, A) and ``policy``
        (n, S) when every ``S_i`` is S, else lists of n arrays (S_i, A) and (S_i,).
    """
    if is_environment_sequence(mdp):
        return _optimal_q_per_environment(mdp, rewards, policy, max_iter=max_iter, planner=planner)
    check_mdp(mdp)
    R, single = check_rewards(mdp, rewards)
    pol = check_policy(mdp, policy, R.shape[0])
    res = plan(get_planner(mdp, planner), R, pol, check_int(max_iter, "max_iter", minimum=1))
    if single:
        return res.Q[0], res.policy[0]
    return res.Q, res.policy


def boltzmann_policy(Q: ArrayLike, beta: float) -> NDArray[np.float64]:
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
    values = check_array(Q, "Q")
    if values.ndim < 1:
        raise ValidationError(f"Q must have an action axis; got shape {values.shape}")
    beta = check_beta(beta)
    z = beta * (values - values.max(axis=-1, keepdims=True))
    np.exp(z, out=z)
    z /= z.sum(axis=-1, keepdims=True)
    return z


@blas_limited
def value_iteration(mdp: Any, rewards: ArrayLike, tol: float = 1e-12, max_iter: int = 100000,
                    planner: str | Planner = "auto") -> NDArray[np.float64]:
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
    if R.shape[0] == 0:  # no tasks: nothing to iterate (as optimal_q returns (0, S, A))
        return Q
    for _ in range(max_iter):
        Q_new = pl.q_from_values(R, Q.max(axis=2))
        delta = np.max(np.abs(Q_new - Q))
        Q = Q_new
        if delta < tol:
            return Q[0] if single else Q
    raise FactIRLError(f"value iteration did not reach tol={tol:g} in {max_iter} sweeps (last change {delta:.3g}); "
                       "raise max_iter or use optimal_q (exact policy iteration)")

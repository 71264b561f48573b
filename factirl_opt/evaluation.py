"""Scoring learnt rewards on the true task (paper eq. 13; docs/maths.md §9).

Rewards enter as (n, S, A) or (S, A) state-action rewards, or as (n, S) or (S,) state rewards
repeated over the actions. A 2-d array of shape (S, A) is always one (S, A) reward: on an MDP
with ``A == S``, pass S state rewards as (S, S, A)
(:func:`~factirl_opt.datasets.objectworld.state_action_rewards`).

Tasks in many environments: every function also takes a sequence of n MDPs, one per task,
with per-task rewards, a list of n (S_i, A) or (S_i,) arrays or a stacked array when all
``S_i`` are equal (:mod:`factirl_opt.mdp.environments`); the scores are then an (n,) array.

Two scores: :func:`score` / :func:`deviation` act greedily on the learnt reward (the paper's
eq. 13, Levine's "standard MDP" value), :func:`soft_deviation` with the soft-optimal (maximum
causal entropy) policy at inverse temperature ``beta`` (the "linear MDP" value difference that
ELIRL reports).

:func:`dictionary_match` scores a learnt dictionary against the true one (the recovery of the
primitives, not of the tasks' behaviour).
"""

from __future__ import annotations

import typing

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._threads import blas_limited
from ._validation import check_array, check_beta, check_mdp, check_rewards, check_start
from .exceptions import FactIRLError, ValidationError
from .objectives.mce import soft_values
from .planning import Planner, get_planner, plan
from .planning.engine import greedy_values
from .mdp.environments import (
    by_environment, check_environments, is_environment_sequence, one_for_all, per_task_values,
    check_task_rewards,
)

from collections.abc import Sequence

from .mdp.tabular import TabularMDP  # at run time too: typing.get_type_hints resolves the annotations

__all__ = ["score", "optimal_score", "deviation", "soft_deviation", "dictionary_match"]


def _per_environment(func: typing.Callable[..., typing.Any], mdps: typing.Any, rewards: dict[str, typing.Any],
                     per_task: dict[str, typing.Any] | None = None, **kwargs: typing.Any) -> NDArray[np.float64]:
    """``func`` (a scorer of this module) over tasks in many environments: the (n,) scores in task order."""
    envs = check_environments(mdps)
    values: dict[str, list[typing.Any] | None] = {k: check_task_rewards(envs, v, k) for k, v in rewards.items()}
    values.update({k: per_task_values(envs, v, k) for k, v in (per_task or {}).items()})
    return np.array(by_environment(envs, lambda m, **r: func(m, **r, **kwargs), values), dtype=np.float64)


def _pair(mdp, true_rewards, learnt_rewards):
    """Validated (n, S, A) true and learnt rewards and whether single rewards were given."""
    check_mdp(mdp)
    Rt, single_t = check_rewards(mdp, true_rewards, "true_rewards")
    Rl, single_l = check_rewards(mdp, learnt_rewards, "learnt_rewards")
    if Rt.shape != Rl.shape:
        raise ValidationError(
            f"true_rewards and learnt_rewards must describe the same number of tasks; got {Rt.shape[0]} true "
            f"(shape {np.shape(true_rewards)}) and {Rl.shape[0]} learnt (shape {np.shape(learnt_rewards)})"
        )
    return Rt, Rl, single_t and single_l


def _greedy_score(planner, Rt, Rl):
    """``mean_s V^{pi_l}_{R_true}(s)`` for ``pi_l`` greedy on ``Q*`` of the learnt rewards, (n,)."""
    return greedy_values(planner, Rt, plan(planner, Rl).policy)[0].mean(axis=1)


@blas_limited
def score(mdp: TabularMDP | Sequence[TabularMDP], true_rewards: ArrayLike, learnt_rewards: ArrayLike,
          planner: str = "auto") -> float | NDArray[np.float64]:
    """Score of learnt rewards on the true tasks (eq. 13).

    ``score = mean_s V^{pi_l}_{R_true}(s)`` where ``pi_l`` is a greedy policy on the ``Q*`` of
    the learnt reward, evaluated exactly on the true reward (random start states).

    Parameters
    ----------
    mdp : TabularMDP or sequence of n TabularMDP
        One MDP shared by every task, or one per task (same number of actions; tasks given
        the same MDP object are planned as one batch).
    true_rewards, learnt_rewards : array_like, shape (n, S, A), (S, A), (n, S) or (S,)
        State rewards (n, S) or (S,) are broadcast over the actions; an (S, S) array with
        ``A == S`` is one (S, A) reward. The two may use different layouts but must describe
        the same number of tasks. With a sequence of MDPs: a list of n arrays, task ``i``'s
        of shape (S_i, A) or (S_i,), or a stacked (n, S, A) or (n, S) array when every
        ``S_i`` is S.
    planner : str, default="auto"
        See :func:`factirl_opt.available_planners`.

    Returns
    -------
    score : float or ndarray of shape (n,)
        A float when one MDP and single-task layouts ((S, A) or (S,)) were given; an (n,)
        array for a sequence of MDPs.

    Raises
    ------
    ValidationError
        Rewards of the wrong shape or count; with a sequence of MDPs, naming the task whose
        reward does not fit its MDP, or whose number of actions differs from task 0's.
    """
    if is_environment_sequence(mdp):
        return _per_environment(score, mdp, {"true_rewards": true_rewards, "learnt_rewards": learnt_rewards},
                                planner=planner)
    Rt, Rl, single = _pair(mdp, true_rewards, learnt_rewards)
    s = _greedy_score(get_planner(mdp, planner), Rt, Rl)
    return float(s[0]) if single else s


@blas_limited
def optimal_score(mdp: TabularMDP | Sequence[TabularMDP], true_rewards: ArrayLike, planner: str = "auto") -> float | NDArray[np.float64]:
    """The best possible score, ``mean_s V*_{R_true}(s)``.

    Parameters
    ----------
    mdp : TabularMDP or sequence of n TabularMDP
        As in :func:`score`.
    true_rewards : array_like, shape (n, S, A), (S, A), (n, S) or (S,), or list of n (S_i, A) or (S_i,)
        As in :func:`score`.
    planner : str, default="auto"

    Returns
    -------
    score : float or ndarray of shape (n,)
        An (n,) array for a sequence of MDPs.
    """
    if is_environment_sequence(mdp):
        return _per_environment(optimal_score, mdp, {"true_rewards": true_rewards}, planner=planner)
    model: TabularMDP = check_mdp(mdp)
    Rt, single = check_rewards(model, true_rewards, "true_rewards")
    s = plan(get_planner(model, planner), Rt).V.mean(axis=1)
    return float(s[0]) if single else s


@blas_limited
def deviation(mdp: TabularMDP | Sequence[TabularMDP], true_rewards: ArrayLike, learnt_rewards: ArrayLike,
              planner: str = "auto") -> float | NDArray[np.float64]:
    """Deviation from the optimal score: ``optimal_score - score`` (>= 0; lower is better).

    This is what the paper's figures 1 and 2 plot. To score rewards learnt on features on
    environments where no demonstration was given::

        deviation(new_mdps, true_rewards, feature_rewards(new_features, model.weights_, new_mdps))

    Parameters
    ----------
    mdp : TabularMDP or sequence of n TabularMDP
        As in :func:`score`.
    true_rewards, learnt_rewards : array_like, or list of n per-task arrays
        As in :func:`score`.
    planner : str, default="auto"

    Returns
    -------
    deviation : float or ndarray of shape (n,)
        An (n,) array for a sequence of MDPs.

    Raises
    ------
    FactIRLError
        The values overflowed float64 (rewards near the float64 limit).
    """
    if is_environment_sequence(mdp):
        return _per_environment(deviation, mdp, {"true_rewards": true_rewards, "learnt_rewards": learnt_rewards},
                                planner=planner)
    Rt, Rl, single = _pair(mdp, true_rewards, learnt_rewards)
    pl = get_planner(mdp, planner)
    V_opt = plan(pl, Rt).V
    dev = V_opt.mean(axis=1) - _greedy_score(pl, Rt, Rl)
    if not np.all(np.isfinite(dev)):
        bad = int(np.argmax(~np.isfinite(dev)))
        raise FactIRLError(f"the deviation of task {bad} overflowed ({dev[bad]!r}): rewards near the float64 limit; rescale the rewards")
    dev = np.maximum(dev, 0.0)  # exact zero for an optimal policy, up to round-off
    return float(dev[0]) if single else dev


def _soft_value(planner: Planner, R_true: NDArray[np.float64], R: NDArray[np.float64], beta: float,
                start: int | NDArray[np.float64] | None) -> NDArray[np.float64]:
    """``rho^T V^{pi_beta(R)}_{R_true}`` per task (n,): the soft-optimal policy of ``R`` valued on ``R_true``."""
    pi = np.exp(soft_values(planner, R, beta)[2])
    V = planner.system(pi).solve(np.sum(pi * R_true, axis=2))
    if start is None:
        return V.mean(axis=1)
    if isinstance(start, int):
        return V[:, start]
    return np.sum(start * V, axis=1)


@blas_limited
def soft_deviation(mdp: TabularMDP | Sequence[TabularMDP], true_rewards: ArrayLike,
                   learnt_rewards: ArrayLike, beta: float = 1.0,
                   start: int | ArrayLike | None = None,
                   planner: str = "auto") -> float | NDArray[np.float64]:
    """Value lost by the soft-optimal policy of the learnt reward (docs/maths.md §9).

    The soft-optimal (maximum causal entropy) policy of a reward ``R`` at inverse temperature
    ``beta`` is ``pi_R(a|s) = exp(beta (Q_R(s, a) - V_R(s)))`` with the soft Bellman equation
    ``Q_R = R + gamma P V_R``, ``V_R(s) = (1/beta) log sum_a exp(beta Q_R(s, a))``
    (docs/maths.md §6). Valued on the TRUE reward from the start distribution ``rho``,

        value(R) = rho^T V^{pi_R},    (I - gamma P_{pi_R}) V^{pi_R} = sum_a pi_R(a|.) R_true(., a),

    and the soft deviation is ``value(R_true) - value(R_learnt)``: the "linear MDP" value
    difference of Levine's toolkit that ELIRL prints, with both policies soft at the same
    ``beta`` (temperature 1 there). Computed exactly: the soft values by Newton's method on the
    soft Bellman equation (every step an exact solve of a policy's system, to a residual of
    1e-12 relative), then one exact policy evaluation, both through the planning engine; no
    truncated value iteration. 0 when ``learnt = true``. Unlike :func:`deviation` it can be
    negative (a sharper learnt reward can beat the soft policy of the true one) and it depends
    on the scale of the learnt reward; as ``beta -> inf`` both policies become greedy and it
    tends to :func:`deviation` (for rewards without ties in the greedy actions).

    Parameters
    ----------
    mdp : TabularMDP or sequence of n TabularMDP
        As in :func:`score`.
    true_rewards, learnt_rewards : array_like, or list of n per-task arrays
        As in :func:`score`.
    beta : float, default=1.0
        Inverse temperature of both soft-optimal policies, > 0.
    start : None, int, or array_like of shape (S,) or (n, S), optional
        ``rho``: None for uniform over the states (the toolkit's), a state, one distribution
        for every task or one per task. With a sequence of MDPs: None, an int, or one
        distribution per task (a list of n (S_i,) arrays, or stacked (n, S)).
    planner : str, default="auto"

    Returns
    -------
    soft_deviation : float or ndarray of shape (n,)
        A float when one MDP and single-task layouts were given.

    Raises
    ------
    ValidationError
        For rewards or start distributions of the wrong shape or count, or a bad ``beta``.
    FactIRLError
        The values overflowed float64.
    """
    if is_environment_sequence(mdp):
        shared = one_for_all(start)  # None, or one state for every task
        return _per_environment(soft_deviation, mdp, {"true_rewards": true_rewards, "learnt_rewards": learnt_rewards},
                                {} if shared else {"start": start}, beta=beta, planner=planner,
                                **({"start": start} if shared else {}))
    model: TabularMDP = check_mdp(mdp)
    Rt, Rl, single = _pair(model, true_rewards, learnt_rewards)
    beta = check_beta(beta)
    rho = check_start(start, Rt.shape[0], model.n_states)
    pl = get_planner(model, planner)
    dev = _soft_value(pl, Rt, Rt, beta, rho) - _soft_value(pl, Rt, Rl, beta, rho)
    if not np.all(np.isfinite(dev)):
        bad = int(np.argmax(~np.isfinite(dev)))
        raise FactIRLError(f"the soft deviation of task {bad} overflowed ({dev[bad]!r}): rescale the rewards")
    return float(dev[0]) if single else dev


def dictionary_match(learnt: ArrayLike, true: ArrayLike) -> tuple[float, NDArray[np.float64], NDArray[np.intp]]:
    """How well learnt primitives recover the true ones: the best one-to-one matching of columns.

    The factorial model leaves the order, the sign and the scale of the primitives free (and
    only their span is identified). Each pair (learnt column l, true column j) is scored by
    the absolute cosine ``|<d_l, d*_j>| / (||d_l|| ||d*_j||)``; the columns are matched one to
    one to maximise the sum (the Hungarian algorithm, ``scipy.optimize.linear_sum_assignment``).

    Parameters
    ----------
    learnt : array_like, shape (p, k)
    true : array_like, shape (p, k_true)

    Returns
    -------
    score : float
        Mean absolute cosine over the ``min(k, k_true)`` matched pairs, in [0, 1]; 1 when every
        true primitive is a learnt one up to sign and scale. Unmatched columns (``k != k_true``)
        do not count.
    cosines : ndarray, shape (k, k_true)
        The absolute cosines (zero for a zero column).
    matched : ndarray of int, shape (k_true,)
        The learnt column matched to each true one, -1 for a true column left unmatched.

    Raises
    ------
    ValidationError
        When an array is not 2-d, not finite, or the two have a different number of rows p.
    """
    from scipy.optimize import linear_sum_assignment

    L = check_array(learnt, "learnt", ndim=2)
    T = check_array(true, "true", ndim=2)
    if L.shape[0] != T.shape[0] or L.shape[1] == 0 or T.shape[1] == 0:
        raise ValidationError(f"learnt (p, k) and true (p, k_true) dictionaries need the same p and at least one column; "
                              f"got {L.shape} and {T.shape}")
    nl, nt = np.linalg.norm(L, axis=0), np.linalg.norm(T, axis=0)
    C = np.abs(L.T @ T) / np.outer(np.where(nl > 0, nl, 1.0), np.where(nt > 0, nt, 1.0))
    rows, cols = linear_sum_assignment(C, maximize=True)
    matched = np.full(T.shape[1], -1, dtype=np.intp)
    matched[cols] = rows
    return float(C[rows, cols].mean()), C, matched

"""Scoring learnt rewards on the true task (paper eq. 13; docs/maths.md §9).

Rewards enter as (n, S, A) or (S, A) state-action rewards, or as (n, S) or (S,) state rewards
repeated over the actions. A 2-d array of shape (S, A) is always one (S, A) reward: on an MDP
with ``A == S``, pass S state rewards as (S, S, A)
(:func:`~factirl_opt.objectworld.state_action_rewards`).
"""

from __future__ import annotations

import typing

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._threads import blas_limited
from ._validation import check_mdp, check_rewards
from .exceptions import FactIRLError, ValidationError
from .planning import get_planner, plan

if typing.TYPE_CHECKING:
    from .mdp import TabularMDP

__all__ = ["score", "optimal_score", "deviation"]


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
    pol = plan(planner, Rl).policy
    R_pi = np.take_along_axis(Rt, pol[:, :, None], axis=2)[:, :, 0]
    return planner.system(pol).solve(R_pi).mean(axis=1)


@blas_limited
def score(mdp: TabularMDP, true_rewards: ArrayLike, learnt_rewards: ArrayLike,
          planner: str = "auto") -> float | NDArray[np.float64]:
    """Score of learnt rewards on the true tasks (eq. 13).

    ``score = mean_s V^{pi_l}_{R_true}(s)`` where ``pi_l`` is a greedy policy on the ``Q*`` of
    the learnt reward, evaluated exactly on the true reward (random start states).

    Parameters
    ----------
    mdp : TabularMDP
    true_rewards, learnt_rewards : array_like, shape (n, S, A), (S, A), (n, S) or (S,)
        State rewards (n, S) or (S,) are broadcast over the actions; an (S, S) array with
        ``A == S`` is one (S, A) reward. The two may use different layouts but must describe
        the same number of tasks.
    planner : str, default="auto"
        See :func:`factirl_opt.available_planners`.

    Returns
    -------
    score : float or ndarray of shape (n,)
        A float when both rewards are single-task layouts ((S, A) or (S,)).
    """
    Rt, Rl, single = _pair(mdp, true_rewards, learnt_rewards)
    s = _greedy_score(get_planner(mdp, planner), Rt, Rl)
    return float(s[0]) if single else s


@blas_limited
def optimal_score(mdp: TabularMDP, true_rewards: ArrayLike, planner: str = "auto") -> float | NDArray[np.float64]:
    """The best possible score, ``mean_s V*_{R_true}(s)``.

    Parameters
    ----------
    mdp : TabularMDP
    true_rewards : array_like, shape (n, S, A), (S, A), (n, S) or (S,)
        As in :func:`score`.
    planner : str, default="auto"

    Returns
    -------
    score : float or ndarray of shape (n,)
    """
    check_mdp(mdp)
    Rt, single = check_rewards(mdp, true_rewards, "true_rewards")
    s = plan(get_planner(mdp, planner), Rt).V.mean(axis=1)
    return float(s[0]) if single else s


@blas_limited
def deviation(mdp: TabularMDP, true_rewards: ArrayLike, learnt_rewards: ArrayLike,
              planner: str = "auto") -> float | NDArray[np.float64]:
    """Deviation from the optimal score: ``optimal_score - score`` (>= 0; lower is better).

    This is what the paper's figures 1 and 2 plot.

    Parameters
    ----------
    mdp : TabularMDP
    true_rewards, learnt_rewards : array_like, shape (n, S, A), (S, A), (n, S) or (S,)
        As in :func:`score`.
    planner : str, default="auto"

    Returns
    -------
    deviation : float or ndarray of shape (n,)

    Raises
    ------
    FactIRLError
        The values overflowed float64 (rewards near the float64 limit).
    """
    Rt, Rl, single = _pair(mdp, true_rewards, learnt_rewards)
    pl = get_planner(mdp, planner)
    V_opt = plan(pl, Rt).V
    dev = V_opt.mean(axis=1) - _greedy_score(pl, Rt, Rl)
    if not np.all(np.isfinite(dev)):
        bad = int(np.argmax(~np.isfinite(dev)))
        raise FactIRLError(f"the deviation of task {bad} overflowed ({dev[bad]!r}): rewards near the float64 limit; rescale the rewards")
    dev = np.maximum(dev, 0.0)  # exact zero for an optimal policy, up to round-off
    return float(dev[0]) if single else dev

"""Scoring learnt rewards on the true task (paper eq. 13)."""

import numpy as np

from ._threads import blas_limited
from ._validation import check_mdp, check_rewards
from .exceptions import FactIRLError, ValidationError
from .planning import get_planner, plan

__all__ = ["score", "optimal_score", "deviation"]


def _pair(mdp, true_rewards, learnt_rewards):
    """Validated (n, S, A) true and learnt rewards and whether single (S, A) rewards were given."""
    check_mdp(mdp)
    Rt, single_t = check_rewards(mdp, true_rewards, "true_rewards")
    Rl, single_l = check_rewards(mdp, learnt_rewards, "learnt_rewards")
    if Rt.shape != Rl.shape:
        raise ValidationError(f"true_rewards {Rt.shape} and learnt_rewards {Rl.shape} must describe the same tasks")
    return Rt, Rl, single_t and single_l


def _greedy_score(planner, Rt, Rl):
    """``mean_s V^{pi_l}_{R_true}(s)`` for ``pi_l`` greedy on ``Q*`` of the learnt rewards, (n,)."""
    pol = plan(planner, Rl).policy
    R_pi = np.take_along_axis(Rt, pol[:, :, None], axis=2)[:, :, 0]
    return planner.system(pol).solve(R_pi).mean(axis=1)


@blas_limited
def score(mdp, true_rewards, learnt_rewards, planner="auto"):
    """Score of learnt rewards on the true tasks (eq. 13).

    ``score = mean_s V^{pi_l}_{R_true}(s)`` where ``pi_l`` is a greedy policy on the ``Q*`` of
    the learnt reward, evaluated exactly on the true reward (random start states).

    Parameters
    ----------
    mdp : TabularMDP
    true_rewards, learnt_rewards : array_like, shape (S, A) or (n, S, A)
    planner : str, default="auto"
        See :func:`factirl_opt.available_planners`.

    Returns
    -------
    score : float or ndarray of shape (n,)
    """
    Rt, Rl, single = _pair(mdp, true_rewards, learnt_rewards)
    s = _greedy_score(get_planner(mdp, planner), Rt, Rl)
    return float(s[0]) if single else s


@blas_limited
def optimal_score(mdp, true_rewards, planner="auto"):
    """The best possible score, ``mean_s V*_{R_true}(s)``; float or (n,)."""
    check_mdp(mdp)
    Rt, single = check_rewards(mdp, true_rewards, "true_rewards")
    s = plan(get_planner(mdp, planner), Rt).V.mean(axis=1)
    return float(s[0]) if single else s


@blas_limited
def deviation(mdp, true_rewards, learnt_rewards, planner="auto"):
    """Deviation from the optimal score: ``optimal_score - score`` (>= 0; lower is better).

    This is what the paper's figures 1 and 2 plot. Returns float or (n,).
    """
    Rt, Rl, single = _pair(mdp, true_rewards, learnt_rewards)
    pl = get_planner(mdp, planner)
    V_opt = plan(pl, Rt).V
    dev = V_opt.mean(axis=1) - _greedy_score(pl, Rt, Rl)
    if not np.all(np.isfinite(dev)):
        raise FactIRLError("the deviation overflowed (rewards near the float64 limit); rescale the rewards")
    dev = np.maximum(dev, 0.0)  # exact zero for an optimal policy, up to round-off
    return float(dev[0]) if single else dev

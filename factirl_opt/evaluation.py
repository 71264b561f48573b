"""Scoring learnt rewards on the true task (paper eq. 13)."""

import numpy as np

from ._threads import blas_limited
from ._validation import check_mdp, check_rewards
from .exceptions import ValidationError
from .planning import _optimal_q, _solve_policy_values

__all__ = ["score", "optimal_score", "deviation"]


def _pair(mdp, true_rewards, learnt_rewards):
    check_mdp(mdp)
    Rt, single_t = check_rewards(mdp, true_rewards, "true_rewards")
    Rl, single_l = check_rewards(mdp, learnt_rewards, "learnt_rewards")
    if Rt.shape != Rl.shape:
        raise ValidationError(f"true_rewards {Rt.shape} and learnt_rewards {Rl.shape} must describe the same tasks")
    return Rt, Rl, single_t and single_l


@blas_limited
def score(mdp, true_rewards, learnt_rewards):
    """Score of learnt rewards on the true tasks (eq. 13).

    ``score = mean_s V^{pi_l}_{R_true}(s)`` where ``pi_l`` is a greedy policy on the ``Q*`` of
    the learnt reward, evaluated exactly on the true reward (random start states).

    Parameters
    ----------
    mdp : TabularMDP
    true_rewards, learnt_rewards : array_like, shape (S, A) or (n, S, A)

    Returns
    -------
    score : float or ndarray of shape (n,)
    """
    Rt, Rl, single = _pair(mdp, true_rewards, learnt_rewards)
    _, pol, _ = _optimal_q(mdp, Rl)
    s = _solve_policy_values(mdp, Rt, pol).mean(axis=1)
    return float(s[0]) if single else s


@blas_limited
def optimal_score(mdp, true_rewards):
    """The best possible score, ``mean_s V*_{R_true}(s)``; float or (n,)."""
    check_mdp(mdp)
    Rt, single = check_rewards(mdp, true_rewards, "true_rewards")
    _, _, V = _optimal_q(mdp, Rt)
    s = V.mean(axis=1)
    return float(s[0]) if single else s


@blas_limited
def deviation(mdp, true_rewards, learnt_rewards):
    """Deviation from the optimal score: ``optimal_score - score`` (>= 0; lower is better).

    This is what the paper's figures 1 and 2 plot. Returns float or (n,).
    """
    Rt, Rl, single = _pair(mdp, true_rewards, learnt_rewards)
    _, pol_t, V_opt = _optimal_q(mdp, Rt)
    _, pol_l, _ = _optimal_q(mdp, Rl)
    dev = V_opt.mean(axis=1) - _solve_policy_values(mdp, Rt, pol_l).mean(axis=1)
    dev = np.maximum(dev, 0.0)  # exact zero for an optimal policy, up to round-off
    return float(dev[0]) if single else dev

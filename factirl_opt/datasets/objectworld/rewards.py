"""Objectworld rewards: Levine et al.'s single-task rule and ELIRL's multi-task rewards.

Rewards here are state rewards, (S,) or (n, S): the library's functions that take rewards
accept them as they are (repeated over the actions); :func:`state_action_rewards` gives the
(S, A) / (n, S, A) layout explicitly.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..._validation import RNGLike, as_rng, check_int, check_real
from ...exceptions import ValidationError
from .features import squared_distances
from .world import N_ACTIONS, ObjectWorld, check_world

__all__ = ["ELIRL_RADIUS", "ELIRL_SCALE", "levine_reward", "multitask_primitives", "multitask_rewards", "state_action_rewards"]

ELIRL_RADIUS = 3  # a colour is "near" when its distance is < 3 (ELIRL's rew_dist)
ELIRL_SCALE = 5.0  # ELIRL's R_SCALE: weights 5 * (3u - 2), in [-10, 5)


def levine_reward(world: ObjectWorld, positive: float = 1.0, negative: float = -1.0) -> NDArray[np.float64]:
    """Levine et al.'s single-task reward, as a state reward.

    ``r(s) = positive`` if the distance to inner colour 0 is < 3 **and** the distance to inner
    colour 1 is < 2; ``negative`` if the distance to inner colour 0 is < 3 but the distance to
    inner colour 1 is not < 2; ``0`` elsewhere. This is the paper's rule ("positive within
    distance 3 of colour 1 and distance 2 of colour 2, negative within distance 3 of colour 1,
    zero otherwise", colours 1 and 2 being the toolkit's first two ``c1`` colours, which this
    library calls inner colours 0 and 1 — see :mod:`factirl_opt.datasets.objectworld`). "Within distance d" is
    the strict ``< d`` of the toolkit's features, so ``r`` is a function of two discrete
    features (inner colour 0 at ``d = 3``, inner colour 1 at ``d = 2``).

    Parameters
    ----------
    world : ObjectWorld
        Needs ``n_inner >= 2``.
    positive, negative : float, default=1.0, -1.0
        The two nonzero reward values. The paper gives only their signs; the MATLAB toolkit
        scales its reward tree by ``R_SCALE = 5`` (leaf values +1 and -2 in the versions we
        checked), i.e. ``positive=5.0, negative=-10.0``.

    Returns
    -------
    reward : ndarray of float64, shape (S,)
    """
    world = check_world(world)
    if world.n_inner < 2:
        raise ValidationError(f"levine_reward needs at least 2 inner colours; the world has n_inner={world.n_inner}")
    pos, neg = check_real(positive, "positive"), check_real(negative, "negative")
    dsq = squared_distances(world)
    near0, near1 = dsq[:, 0] < 9.0, dsq[:, 1] < 4.0
    return np.where(near0 & near1, pos, np.where(near0, neg, 0.0))


def multitask_primitives(world: ObjectWorld) -> NDArray[np.float64]:
    """ELIRL's true reward primitives ``1[distance to inner colour c < 3]``.

    Parameters
    ----------
    world : ObjectWorld

    Returns
    -------
    primitives : ndarray of float64, shape (S, c1)
        Column ``c`` for inner colour ``c``; equal to discrete feature column ``c * (N-1) + 2``
        of :func:`objectworld_features` (``d = 3``) when ``N >= 4``.
    """
    dsq = squared_distances(check_world(world))
    return (dsq[:, : world.n_inner] < float(ELIRL_RADIUS**2)).astype(np.float64)


def multitask_rewards(world: ObjectWorld, n_tasks: int,
                      rng: RNGLike = None) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """ELIRL's multi-task rewards and their coefficients on the true primitives.

    For each task, independently: draw ``k`` uniformly in {2, 3, 4} (capped at ``c1``), choose
    ``k`` distinct inner colours uniformly without replacement, give each chosen colour ``c``
    the weight ``w_c = 5 * (3 u_c - 2)`` with ``u_c ~ U[0, 1)`` (so ``w_c`` in [-10, 5),
    nonzero almost surely) and every other colour 0. The reward is
    ``r(s) = sum_c w_c 1[distance(s, inner colour c) < 3]`` (ELIRL's ``objectworld2``
    defaults, ``R_SCALE = 5``, ``rew_dist = 3``).

    Parameters
    ----------
    world : ObjectWorld
    n_tasks : int
        Number of tasks ``n``, >= 1.
    rng : numpy.random.Generator or int or SeedSequence or None

    Returns
    -------
    rewards : ndarray of float64, shape (n, S)
        State rewards, ``rewards = coefficients @ primitives.T`` exactly (computed that way).
        :func:`~factirl_opt.sample_demonstrations`, :func:`~factirl_opt.deviation`,
        :func:`~factirl_opt.optimal_q` and the other functions taking rewards accept them as
        they are (repeated over the actions); :func:`state_action_rewards` gives the (n, S, A)
        array.
    coefficients : ndarray of float64, shape (n, c1)
        ``coefficients[i, c] = w_c`` of task ``i``.
    primitives : ndarray of float64, shape (S, c1)
        :func:`multitask_primitives`, the "ground truth features".
    """
    world = check_world(world)
    check_int(n_tasks, "n_tasks", minimum=1)
    rng = as_rng(rng)
    c1 = world.n_inner
    H = np.zeros((int(n_tasks), c1))
    for i in range(int(n_tasks)):
        k = min(int(rng.integers(2, 5)), c1)
        chosen = rng.choice(c1, size=k, replace=False)
        H[i, chosen] = ELIRL_SCALE * (3.0 * rng.random(k) - 2.0)
    primitives = multitask_primitives(world)
    return H @ primitives.T, H, primitives


def state_action_rewards(rewards: ArrayLike, n_actions: int = N_ACTIONS) -> NDArray[np.float64]:
    """State rewards (..., S) repeated over actions: (..., S, A), a new C-contiguous array.

    ``out[..., s, a] = rewards[..., s]``, the layout the learners take (``R[s, a]``). The
    functions taking rewards also accept (S,) and (n, S) state rewards directly; this explicit
    form is needed only for n == S tasks on an MDP with ``A == S``, where an (S, S) array
    would be read as one (S, A) reward.

    Parameters
    ----------
    rewards : array_like, shape (..., S)
    n_actions : int, default=5
        ``A`` (Objectworld has 5 actions).

    Returns
    -------
    ndarray of float64, shape (..., S, A)
    """
    r = np.asarray(rewards, dtype=np.float64)
    if r.ndim == 0:
        raise ValidationError(f"rewards must have shape (S,) or (n, S); got a scalar {rewards!r}")
    check_int(n_actions, "n_actions", minimum=1)
    return np.repeat(r[..., None], int(n_actions), axis=-1)

"""The tasks of a fit: one shared MDP or one per task, their reward features and demonstrations, set up once.

Every learner entry point (``GradIRL.fit``, ``FactIRL.fit``, ``FactIRL.transfer``,
``MultiIntentIRL.fit``, :func:`~factirl_opt.fit_factorial`,
:func:`~factirl_opt.transfer_coefficients`) starts with :func:`task_set`, which reads
``(mdp or mdps, demos, features, reward)`` once, validates it once and returns a
:class:`TaskSet`. What differs between the two layouts of tasks is a method of that type, not a
branch at the call sites:

- *one environment*: every task on one MDP object with one feature matrix (or tabular or state
  rewards): ``TaskSet.mdp`` is that MDP, ``features`` None, an (S*A, p) matrix or a
  :class:`~factirl_opt.tasks.features.StateBroadcast`; ``fit([m] * n, ...)`` with one object
  ``m`` takes this path, bit for bit the one of ``fit(m, ...)``;
- *several environments*: one MDP per task, or one feature matrix per task (docs/maths.md §7):
  ``TaskSet.mdps`` lists them and ``features`` is their
  :class:`~factirl_opt.tasks.features.TaskFeatures`.

The objective is bound later by the learners (:func:`factirl_opt.learners.fitting.make_objective`),
after their own hyper-parameters are checked: a TaskSet holds data only.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._validation import check_features, check_mdp
from ..exceptions import ValidationError
from ..mdp.environments import check_environments
from ..mdp.tabular import TabularMDP
from .features import StateBroadcast, TaskFeatures, weights_rewards

__all__ = ["TaskSet", "task_set", "environment_tasks", "REWARDS", "reward_features", "reward_dimension", "per_task_features",
           "features_digest", "environment_signatures"]


#: what a learner's reward depends on: ``"state-action"`` R(s, a), or ``"state"`` r(s) broadcast over actions
REWARDS = ("state-action", "state")


def reward_features(mdp: Any, features: Any = None, reward: str = "state-action",
                    min_columns: int = 1) -> np.ndarray | StateBroadcast | None:
    """What a learner's rewards are linear in: ``R_i = Phi theta_i`` (docs/maths.md §7).

    Parameters
    ----------
    mdp : TabularMDP
    features : array_like, shape (S*A, p) or (S, p), optional
    reward : {"state-action", "state"}
        ``"state"``: one reward per state, repeated over the actions (p = S), at the cost of
        tabular rewards; only without ``features``.
    min_columns : int
        Smallest accepted number of features.

    Returns
    -------
    None, StateBroadcast or ndarray of shape (S*A, p)
        None for tabular rewards (p = S*A); ``kron(I_S, 1_A)`` unformed for ``reward="state"``;
        else the validated features (state features repeated over the actions).
    """
    if not isinstance(reward, str) or reward not in REWARDS:
        raise ValidationError(f"reward must be one of {', '.join(map(repr, REWARDS))}; got {reward!r}")
    if reward == "state":
        if features is not None:
            raise ValidationError(
                f"reward='state' learns one free reward per state and takes no features (got features of shape "
                f"{np.shape(features)}); for rewards of the states on features pass state features (S, p) with "
                "reward='state-action'")
        return StateBroadcast(mdp.n_states, mdp.n_actions)
    if features is None:
        return None
    return check_features(features, mdp.n_params, mdp.n_states, min_columns=min_columns)


def features_digest(features: np.ndarray | None) -> str | None:
    """SHA-256 (hex) of validated base features (S*A, p) as float64, shape included; None without.

    Two feature matrices have the same digest exactly when they have the same shape and the
    same values bit for bit.
    """
    if features is None:
        return None
    F = np.ascontiguousarray(features, dtype=np.float64)
    h = hashlib.sha256(repr(F.shape).encode())
    h.update(F.tobytes())
    return h.hexdigest()


def reward_dimension(mdp: Any, features: Any) -> int:
    """p, the number of reward parameters per task: ``S*A`` (tabular), or the features' columns."""
    if isinstance(features, TaskFeatures):
        return features.n_features
    return mdp.n_params if features is None else features.shape[1]


def per_task_features(features: Any) -> bool:
    """Whether ``features`` is one matrix per task (a sequence of 2-d arrays, or a 3-d array)."""
    if isinstance(features, np.ndarray):
        return features.ndim == 3
    return (isinstance(features, Sequence) and not isinstance(features, (str, bytes)) and len(features) > 0
            and np.ndim(features[0]) == 2)


def _n_tasks(demos_per_task: Any) -> int | None:
    try:
        return len(demos_per_task)
    except TypeError:
        return None


def one_environment(mdp: Any, demos_per_task: Any, features: Any) -> Any:
    """The MDP of a fit whose tasks all share one MDP object and one feature matrix (or none), else None.

    That fit runs the one-MDP code path, so ``fit([mdp] * n, ...)`` with the same object is
    ``fit(mdp, ...)`` bit for bit. Anything that is neither a TabularMDP nor a sequence is
    returned as is, for the one-MDP path to refuse.
    """
    if per_task_features(features):
        return None
    if isinstance(mdp, TabularMDP) or not isinstance(mdp, Sequence) or isinstance(mdp, (str, bytes)):
        return mdp
    mdps = check_environments(mdp, _n_tasks(demos_per_task))
    return mdps[0] if all(m is mdps[0] for m in mdps) else None


def _task_features(mdps: list, features: Any, reward: str, min_columns: int) -> tuple[TaskFeatures, str | None]:
    if reward != "state-action":
        raise ValidationError(f"reward={reward!r} learns one free reward per state of one MDP; tasks in several "
                              "environments need features (pass state features (S_i, p) per task instead)")
    if features is None:
        raise ValidationError(
            "tasks in several environments need features (one shared (S*A, p) matrix, or one (S_i*A, p) or (S_i, p) "
            "matrix per task): tabular rewards are defined on one MDP")
    S = [m.n_states for m in mdps]
    if per_task_features(features):
        tf = TaskFeatures(list(features), S, mdps[0].n_actions)
        digest = None
    else:
        F = check_features(features, mdps[0].n_params, mdps[0].n_states, min_columns=min_columns)
        bad = [i for i, s in enumerate(S) if s != S[0]]
        if bad:
            raise ValidationError(f"one shared feature matrix ({np.shape(features)}) cannot fit every environment: task 0 "
                                  f"has S = {S[0]} states, task {bad[0]} has {S[bad[0]]}; give one feature matrix per task")
        tf, digest = TaskFeatures([F] * len(mdps), S, mdps[0].n_actions), features_digest(F)
    if tf.n_features < min_columns:
        raise ValidationError(f"features must have p >= {min_columns} columns; got p = {tf.n_features}")
    return tf, digest


def environment_signatures(mdps: Sequence[TabularMDP]) -> list[dict]:
    """One :meth:`TabularMDP.signature` per task (computed once per distinct MDP object)."""
    seen: dict[int, dict] = {}
    for m in mdps:
        if id(m) not in seen:
            seen[id(m)] = m.signature()
    return [dict(seen[id(m)]) for m in mdps]


@dataclasses.dataclass(frozen=True)
class TaskSet:
    """The tasks of one fit or transfer, validated (built by :func:`task_set`).

    Attributes
    ----------
    demos_per_task : list of n task demonstrations
        As given (parsed when the objective is bound to them).
    features : None, ndarray (S*A, p), StateBroadcast or TaskFeatures
        What the rewards are linear in: ``R_i = Phi_i w_i`` (None: tabular, ``w_i = R_i``).
    mdp : TabularMDP or None
        The one MDP every task shares (one environment), else None.
    mdps : list of n TabularMDP or None
        One MDP per task (several environments), else None.
    digest : str or None
        :func:`features_digest` of the features a model records (``features_sha256_``): of
        the one shared matrix given, None for tabular or state rewards and per-task features.
    """

    demos_per_task: Any
    features: Any
    mdp: TabularMDP | None
    mdps: list[TabularMDP] | None
    digest: str | None

    @property
    def shared(self) -> bool:
        """Whether every task shares one MDP object and one feature matrix (one environment)."""
        return self.mdp is not None

    @property
    def n_params(self) -> int:
        """p, the reward parameters per task (``S*A`` for tabular rewards)."""
        return reward_dimension(self.mdp, self.features)

    def rewards(self, weights: NDArray[np.float64]) -> NDArray[np.float64] | list[NDArray[np.float64]]:
        """Rewards ``R_i = Phi_i w_i`` of weights (n, p): (n, S, A), or a list of (S_i, A) arrays."""
        if self.mdp is None:
            return self.features.rewards(weights)
        return weights_rewards(self.features, weights, self.mdp.n_states, self.mdp.n_actions)

    def signature(self) -> dict | list[dict]:
        """What a model records as ``mdp_signature_``: the MDP's signature, or one per task."""
        if self.mdp is None:
            return environment_signatures(self.mdps or [])
        return self.mdp.signature()


def task_set(mdp: Any, demos_per_task: Any, features: Any = None, reward: str = "state-action",
             min_columns: int = 1) -> TaskSet:
    """The tasks of a fit from ``(mdp or mdps, demos, features, reward)``, validated once.

    Parameters
    ----------
    mdp : TabularMDP or sequence of n TabularMDP
        One MDP shared by every task, or one per task (the same number of actions; tasks given
        the same object are planned as one batch).
    demos_per_task : list of n task demonstrations
        Each an int array (m, L, 2) or a list of (L_j, 2) episodes, on its task's MDP.
    features : array_like, or sequence of n array_like, optional
        One (S*A, p) or (S, p) matrix shared by every task, or one (S_i*A, p) or (S_i, p)
        matrix per task (the same p). None: tabular (or state) rewards, on one MDP only.
    reward : {"state-action", "state"}
        ``"state"``: one free reward per state of one MDP (no features).
    min_columns : int, default=1
        Smallest accepted p.

    Returns
    -------
    TaskSet

    Raises
    ------
    ValidationError
        For an MDP that is not a TabularMDP, a wrong count of MDPs or feature matrices,
        numbers of actions that differ, features that do not fit their task's MDP or have
        fewer than ``min_columns`` columns, several environments without features, or
        ``reward="state"`` with features (each naming the task).
    """
    one = one_environment(mdp, demos_per_task, features)
    if one is not None:
        check_mdp(one)
        F = reward_features(one, features, reward, min_columns)
        digest = features_digest(F) if isinstance(F, np.ndarray) else None  # of the matrix given, not of a StateBroadcast
        return TaskSet(demos_per_task, F, one, None, digest)
    return environment_tasks(mdp, demos_per_task, features, reward, min_columns)


def environment_tasks(mdp: Any, demos_per_task: Any, features: Any, reward: str = "state-action",
                      min_columns: int = 1) -> TaskSet:
    """The tasks as several environments, whatever their MDPs: :func:`task_set`'s second layout.

    For a transfer to new environments, whose tasks are planned on their own maps even when
    one MDP object is given for all of them. Parameters and errors as in :func:`task_set`.
    """
    n = _n_tasks(demos_per_task)
    if n is None:
        raise ValidationError(f"demos_per_task must be a list with one entry per task; got {type(demos_per_task).__name__}")
    mdps = check_environments(mdp, n)
    tf, digest = _task_features(mdps, features, reward, min_columns)
    return TaskSet(demos_per_task, tf, None, mdps, digest)


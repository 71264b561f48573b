"""The tasks of a fit: one shared MDP or one per task, their reward features and demonstrations, set up once.

Every learner entry point (``GradIRL.fit``, ``FactIRL.fit``, ``FactIRL.transfer``,
``MultiIntentIRL.fit``, :func:`~factirl_opt.fit_factorial`,
:func:`~factirl_opt.transfer_coefficients`) starts with :func:`task_set`, which reads
``(mdp or mdps, demos, features, reward)`` once, validates it once and returns a
:class:`TaskSet`. What differs between the two layouts of tasks is a method of that type, not a
branch at the call sites:

- *one environment*: every task on one MDP object with one feature matrix (or tabular or state
  rewards): ``TaskSet.mdp`` is that MDP and ``basis`` a shared
  :class:`~factirl_opt.tasks.basis.RewardBasis` (tabular, state or one matrix);
  ``fit([m] * n, ...)`` with one object ``m`` takes this path, bit for bit the one of
  ``fit(m, ...)``;
- *several environments*: one MDP per task, or one feature matrix per task (docs/maths.md §7):
  ``TaskSet.mdps`` lists them and ``basis`` is a :class:`~factirl_opt.tasks.basis.TaskBasis`.

Whatever the features, the fit's reward model is ``TaskSet.basis``: the code below the
estimators never asks which kind it is. The objective is bound later by the learners
(:func:`factirl_opt.learners.fitting.task_objective`), after their own hyper-parameters are
checked: a TaskSet holds data only (its demonstrations parsed once, with their statistics).
:meth:`TaskSet.subset` gives the task set of some of its tasks (validation folds, held-out tasks).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._validation import check_features, check_mdp
from ..exceptions import ValidationError
from ..mdp.environments import check_environments
from ..mdp.tabular import TabularMDP
from .demonstrations import environment_demonstrations, environment_statistics, step_statistics
from .trajectories import TaskDemonstrations, parse_demonstrations
from .basis import RewardBasis, SharedBasis, StateBasis, TabularBasis, TaskBasis, check_basis, matrix_digest
from .features import StateBroadcast, TaskFeatures

__all__ = ["TaskSet", "task_set", "environment_tasks", "REWARDS", "reward_features", "reward_basis", "reward_dimension",
           "per_task_features", "features_per_task", "features_digest", "environment_signatures", "transfer_task_set",
           "parameter_matrix", "refuse_features_digest"]


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
    return matrix_digest(features)


def reward_basis(mdp: Any, features: Any = None, reward: str = "state-action", min_columns: int = 1) -> RewardBasis:
    """The :class:`~factirl_opt.tasks.basis.RewardBasis` of a learner's ``features`` and ``reward``
    parameters on one MDP (validated as :func:`reward_features` does; a basis given as
    ``features`` is checked against the MDP and taken as it is)."""
    if isinstance(features, RewardBasis):
        return _given_basis(features, [mdp.n_states], mdp.n_actions, reward, min_columns)
    F = reward_features(mdp, features, reward, min_columns)
    if F is None:
        return TabularBasis(mdp.n_states, mdp.n_actions)
    if isinstance(F, StateBroadcast):
        return StateBasis(mdp.n_states, mdp.n_actions)
    return SharedBasis(F, mdp.n_states, mdp.n_actions)


def reward_dimension(mdp: Any, features: Any) -> int:
    """p, the number of reward parameters per task: ``S*A`` (tabular), or the features' columns."""
    if isinstance(features, RewardBasis):
        return features.n_params
    if isinstance(features, TaskFeatures):
        return features.n_features
    return mdp.n_params if features is None else int(np.shape(features)[1])


def parameter_matrix(mdp: Any, features: Any = None) -> NDArray[np.float64]:
    """``Phi`` of a public ``features`` parameter as a dense (S*A, p) matrix: the identity for None
    (tabular rewards, p = S*A), else the validated (S*A, p) features."""
    return np.eye(mdp.n_params) if features is None else check_features(features, mdp.n_params)


def per_task_features(features: Any) -> bool:
    """Whether ``features`` is one matrix per task (a sequence of 2-d arrays, or a 3-d array)."""
    if isinstance(features, np.ndarray):
        return features.ndim == 3
    return (isinstance(features, Sequence) and not isinstance(features, (str, bytes)) and len(features) > 0
            and np.ndim(features[0]) == 2)


def features_per_task(features: Any, n: int) -> list[Any]:
    """A public ``features`` parameter for ``n`` tasks as one entry per task: None (tabular) or the
    one matrix repeated, or the per-task matrices (their count checked against ``n``)."""
    if per_task_features(features):
        feats = list(features)
        if len(feats) != n:
            raise ValidationError(f"features must be one matrix or one per new task ({n}); got {len(feats)}")
        return feats
    return [features] * n


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
    if per_task_features(features) or (isinstance(features, RewardBasis) and not features.shared):
        return None
    if isinstance(mdp, TabularMDP) or not isinstance(mdp, Sequence) or isinstance(mdp, (str, bytes)):
        return mdp
    mdps = check_environments(mdp, _n_tasks(demos_per_task))
    return mdps[0] if all(m is mdps[0] for m in mdps) else None


def _given_basis(basis: RewardBasis, n_states: list, n_actions: int, reward: str, min_columns: int) -> RewardBasis:
    """A :class:`~factirl_opt.tasks.basis.RewardBasis` given as ``features``, checked against the environments."""
    if reward != "state-action":
        raise ValidationError(f"reward={reward!r} learns one free reward per state and takes no features (got a "
                              f"{type(basis).__name__})")
    check_basis(basis)
    basis.check_environments(n_states, n_actions)
    if basis.n_params < min_columns:
        raise ValidationError(f"features must have p >= {min_columns} columns; got p = {basis.n_params}")
    return basis


def _task_features(mdps: list, features: Any, reward: str, min_columns: int) -> tuple[RewardBasis, str | None]:
    if reward != "state-action":
        raise ValidationError(f"reward={reward!r} learns one free reward per state of one MDP; tasks in several "
                              "environments need features (pass state features (S_i, p) per task instead)")
    if features is None:
        raise ValidationError(
            "tasks in several environments need features (one shared (S*A, p) matrix, or one (S_i*A, p) or (S_i, p) "
            "matrix per task): tabular rewards are defined on one MDP")
    S = [m.n_states for m in mdps]
    if isinstance(features, RewardBasis):
        basis = _given_basis(features, S, mdps[0].n_actions, reward, min_columns)
        return basis, basis.digest()
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
    return TaskBasis(tf, digest), digest


def environment_signatures(mdps: Sequence[TabularMDP]) -> list[dict]:
    """One :meth:`TabularMDP.signature` per task (computed once per distinct MDP object)."""
    seen: dict[int, dict] = {}
    for m in mdps:
        if id(m) not in seen:
            seen[id(m)] = m.signature()
    return [dict(seen[id(m)]) for m in mdps]


@dataclasses.dataclass(frozen=True)
class TaskSet:
    """The tasks of one fit or transfer, validated, their demonstrations parsed once (built by :func:`task_set`).

    Attributes
    ----------
    demos_per_task : list of n task demonstrations
        As given.
    basis : RewardBasis
        What the rewards are linear in: ``R_i = Phi_i w_i`` (:mod:`factirl_opt.tasks.basis`;
        tabular rewards are a basis too).
    mdp : TabularMDP or None
        The one MDP every task shares (one environment), else None.
    mdps : list of n TabularMDP or None
        One MDP per task (several environments), else None.
    digest : str or None
        :func:`features_digest` of the features a model records (``features_sha256_``): of
        the one shared matrix given, None for tabular or state rewards and per-task features.
    demonstrations : list of n TaskDemonstrations
        Parsed on each task's MDP when the task set is made (errors name the task, episode and step).
    mu_hat, pi_hat : ndarray (n, S) and (n, S, A), or lists of n arrays (S_i,) and (S_i, A)
        Their statistics (eq. 5), which every objective, held-out score and posterior of the tasks binds.
    """

    demos_per_task: Any
    basis: RewardBasis
    mdp: TabularMDP | None
    mdps: list[TabularMDP] | None
    digest: str | None
    demonstrations: Any = dataclasses.field(default=None, repr=False, compare=False)  # list of TaskDemonstrations
    mu_hat: Any = dataclasses.field(init=False, repr=False, compare=False)
    pi_hat: Any = dataclasses.field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        one, parsed = self.mdp, self.demonstrations
        if parsed is None:
            parsed = (parse_demonstrations(self.demos_per_task, one.n_states, one.n_actions) if one is not None
                      else environment_demonstrations(self.mdps, self.demos_per_task)[1])
        stats = (step_statistics(parsed, one.n_states, one.n_actions) if one is not None
                 else environment_statistics(self.mdps or [], parsed))
        for name, value in zip(("demonstrations", "mu_hat", "pi_hat"), (parsed, *stats)):
            object.__setattr__(self, name, value)  # frozen: set once, here

    @property
    def shared(self) -> bool:
        """Whether every task shares one MDP object and one feature matrix (one environment)."""
        return self.mdp is not None

    @property
    def n_params(self) -> int:
        """p, the reward parameters per task (``S*A`` for tabular rewards)."""
        return self.basis.n_params

    @property
    def n_tasks(self) -> int:
        """n, the number of tasks."""
        return len(self.demos_per_task)

    def rewards(self, weights: NDArray[np.float64]) -> NDArray[np.float64] | list[NDArray[np.float64]]:
        """Rewards ``R_i = Phi_i w_i`` of weights (n, p): (n, S, A), or a list of (S_i, A) arrays."""
        return self.basis.rewards(weights)

    @property
    def n_pairs(self) -> NDArray[np.float64]:
        """``N_i`` (n,), the demonstrated (state, action) pairs of each task."""
        return np.array([len(task.steps) for task in self.demonstrations], dtype=np.float64)

    def subset(self, rows: Any) -> TaskSet:
        """The task set of tasks ``rows`` only (in that order): their demonstrations, MDPs and basis
        rows (validation folds, held-out tasks).

        Raises
        ------
        ValidationError
            For rows that are not task indices.
        """
        idx = np.asarray(rows).reshape(-1)
        if idx.size == 0 or idx.dtype.kind not in "iu" or idx.min() < 0 or idx.max() >= self.n_tasks:
            raise ValidationError(f"rows must be a nonempty list of task indices in [0, {self.n_tasks}); got {np.asarray(rows).tolist()}")
        demos = [self.demos_per_task[int(i)] for i in idx]
        mdps = None if self.mdps is None else [self.mdps[int(i)] for i in idx]
        return TaskSet(demos, self.basis.subset(idx), self.mdp, mdps, self.digest, [self.demonstrations[int(i)] for i in idx])

    def episodes(self, start: int, stop: int | None = None) -> TaskSet:
        """The same tasks (environments and basis) with episodes ``start:stop`` of each task's
        demonstrations only (e.g. the first to transfer a held-out task from, the others to score it on)."""
        demos = [task[start:stop] for task in self.demos_per_task]
        return TaskSet(demos, self.basis, self.mdp, self.mdps, self.digest,
                       [task.episode_range(start, stop) for task in self.demonstrations])

    def signature(self) -> dict | list[dict]:
        """What a model records as ``mdp_signature_``: the MDP's signature, or one per task."""
        if self.mdp is None:
            return environment_signatures(self.mdps or [])
        return self.mdp.signature()


def task_set(mdp: Any, demos_per_task: Any, features: Any = None, reward: str = "state-action",
             min_columns: int = 1, parsed: list[TaskDemonstrations] | None = None) -> TaskSet:
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
    parsed : list of n TaskDemonstrations, optional
        The demonstrations already parsed by the caller (who named them in its own messages).

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
        basis = reward_basis(one, features, reward, min_columns)
        return TaskSet(demos_per_task, basis, one, None, basis.digest(), parsed)
    return environment_tasks(mdp, demos_per_task, features, reward, min_columns, parsed)


def environment_tasks(mdp: Any, demos_per_task: Any, features: Any, reward: str = "state-action",
                      min_columns: int = 1, parsed: list[TaskDemonstrations] | None = None) -> TaskSet:
    """The tasks as several environments, whatever their MDPs: :func:`task_set`'s second layout.

    For a transfer to new environments, whose tasks are planned on their own maps even when
    one MDP object is given for all of them. Parameters and errors as in :func:`task_set`.
    """
    n = _n_tasks(demos_per_task)
    if n is None:
        raise ValidationError(f"demos_per_task must be a list with one entry per task; got {type(demos_per_task).__name__}")
    mdps = check_environments(mdp, n)
    basis, digest = _task_features(mdps, features, reward, min_columns)
    return TaskSet(demos_per_task, basis, None, mdps, digest, parsed)



def _transfer_mdp(mdp: Any, demos_per_task: Any, fitted: Any, signature: Any) -> Any:
    """The one MDP of a transfer on the one-MDP path (no features given), else None.

    ``mdp`` itself when it is not a sequence (the one-MDP path checks it); a sequence of one
    MDP object (``[m] * n_new``, as in ``fit``); or, for a model fitted without features on
    one MDP, a sequence of MDPs that each have that MDP's saved signature (equal models).
    """
    one = one_environment(mdp, demos_per_task, None)
    if one is not None or fitted is not None:
        return one
    mdps = check_environments(mdp)  # their count is checked against the demonstrations' by the one-MDP path
    return mdps[0] if isinstance(signature, dict) and all(m.signature() == signature for m in mdps) else None


def transfer_task_set(mdp: Any, demos_per_task: Any, features: Any, fitted_features: Any, *,
                      reward: str = "state-action", signature: Any = None, digest: Any = None, check_digest: bool = False,
                      min_columns: int = 1, what: str = "this FactIRL model") -> TaskSet:
    """The new tasks of a fitted model's transfer, checked against what the model was fitted on.

    Parameters
    ----------
    mdp : TabularMDP or sequence of n_new TabularMDP
    demos_per_task : list of n_new task demonstrations
    features : array_like or sequence of n_new array_like, or None
        The new environments' features (one shared matrix, or one per new task); None: the
        model's own.
    fitted_features : the model's ``features`` parameter (None: tabular or state rewards)
    reward : {"state-action", "state"}
        The model's.
    signature : dict, list of dict or None
        The model's ``mdp_signature_``.
    digest : str or None
        The model's ``features_sha256_``, checked when ``check_digest``.
    min_columns : int
        The model's number of primitives (smallest accepted p).

    Returns
    -------
    TaskSet
        On the one-MDP path (no ``features``; the model's own MDP, one object or a sequence of
        MDPs equal to it) the model's basis on that MDP, whose signature is checked; else the
        new tasks in their own environments (:func:`environment_tasks`).

    Raises
    ------
    ValidationError
        Another MDP than the one of a model fitted on one MDP without ``features``; tabular
        or state rewards carried to other environments (they live on the states of the
        model's MDP); features missing for a model fitted with per-task features; environments
        with another number of actions; the model's shared features changed since ``fit``.
    """
    from ..mdp.tabular import check_signature

    per_task = per_task_features(fitted_features)
    given = features is not None
    one = None if given or per_task else _transfer_mdp(mdp, demos_per_task, fitted_features, signature)
    if one is not None:  # the one-MDP path: ``[m] * n_new`` of one MDP is ``m``, as in ``fit``
        check_mdp(one)
        if isinstance(signature, dict):  # a list: fitted on several environments
            check_signature(signature, one, what)
        basis = reward_basis(one, fitted_features, reward, min_columns)
        if check_digest:
            _check_digest(digest, basis, fitted_features is not None, what)
        return TaskSet(demos_per_task, basis, one, None, basis.digest())
    if fitted_features is None:
        raise ValidationError(f"{what} was fitted without features (tabular rewards): its dictionary lives on the states "
                              "of its MDP, so it transfers only to that MDP, without features")
    if not given and per_task:
        raise ValidationError(f"{what} was fitted with one feature matrix per task: transfer to new environments needs "
                              "their features (features=[one (S_i*A, p) or (S_i, p) per new task])")
    tasks = environment_tasks(mdp, demos_per_task, features if given else fitted_features)
    n_actions = signature["n_actions"] if isinstance(signature, dict) else signature[0]["n_actions"] if signature else None
    new_actions = tasks.mdps[0].n_actions if tasks.mdps else None
    if n_actions is not None and new_actions != n_actions:
        raise ValidationError(f"the new tasks' environments have {new_actions} actions, but the model was fitted with "
                              f"{n_actions}")
    if check_digest and not given and digest != tasks.digest:
        raise ValidationError(f"{what} was fitted with other features than the ones set now (sha256 "
                              f"{str(tasks.digest)[:12]}... instead of {str(digest)[:12]}...): restore them or fit again")
    return tasks


def _check_digest(expected: str | None, basis: RewardBasis, has_features: bool, what: str) -> None:
    """Refuse model features other than those it was fitted with (digest ``expected``)."""
    actual = basis.digest() if has_features else None
    if actual != expected:
        refuse_features_digest(expected, actual, np.shape(basis.dense()[0]) if has_features else None, what)


def refuse_features_digest(expected: str | None, actual: str | None, shape: tuple[int, ...] | None, what: str) -> None:
    """Raise the refusal of features whose digest ``actual`` (of an array of ``shape``, None
    without features) is not ``expected``, the digest of the features ``what`` was fitted with."""
    if expected is None:
        raise ValidationError(f"{what} was fitted without features, but features of shape {shape} are set now")
    if actual is None:
        raise ValidationError(f"{what} was fitted with features (sha256 {expected[:12]}...), but features=None now")
    raise ValidationError(
        f"{what} was fitted with other features than the ones set now (shape {shape}, sha256 "
        f"{actual[:12]}... instead of {expected[:12]}...): the dictionary only means something on the features it was "
        "learnt with; restore those features or fit again"
    )

"""Tasks in many environments at the public scoring, sampling and planning functions.

:func:`~factirl_opt.score`, :func:`~factirl_opt.optimal_score`, :func:`~factirl_opt.deviation`,
:func:`~factirl_opt.soft_deviation`, :func:`~factirl_opt.sample_demonstrations` and
:func:`~factirl_opt.optimal_q` take either one :class:`~factirl_opt.mdp.TabularMDP` shared by
every task (the task axis of the rewards) or a sequence of n MDPs, one per task, all with the
same number of actions ``A``. With a sequence, task ``i``'s reward is an (S_i, A) state-action
or an (S_i,) state reward on its own MDP, given either as a list of n such arrays or as one
stacked (n, S, A) or (n, S) array when every ``S_i`` equals ``S``.

Tasks given the *same MDP object* form a group (:func:`~factirl_opt.objectives.environments.group_tasks`):
each group is one call of the single-MDP function on the group's stacked rewards, and the
results are put back in task order. A sequence of n references to one MDP is therefore one
call on the stacked rewards, bit for bit; tasks on distinct MDPs give exactly the results of
one call per environment.

Per-task outputs are stacked arrays when every environment has the same number of states and
lists of per-task arrays otherwise (each function documents its own). :func:`feature_rewards`
evaluates feature weights on environments of any size, e.g. a learnt reward on maps where no
demonstration was given (docs/maths.md §7, §9).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeGuard

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import check_array, check_rewards
from .exceptions import FactIRLError, ValidationError
from .mdp import TabularMDP
from .task_features import TaskFeatures

__all__ = ["is_environment_sequence", "environments", "task_rewards", "one_for_all", "per_task_values", "by_environment",
           "assemble", "feature_rewards"]


def is_environment_sequence(mdp: Any) -> TypeGuard[Sequence[TabularMDP]]:
    """Whether ``mdp`` is a sequence of per-task MDPs (a list or tuple, not one model)."""
    return not isinstance(mdp, TabularMDP) and isinstance(mdp, Sequence) and not isinstance(mdp, (str, bytes))


def environments(mdps: Sequence[TabularMDP], n_tasks: int | None = None) -> list[TabularMDP]:
    """The validated list of per-task MDPs (one home: :func:`~factirl_opt.objectives.environments.check_environments`)."""
    from .objectives.environments import check_environments  # the objectives import this package's samplers

    return check_environments(mdps, n_tasks)


def _task_items(values: Any, name: str, n: int) -> list[Any]:
    """The n per-task entries of a list or a stacked array (leading task axis)."""
    if isinstance(values, np.ndarray):
        if values.ndim == 0:
            raise ValidationError(f"{name} must hold one entry per task ({n}); got a 0-d array")
        items = list(values)
    elif isinstance(values, Sequence) and not isinstance(values, (str, bytes)):
        items = list(values)
    else:
        raise ValidationError(f"{name} must be a list of one array per task or a stacked array; got {type(values).__name__}")
    if len(items) != n:
        raise ValidationError(f"{name} describes {len(items)} tasks but {n} MDPs were given (one per task)")
    return items


def task_rewards(mdps: Sequence[TabularMDP], rewards: Any, name: str = "rewards") -> list[NDArray[np.float64]]:
    """Task ``i``'s reward as a validated float64 (S_i, A) array on its own MDP, for every task.

    Parameters
    ----------
    mdps : list of n TabularMDP
        From :func:`environments`.
    rewards : sequence of n array_like, or ndarray of shape (n, S, A) or (n, S)
        Each (S_i, A), or (S_i,) repeated over the actions.

    Raises
    ------
    ValidationError
        For a wrong count, or a task whose reward does not fit its MDP (naming the task).
    """
    items = _task_items(rewards, name, len(mdps))
    out = []
    for i, (mdp, r) in enumerate(zip(mdps, items)):
        label = f"{name}[{i}] (task {i}, S = {mdp.n_states})"
        if np.ndim(r) not in (1, 2):
            raise ValidationError(f"{label} must be one reward of shape (S_i, A) = ({mdp.n_states}, {mdp.n_actions}) or "
                                  f"(S_i,) = ({mdp.n_states},); got shape {np.shape(r)}")
        R, single = check_rewards(mdp, r, label)
        if not single:
            raise ValidationError(f"{label} must be one reward of shape (S_i, A) = ({mdp.n_states}, {mdp.n_actions}) or "
                                  f"(S_i,) = ({mdp.n_states},); got shape {np.shape(r)}")
        out.append(R[0])
    return out


def one_for_all(value: Any) -> bool:
    """Whether an optional argument is None or a scalar (e.g. one start state for every task)."""
    return value is None or np.isscalar(value) or (isinstance(value, np.ndarray) and value.ndim == 0)


def per_task_values(mdps: Sequence[TabularMDP], values: Any, name: str) -> list[Any] | None:
    """Per-task entries of an optional per-task argument (e.g. start distributions), or None."""
    if values is None:
        return None
    return _task_items(values, name, len(mdps))


def by_environment(mdps: Sequence[TabularMDP], call: Callable[..., Any], per_task: dict[str, list[Any] | None]) -> list[Any]:
    """``call(mdp, **stacked)`` once per distinct MDP object; each task's result, in task order.

    Parameters
    ----------
    mdps : list of n TabularMDP
    call : callable
        ``call(mdp, **kwargs)`` returning per-task results on its leading axis (an array or a
        list), or a tuple of such.
    per_task : dict of name -> list of n entries, or None
        Stacked over each group's tasks (np.stack) and passed by name; None is passed as is.

    Returns
    -------
    list of n results
        Task ``i``'s entry of the result (a tuple of entries when ``call`` returns a tuple).

    Raises
    ------
    ValidationError, FactIRLError
        From ``call``; with several groups, the message is prefixed with the group's tasks.
    """
    from .objectives.environments import group_tasks  # the objectives import this package's samplers

    group_mdps, task_group, _ = group_tasks(mdps)
    out: list[Any] = [None] * len(mdps)
    for g, mdp in enumerate(group_mdps):
        tasks = np.flatnonzero(task_group == g)
        kwargs = {k: None if v is None else np.stack([np.asarray(v[t]) for t in tasks]) for k, v in per_task.items()}
        try:
            res = call(mdp, **kwargs)
        except FactIRLError as exc:
            if len(group_mdps) == 1:
                raise
            raise type(exc)(f"tasks {tasks.tolist()} (one MDP, S = {mdp.n_states}; a task number below counts within "
                            f"these): {exc}") from exc
        for j, t in enumerate(tasks):
            out[t] = tuple(part[j] for part in res) if isinstance(res, tuple) else res[j]
    return out


def assemble(mdps: Sequence[TabularMDP], values: list[Any]) -> NDArray[Any] | list[Any]:
    """Per-task arrays stacked when every MDP has the same number of states, else the list."""
    if len({m.n_states for m in mdps}) > 1:
        return list(values)
    return np.stack(values)


def _feature_list(features: Any, n: int) -> list[Any]:
    """n per-task feature matrices: one shared 2-d matrix repeated, or the n given."""
    if isinstance(features, np.ndarray):
        if features.ndim != 3:
            return [check_array(features, "features", ndim=2)] * n
        shared = False
    elif isinstance(features, Sequence) and not isinstance(features, (str, bytes)) and len(features) > 0:
        shared = np.ndim(features[0]) != 2
    else:
        raise ValidationError(f"features must be one (S, p) or (S*A, p) matrix or a sequence of one per task; "
                              f"got {type(features).__name__}")
    if shared:
        return [check_array(features, "features", ndim=2)] * n
    if len(features) != n:
        raise ValidationError(f"got {len(features)} feature matrices for {n} tasks (the rows of weights): give one per "
                              "task, or one shared matrix")
    return list(features)


def feature_rewards(features: ArrayLike | Sequence[ArrayLike], weights: ArrayLike,
                    mdps: TabularMDP | Sequence[TabularMDP] | None = None) -> NDArray[np.float64] | list[NDArray[np.float64]]:
    """Rewards ``R_i = Phi_i w_i`` of feature weights, on the tasks' own or on new environments.

    The way to score a reward learnt on features where no demonstration was given
    (docs/maths.md §7, §9)::

        fo.deviation(new_mdps, true_rewards, fo.feature_rewards(new_features, model.weights_, new_mdps))

    Parameters
    ----------
    features : array_like (S, p) or (S*A, p), or sequence of n array_like (S_i, p) or (S_i*A, p)
        One matrix shared by every task, or one per task (rows ``s`` for state features, rows
        ``s * A + a`` for state-action features); the same p columns everywhere.
    weights : array_like, shape (n, p)
        Row ``i`` weights task ``i``'s features (e.g. a flat learner's ``weights_``, or ``D h_i``).
    mdps : TabularMDP or sequence of n TabularMDP, optional
        The environments the rewards are for: they give ``A`` and check each ``S_i``. Without
        them, the rows of every matrix are states (state features only).

    Returns
    -------
    rewards : ndarray or list of ndarray
        With ``mdps``: (n, S, A) when every task has S states, else a list of n (S_i, A)
        arrays. Without: state rewards (n, S), or a list of n (S_i,) arrays, which every
        scoring function repeats over the actions.

    Raises
    ------
    ValidationError
        For weights that are not (n, p) with n >= 1, a wrong number of matrices or MDPs,
        features whose rows or columns do not fit, or rewards that overflow float64 (naming
        the task).
    """
    W = check_array(weights, "weights", ndim=2)
    n = W.shape[0]
    if n == 0:
        raise ValidationError(f"weights must have shape (n, p) with n >= 1 (one row per task); got {W.shape}")
    F = _feature_list(features, n)
    if mdps is None:
        rows = [np.shape(f)[0] for f in F]
        if 0 in rows:
            raise ValidationError(f"features of task {rows.index(0)} have no rows (shape {np.shape(F[rows.index(0)])}); "
                                  "give one row per state")
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported below, naming the task
            R = _check_overflow(TaskFeatures(F, rows, 1).rewards(W), F, W)
        return [r[:, 0] for r in R] if isinstance(R, list) else R[:, :, 0]
    envs = environments([mdps] * n if isinstance(mdps, TabularMDP) else mdps, n)
    with np.errstate(over="ignore", invalid="ignore"):
        return _check_overflow(TaskFeatures(F, [m.n_states for m in envs], envs[0].n_actions).rewards(W), F, W)


def _check_overflow(R: Any, F: list[Any], W: NDArray[np.float64]) -> Any:
    """``R`` (an array or a list of per-task arrays), or a ValidationError naming the first task whose rewards overflow."""
    for i, r in enumerate(R):
        if not np.all(np.isfinite(r)):
            raise ValidationError(
                f"the rewards features @ weights of task {i} overflow float64 (largest |features| entry "
                f"{np.max(np.abs(np.asarray(F[i], dtype=float))):.3g}, largest |weights[{i}]| entry {np.max(np.abs(W[i])):.3g}): "
                "rescale the features or the weights towards order 1")
    return R

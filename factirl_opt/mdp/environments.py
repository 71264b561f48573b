"""Tasks in many environments at the public scoring, sampling and planning functions.

:func:`~factirl_opt.score`, :func:`~factirl_opt.optimal_score`, :func:`~factirl_opt.deviation`,
:func:`~factirl_opt.soft_deviation`, :func:`~factirl_opt.sample_demonstrations` and
:func:`~factirl_opt.optimal_q` take either one :class:`~factirl_opt.mdp.tabular.TabularMDP` shared by
every task (the task axis of the rewards) or a sequence of n MDPs, one per task, all with the
same number of actions ``A``. With a sequence, task ``i``'s reward is an (S_i, A) state-action
or an (S_i,) state reward on its own MDP, given either as a list of n such arrays or as one
stacked (n, S, A) or (n, S) array when every ``S_i`` equals ``S``.

Tasks given the *same MDP object* form a group (:func:`group_tasks`):
each group is one call of the single-MDP function on the group's stacked rewards, and the
results are put back in task order. A sequence of n references to one MDP is therefore one
call on the stacked rewards, bit for bit; tasks on distinct MDPs give exactly the results of
one call per environment. In this library an *environment* is always one MDP on which tasks are demonstrated.

Per-task outputs are stacked arrays when every environment has the same number of states and
lists of per-task arrays otherwise (each function documents its own).
:func:`~factirl_opt.tasks.features.feature_rewards`
evaluates feature weights on environments of any size, e.g. a learnt reward on maps where no
demonstration was given (docs/maths.md §7, §9).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeGuard

import numpy as np
from numpy.typing import NDArray

from .._validation import check_rewards
from ..exceptions import FactIRLError, ValidationError
from .tabular import TabularMDP

__all__ = ["is_environment_sequence", "check_task_rewards", "check_environments", "group_tasks", "one_for_all", "per_task_values", "by_environment",
           "assemble"]


def is_environment_sequence(mdp: Any) -> TypeGuard[Sequence[TabularMDP]]:
    """Whether ``mdp`` is a sequence of per-task MDPs (a list or tuple, not one model)."""
    return not isinstance(mdp, TabularMDP) and isinstance(mdp, Sequence) and not isinstance(mdp, (str, bytes))


def check_environments(mdps: TabularMDP | Sequence[TabularMDP], n_tasks: int | None = None) -> list[TabularMDP]:
    """One :class:`TabularMDP` per task, all with the same number of actions.

    Parameters
    ----------
    mdps : TabularMDP or sequence of TabularMDP
        One MDP shared by every task (needs ``n_tasks``), or one MDP per task.
    n_tasks : int, optional
        The number of tasks the MDPs must describe.

    Returns
    -------
    mdps : list of n TabularMDP

    Raises
    ------
    ValidationError
        For a wrong count, an entry that is not a TabularMDP, or a number of actions that
        differs from task 0's (naming the task).
    """
    if isinstance(mdps, TabularMDP):
        if n_tasks is None:
            raise ValidationError("one shared MDP needs the number of tasks; pass a sequence of one MDP per task")
        return [mdps] * int(n_tasks)
    if isinstance(mdps, (str, bytes)) or not isinstance(mdps, Sequence) or len(mdps) == 0:
        raise ValidationError(f"mdps must be a TabularMDP or a non-empty sequence of TabularMDP (one per task); got {type(mdps).__name__}")
    if n_tasks is not None and len(mdps) != n_tasks:
        raise ValidationError(f"got {len(mdps)} MDPs for {n_tasks} tasks: give one MDP per task (or one shared MDP)")
    out = []
    for i, mdp in enumerate(mdps):
        if not isinstance(mdp, TabularMDP):
            raise ValidationError(f"mdps[{i}] (task {i}) must be a TabularMDP; got {type(mdp).__name__}")
        if mdp.n_actions != mdps[0].n_actions:
            raise ValidationError(
                f"every environment must have the same number of actions: task {i} has {mdp.n_actions}, task 0 has "
                f"{mdps[0].n_actions}"
            )
        out.append(mdp)
    return out


def group_tasks(mdps: Sequence[TabularMDP]) -> tuple[list[TabularMDP], NDArray[np.intp], NDArray[np.intp]]:
    """Group tasks by MDP object (identity), groups in order of first appearance.

    Returns
    -------
    group_mdps : list of TabularMDP
        The distinct MDP objects.
    task_group : ndarray of intp, shape (n,)
        The group of each task.
    local_index : ndarray of intp, shape (n,)
        Each task's position within its group (the row of the group's objective).
    """
    index: dict[int, int] = {}
    group_mdps: list[TabularMDP] = []
    sizes: list[int] = []
    task_group = np.empty(len(mdps), dtype=np.intp)
    local_index = np.empty(len(mdps), dtype=np.intp)
    for i, mdp in enumerate(mdps):
        g = index.setdefault(id(mdp), len(group_mdps))
        if g == len(group_mdps):
            group_mdps.append(mdp)
            sizes.append(0)
        task_group[i], local_index[i] = g, sizes[g]
        sizes[g] += 1
    return group_mdps, task_group, local_index


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


def check_task_rewards(mdps: Sequence[TabularMDP], rewards: Any, name: str = "rewards") -> list[NDArray[np.float64]]:
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

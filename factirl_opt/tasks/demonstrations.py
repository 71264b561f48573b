"""Expert demonstrations: sampling a greedy expert and the empirical statistics of eq. (5).

A demonstration (episode) is a sequence of (state, action) pairs. The demonstrations of one
task are either an int array of shape (m, L, 2) (m episodes of equal length L), or a list of
episodes of any lengths, each array-like of shape (L_j, 2) or a trajectory from another
library (``obs``/``acts``). ``demos_per_task`` is a list with one such entry per task (one
task is a list of one), never a list of episodes; the layouts and their one parser are in
:mod:`factirl_opt.tasks.trajectories`.
"""

from __future__ import annotations

import os
import threading
import typing
import weakref

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._threads import blas_limited
from .._validation import RNGLike, as_rng, check_bool, check_int, check_mdp, check_rewards, check_start
from ..exceptions import ValidationError
from ..planning import get_planner, plan
from ..mdp.environments import (
    by_environment, check_environments, is_environment_sequence, one_for_all, per_task_values,
    check_task_rewards,
)
from .trajectories import TaskDemonstrations, parse_demonstrations, parse_task, task_steps

from collections.abc import Sequence

from ..mdp.tabular import TabularMDP  # at run time too: typing.get_type_hints resolves the annotations

__all__ = ["sample_demonstrations", "empirical_statistics", "task_steps", "step_statistics", "environment_demonstrations",
           "environment_statistics"]

#: Cache of :func:`row_cdfs`, owned by this module: MDP -> (cum, succ). Keys are held weakly,
#: so an entry lives exactly as long as its MDP; nothing is stored on the MDP itself (which is
#: immutable and pickles without it). Guarded by ``_ROW_CDFS_LOCK``.
_ROW_CDFS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_ROW_CDFS_LOCK = threading.Lock()


def _after_fork_in_child() -> None:
    """A forked child gets a free lock (another thread may have held it at the fork)."""
    global _ROW_CDFS_LOCK
    _ROW_CDFS_LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def _build_row_cdfs(mdp: TabularMDP) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    P = mdp.csr()
    nnz = np.diff(P.indptr)
    K = int(nnz.max())
    pos = np.arange(K)[None, :]
    take = P.indptr[:-1, None] + np.minimum(pos, nnz[:, None] - 1)
    vals = np.where(pos < nnz[:, None], P.data[take], 0.0)
    cum, succ = np.cumsum(vals, axis=1), P.indices[take].astype(np.int64)
    cum.setflags(write=False)
    succ.setflags(write=False)
    return cum, succ


def row_cdfs(mdp: TabularMDP) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Cumulative successor probabilities of every (s, a) row, padded; cached per MDP.

    Returns ``cum`` (S*A, K) and ``succ`` (S*A, K), read-only: row ``s * A + a`` lists the K
    (at most) successors of (s, a) in increasing state order with their cumulative
    probabilities, padded with the row's last successor and cumulative value. Summing only the
    nonzero entries in state order gives exactly the dense cumulative sums (adding a zero is
    exact), so sampling is the same for a dense and a sparse copy of a model. Memory is
    (S*A, K): linear in S for sparse dynamics with few successors per row.

    The cache belongs to this module (a lock-protected ``weakref.WeakKeyDictionary`` keyed by
    the MDP, safe to use from several threads): an entry is built on first use and freed with
    its MDP. Two threads asking at once may both build it; the first stored is kept (they are
    equal).
    """
    with _ROW_CDFS_LOCK:
        cached = _ROW_CDFS.get(mdp)
    if cached is None:
        built = _build_row_cdfs(mdp)
        with _ROW_CDFS_LOCK:
            cached = _ROW_CDFS.setdefault(mdp, built)
    return cached


def _start_states(start: int | NDArray[np.float64] | None, n: int, m: int, S: int,
                  rng: np.random.Generator) -> NDArray[np.int64]:
    """(n, m) start states drawn as :func:`sample_demonstrations` documents."""
    if start is None or (not isinstance(start, int) and np.all(start == 1.0 / S)):
        return rng.integers(0, S, size=(n, m))  # uniform: the draw of every release so far
    if isinstance(start, int):
        return np.full((n, m), start, dtype=np.int64)
    cum = np.cumsum(start, axis=1)
    u = rng.random((n, m)) * cum[:, -1:]  # rows sum to 1 within START_SUM_TOL; scale out the rest
    states = np.stack([np.searchsorted(cum[i], u[i], side="right") for i in range(n)])
    last = S - 1 - np.argmax(start[:, ::-1] > 0, axis=1)  # the last state of positive probability
    return np.minimum(states, last[:, None]).astype(np.int64)


def _sample_per_environment(mdps: Sequence[TabularMDP], rewards: typing.Any, rng: np.random.Generator,
                            start: typing.Any, return_final_states: bool, **kwargs: typing.Any) -> typing.Any:
    """:func:`sample_demonstrations` over tasks in many environments, one call per distinct MDP."""
    envs = check_environments(mdps)
    per_task: dict[str, list[typing.Any] | None] = {"rewards": check_task_rewards(envs, rewards, "rewards")}
    fixed = {"start": start} if one_for_all(start) else {}  # None, or one state for every task
    if not fixed:
        per_task["start"] = per_task_values(envs, start, "start")
    out = by_environment(
        envs, lambda m, **args: sample_demonstrations(m, rng=rng, return_final_states=True, **args, **fixed, **kwargs), per_task
    )
    demos = [d for d, _ in out]
    return (demos, np.stack([f for _, f in out])) if return_final_states else demos


@blas_limited
def sample_demonstrations(
    mdp: TabularMDP | Sequence[TabularMDP],
    rewards: ArrayLike,
    n_demos: int,
    length: int,
    rng: RNGLike = None,
    planner: str = "auto",
    start: int | ArrayLike | None = None,
    return_final_states: bool = False,
) -> list[NDArray[np.int64]] | tuple[list[NDArray[np.int64]], NDArray[np.int64]]:
    """Sample demonstrations of a greedy expert (docs/maths.md §2).

    For each task the expert acts greedily on its true ``Q*``; each demonstration starts in a
    state drawn from ``start`` (uniform by default) and follows the MDP's dynamics for
    ``length`` steps.

    With a sequence of MDPs, tasks given the same MDP object are sampled by one call on that
    MDP, the calls made in order of each MDP's first task and drawing from the one ``rng`` in
    turn; so the demonstrations equal those of one call per distinct MDP with the same
    generator, and n references to one MDP give exactly the demonstrations of that MDP.

    Parameters
    ----------
    mdp : TabularMDP or sequence of n TabularMDP
        One MDP shared by every task, or one per task (the same number of actions).
    rewards : array_like, shape (n, S, A), (S, A), (n, S) or (S,)
        The tasks' true rewards; state rewards (n, S) or (S,) (e.g. from
        :func:`~factirl_opt.datasets.objectworld.multitask_rewards`) are repeated over the actions. A
        2-d array of shape (S, A) is always one (S, A) reward: on an MDP with ``A == S``, pass
        S state rewards as (S, S, A) (:func:`~factirl_opt.datasets.objectworld.state_action_rewards`).
        With a sequence of MDPs: a list of n arrays, task ``i``'s (S_i, A) or (S_i,), or a
        stacked (n, S, A) or (n, S) array when every ``S_i`` is S.
    n_demos : int
        Demonstrations per task, m >= 1.
    length : int
        Steps per demonstration, L >= 1.
    rng : numpy.random.Generator or int or SeedSequence or None
    planner : str, default="auto"
        Planner of the expert's ``Q*`` (see :func:`factirl_opt.available_planners`).
    start : None, int, or array_like of shape (S,) or (n, S), default=None
        Start states. None: uniform over the states (the draws of earlier releases, so the same
        ``rng`` gives the same demonstrations); a uniform vector draws exactly as None. An int:
        every episode starts in that state (no random draw). A probability vector (S,): the
        start distribution of every task; (n, S): one per task. Probabilities must be
        nonnegative and sum to 1; states of probability 0 are never drawn. With a sequence
        of MDPs: None, an int (a state of every environment), or one distribution per task
        (a list of n (S_i,) arrays, or stacked (n, S)).
    return_final_states : bool, default=False
        Also return the state reached after the last action of each demonstration (the final
        observation that trajectory formats such as imitation's ``Trajectory`` carry). Drawing
        it consumes no extra random numbers: the samples are the same either way.

    Returns
    -------
    demos_per_task : list of n ndarrays of int64, each of shape (m, L, 2)
        ``demos[i][j, t] = (state, action)`` at step t of demonstration j of task i (states
        of task i's own MDP); a list also for a sequence of MDPs.
    final_states : ndarray of int64, shape (n, m)
        Only with ``return_final_states=True``: ``final_states[i, j]`` is the state reached
        after the last action of demonstration j of task i.

    Raises
    ------
    ValidationError
        Naming the bad argument: rewards of an unknown shape, ``n_demos`` or ``length`` below
        1, a start state out of range, or a start distribution of the wrong shape, with a
        negative entry, or not summing to 1. With a sequence of MDPs: a wrong count of
        rewards or start distributions, a reward that does not fit its task's MDP, or a
        number of actions that differs from task 0's (naming the task).
    """
    if is_environment_sequence(mdp):
        return _sample_per_environment(mdp, rewards, as_rng(rng), start, check_bool(return_final_states, "return_final_states"),
                                       n_demos=n_demos, length=length, planner=planner)
    model: TabularMDP = check_mdp(mdp)
    R, _ = check_rewards(model, rewards)
    n_demos = check_int(n_demos, "n_demos", minimum=1)
    length = check_int(length, "length", minimum=1)
    return_final_states = check_bool(return_final_states, "return_final_states")
    rng = as_rng(rng)
    n, S, A = R.shape
    start_p = check_start(start, n, S)
    policy = plan(get_planner(model, planner), R).policy
    cum, nxt_state = row_cdfs(model)
    out = np.empty((n, n_demos, length, 2), dtype=np.int64)
    states = _start_states(start_p, n, n_demos, S, rng)
    task = np.arange(n)[:, None]
    for t in range(length):
        actions = policy[task, states]
        out[:, :, t, 0] = states
        out[:, :, t, 1] = actions
        u = rng.random((n, n_demos, 1))
        rows = states * A + actions
        k = (u > cum[rows]).sum(axis=2)  # successors whose cumulative probability is below u
        states = nxt_state[rows, np.minimum(k, cum.shape[1] - 1)]  # guard: a cdf ending just below 1
    demos = [out[i] for i in range(n)]
    return (demos, states.astype(np.int64)) if return_final_states else demos


def empirical_statistics(mdp: TabularMDP, demos_per_task: typing.Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Empirical state frequencies and policies of each task (the hats of eq. 5).

    ``mu_hat(s)`` is the visit frequency of state s over all steps of the task's demonstrations;
    ``pi_hat(a|s)`` is the frequency of action a among the visits of s, and 0 in unvisited
    states (which carry weight ``mu_hat(s) = 0``).

    Parameters
    ----------
    mdp : TabularMDP
    demos_per_task : list of n task demonstrations, or ndarray (n, m, L, 2)
        Each an int array (m, L, 2) or a list of episodes, each (L_j, 2) (state, action)
        pairs or a trajectory with integer ``obs`` and ``acts`` (see
        :mod:`factirl_opt.tasks.trajectories`; a list of episodes without the task wrapper is
        refused, the message shows the two layouts it could mean).

    Returns
    -------
    mu_hat : ndarray, shape (n, S)
        Rows sum to 1.
    pi_hat : ndarray, shape (n, S, A)
        Rows of visited states sum to 1; rows of unvisited states are 0.
    """
    check_mdp(mdp)
    return step_statistics(parse_demonstrations(demos_per_task, mdp.n_states, mdp.n_actions), mdp.n_states, mdp.n_actions)


def step_statistics(tasks: Sequence[TaskDemonstrations], S: int, A: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`empirical_statistics` of demonstrations already parsed: ``mu_hat`` (n, S), ``pi_hat`` (n, S, A)."""
    n = len(tasks)
    counts = np.zeros((n, S * A))
    for i, task in enumerate(tasks):
        steps = task.steps
        counts[i] = np.bincount(steps[:, 0] * A + steps[:, 1], minlength=S * A)
    per_pair = counts.reshape(n, S, A)
    visits = per_pair.sum(axis=2)
    mu_hat = visits / visits.sum(axis=1, keepdims=True)
    pi_hat = np.divide(per_pair, visits[:, :, None], out=np.zeros_like(per_pair), where=visits[:, :, None] > 0)
    return mu_hat, pi_hat


def environment_demonstrations(mdps: typing.Any, demos_per_task: typing.Any) -> tuple[list, list[TaskDemonstrations]]:
    """The environments of n tasks (:func:`~factirl_opt.mdp.environments.check_environments`) and their
    demonstrations, each parsed on its own task's MDP (errors name the task, episode and step)."""
    if isinstance(demos_per_task, np.ndarray) and demos_per_task.ndim == 4:
        demos_per_task = list(demos_per_task)
    if not isinstance(demos_per_task, Sequence) or isinstance(demos_per_task, (str, bytes)):
        raise ValidationError(f"demos_per_task must be a list with one entry per task; got {type(demos_per_task).__name__}")
    envs = check_environments(mdps, len(demos_per_task))
    return envs, [parse_task(mdp, demos, task=i) for i, (mdp, demos) in enumerate(zip(envs, demos_per_task))]


def environment_statistics(mdps: Sequence[TabularMDP], tasks: Sequence[TaskDemonstrations]) -> tuple[list, list]:
    """Each task's :func:`step_statistics` on its own MDP: lists of n arrays (S_i,) and (S_i, A)."""
    pairs = [step_statistics([task], mdp.n_states, mdp.n_actions) for mdp, task in zip(mdps, tasks)]
    return [mu[0] for mu, _ in pairs], [pi[0] for _, pi in pairs]

"""Expert demonstrations: sampling a greedy expert and the empirical statistics of eq. (5).

A demonstration (episode) is a sequence of (state, action) pairs. The demonstrations of one
task are either an int array of shape (m, L, 2) (m episodes of equal length L), or a list of
episodes of any lengths, each array-like of shape (L_j, 2) or a trajectory from another
library (``obs``/``acts``). ``demos_per_task`` is a list with one such entry per task (one
task is a list of one), never a list of episodes; the layouts and their one parser are in
:mod:`factirl_opt.trajectories`.
"""

import numpy as np

from ._threads import blas_limited
from ._validation import as_rng, check_int, check_mdp, check_rewards
from .planning import get_planner, plan
from .trajectories import parse_demonstrations, task_steps

__all__ = ["sample_demonstrations", "empirical_statistics", "task_steps"]


def _row_cdfs(mdp):
    """Cumulative successor probabilities of every (s, a) row, padded, cached on the MDP.

    Returns ``cum`` (S*A, K) and ``succ`` (S*A, K): row ``s * A + a`` lists the K (at most)
    successors of (s, a) in increasing state order with their cumulative probabilities, padded
    with the row's last successor and cumulative value. Summing only the nonzero entries in
    state order gives exactly the dense cumulative sums (adding a zero is exact), so sampling
    is the same for a dense and a sparse copy of a model. Memory is (S*A, K): linear in S for
    sparse dynamics with few successors per row.
    """
    cache = mdp.__dict__.get("_row_cdfs")
    if cache is None:
        P = mdp.csr()
        nnz = np.diff(P.indptr)
        K = int(nnz.max())
        pos = np.arange(K)[None, :]
        take = P.indptr[:-1, None] + np.minimum(pos, nnz[:, None] - 1)
        vals = np.where(pos < nnz[:, None], P.data[take], 0.0)
        cache = (np.cumsum(vals, axis=1), P.indices[take].astype(np.int64))
        mdp.__dict__["_row_cdfs"] = cache
    return cache


@blas_limited
def sample_demonstrations(mdp, rewards, n_demos, length, rng=None, planner="auto"):
    """Sample demonstrations of a greedy expert (DESIGN section 2).

    For each task the expert acts greedily on its true ``Q*``; each demonstration starts in a
    uniformly random state and follows the MDP's dynamics for ``length`` steps.

    Parameters
    ----------
    mdp : TabularMDP
    rewards : array_like, shape (S, A) or (n, S, A)
        The tasks' true rewards.
    n_demos : int
        Demonstrations per task, m >= 1.
    length : int
        Steps per demonstration, L >= 1.
    rng : numpy.random.Generator or int or None
    planner : str, default="auto"
        Planner of the expert's ``Q*`` (see :func:`factirl_opt.available_planners`).

    Returns
    -------
    demos_per_task : list of n ndarrays of int64, each of shape (m, L, 2)
        ``demos[i][j, t] = (state, action)`` at step t of demonstration j of task i.
    """
    check_mdp(mdp)
    R, _ = check_rewards(mdp, rewards)
    n_demos = check_int(n_demos, "n_demos", minimum=1)
    length = check_int(length, "length", minimum=1)
    rng = as_rng(rng)
    n, S, A = R.shape
    policy = plan(get_planner(mdp, planner), R).policy
    cum, nxt_state = _row_cdfs(mdp)
    out = np.empty((n, n_demos, length, 2), dtype=np.int64)
    states = rng.integers(0, S, size=(n, n_demos))
    task = np.arange(n)[:, None]
    for t in range(length):
        actions = policy[task, states]
        out[:, :, t, 0] = states
        out[:, :, t, 1] = actions
        u = rng.random((n, n_demos, 1))
        rows = states * A + actions
        k = (u > cum[rows]).sum(axis=2)  # successors whose cumulative probability is below u
        states = nxt_state[rows, np.minimum(k, cum.shape[1] - 1)]  # guard: a cdf ending just below 1
    return [out[i] for i in range(n)]


def empirical_statistics(mdp, demos_per_task):
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
        :mod:`factirl_opt.trajectories`; a list of episodes without the task wrapper is
        refused, the message shows the two layouts it could mean).

    Returns
    -------
    mu_hat : ndarray, shape (n, S)
        Rows sum to 1.
    pi_hat : ndarray, shape (n, S, A)
        Rows of visited states sum to 1; rows of unvisited states are 0.
    """
    check_mdp(mdp)
    S, A = mdp.n_states, mdp.n_actions
    tasks = parse_demonstrations(demos_per_task, S, A)
    n = len(tasks)
    counts = np.zeros((n, S * A))
    for i, task in enumerate(tasks):
        steps = task.steps
        counts[i] = np.bincount(steps[:, 0] * A + steps[:, 1], minlength=S * A)
    counts = counts.reshape(n, S, A)
    visits = counts.sum(axis=2)
    mu_hat = visits / visits.sum(axis=1, keepdims=True)
    pi_hat = np.divide(counts, visits[:, :, None], out=np.zeros_like(counts), where=visits[:, :, None] > 0)
    return mu_hat, pi_hat

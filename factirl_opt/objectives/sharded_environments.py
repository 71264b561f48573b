"""Tasks in several environments evaluated over shards of whole environments.

A :class:`~factirl_opt.objectives.environments.MultiEnvironmentObjective` plans each group of
tasks sharing one MDP object as one batch and counts one evaluation per group and call.
:class:`ShardedEnvironments` gives every group wholly to one shard (groups dealt to the
least-loaded shard, largest first), and each shard keeps a ``MultiEnvironmentObjective`` over
its groups on its worker (:mod:`factirl_opt.parallel.shards`). A group is planned exactly as in the
unsharded objective (the same tasks in the same order), so losses and gradients agree, and
the evaluations, summed over the shards, are counted by the same rule. Rewards and gradients
travel per task (stacked, or lists for environments of different sizes); Gauss-Newton
Jacobians in reduced form (:func:`.distributed.reduced_least_squares`); residuals padded to
the largest ``S_i * A`` as in the unsharded objective (docs/maths.md §5).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from solvers import Linearization

from ..parallel.shards import Shards
from ..planning.budget import budget_options
from .distributed import ShardedBase, reduced_least_squares
from .environments import MultiEnvironmentObjective

__all__ = ["EnvironmentShardState", "ShardedEnvironments", "deal_groups"]


def deal_groups(task_group: NDArray[np.intp], n_shards: int) -> list[NDArray[np.intp]]:
    """Tasks of each shard (sorted) when whole groups are dealt, largest first, to the least-loaded shard."""
    sizes = np.bincount(task_group)
    load, owner = np.zeros(n_shards, dtype=np.intp), np.empty(len(sizes), dtype=np.intp)
    for g in sorted(range(len(sizes)), key=lambda g: (-sizes[g], g)):
        owner[g] = int(np.argmin(load))
        load[owner[g]] += sizes[g]
    return [tasks for k in range(n_shards) if (tasks := np.flatnonzero(owner[task_group] == k)).size]


def _take(arrays: Any, pos: NDArray[np.intp]) -> Any:
    """Rows ``pos`` of per-task arrays (stacked, or a list)."""
    return arrays[pos] if isinstance(arrays, np.ndarray) else [arrays[j] for j in pos]


class EnvironmentShardState:
    """A shard's ``MultiEnvironmentObjective`` over its groups; evaluating calls return their evaluation count."""

    def __init__(self, mdps: list, mu_hat: list, pi_hat: list, beta: float, cls: type, planner: Any,
                 planner_options: dict | None = None) -> None:
        self.objective = MultiEnvironmentObjective(mdps, mu_hat, pi_hat, beta, cls, planner, planner_options)
        self.linearizations: dict[int, Linearization] = {}

    def _counted(self, fn: Any, *args: Any) -> tuple:
        before = self.objective.n_evaluations
        return fn(*args), self.objective.n_evaluations - before

    def loss_and_grad(self, R: Any, rows: NDArray[np.intp]) -> tuple:
        return self._counted(self.objective.loss_and_grad, R, rows)

    def residual_jacobian(self, R: Any, rows: NDArray[np.intp], features: Any) -> tuple:
        (loss, residual, jacobian), n = self._counted(self.objective.residual_jacobian, R, rows, features)
        return (loss, *reduced_least_squares(residual, jacobian)), n

    def linearize(self, R: Any, rows: NDArray[np.intp], token: int) -> tuple:
        lin, n = self._counted(self.objective.linearize, R, rows)
        self.linearizations = {t: v for t, v in self.linearizations.items() if t > token - 4}
        self.linearizations[token] = lin
        return (lin.loss, lin.residual), n

    def product(self, token: int, name: str, X: Any) -> Any:
        return getattr(self.linearizations[token], name)(X)

    def reset(self) -> None:
        self.objective.reset()
        self.linearizations.clear()


class ShardedEnvironments(ShardedBase):
    """A :class:`MultiEnvironmentObjective`'s environments evaluated shard by shard (see the module docstring).

    Parameters
    ----------
    objective : MultiEnvironmentObjective
    n_shards : int
        At most the number of groups are used.
    backend, client
        As for :class:`~factirl_opt.parallel.shards.Shards`.
    planner : str
        The planner name the objective was built with (``"auto"`` resolves per environment).
    """

    n_evaluations = 0  # counted per instance

    def __init__(self, objective: MultiEnvironmentObjective, n_shards: int, backend: str = "processes",
                 client: Any = None, planner: Any = "auto") -> None:
        src = objective
        self.name, self.least_squares, self.mdp = src.name, src.least_squares, src.mdp
        self.n_tasks, self.ragged, self.n_residuals, self.n_evaluations = src.n_tasks, src.ragged, src.n_residuals, 0
        self.n_states, self.n_actions = src.n_states, src.n_actions
        self._limit = src.reward_limit()
        self.parts = deal_groups(src.task_group, n_shards)
        self.owner = np.empty(self.n_tasks, dtype=np.intp)
        self.local = np.empty(self.n_tasks, dtype=np.intp)
        for k, tasks in enumerate(self.parts):
            self.owner[tasks], self.local[tasks] = k, np.arange(tasks.size)
        cls, beta = type(src.objectives[0]), src.objectives[0].beta
        options = budget_options(src.objectives[0])  # every group's objective has the same planner options

        def stats(i):
            obj = src.objectives[src.task_group[i]]
            return obj.mu[src.local_index[i]], obj.pi_hat[src.local_index[i]]

        specs = [(EnvironmentShardState, ([src.mdps[i] for i in tasks], [stats(i)[0] for i in tasks],
                                          [stats(i)[1] for i in tasks], beta, cls, planner, options))
                 for tasks in self.parts]
        self.shards = Shards(specs, backend, client, serve_while_starting=True)  # every call passes on_restart
        self._token = 0
        self._lins: dict[int, tuple] = {}  # token -> (rewards, rows): linearised again on a rebuilt shard

    def reward_limit(self) -> float:
        """The largest ``|reward|`` planned without overflow on every task's MDP (:func:`limit_of`)."""
        return self._limit

    def rebuilt(self, k: int) -> None:
        """A rebuilt shard ``k`` linearises its tasks again at the kept points (its state was lost)."""
        for token, (R, rows) in sorted(self._lins.items()):
            pos = np.flatnonzero(self.owner[rows] == k)
            if pos.size:
                self.shards.handles[k].submit("linearize", (_take(R, pos), self.local[rows[pos]], token))
                self.shards.handles[k].result()

    def _split(self, rows: NDArray[np.intp]) -> list[tuple[int, NDArray[np.intp]]]:
        owners = self.owner[rows]
        return [(k, pos) for k in range(self.n_shards) if (pos := np.flatnonzero(owners == k)).size]

    def _map(self, method: str, R: Any, rows: ArrayLike | None, *extra: Any,
             per_row: Any = None) -> tuple[NDArray[np.intp], list, list]:
        rows = np.arange(self.n_tasks) if rows is None else np.asarray(rows, dtype=np.intp)
        split = self._split(rows)
        calls = [(k, method, (_take(R, pos), self.local[rows[pos]], *extra,
                              *(() if per_row is None else (per_row(pos),)))) for k, pos in split]
        out = self.shards.call(calls, on_restart=self.rebuilt)
        self.n_evaluations += sum(n for _, n in out)
        return rows, split, [res for res, _ in out]

    def _tasks(self, rows: NDArray[np.intp], split: list, parts: list) -> Any:
        """Per-task arrays of the shards placed in row order: a list when ragged, else stacked."""
        out: Any = [None] * len(rows)
        for (_, pos), part in zip(split, parts):
            for j, p in enumerate(pos):
                out[p] = part[j]
        return out if self.ragged else np.stack(out)

    def _padded(self, split: list, parts: list, n: int) -> NDArray[np.float64]:
        first = np.asarray(parts[0])
        out = np.zeros((n, self.n_residuals, *first.shape[2:]))
        for (_, pos), part in zip(split, parts):
            out[pos, : np.shape(part)[1]] = part
        return out

    def loss_and_grad(self, rewards: Any, rows: ArrayLike | None = None) -> tuple:
        """As :meth:`MultiEnvironmentObjective.loss_and_grad`."""
        idx, split, out = self._map("loss_and_grad", rewards, rows)
        loss = np.empty(len(idx))
        for (_, pos), (lo, _) in zip(split, out):
            loss[pos] = lo
        return loss, self._tasks(idx, split, [g for _, g in out])

    def residual_jacobian(self, rewards: Any, rows: ArrayLike | None, features: Any) -> tuple:
        """Loss (r,) and the reduced residuals (r, p+1) and Jacobians (r, p+1, p) of
        :meth:`MultiEnvironmentObjective.residual_jacobian` (the same normal equations)."""
        shared = isinstance(features, np.ndarray) and features.ndim == 2
        extra = (features,) if shared else ()
        idx, split, out = self._map("residual_jacobian", rewards, rows, *extra,
                                     per_row=None if shared else (lambda pos: _take(features, pos)))
        n = len(idx)
        loss, res = np.empty(n), np.empty((n, *np.shape(out[0][1])[1:]))
        jac = np.empty((n, *np.shape(out[0][2])[1:]))
        for (_, pos), (lo, r, J) in zip(split, out):
            loss[pos], res[pos], jac[pos] = lo, r, J
        return loss, res, jac

    def linearize(self, rewards: Any, rows: ArrayLike | None = None) -> Linearization:
        """As :meth:`MultiEnvironmentObjective.linearize`, products on the shards."""
        self._token += 1
        token = self._token
        rows = np.arange(self.n_tasks) if rows is None else np.asarray(rows, dtype=np.intp)
        self._lins = {t: v for t, v in self._lins.items() if t > token - 4}
        self._lins[token] = (rewards, rows)
        idx, split, out = self._map("linearize", rewards, rows, token)
        loss = np.empty(len(idx))
        for (_, pos), (lo, _) in zip(split, out):
            loss[pos] = lo
        widths = [np.shape(r)[1] for _, r in out]
        residual = self._padded(split, [r for _, r in out], len(idx))

        def jvp(dR: Any) -> NDArray[np.float64]:
            parts = self.shards.call([(k, "product", (token, "jvp", _take(dR, pos))) for k, pos in split],
                                     on_restart=self.rebuilt)
            return self._padded(split, parts, len(idx))

        def vjp(U: ArrayLike) -> Any:
            U = np.asarray(U, dtype=np.float64)
            parts = self.shards.call([(k, "product", (token, "vjp", U[pos, :w])) for (k, pos), w in zip(split, widths)],
                                     on_restart=self.rebuilt)
            return self._tasks(idx, split, parts)

        return Linearization(loss, residual, jvp, vjp)

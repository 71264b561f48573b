"""An objective evaluated over task shards, each kept by a worker between evaluations.

The per-task work of an objective is independent given the rewards: planning, loss, adjoint
and Gauss-Newton products are per task, and every sum over tasks happens in the step problems
(docs/maths.md §5, §8). :class:`ShardedObjective` therefore composes per-shard sub-objectives,
as :class:`~factirl_opt.objectives.environments.MultiEnvironmentObjective` composes
per-environment ones: the tasks are cut into contiguous shards, and each shard's objective,
of the same registered class over the shard's tasks (renumbered 0..m-1), lives on a worker
(:mod:`factirl_opt.parallel`: this process for shard 0 and processes for the others, or Dask
actors). The worker keeps the MDP, the shard's statistics, its warm starts and its planner's
factorisations; per evaluation only the shard's rewards go in and its losses, gradients,
residuals and Jacobians (or Jacobian products) come out.

A sub-objective over a subset of the tasks makes, task by task, the computation of the whole
objective: the results agree with the unsharded objective to rounding (batched products may
round differently by batch size), and the number of evaluations is counted by the same rule
(one per batched call; a call at the last rewards is served from the last-point cache).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from solvers import Linearization

from ..parallel import Shards, contiguous_shards, effective_n_jobs
from ._base import Objective

__all__ = ["ShardState", "ShardedObjective", "sharded", "reduced_least_squares", "KEEP_LINEARIZATIONS"]

#: linearisations a shard keeps for Jacobian products (a Gauss-Newton CG step uses the latest few)
KEEP_LINEARIZATIONS = 4


def reduced_least_squares(residual: NDArray[np.float64], jacobian: NDArray[np.float64]) -> tuple:
    """Residuals (n, k+1) and Jacobians (n, k+1, k) with the normal equations of ``(residual, jacobian)``.

    ``[J_i r_i] = Q_i T_i`` (thin QR, ``T_i`` upper triangular (k+1, k+1)): ``J'_i = T_i[:, :k]``
    and ``r'_i = T_i[:, k]`` give ``J'^T J' = J^T J``, ``J'^T r' = J^T r`` and
    ``||r'||^2 = ||r||^2``, everything a Gauss-Newton step uses (docs/maths.md §5), in
    ``k+1`` rows per task instead of ``S*A``: what a shard sends back for the Gauss-Newton
    QP steps. Rows beyond ``m`` (a task with fewer residuals than k+1) are zeros.

    Parameters
    ----------
    residual : ndarray, shape (n, m)
    jacobian : ndarray, shape (n, m, k)
    """
    n, m, k = jacobian.shape
    T = np.linalg.qr(np.concatenate([jacobian, residual[:, :, None]], axis=2), mode="r")
    if T.shape[1] < k + 1:
        T = np.concatenate([T, np.zeros((n, k + 1 - T.shape[1], k + 1))], axis=1)
    return np.ascontiguousarray(T[:, :, k]), np.ascontiguousarray(T[:, :, :k])


class ShardState:
    """One shard's objective on its worker: a registered objective over the shard's tasks.

    Parameters
    ----------
    cls : type
        The :class:`~factirl_opt.objectives.Objective` subclass.
    mdp : TabularMDP
    mu_hat : ndarray, shape (m, S)
    pi_hat : ndarray, shape (m, S, A)
    beta : float
    planner : str
        A registered planner name.
    """

    def __init__(self, cls: type, mdp: Any, mu_hat: NDArray[np.float64], pi_hat: NDArray[np.float64], beta: float,
                 planner: str) -> None:
        self.objective = cls(mdp, mu_hat, pi_hat, beta, planner=planner)
        self.linearizations: dict[int, Linearization] = {}

    def loss_and_grad(self, R: NDArray[np.float64], rows: NDArray[np.intp]) -> tuple:
        return self.objective.loss_and_grad(R, rows)

    def residual_jacobian(self, R: NDArray[np.float64], rows: NDArray[np.intp], features: NDArray[np.float64]) -> tuple:
        """Loss and the :func:`reduced_least_squares` form of the residuals and Jacobian (k+1 rows per task)."""
        loss, residual, jacobian = self.objective.residual_jacobian(R, rows, features)
        return (loss, *reduced_least_squares(residual, jacobian))

    def linearize(self, R: NDArray[np.float64], rows: NDArray[np.intp], token: int) -> tuple:
        lin = self.objective.linearize(R, rows)
        self.linearizations[token] = lin
        for old in sorted(self.linearizations)[:-KEEP_LINEARIZATIONS]:
            del self.linearizations[old]
        return lin.loss, lin.residual

    def product(self, token: int, name: str, X: NDArray[np.float64]) -> NDArray[np.float64]:
        """``jvp`` or ``vjp`` (``name``) of the linearisation ``token`` applied to X."""
        return getattr(self.linearizations[token], name)(X)

    def reset(self) -> None:
        self.objective.reset()
        self.linearizations.clear()


class ShardedObjective:
    """An objective's tasks evaluated shard by shard on :class:`~factirl_opt.parallel.Shards`.

    Offers what the step problems use of an :class:`~factirl_opt.objectives.Objective`:
    ``loss_and_grad``, ``residual_jacobian``, ``linearize``, ``reset``, ``n_evaluations``,
    ``n_tasks``, ``mdp``, ``name`` and ``least_squares``.

    Parameters
    ----------
    objective : Objective
        The whole objective (its statistics are cut into the shards' specs; it is not evaluated).
    n_shards : int
    backend : {"processes", "dask"}
    client : dask.distributed.Client, optional
    planner : str, optional
        The planner name the shards use; default the objective's planner's name.

    Attributes
    ----------
    shards : Shards
        The backend (``bytes_sent``, ``n_restarts``).
    """

    def __init__(self, objective: Objective, n_shards: int, backend: str = "processes", client: Any = None,
                 planner: str | None = None) -> None:
        self.mdp, self.name, self.least_squares = objective.mdp, objective.name, objective.least_squares
        self.n_tasks, self.n_evaluations = objective.n_tasks, 0
        self.parts = contiguous_shards(self.n_tasks, n_shards)
        self.owner = np.empty(self.n_tasks, dtype=np.intp)
        self.local = np.empty(self.n_tasks, dtype=np.intp)
        for k, rows in enumerate(self.parts):
            self.owner[rows], self.local[rows] = k, np.arange(rows.size)
        name = objective.planner.name if planner is None else planner
        specs = [(ShardState, (type(objective), objective.mdp, objective.mu[rows], objective.pi_hat[rows],
                               objective.beta, name)) for rows in self.parts]
        self.shards = Shards(specs, backend, client)
        S, A = self.mdp.n_states, self.mdp.n_actions
        self._last_R = np.full((self.n_tasks, S, A), np.nan)
        self._last_loss, self._last_grad = np.zeros(self.n_tasks), np.zeros((self.n_tasks, S, A))
        self._token = 0
        self._replay: dict[int, tuple] = {}  # token -> (rewards, rows) to linearise a rebuilt shard again

    @property
    def n_shards(self) -> int:
        return len(self.parts)

    def close(self) -> None:
        """Stop the shards' workers."""
        self.shards.close()

    def reset(self) -> None:
        """As :meth:`Objective.reset`, on every shard."""
        self._last_R[:] = np.nan
        self._last_loss[:], self._last_grad[:] = 0.0, 0.0
        self._replay.clear()
        self.shards.call([(k, "reset", ()) for k in range(self.n_shards)])

    def _rows(self, rows: ArrayLike | None) -> NDArray[np.intp]:
        return np.arange(self.n_tasks) if rows is None else np.asarray(rows)

    def _split(self, rows: NDArray[np.intp]) -> list[tuple[int, NDArray[np.intp]]]:
        """``(shard, positions in rows)`` for every shard with tasks among ``rows``."""
        owners = self.owner[rows]
        return [(k, pos) for k in range(self.n_shards) if (pos := np.flatnonzero(owners == k)).size]

    def _map(self, method: str, R: NDArray[np.float64], rows: NDArray[np.intp], *extra: Any) -> tuple:
        """``method`` on every shard with rows; returns the splits and their results."""
        split = self._split(rows)
        out = self.shards.call([(k, method, (R[pos], self.local[rows[pos]], *extra)) for k, pos in split],
                               on_restart=self._relinearize)
        return split, out

    @staticmethod
    def _gather(split: list, parts: list, n: int) -> NDArray[np.float64]:
        first = np.asarray(parts[0])
        out = np.empty((n, *first.shape[1:]), dtype=first.dtype)
        for (_, pos), part in zip(split, parts):
            out[pos] = part
        return out

    def loss_and_grad(self, rewards: ArrayLike, rows: ArrayLike | None = None) -> tuple:
        """Loss per task (r,) and ``dJ/dR`` (r, S, A), as :meth:`Objective.loss_and_grad`."""
        rows = self._rows(rows)
        rewards = np.asarray(rewards, dtype=np.float64)
        if np.array_equal(self._last_R[rows], rewards):
            return self._last_loss[rows].copy(), self._last_grad[rows].copy()
        split, out = self._map("loss_and_grad", rewards, rows)
        self.n_evaluations += 1
        loss = self._gather(split, [o[0] for o in out], len(rows))
        grad = self._gather(split, [o[1] for o in out], len(rows))
        self._last_R[rows], self._last_loss[rows], self._last_grad[rows] = rewards, loss, grad
        return loss, grad

    def residual_jacobian(self, rewards: ArrayLike, rows: ArrayLike | None, features: ArrayLike) -> tuple:
        """Loss (r,), residuals (r, p+1) and Jacobian (r, p+1, p): the :func:`reduced_least_squares` form
        of :meth:`Objective.residual_jacobian`'s (the same Gauss-Newton steps; p+1 rows per task travel)."""
        rows = self._rows(rows)
        F = np.asarray(features, dtype=np.float64)
        split, out = self._map("residual_jacobian", np.asarray(rewards, dtype=np.float64), rows, F)
        self.n_evaluations += 1
        return tuple(self._gather(split, [o[j] for o in out], len(rows)) for j in range(3))

    def _relinearize(self, k: int) -> None:
        """A rebuilt shard ``k`` linearised again at the kept points (its linearisations were lost)."""
        for token, (R, rows) in sorted(self._replay.items()):
            pos = np.flatnonzero(self.owner[rows] == k)
            if pos.size:
                self.shards.handles[k].submit("linearize", (R[pos], self.local[rows[pos]], token))
                self.shards.handles[k].result()

    def linearize(self, rewards: ArrayLike, rows: ArrayLike | None = None) -> Linearization:
        """A :class:`solvers.Linearization` whose products run on the shards (:meth:`Objective.linearize`)."""
        rows = self._rows(rows)
        R = np.asarray(rewards, dtype=np.float64)
        self._token += 1
        token = self._token
        self._replay[token] = (R, rows)
        for old in sorted(self._replay)[:-KEEP_LINEARIZATIONS]:
            del self._replay[old]
        split, out = self._map("linearize", R, rows, token)
        self.n_evaluations += 1
        n = len(rows)
        loss, residual = (self._gather(split, [o[j] for o in out], n) for j in range(2))

        def product(name: str, X: ArrayLike) -> NDArray[np.float64]:
            X = np.asarray(X, dtype=np.float64)
            parts = self.shards.call([(k, "product", (token, name, X[pos])) for k, pos in split],
                                     on_restart=self._relinearize)
            return self._gather(split, parts, n)

        return Linearization(loss, residual, lambda dR: product("jvp", dR), lambda U: product("vjp", U))


@contextlib.contextmanager
def sharded(objective: Any, n_jobs: int | None = None, backend: str = "processes", client: Any = None,
            planner: Any = None) -> Iterator[Any]:
    """The objective evaluated over task shards while the block is open, its workers stopped after.

    Parameters
    ----------
    objective : Objective
    n_jobs : int or None
        Shards (:func:`factirl_opt.parallel.effective_n_jobs`: None is 1, -1 every core); with
        ``backend="dask"``, None or -1 is one shard per worker of ``client``.
    backend : {"processes", "dask"}
    client : dask.distributed.Client, optional
    planner : str, optional
        The planner name the shards use (default the objective's).

    Yields
    ------
    Objective or ShardedObjective
        ``objective`` itself when one shard is asked for (``n_jobs=1``: today's code path),
        inside a worker process, for a single task, and for objectives over several
        environments; else a :class:`ShardedObjective`, closed when the block exits (also on
        an error or a KeyboardInterrupt).
    """
    from ..parallel import check_backend, in_worker

    check_backend(backend, client)
    if backend == "dask" and n_jobs in (None, -1) and not in_worker():
        n = len(client.scheduler_info()["workers"])
    else:
        n = effective_n_jobs(n_jobs)
    if n <= 1 or not isinstance(objective, Objective) or objective.n_tasks <= 1:
        yield objective
        return
    sharded_obj = ShardedObjective(objective, n, backend, client, None if not isinstance(planner, str) else planner)
    try:
        yield sharded_obj
    finally:
        sharded_obj.close()

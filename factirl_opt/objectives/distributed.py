"""An objective evaluated over task shards, each kept by a worker between evaluations.

The per-task work of an objective is independent given the rewards: planning, loss, adjoint
and Gauss-Newton products are per task, and every sum over tasks happens in the step problems
(docs/maths.md §5, §8). :class:`ShardedObjective` therefore composes per-shard sub-objectives,
as :class:`~factirl_opt.objectives.environments.MultiEnvironmentObjective` composes
per-environment ones: the tasks are cut into contiguous shards, and each shard's objective,
of the same registered class over the shard's tasks (renumbered 0..m-1), lives on a worker
(:mod:`factirl_opt.parallel.shards`: this process for shard 0 and processes for the others, or Dask
actors). The worker keeps the MDP, the shard's statistics, its warm starts and its planner's
factorisations; per evaluation only the shard's rewards go in and its losses, gradients,
residuals and Jacobians (or Jacobian products) come out.

A sub-objective over a subset of the tasks makes, task by task, the computation of the whole
objective: the results agree with the unsharded objective to rounding (batched products may
round differently by batch size), and the number of evaluations is counted by the same rule
(one per batched call; a call at the last rewards is served from the last-point cache).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from solvers import Linearization

from ..parallel.shards import Shards, contiguous_shards
from ..planning.budget import budget_options
from ._base import Objective
from .contract import TaskObjective, limit_of

__all__ = ["ShardState", "ShardedBase", "ShardedObjective", "reduced_least_squares", "KEEP_LINEARIZATIONS"]

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
    T: NDArray[np.float64] = np.asarray(np.linalg.qr(np.concatenate([jacobian, residual[:, :, None]], axis=2), mode="r"))
    if T.shape[1] < k + 1:
        T = np.concatenate([T, np.zeros((n, k + 1 - T.shape[1], k + 1))], axis=1)
    return np.ascontiguousarray(T[:, :, k]), np.ascontiguousarray(T[:, :, :k])


class ShardState:
    """One shard's objective on its worker: a registered objective over the shard's tasks.

    Every evaluating call returns its result and how many evaluations the shard's objective
    made (0 when served from its last-point cache), from which the driver counts.

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
    planner_options : dict, optional
        The sharded objective's planning options (its budget, ``{"max_bytes": ...}``), applied in
        the shard's process.
    """

    def __init__(self, cls: type, mdp: Any, mu_hat: NDArray[np.float64], pi_hat: NDArray[np.float64], beta: float,
                 planner: str, planner_options: dict | None = None) -> None:
        self.objective = cls(mdp, mu_hat, pi_hat, beta, planner=planner, planner_options=planner_options)
        self.linearizations: dict[int, Linearization] = {}
        self.features: dict[int, Any] = {}
        self.problems: dict[int, Any] = {}

    def _counted(self, fn: Any, *args: Any) -> tuple:
        before = self.objective.n_evaluations
        out = fn(*args)
        return out, self.objective.n_evaluations - before

    def _keep(self, store: dict, token: int, value: Any) -> None:
        store[token] = value
        for old in sorted(store)[:-KEEP_LINEARIZATIONS]:
            del store[old]

    def loss_and_grad(self, R: NDArray[np.float64], rows: NDArray[np.intp]) -> tuple:
        return self._counted(self.objective.loss_and_grad, R, rows)

    def residual_jacobian(self, R: NDArray[np.float64], rows: NDArray[np.intp], features: NDArray[np.float64]) -> tuple:
        """Loss and the :func:`reduced_least_squares` form of the residuals and Jacobian (k+1 rows per task)."""
        (loss, residual, jacobian), n = self._counted(self.objective.residual_jacobian, R, rows, features)
        return (loss, *reduced_least_squares(residual, jacobian)), n

    def linearize(self, R: NDArray[np.float64], rows: NDArray[np.intp], token: int) -> tuple:
        lin, n = self._counted(self.objective.linearize, R, rows)
        self._keep(self.linearizations, token, lin)
        return (lin.loss, lin.residual), n

    def product(self, token: int, name: str, X: NDArray[np.float64]) -> NDArray[np.float64]:
        """``jvp`` or ``vjp`` (``name``) of the linearisation ``token`` applied to X."""
        return getattr(self.linearizations[token], name)(X)

    def receive(self, key: int, payload: Any, keep: tuple) -> Any:
        """The basis kept under ``key`` (``payload`` None: the one already kept); only ``keep`` stay."""
        if payload is not None:
            self.features[key] = payload
        self.features = {kk: v for kk, v in self.features.items() if kk in keep}
        return self.features[key]

    def make_problem(self, token: int, build: Any, args: tuple, key: int, features: Any, keep: tuple) -> None:
        """``build(objective, features, *args)``, a step problem over the shard's tasks, kept as ``token``
        (features as in :meth:`receive`)."""
        self.problems[token] = build(self.objective, self.receive(key, features, keep), *args)
        for old in sorted(self.problems)[:-KEEP_LINEARIZATIONS]:
            del self.problems[old]

    def problem_call(self, x: NDArray[np.float64], rows: NDArray[np.intp], token: int, method: str,
                     lin_token: int = 0) -> tuple:
        """The step problem ``token``'s ``method`` at ``x`` (its rows ``rows``); Jacobians in reduced form,
        a linearisation kept as ``lin_token`` (its loss and residuals returned)."""
        out, n = self._counted(getattr(self.problems[token], method), x, rows)
        if method == "residual_jacobian":
            out = (out[0], *reduced_least_squares(out[1], out[2]))
        elif method == "linearize":
            self._keep(self.linearizations, lin_token, out)
            out = (out.loss, out.residual)
        return out, n

    def factorial_point(self, features: tuple, D: NDArray[np.float64], H: NDArray[np.float64]) -> tuple:
        """Loss (m,) at the rewards ``Phi D h_i`` of the shard's tasks and ``Phi^T y_i`` (m, p)
        (the basis as in :meth:`receive`): what the factorial loop's optimality measure needs."""
        basis = self.receive(*features)
        (loss, y), n = self._counted(self.objective.loss_and_grad, basis.factorial_rewards(D, H), None)
        return (loss, basis.point_pull(y)), n

    def reset(self) -> None:
        self.objective.reset()
        self.linearizations.clear()


class ShardedBase(TaskObjective):
    """What the sharded objectives share: their ``parts`` (task indices per shard), ``shards``
    (:class:`~factirl_opt.parallel.shards.Shards`), the kept linearisations ``_lins`` and
    :meth:`rebuilt`, which restores a rebuilt shard's state."""

    parts: list
    shards: Shards
    _lins: dict

    @property
    def n_shards(self) -> int:
        return len(self.parts)

    def close(self) -> None:
        """Stop the shards' workers, and drop what would rebuild them: the kept linearisations and problems
        refer back to this object (a reference cycle that would keep the shards' specs, the MDP and the
        statistics until the next full garbage collection)."""
        self.shards.close()
        self._lins.clear()
        for kept in ("_problems", "_features"):
            getattr(self, kept, {}).clear()

    def reset(self) -> None:
        """As :meth:`Objective.reset`, on every shard."""
        self._lins.clear()
        self.shards.call([(k, "reset", ()) for k in range(self.n_shards)], on_restart=self.rebuilt)

    def rebuilt(self, k: int) -> None:  # pragma: no cover - every subclass defines it
        raise NotImplementedError


class ShardedObjective(ShardedBase):
    """An objective's tasks evaluated shard by shard on :class:`~factirl_opt.parallel.shards.Shards`.

    Offers what the step problems use of an :class:`~factirl_opt.objectives.Objective`:
    ``loss_and_grad``, ``residual_jacobian``, ``linearize``, ``reset``, ``n_evaluations``,
    ``n_tasks``, ``mdp``, ``name`` and ``least_squares``; and the step problems themselves
    (:meth:`weights_problem`, :meth:`dictionary_problem`,
    :mod:`factirl_opt.objectives.shard_problems`), evaluated on the shards from the weights,
    so that per evaluation only O(n p) numbers travel. A call counts as one evaluation when
    some shard's objective evaluated (not served from its last-point cache): the rule of
    :class:`~factirl_opt.objectives.Objective`, task by task.

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

    #: its step problems are built on the shards, from the weights (:mod:`.shard_problems`)
    builds_problems = True
    n_evaluations = 0  # counted per instance

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
        options = budget_options(objective)
        specs = [(ShardState, (type(objective), objective.mdp, objective.mu[rows], objective.pi_hat[rows],
                               objective.beta, name, options)) for rows in self.parts]
        self.shards = Shards(specs, backend, client, serve_while_starting=True)  # every call passes on_restart
        self._token = 0
        self._problems: dict[int, tuple] = {}  # token -> (build, features id, shard_args) of the kept problems
        self._lins: dict[int, Any] = {}  # token -> k -> (method, args) linearising shard k again, or None
        self._features: dict[int, Any] = {}  # id -> features kept (the id stays theirs while kept)
        self._sent: list[set] = [set() for _ in self.parts]  # features ids each shard holds
        self._point_key: int | None = None  # the features of the last factorial_point

    def reward_limit(self) -> float:
        """The largest ``|reward|`` planned without overflow on the MDP (:func:`limit_of`)."""
        return limit_of([self.mdp.gamma])

    def keep_linearization(self, again: Any) -> int:
        """A token for a new linearisation; ``again(k)`` gives the ``(method, args)`` that makes it again on a
        rebuilt shard k (None: shard k has none of its tasks)."""
        return self._next_token(self._lins, (again,))

    def _next_token(self, store: dict, entry: tuple) -> int:
        """A new token for ``entry`` in ``store`` (the latest :data:`KEEP_LINEARIZATIONS` kept, as on the shards)."""
        self._token += 1
        store[self._token] = entry
        for old in sorted(store)[:-KEEP_LINEARIZATIONS]:
            del store[old]
        return self._token

    def _rows(self, rows: ArrayLike | None) -> NDArray[np.intp]:
        return np.arange(self.n_tasks) if rows is None else np.asarray(rows)

    def split(self, rows: NDArray[np.intp]) -> list[tuple[int, NDArray[np.intp]]]:
        """``(shard, positions in rows)`` for every shard with tasks among ``rows``."""
        owners = self.owner[rows]
        return [(k, pos) for k in range(self.n_shards) if (pos := np.flatnonzero(owners == k)).size]

    def call(self, method: str, calls: list[tuple[int, tuple]]) -> list:
        """``method`` on shards ``(k, args)``; counts one evaluation if any shard evaluated."""
        out = self.shards.call([(k, method, args) for k, args in calls], on_restart=self.rebuilt)
        self.n_evaluations += int(any(n > 0 for _, n in out))
        return [res for res, _ in out]

    def map_tasks(self, method: str, R: NDArray[np.float64], rows: NDArray[np.intp], *extra: Any) -> tuple:
        split = self.split(rows)
        return split, self.call(method, [(k, (R[pos], self.local[rows[pos]], *extra)) for k, pos in split])

    @staticmethod
    def gather(split: list, parts: list, n: int) -> NDArray[np.float64]:
        """Per-shard arrays (rows of ``split``) placed into one (n, ...) array."""
        first = np.asarray(parts[0])
        out = np.empty((n, *first.shape[1:]), dtype=first.dtype)
        for (_, pos), part in zip(split, parts):
            out[pos] = part
        return out

    def loss_and_grad(self, rewards: ArrayLike, rows: ArrayLike | None = None) -> tuple:
        """Loss per task (r,) and ``dJ/dR`` (r, S, A), as :meth:`Objective.loss_and_grad`."""
        rows = self._rows(rows)
        split, out = self.map_tasks("loss_and_grad", np.asarray(rewards, dtype=np.float64), rows)
        return tuple(self.gather(split, [o[j] for o in out], len(rows)) for j in range(2))

    def residual_jacobian(self, rewards: ArrayLike, rows: ArrayLike | None, features: ArrayLike) -> tuple:
        """Loss (r,), residuals (r, p+1) and Jacobian (r, p+1, p): the :func:`reduced_least_squares` form
        of :meth:`Objective.residual_jacobian`'s (the same Gauss-Newton steps; p+1 rows per task travel)."""
        rows = self._rows(rows)
        F = np.asarray(features, dtype=np.float64)
        split, out = self.map_tasks("residual_jacobian", np.asarray(rewards, dtype=np.float64), rows, F)
        return tuple(self.gather(split, [o[j] for o in out], len(rows)) for j in range(3))

    def linearize(self, rewards: ArrayLike, rows: ArrayLike | None = None) -> Linearization:
        """A :class:`solvers.Linearization` whose products run on the shards (:meth:`Objective.linearize`)."""
        rows = self._rows(rows)
        R = np.asarray(rewards, dtype=np.float64)
        token: int = self.keep_linearization(lambda k: self.task_call(k, "linearize", R, rows, token))
        split, out = self.map_tasks("linearize", R, rows, token)
        loss, residual = (self.gather(split, [o[j] for o in out], len(rows)) for j in range(2))
        return Linearization(loss, residual, lambda dR: self.product(token, split, "jvp", dR),
                             lambda U: self.product(token, split, "vjp", U))

    def product(self, token: int, split: list, name: str, X: ArrayLike) -> NDArray[np.float64]:
        """``jvp`` or ``vjp`` of the shards' linearisation ``token`` at the rows of ``split``."""
        X = np.asarray(X, dtype=np.float64)
        parts = self.shards.call([(k, "product", (token, name, X[pos])) for k, pos in split], on_restart=self.rebuilt)
        return self.gather(split, parts, len(X))

    def make_problem(self, build: Any, features: Any, shard_args: Any) -> int:
        """A step problem ``build(objective, features, *shard_args(k))`` on every shard; its token.

        The features travel to a shard once while a problem kept by the driver uses them.
        """
        key = id(features)
        self._features[key] = features  # kept: its id is not reused while a problem uses it
        token = self._next_token(self._problems, (build, key, shard_args))
        self._prune_features()
        self.shards.call([(k, "make_problem", self._problem_args(k, token)) for k in range(self.n_shards)],
                         on_restart=self.rebuilt)
        return token

    def _prune_features(self) -> None:
        keep = {entry[1] for entry in self._problems.values()} | {self._point_key}
        self._features = {kk: v for kk, v in self._features.items() if kk in keep}

    def _features_args(self, k: int, key: int) -> tuple:
        """``(key, payload, keep)`` for :meth:`ShardState.receive` on shard k: the features travel once."""
        features = self._features[key]
        payload = None if key in self._sent[k] else features  # None: the shard keeps it already
        self._sent[k] = {kk for kk in self._sent[k] if kk in self._features} | {key}
        return key, payload, tuple(self._features)

    def _problem_args(self, k: int, token: int) -> tuple:
        build, key, shard_args = self._problems[token]
        return (token, build, shard_args(k), *self._features_args(k, key))

    def factorial_point(self, basis: Any, dictionary: NDArray[np.float64], coefficients: NDArray[np.float64]) -> tuple:
        """Loss (n,) at ``R_i = Phi D h_i`` and the gradients there from ``G = [Phi^T y_i]`` (n, p),
        rewards formed on the shards (:meth:`TaskObjective.factorial_point`).

        ``dJ/dH = G D``, ``dJ/dD = G^T H`` (eqs. 11-12): O(n p) numbers come back instead of
        ``dJ/dR`` (n, S, A).
        """
        key = self._point_key = id(basis)
        self._features[key] = basis
        self._prune_features()
        out = self.call("factorial_point", [(k, (self._features_args(k, key), dictionary, coefficients[rows]))
                                            for k, rows in enumerate(self.parts)])
        G = np.concatenate([o[1] for o in out])
        return np.concatenate([o[0] for o in out]), lambda D, H: (G @ D, G.T @ H)

    def rebuilt(self, k: int) -> None:
        """A rebuilt shard ``k`` gets the kept problems and linearisations again (its state was lost)."""
        self._sent[k] = set()
        if self._point_key in self._features:
            self.shards.handles[k].submit("receive", self._features_args(k, self._point_key))
            self.shards.handles[k].result()
        for token in sorted(self._problems):
            self.shards.handles[k].submit("make_problem", self._problem_args(k, token))
            self.shards.handles[k].result()
        for token, (again,) in sorted(self._lins.items()):
            call = again(k)
            if call is not None:
                self.shards.handles[k].submit(*call)
                self.shards.handles[k].result()

    def task_call(self, k: int, method: str, X: NDArray[np.float64], rows: NDArray[np.intp], *extra: Any) -> tuple | None:
        """``(method, (X[pos], local rows, *extra))`` for shard k's tasks among ``rows``; None without any."""
        pos = np.flatnonzero(self.owner[rows] == k)
        return (method, (X[pos], self.local[rows[pos]], *extra)) if pos.size else None

    def weights_problem(self, features: Any, names: tuple[str, str] | None) -> Any:
        """:func:`factirl_opt.objectives.problems.weights_problem` evaluated on the shards (see :mod:`.shard_problems`)."""
        from .shard_problems import sharded_weights_problem

        return sharded_weights_problem(self, features, names)

    def dictionary_problem(self, coefficients: NDArray[np.float64], base_features: Any, unit_norm: bool) -> Any:
        """:func:`factirl_opt.objectives.problems.dictionary_problem` evaluated on the shards (see :mod:`.shard_problems`)."""
        from .shard_problems import sharded_dictionary_problem

        return sharded_dictionary_problem(self, coefficients, base_features, unit_norm)

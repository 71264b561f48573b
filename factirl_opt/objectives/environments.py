"""Tasks in many environments: one registered objective per distinct MDP, seen as one objective.

Each task ``i`` has its own MDP ``M_i`` (``S_i`` states, the same ``A`` actions), empirical
statistics ``(mu_hat_i, pi_hat_i)`` and reward ``R_i`` of shape (S_i, A). Tasks whose MDP is
the *same object* form a group; every group is planned as one batch by the registered
objective (policy matching, MCE, ...) exactly as a single-MDP problem is today, so a problem
whose tasks all share one MDP object gives today's results bit for bit (docs/maths.md §5, §6).

Per-task arrays (rewards, ``dJ/dR``) are *stacked* ``(r, S, A)`` arrays when every environment
of the objective has the same number of states, and lists of ``r`` arrays ``(S_i, A)``
otherwise (:attr:`MultiEnvironmentObjective.ragged`). Residuals of least-squares objectives
are padded with zeros to the largest ``S_i * A`` (:attr:`MultiEnvironmentObjective.n_residuals`):
the padding changes neither ``||r_i||^2`` nor ``J_i^T u``, so the Gauss-Newton solvers see
one (r, m) array (docs/maths.md §5).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from solvers import Linearization

from .._validation import check_beta, check_statistics
from ..tasks.demonstrations import environment_demonstrations, environment_statistics
from ..exceptions import ValidationError
from ..mdp.environments import check_environments, group_tasks
from ..mdp.tabular import TabularMDP
from . import get_objective
from .contract import TaskObjective, limit_of

__all__ = ["MultiEnvironmentObjective", "multi_environment_objective"]

#: per-task arrays: a stacked (r, S, A, ...) array, or a sequence of r arrays (S_i, A, ...)
TaskArrays = NDArray[np.float64] | Sequence[NDArray[np.float64]]


def _task_statistics(mdps: list[TabularMDP], mu_hat: Any, pi_hat: Any) -> tuple[list, list]:
    """Per-task validated statistics (mu (S_i,), pi (S_i, A)); errors name the task."""
    n = len(mdps)
    for name, value in (("mu_hat", mu_hat), ("pi_hat", pi_hat)):
        if len(value) != n:
            raise ValidationError(f"{name} describes {len(value)} tasks but {n} MDPs were given (one per task)")
    mus, pis = [], []
    for i, mdp in enumerate(mdps):
        try:
            mu, pi = check_statistics(mdp, mu_hat[i], pi_hat[i])
        except ValidationError as exc:
            raise ValidationError(f"task {i} (S = {mdp.n_states}): {exc}") from None
        mus.append(mu[0])
        pis.append(pi[0])
    return mus, pis


class MultiEnvironmentObjective(TaskObjective):
    """A registered objective over tasks in several environments (see the module docstring).

    Parameters
    ----------
    mdps : TabularMDP or sequence of n TabularMDP
        Each task's MDP; tasks given the same object are planned together.
    mu_hat : sequence of n arrays (S_i,), or ndarray (n, S)
        Empirical state frequencies of each task on its own MDP.
    pi_hat : sequence of n arrays (S_i, A), or ndarray (n, S, A)
        Empirical policies.
    beta : float
        Inverse temperature.
    objective : str or Objective subclass, default="policy-matching"
        The per-group objective (see :func:`factirl_opt.available_objectives`).
    planner : str, default="auto"
    planner_options : dict, optional
        Given to every group's objective (``{"max_bytes": ...}``: each group's planning budget,
        :mod:`factirl_opt.planning.budget`).

    Attributes
    ----------
    objectives : list of Objective
        One per group, bound to the group's MDP and its tasks' statistics (in task order).
    mdps : list of n TabularMDP
    group_mdps : list of TabularMDP
    task_group, local_index : ndarray of intp, shape (n,)
        See :func:`group_tasks`.
    n_states : ndarray of intp, shape (n,)
        ``S_i``.
    n_actions, n_tasks : int
    ragged : bool
        Whether the environments differ in their number of states (per-task arrays are then
        lists, else stacked arrays).
    n_residuals : int
        ``max_i S_i * A``: the width of the (padded) residuals.
    mdp : TabularMDP or None
        The MDP when every task shares one, else None.
    name : str
    least_squares : bool
    """

    def __init__(self, mdps: TabularMDP | Sequence[TabularMDP], mu_hat: Any, pi_hat: Any, beta: float,
                 objective: Any = "policy-matching", planner: Any = "auto", planner_options: dict | None = None) -> None:
        cls = get_objective(objective)
        self.mdps = check_environments(mdps, len(mu_hat))
        mus, pis = _task_statistics(self.mdps, mu_hat, pi_hat)
        beta = check_beta(beta)
        self.group_mdps, self.task_group, self.local_index = group_tasks(self.mdps)
        self.objectives = []
        for g, mdp in enumerate(self.group_mdps):
            tasks = np.flatnonzero(self.task_group == g)
            self.objectives.append(cls(mdp, np.stack([mus[i] for i in tasks]), np.stack([pis[i] for i in tasks]), beta,
                                       planner=planner, planner_options=planner_options))
        self.name, self.least_squares = cls.name, cls.least_squares
        self.has_hessian = bool(getattr(cls, "has_hessian", False))
        self.n_tasks = len(self.mdps)
        self.n_actions = self.mdps[0].n_actions
        self.n_states = np.array([m.n_states for m in self.mdps], dtype=np.intp)
        self.ragged = bool(np.any(self.n_states != self.n_states[0]))
        self.n_residuals = int(self.n_states.max()) * self.n_actions
        self.mdp = self.group_mdps[0] if len(self.group_mdps) == 1 else None

    @property
    def n_evaluations(self) -> int:
        """Batched planning evaluations so far, summed over the groups (one per group and call)."""
        return int(sum(obj.n_evaluations for obj in self.objectives))

    def reward_limit(self) -> float:
        """The largest ``|reward|`` planned without overflow on every task's MDP (:func:`limit_of`)."""
        return limit_of([m.gamma for m in self.mdps])

    def reset(self) -> None:
        """Forget every group's warm starts and last-point cache (statistics and counts kept)."""
        for obj in self.objectives:
            obj.reset()

    # -- rows, groups and per-task arrays ----------------------------------------------------------
    def _rows(self, rows: ArrayLike | None) -> NDArray[np.intp]:
        if rows is None:
            return np.arange(self.n_tasks)
        rows = np.asarray(rows, dtype=np.intp).reshape(-1)
        if rows.size and (rows.min() < 0 or rows.max() >= self.n_tasks):
            raise ValidationError(f"rows must be task indices in [0, {self.n_tasks}); got {rows.tolist()}")
        return rows

    def _split(self, rows: NDArray[np.intp]) -> list[tuple[int, NDArray[np.intp], NDArray[np.intp]]]:
        """``(group, positions in rows, rows of the group's objective)`` for each group present."""
        groups = self.task_group[rows]
        parts = []
        for g in np.unique(groups):
            pos = np.flatnonzero(groups == g)
            parts.append((int(g), pos, self.local_index[rows[pos]]))
        return parts

    def _gather(self, arrays: TaskArrays, rows: NDArray[np.intp], pos: NDArray[np.intp], what: str) -> NDArray[np.float64]:
        """The per-task arrays of positions ``pos`` stacked as (len(pos), S_g, A, ...), shapes checked."""
        if len(arrays) != len(rows):
            raise ValidationError(f"{what} must hold one array per row ({len(rows)}); got {len(arrays)}")
        S, A = int(self.n_states[rows[pos[0]]]), self.n_actions
        if isinstance(arrays, np.ndarray):
            out = np.asarray(arrays[pos], dtype=np.float64)
            bad = [] if out.shape[1:3] == (S, A) else [(pos[0], out.shape[1:])]
        else:
            parts = [np.asarray(arrays[j], dtype=np.float64) for j in pos]
            bad = [(j, a.shape) for j, a in zip(pos, parts) if a.shape[:2] != (S, A)]
        if bad:
            task = int(rows[bad[0][0]])
            raise ValidationError(f"{what} of task {task} must have shape (S, A) = ({S}, {A}) (its MDP); got {bad[0][1]}")
        return out if isinstance(arrays, np.ndarray) else np.stack(parts)

    def _empty(self, rows: NDArray[np.intp], extra: tuple[int, ...] = ()) -> Any:
        if self.ragged:
            return [None] * len(rows)
        return np.empty((len(rows), int(self.n_states[0]), self.n_actions, *extra))

    @staticmethod
    def _place(out: Any, pos: NDArray[np.intp], values: NDArray[np.float64]) -> None:
        if isinstance(out, np.ndarray):
            out[pos] = values
        else:
            for j, p in enumerate(pos):
                out[p] = values[j]

    # -- the operations step problems use -----------------------------------------------------------
    def loss_and_grad(self, rewards: TaskArrays, rows: ArrayLike | None = None) -> tuple[NDArray[np.float64], Any]:
        """Loss per task (r,) and ``dJ/dR`` of each task at ``rewards`` of tasks ``rows``.

        ``rewards`` and the returned gradient are stacked (r, S, A) arrays, or lists of
        (S_i, A) arrays when the environments differ in size (:attr:`ragged`).
        """
        rows = self._rows(rows)
        loss, grad = np.empty(len(rows)), self._empty(rows)
        for g, pos, local in self._split(rows):
            loss[pos], y = self.objectives[g].loss_and_grad(self._gather(rewards, rows, pos, "rewards"), local)
            self._place(grad, pos, y)
        return loss, grad

    def _require_least_squares(self, what: str) -> None:
        if not self.least_squares:
            raise ValidationError(
                f"{what} needs a least-squares objective (residuals); the {self.name!r} objective has none: "
                "use a gradient solver (armijo, lbfgs)"
            )

    def _task_features(self, F: ArrayLike, task: int, p: int) -> NDArray[np.float64]:
        """Task ``task``'s features (S_i*A, p) as (S_i, A, p), the shape checked against its MDP."""
        F = np.asarray(F, dtype=np.float64)
        S, A = int(self.n_states[task]), self.n_actions
        if F.shape != (S * A, p):
            raise ValidationError(f"features of task {task} must have shape (S*A, p) = ({S * A}, {p}) (its MDP); got {F.shape}")
        return F.reshape(S, A, p)

    def residual_jacobian(self, rewards: TaskArrays, rows: ArrayLike | None,
                          features: Any) -> tuple[NDArray, NDArray, NDArray]:
        """Loss (r,), padded residuals (r, m) and Jacobians (r, m, p) for rewards ``R_i = F_i w_i``.

        Parameters
        ----------
        features : ndarray (S*A, p), or sequence of r arrays (S_i*A, p)
            One ``F`` for every row (all rows then need ``S_i * A`` rows of it), or one per
            row (aligned with ``rows``; e.g. ``Phi_i D`` in the H-step).
        """
        self._require_least_squares("residual_jacobian")
        rows = self._rows(rows)
        shared = isinstance(features, np.ndarray) and features.ndim == 2
        if not shared and len(features) != len(rows):
            raise ValidationError(f"features must be one (S*A, p) array or one per row ({len(rows)}); got {len(features)}")
        p = np.shape(features if shared else features[0])[-1]
        loss = np.empty(len(rows))
        res, jac = np.zeros((len(rows), self.n_residuals)), np.zeros((len(rows), self.n_residuals, p))
        for g, pos, local in self._split(rows):
            R, obj = self._gather(rewards, rows, pos, "rewards"), self.objectives[g]
            m = R.shape[1] * self.n_actions
            if shared:
                if features.shape[0] != m:
                    raise ValidationError(f"features must have S*A = {m} rows for task {int(rows[pos[0]])}; got {features.shape}")
                loss[pos], res[pos, :m], jac[pos, :m] = obj.residual_jacobian(R, local, features)
                continue
            F = np.stack([self._task_features(features[j], int(rows[j]), p) for j in pos])
            lin = obj.linearize(R, local)
            loss[pos], res[pos, :m], jac[pos, :m] = lin.loss, lin.residual, lin.jvp(F)
        return loss, res, jac

    def environment_groups(self) -> list[tuple[Any, NDArray[np.intp], NDArray[np.intp]]]:
        """``(group objective, tasks, local rows)`` per environment (:attr:`objectives`)."""
        return [(sub, tasks, np.asarray(self.local_index[tasks], dtype=np.intp))
                for g, sub in enumerate(self.objectives) for tasks in [np.flatnonzero(self.task_group == g)]]

    def hessian(self, rewards: TaskArrays, rows: ArrayLike | None, features: Any) -> NDArray[np.float64]:
        """Hessian of every task's loss (r, p, p) with respect to weights of rewards ``R_i = F_i w_i``.

        Each group's objective's ``hessian`` (e.g. :meth:`MCEObjective.hessian`) on its tasks.

        Parameters
        ----------
        features : ndarray (S*A, p), or sequence of r arrays (S_i*A, p)
            One ``F`` for every row, or one per row (aligned with ``rows``).

        Raises
        ------
        ValidationError
            When the objective gives no Hessian, or for features of the wrong shape.
        """
        if not self.has_hessian:
            raise ValidationError(f"the {self.name!r} objective gives no Hessian (use a gradient or Gauss-Newton solver)")
        rows = self._rows(rows)
        shared = isinstance(features, np.ndarray) and features.ndim == 2
        if not shared and len(features) != len(rows):
            raise ValidationError(f"features must be one (S*A, p) array or one per row ({len(rows)}); got {len(features)}")
        p = np.shape(features if shared else features[0])[-1]
        out = np.empty((len(rows), p, p))
        for g, pos, local in self._split(rows):
            R, obj = self._gather(rewards, rows, pos, "rewards"), self.objectives[g]
            F = features if shared else np.stack([self._task_features(features[j], int(rows[j]), p).reshape(-1, p)
                                                  for j in pos])
            out[pos] = obj.hessian(R, local, F)
        return out

    def linearize(self, rewards: TaskArrays, rows: ArrayLike | None = None) -> Linearization:
        """``solvers.Linearization`` at ``rewards`` of tasks ``rows``, residuals padded to (r, m).

        ``jvp`` maps per-task reward directions (stacked or a list, as ``rewards``) to (r, m);
        ``vjp`` maps (r, m) to per-task reward gradients (the padding is ignored).
        """
        self._require_least_squares("linearize")
        rows = self._rows(rows)
        parts = [(pos, self.objectives[g].linearize(self._gather(rewards, rows, pos, "rewards"), local))
                 for g, pos, local in self._split(rows)]
        loss, res = np.empty(len(rows)), np.zeros((len(rows), self.n_residuals))
        for pos, lin in parts:
            loss[pos], res[pos, : lin.residual.shape[1]] = lin.loss, lin.residual

        def jvp(dR: TaskArrays) -> NDArray[np.float64]:
            ds = [(pos, lin.jvp(self._gather(dR, rows, pos, "directions"))) for pos, lin in parts]
            out = np.zeros((len(rows), self.n_residuals, *ds[0][1].shape[2:]))
            for pos, d in ds:
                out[pos, : d.shape[1]] = d
            return out

        def vjp(U: ArrayLike) -> Any:
            U = np.asarray(U, dtype=np.float64)
            out = self._empty(rows)
            for pos, lin in parts:
                self._place(out, pos, lin.vjp(U[pos, : lin.residual.shape[1]]))
            return out

        return Linearization(loss, res, jvp, vjp)


def multi_environment_objective(mdps: TabularMDP | Sequence[TabularMDP], demos_per_task: Sequence[Any], beta: float,
                                objective: Any = "policy-matching", planner: Any = "auto",
                                planner_options: dict | None = None) -> MultiEnvironmentObjective:
    """The named objective over tasks in several environments, bound to their demonstrations.

    Parameters
    ----------
    mdps : TabularMDP or sequence of n TabularMDP
        One MDP per task (or one shared by all).
    demos_per_task : list of n task demonstrations
        Each on its own task's MDP (see :func:`factirl_opt.empirical_statistics`).
    beta : float
    objective : str, default="policy-matching"
    planner : str, default="auto"
    planner_options : dict, optional
        See :class:`MultiEnvironmentObjective`.

    Raises
    ------
    ValidationError
        For a wrong number of MDPs, or a state or action out of range of its task's MDP
        (the message names the task, episode and step).
    """
    envs, parsed = environment_demonstrations(mdps, demos_per_task)
    mus, pis = environment_statistics(envs, parsed)
    return MultiEnvironmentObjective(envs, mus, pis, beta, objective, planner, planner_options)

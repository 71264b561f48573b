"""The demonstration likelihood of transferred tasks, the likelihood term of their posterior
(:mod:`~factirl_opt.learners.posterior`): a :class:`TransferProblem` (the new tasks' objective,
environments, features, the dictionary and the residual penalty), the likelihood's scaling ``s``
(:func:`likelihood_scaling`), and the loss, gradient and curvature ``G`` of each task's
demonstration loss at a point, dense (:func:`demonstration_curvature`) or as low-rank factors.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..exceptions import ValidationError
from ..tasks.basis import as_basis
from .transfer import transfer_tasks

__all__ = ["TransferProblem", "likelihood_scaling", "demonstration_curvature", "transfer_problem", "tasks_problem",
           "repeated_problem", "CHUNK_BYTES"]

#: tasks whose feature tangents (r, S*A, d) are formed at once, at most this many bytes
CHUNK_BYTES = 64 * 2**20


def _basis(features, D, residual, mdp):
    """``Phi [D, I]`` (S*A, d) of a task's features (None: tabular) on ``mdp`` (``Phi D`` without residual)."""
    base = as_basis(features, mdp.n_states, mdp.n_actions)
    B = base.compose(D).jacobian_features()
    if residual:
        B = np.concatenate([B, base.jacobian_features()], axis=1)
    return np.ascontiguousarray(B)


def likelihood_scaling(objective_name: str, n_pairs: ArrayLike, mu: Any = None, pi: Any = None) -> NDArray[np.float64]:
    """The scaling ``s`` that makes ``s J`` each task's negative log-likelihood (docs/maths.md §10).

    Parameters
    ----------
    objective_name : str
        ``"mce"``: ``s = N``; otherwise (policy matching) ``s = N / (2 sigma^2)`` with
        ``sigma^2 = sum_s mu(s) (1 - ||pi(.|s)||^2) / (A - 1)``, the multinomial variance per
        component of one visit's action indicator under the policy ``pi``, averaged over the
        demonstrated states.
    n_pairs : array_like, shape (n,)
        ``N``: demonstrated (state, action) pairs of each task.
    mu : sequence of n arrays (S_i,), optional
        Demonstrated state frequencies (policy matching).
    pi : sequence of n arrays (S_i, A), optional
        The policy the noise level is evaluated at (policy matching).

    Returns
    -------
    ndarray, shape (n,)
    """
    N = np.asarray(n_pairs, dtype=np.float64)
    if objective_name == "mce":
        return N
    sig = np.empty(len(N))
    for i in range(len(N)):
        p = np.asarray(pi[i])
        A = p.shape[1]
        sig[i] = float(np.sum(np.asarray(mu[i]) * (1.0 - np.sum(p * p, axis=1)))) / max(A - 1, 1)
    return N / (2.0 * np.maximum(sig, 1e-12))


@dataclasses.dataclass
class TransferProblem:
    """New tasks' objective and reward bases, as the posterior and the requests see them.

    Attributes
    ----------
    objective : Objective or MultiEnvironmentObjective
        Over the new tasks (not sharded).
    mdps : list of n TabularMDP
    features : list of n arrays (S_i*A, p) or None
        Each task's dense base features (None: tabular).
    dictionary : ndarray, shape (p, k)
    residual_penalty : float
        ``lambda``; np.inf: coefficients only.
    n_pairs : ndarray, shape (n,)
        Demonstrated pairs per task.
    tasks : TaskSet or None
        The task set the problem was built from (:func:`tasks_problem`), from which a problem over
        repeated tasks is built (:func:`repeated_problem`); None for a problem set up by hand.
    dictionaries : sequence of n arrays (p, k), or None
        Each task's own dictionary (a problem over the tasks repeated once per dictionary of an
        ensemble, :func:`repeated_problem`); None: ``dictionary`` for every task.
    """

    objective: Any
    mdps: list
    features: list
    dictionary: NDArray[np.float64]
    residual_penalty: float
    n_pairs: NDArray[np.float64]
    tasks: Any = None
    dictionaries: Any = None

    @property
    def residual(self) -> bool:
        return bool(np.isfinite(self.residual_penalty))

    @property
    def n_tasks(self) -> int:
        return len(self.mdps)

    def groups(self) -> list[tuple[Any, NDArray[np.intp], NDArray[np.intp]]]:
        """``(objective, tasks, local rows)`` per MDP group (one group for a one-MDP objective)."""
        return self.objective.environment_groups()

    def dictionary_of(self, task: int) -> NDArray[np.float64]:
        """The dictionary (p, k) of task ``task``."""
        return self.dictionary if self.dictionaries is None else self.dictionaries[task]

    def basis(self, task: int) -> NDArray[np.float64]:
        return _basis(self.features[task], self.dictionary_of(task), self.residual, self.mdps[task])

    def statistics(self, task: int) -> tuple[Any, NDArray[np.float64], NDArray[np.float64]]:
        """``(objective of the task's group, mu (S,), pi_hat (S, A))``."""
        for sub, tasks, local in self.groups():
            hit = np.flatnonzero(tasks == task)
            if hit.size:
                j = int(local[hit[0]])
                return sub, sub.mu[j], sub.pi_hat[j]
        raise ValidationError(f"task {task} is not one of the {self.n_tasks} new tasks")


def _shared(problem, tasks):
    """Whether these tasks share their features (one object)."""
    first = problem.features[tasks[0]]
    return all(problem.features[t] is first for t in tasks)


def _bases(problem, tasks, shape):
    """``Phi_i [D_i, I]`` (r, S*A, d) of these tasks: one basis per distinct (features, dictionary) pair,
    broadcast when they all share one."""
    keys = [(id(problem.features[t]), id(problem.dictionary_of(int(t)))) for t in tasks]
    first: dict = {}
    for j, key in enumerate(keys):
        first.setdefault(key, j)
    if len(first) == 1:
        return np.broadcast_to(problem.basis(int(tasks[0])), (len(tasks), *shape))
    distinct = {key: problem.basis(int(tasks[j])) for key, j in first.items()}
    return np.stack([distinct[key] for key in keys])


def demonstration_curvature(problem: TransferProblem, x: ArrayLike,
                            tasks: ArrayLike | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Each task's demonstration loss ``J`` (r,), its gradient in ``x`` (r, d) and its curvature ``G`` (r, d, d).

    ``G`` is the Gauss-Newton matrix ``2 J_r^T J_r`` of policy matching (eq. 5 is ``||r||^2``), or
    the Fisher information of MCE (the Gauss-Newton part of :meth:`MCEObjective.hessian`); both
    equal the Hessian of ``J`` where the model's policy reproduces the demonstrations'
    statistics exactly.

    Parameters
    ----------
    problem : TransferProblem
    x : array_like, shape (r, d)
        ``[h, delta]`` of each task.
    tasks : array_like of int, shape (r,), optional
        Which tasks (default: all, r = n).
    """
    tasks = np.arange(problem.n_tasks) if tasks is None else np.asarray(tasks, dtype=np.intp)
    X = np.asarray(x, dtype=np.float64)
    k = problem.dictionary.shape[1]
    d = k + (problem.dictionary.shape[0] if problem.residual else 0)
    if X.shape != (len(tasks), d):
        raise ValidationError(f"x must have shape (r, d) = ({len(tasks)}, {d}); got {X.shape}")
    loss, grad, G, _ = _evaluate(problem, X, tasks, True)
    return loss, grad, G


def _evaluate(problem: TransferProblem, x: NDArray[np.float64], tasks: NDArray[np.intp], curvature: bool):
    """Loss (r,) and, if ``curvature``, the gradient in x (r, d), the curvature G (r, d, d) and each
    task's policy at x (list of (S_i, A) arrays, policy matching only) of ``tasks`` at points ``x`` (r, d)."""
    r, d = x.shape
    loss, grad = np.empty(r), np.empty((r, d))
    G = np.empty((r, d, d) if curvature else (0, d, d))
    pis: list = [None] * r
    where = {int(t): j for j, t in enumerate(tasks)}
    for sub, gtasks, glocal in problem.groups():
        sel = np.array([j for j, t in enumerate(gtasks) if int(t) in where], dtype=np.intp)
        if sel.size == 0:
            continue
        mdp = sub.mdp
        S, A = mdp.n_states, mdp.n_actions
        size = max(1, CHUNK_BYTES // (8 * S * A * d)) if curvature else len(sel)
        for lo in range(0, sel.size, size):
            part = sel[lo:lo + size]
            pos = np.array([where[int(gtasks[j])] for j in part], dtype=np.intp)
            local = glocal[part]
            ts = gtasks[part]
            B = _bases(problem, ts, (S * A, d))
            R = np.einsum("rmd,rd->rm", B, x[pos]).reshape(len(ts), S, A)
            if sub.least_squares:  # eq. 5 is ||r||^2: loss, gradient 2 J_r^T r and curvature from one linearisation
                lin = sub.linearize(R, local)
                loss[pos] = lin.loss
                if not curvature:
                    continue
                Jr = lin.jvp(np.ascontiguousarray(B).reshape(len(ts), S, A, d))
                grad[pos] = 2.0 * np.einsum("rmd,rm->rd", Jr, lin.residual)
                G[pos] = 2.0 * np.einsum("rmd,rme->rde", Jr, Jr)
                mu = sub.mu[local]
                with np.errstate(divide="ignore", invalid="ignore"):
                    pi = sub.pi_hat[local] + lin.residual.reshape(len(ts), S, A) / np.sqrt(mu)[:, :, None]
                pi = np.where(mu[:, :, None] > 0, pi, 1.0 / A)
                for j, p in zip(pos, pi):
                    pis[j] = p
                continue
            lo_, y = sub.loss_and_grad(R, local)
            loss[pos], grad[pos] = lo_, np.einsum("rmd,rm->rd", B, y.reshape(len(ts), S * A))
            if curvature:
                G[pos] = sub.hessian(R, local, np.ascontiguousarray(B), kind="gauss-newton")
    return loss, grad, G, pis


def _pad_rows(Z, other):
    """``Z`` (r, m, d) with zero rows appended up to ``other``'s m (a no-op when it has as many)."""
    extra = other.shape[1] - Z.shape[1]
    if extra <= 0:
        return Z
    return np.concatenate([Z, np.zeros((Z.shape[0], extra, Z.shape[2]))], axis=1)


def _evaluate_lowrank(problem: TransferProblem, x: NDArray[np.float64], tasks: NDArray[np.intp], curvature: bool = True):
    """:func:`_evaluate` of a residual model under a least-squares objective with the curvature as its factor:
    loss (r,), gradient (r, d), ``Z`` (r, m, d) the live rows of the residuals' Jacobian in x (``G = 2 Z^T Z``;
    zero rows pad the tasks with fewer), and each task's policy at x.

    The Jacobian with respect to the reward weights ``w`` comes from the objective's
    ``residual_jacobian`` (reverse mode: one adjoint right-hand side per demonstrated row), then
    ``[J D, J]`` on its live rows only: no (S*A, k + p) tangent and no (d, d) product.
    """
    r, d = x.shape
    D = problem.dictionary
    k = D.shape[1]
    loss, grad = np.empty(r), np.empty((r, d))
    factors: list = [None] * r
    pis: list = [None] * r
    where = {int(t): j for j, t in enumerate(tasks)}
    if problem.dictionaries is None:
        W = x[:, :k] @ D.T + x[:, k:]  # (r, p)
    else:
        Ds = [problem.dictionary_of(int(t)) for t in tasks]
        W = np.einsum("rpk,rk->rp", np.stack(Ds), x[:, :k]) + x[:, k:]
    for sub, gtasks, glocal in problem.groups():
        sel = np.array([j for j, t in enumerate(gtasks) if int(t) in where], dtype=np.intp)
        if sel.size == 0:
            continue
        S, A = sub.mdp.n_states, sub.mdp.n_actions
        ts = gtasks[sel]
        shared = _shared(problem, ts)
        batches = [sel] if shared else [sel[i:i + 1] for i in range(sel.size)]
        for part in batches:
            pos = np.array([where[int(gtasks[j])] for j in part], dtype=np.intp)
            feats = problem.features[int(gtasks[part[0]])]
            F = np.eye(S * A) if feats is None else np.asarray(feats, dtype=np.float64)
            R = (W[pos] @ F.T).reshape(len(pos), S, A)
            lo, res, J = sub.residual_jacobian(R, glocal[part], F)
            loss[pos] = lo
            for j, q in enumerate(pos):
                live = np.flatnonzero(np.any(J[j] != 0.0, axis=1))
                Jl = J[j][live]
                Z = np.concatenate([Jl @ problem.dictionary_of(int(tasks[q])), Jl], axis=1)
                grad[q] = 2.0 * Z.T @ res[j][live]
                factors[q] = Z
            mu = sub.mu[glocal[part]]
            with np.errstate(divide="ignore", invalid="ignore"):
                pi = sub.pi_hat[glocal[part]] + res.reshape(len(pos), S, A) / np.sqrt(mu)[:, :, None]
            pi = np.where(mu[:, :, None] > 0, pi, 1.0 / A)
            for q, p_ in zip(pos, pi):
                pis[q] = p_
    m = max(1, max(z.shape[0] for z in factors))
    Z = np.zeros((r, m, d))
    for q, z in enumerate(factors):
        Z[q, :z.shape[0]] = z
    return loss, grad, Z, pis


def repeated_problem(model: Any, problem: TransferProblem, dictionaries: Any) -> TransferProblem:
    """``problem``'s tasks repeated once per dictionary: task ``b n + i`` is task ``i`` under ``dictionaries[b]``.

    Built from ``problem.tasks`` (:func:`tasks_problem`), so that each repeat has its own rows of
    the objective (its own warm starts); the dictionary ensemble's posteriors are one problem
    (one planner call per Newton step for every dictionary and task).

    Parameters
    ----------
    model : FactIRL
        The model ``problem`` was built for.
    problem : TransferProblem
        With its ``tasks``.
    dictionaries : sequence of B arrays (p, k)

    Returns
    -------
    TransferProblem
        Of ``B n`` tasks, with ``dictionaries`` per task.

    Raises
    ------
    ValidationError
        ``problem`` has no task set.
    """
    if problem.tasks is None:
        raise ValidationError("repeated_problem needs a TransferProblem built by tasks_problem (with its task set)")
    n, B = problem.n_tasks, len(dictionaries)
    out = tasks_problem(model, problem.tasks.subset(np.tile(np.arange(n), B)), problem.dictionary)
    out.dictionaries = [np.asarray(D, dtype=np.float64) for D in dictionaries for _ in range(n)]
    return out


def transfer_problem(model: Any, mdp: Any, demos_per_task: Any, features: Any = None) -> TransferProblem:
    """The :class:`TransferProblem` of new tasks for a fitted :class:`FactIRL` (as ``transfer`` sets them up).

    Raises
    ------
    NotFittedError
        The model has no dictionary.
    ValidationError
        As ``FactIRL.transfer`` does for these arguments.
    """
    return tasks_problem(model, *transfer_tasks(mdp, demos_per_task, features, model))


def tasks_problem(model: Any, tasks: Any, D: Any) -> TransferProblem:
    """The :class:`TransferProblem` of a transfer's task set ``tasks`` and dictionary ``D`` (p, k)."""
    from .fitting import task_objective

    obj = task_objective(tasks, model.beta, model.objective, model._group("execution").planner)
    lam = float(getattr(model, "residual_penalty_", np.inf))
    mdps = list(tasks.mdps or []) if tasks.mdp is None else [tasks.mdp] * tasks.n_tasks
    feats = tasks.basis.recorded_features(np.arange(tasks.n_tasks))
    return TransferProblem(obj, mdps, feats, np.asarray(D, dtype=np.float64), lam, tasks.n_pairs, tasks)

"""Step problems: what the learners hand to a step solver, built on any objective and any basis.

One builder per block, each taking the fit's :class:`~factirl_opt.tasks.basis.RewardBasis`
(tabular, state, shared or per-task features: the builders never ask which):

- :func:`weights_problem`: rows are tasks, ``x_i = w_i`` with ``R_i = Phi_i w_i``; used by
  GradIRL, FactIRL's H-step (the basis ``Phi_i D``, :meth:`~factirl_opt.tasks.basis.RewardBasis.compose`,
  eq. 12) and transfer;
- :func:`dictionary_problem`: one row, ``x = vec(D)`` with every task's ``R_i = Phi_i D h_i``,
  loss ``J_Xi = sum_i J_i`` (eq. 10) and gradient ``sum_i Phi_i^T y_i h_i^T`` (eq. 11;
  docs/maths.md §8);
- the residual block: :mod:`factirl_opt.objectives.residuals`.

Gradients come from the objective's ``dJ/dR`` (``y_i``) by the chain rule (the basis'
adjoint); least-squares objectives also provide residuals, Jacobians (for the QP steps, k
columns) and Jacobian-vector products (for matrix-free Gauss-Newton on the dictionary), padded
to the largest ``S_i*A`` for tasks in several environments. An objective that declares
:attr:`~factirl_opt.objectives.contract.TaskObjective.builds_problems` (a sharded one) builds
them where its tasks are.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from solvers import Linearization, StepProblem

from .._deprecation import warn_once
from ..tasks.basis import RewardBasis, as_basis

__all__ = ["weights_problem", "dictionary_problem", "as_problem_basis"]


def effective_dictionary(x: np.ndarray, p: int, k: int, unit_norm: bool) -> tuple[np.ndarray, np.ndarray]:
    """The dictionary (p, k) the rewards use from ``vec(D)`` (unit-norm columns if asked), and the
    column norms (ones without ``unit_norm``; a zero column keeps norm 1)."""
    D = x.reshape(p, k)
    norms = np.where((nrm := np.linalg.norm(D, axis=0)) > 0, nrm, 1.0) if unit_norm else np.ones(k)
    return D / norms, norms


def unit_norm_map(D: np.ndarray, norms: np.ndarray, G: np.ndarray, unit_norm: bool) -> np.ndarray:
    """Derivative of ``D -> D~`` (unit-norm columns) applied to G (it is symmetric):
    ``(G - D~ diag(D~^T G)) / norms``; G itself without ``unit_norm``."""
    return (G - D * np.sum(D * G, axis=0)) / norms if unit_norm else G


def alternating_dictionary_problem(objective: Any, n: int, p: int, k: int, unit_norm: bool,
                                   rewards: Any, gradient: Any, check: Any = None) -> StepProblem:
    """The one-row problem over ``vec(D)`` (1, p*k) shared by the dictionary problems (eqs. 10-11).

    ``rewards(D)`` gives every task's rewards from the effective dictionary (p, k) and
    ``gradient(y)`` the raw dictionary gradient (p, k) from ``dJ/dR`` of every task; both pass
    through the unit-norm normalisation when ``unit_norm`` (:func:`unit_norm_map`).
    ``check(R, D)``, if given, returns the rewards of a point or raises when the planner would
    overflow on them (:func:`check_reward_scale`); directions are not checked.
    """
    if check is None:
        def check(R, D):
            return R

    all_rows = np.arange(n)

    def pull(y, D, norms):
        return unit_norm_map(D, norms, gradient(y), unit_norm).reshape(1, -1)

    def loss_and_grad(x, rows):
        D, norms = effective_dictionary(x, p, k, unit_norm)
        loss, y = objective.loss_and_grad(check(rewards(D), D), all_rows)
        return np.array([loss.sum()]), pull(y, D, norms)

    def linearize(x, rows):
        D, norms = effective_dictionary(x, p, k, unit_norm)
        lin = objective.linearize(check(rewards(D), D), all_rows)

        def jvp(V):  # one direction dD (p, k) -> every task's dr_i, as one row (1, n*m)
            return lin.jvp(rewards(unit_norm_map(D, norms, V.reshape(p, k), unit_norm))).reshape(1, -1)

        def vjp(U):
            return pull(lin.vjp(U.reshape(n, -1)), D, norms)

        return Linearization(np.array([lin.loss.sum()]), lin.residual.reshape(1, -1), jvp, vjp)

    return StepProblem(
        loss_and_grad=loss_and_grad,
        linearize=linearize if objective.least_squares else None,
        n_evaluations=lambda: objective.n_evaluations,
        n_rows=1,
        n_params=p * k,
    )


def has_hessian(objective: Any) -> bool:
    """Whether ``objective`` gives the Hessian of its loss with respect to linear reward weights
    (its declared :attr:`~factirl_opt.objectives.contract.TaskObjective.has_hessian`, e.g.
    :meth:`MCEObjective.hessian`)."""
    return bool(objective.has_hessian)


def reward_limit(objective: Any) -> float:
    """The largest |reward| the objective plans without overflow: ``REWARD_LIMIT * (1 - gamma)`` as
    :func:`~factirl_opt._validation.check_rewards` has it, for the largest gamma of its MDPs."""
    return float(objective.reward_limit())


def as_problem_basis(objective: Any, features: Any) -> RewardBasis:
    """``features`` as a :class:`~factirl_opt.tasks.basis.RewardBasis`: a basis as is; the older
    forms (None for tabular, a (S*A, p) matrix, a StateBroadcast, TaskFeatures) read on the
    objective's MDP (:func:`~factirl_opt.tasks.basis.as_basis`)."""
    if isinstance(features, RewardBasis):
        return features
    mdp = objective.mdp
    return as_basis(features, *((None, None) if mdp is None else (mdp.n_states, mdp.n_actions)))


def weights_problem(objective: Any, basis: Any = None, names: tuple[str, str] | None = None) -> StepProblem:
    """Problem over per-task weights ``w`` (n, p), rewards ``R_i = Phi_i w_i``.

    Parameters
    ----------
    objective : TaskObjective
        Over the n tasks (any kind: :mod:`factirl_opt.objectives.contract`).
    basis : RewardBasis
        ``Phi_i`` (``Phi_i D`` in FactIRL's H-step). The older forms of features are read by
        :func:`as_problem_basis` (None: tabular rewards, p = S*A).
    names : (str, str), optional
        What ``Phi`` and ``w`` are, for the message of an overflow (default the basis' own).

    Returns
    -------
    StepProblem
        n rows (the objective's tasks), p parameters each; the gradient is ``Phi_i^T y_i``
        (docs/maths.md §7).
    """
    basis = as_problem_basis(objective, basis)
    if objective.builds_problems:  # evaluated where its tasks are (objectives.shard_problems)
        return objective.weights_problem(basis, names)
    limit = reward_limit(objective)

    def rewards(x, rows):  # a point: rewards the planner can take
        return basis.point_rewards(x, rows, limit, names)

    def loss_and_grad(x, rows):
        loss, y = objective.loss_and_grad(rewards(x, rows), rows)
        return loss, basis.pull(y, rows)

    def residual_jacobian(x, rows):
        return objective.residual_jacobian(rewards(x, rows), rows, basis.jacobian_features(rows))

    def linearize(x, rows):
        lin = objective.linearize(rewards(x, rows), rows)

        def jvp(V):  # weight directions (r, p) -> reward directions Phi_i v_i
            return lin.jvp(basis.rewards(V, rows, names))

        def vjp(U):
            return basis.pull(lin.vjp(U), rows)

        return Linearization(lin.loss, lin.residual, jvp, vjp)

    def hessian(x, rows):  # the objective's Hessian with respect to the weights, at a point just evaluated
        return objective.hessian(rewards(x, rows), rows, basis.jacobian_features(rows))

    ls = objective.least_squares
    return StepProblem(
        loss_and_grad=loss_and_grad,
        residual_jacobian=residual_jacobian if ls else None,
        linearize=linearize if ls else None,
        hessian=hessian if has_hessian(objective) else None,
        n_evaluations=lambda: objective.n_evaluations,
        n_rows=objective.n_tasks,
        n_params=basis.n_params,
    )


def dictionary_problem(objective: Any, coefficients: NDArray[np.float64], basis: Any = None,
                       unit_norm: bool = False) -> StepProblem:
    """One-row problem over the dictionary ``vec(D)`` (1, p*k) with ``H`` fixed (eqs. 10-11).

    Parameters
    ----------
    objective : TaskObjective
    coefficients : ndarray, shape (n, k)
        ``H``, tasks on the leading axis.
    basis : RewardBasis
        ``Phi_i``: rewards ``R_i = Phi_i D h_i`` with ``D`` of shape (p, k) (older forms of
        features as in :func:`weights_problem`; None: tabular, p = S*A).
    unit_norm : bool, default=False
        Use the primitives at unit norm: rewards ``R_i = Phi_i D~ h_i`` with
        ``D~ = D diag(1 / ||D[:, l]||)``, so the step cannot trade the scale of D against that
        of H (needed when H carries a penalty such as L1). The gradient is then
        ``(G - D~ diag(sum_j D~_jl G_jl)) diag(1 / ||D[:, l]||)`` with ``G`` the gradient at ``D~``.

    Returns
    -------
    StepProblem
        One row of ``p * k`` parameters; least-squares residuals are every task's (padded)
        residuals as one row.
    """
    basis = as_problem_basis(objective, basis)
    if objective.builds_problems:  # evaluated where its tasks are (objectives.shard_problems)
        return objective.dictionary_problem(coefficients, basis, unit_norm)
    H = np.asarray(coefficients, dtype=np.float64)
    n, k = H.shape
    limit = reward_limit(objective)

    def rewards(D):
        return basis.dictionary_rewards(D, H)

    def check(R, D):
        return basis.check_dictionary_rewards(R, D, H, limit)

    def gradient(y):
        """``sum_i Phi_i^T y_i h_i^T`` (eq. 11), (p, k)."""
        return basis.dictionary_gradient(y, H)

    return alternating_dictionary_problem(objective, n, basis.n_params, k, unit_norm, rewards, gradient, check)


def task_weights_problem(objective: Any, features: Any) -> StepProblem:
    """Deprecated: :func:`weights_problem` takes per-task features (any basis) itself."""
    warn_once("objectives.problems.task_weights_problem", "factirl_opt.objectives.problems.task_weights_problem is "
              "deprecated: weights_problem takes every basis, per-task features included")
    return weights_problem(objective, features)


def task_dictionary_problem(objective: Any, coefficients: NDArray[np.float64], features: Any,
                            unit_norm: bool = False) -> StepProblem:
    """Deprecated: :func:`dictionary_problem` takes per-task features (any basis) itself."""
    warn_once("objectives.problems.task_dictionary_problem", "factirl_opt.objectives.problems.task_dictionary_problem "
              "is deprecated: dictionary_problem takes every basis, per-task features included")
    return dictionary_problem(objective, coefficients, features, unit_norm)

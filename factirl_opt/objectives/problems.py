"""Step problems: what the learners hand to a step solver, built on any objective.

- :func:`weights_problem`: rows are tasks, ``x_i = w_i`` with ``R_i = F w_i`` (tabular when
  ``F`` is None); used by GradIRL, FactIRL's H-step (``F = Phi D``, eq. 12) and transfer.
- :func:`dictionary_problem`: one row, ``x = vec(D)`` with every task's ``R_i = Phi D h_i``,
  loss ``J_Xi = sum_i J_i`` (eq. 10) and gradient ``Phi^T sum_i y_i h_i^T`` (eq. 11;
  docs/maths.md §8).
- :func:`task_weights_problem` and :func:`task_dictionary_problem`: the same with one feature
  matrix per task (:class:`~factirl_opt.tasks.features.TaskFeatures`, tasks in several
  environments, ``R_i = Phi_i w_i``; least-squares residuals padded to the largest ``S_i*A``);
  :func:`weights_problem` and :func:`dictionary_problem` hand such features to them;
- :class:`StateBroadcast`: the features of a state-only reward ``R(s, a) = r(s)``,
  ``Phi = kron(I_S, 1_A)`` (S*A, S), applied without forming the matrix (docs/maths.md §7).

Gradients come from the objective's ``dJ/dR`` (``y_i``) by the chain rule; least-squares
objectives also provide residuals, Jacobians (for the QP steps, k columns) and Jacobian-vector
products (for matrix-free Gauss-Newton on the dictionary).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from solvers import Linearization, StepProblem

from .._batched import rows_matmul
from .._validation import REWARD_LIMIT
from ..tasks.features import StateBroadcast, TaskFeatures, check_reward_scale, dense_features, linear_rewards

__all__ = ["weights_problem", "dictionary_problem", "task_weights_problem", "task_dictionary_problem"]


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
    (a ``hessian(rewards, rows, features)`` method, e.g. :meth:`MCEObjective.hessian`)."""
    return bool(getattr(objective, "has_hessian", False))


def reward_limit(objective: Any) -> float:
    """The largest |reward| the objective plans without overflow: ``REWARD_LIMIT * (1 - gamma)`` as
    :func:`~factirl_opt._validation.check_rewards` has it, for the largest gamma of its MDPs."""
    mdps = getattr(objective, "mdps", None) or [getattr(objective, "mdp", None)]
    gammas = [m.gamma for m in mdps if m is not None]
    return REWARD_LIMIT * (1.0 - max(gammas)) if gammas else np.inf


def weights_problem(objective: Any, features: Any = None,
                    names: tuple[str, str] = ("features", "weights")) -> StepProblem:
    """Problem over per-task weights ``w`` (n, p), rewards ``R_i = F w_i``.

    Parameters
    ----------
    objective : Objective
    features : ndarray, shape (S*A, p), or StateBroadcast, optional
        Shared features (``Phi D`` in FactIRL's H-step; a :class:`StateBroadcast` for
        state-only rewards, p = S). None: tabular rewards, p = S*A.
    names : (str, str)
        What ``F`` and ``w`` are, for the message of an overflow (:func:`linear_rewards`).

    Returns
    -------
    StepProblem
        n rows (the objective's tasks), p parameters each.
    """
    if isinstance(features, TaskFeatures):
        return task_weights_problem(objective, features)
    if hasattr(objective, "weights_problem"):  # evaluated where its tasks are (objectives.shard_problems)
        return objective.weights_problem(features, names)
    mdp = objective.mdp
    S, A = mdp.n_states, mdp.n_actions
    F = features if features is None or isinstance(features, StateBroadcast) else np.asarray(features, dtype=np.float64)
    p = S * A if F is None else F.shape[1]
    limit = reward_limit(objective)

    def directions(x):
        return x.reshape(-1, S, A) if F is None else linear_rewards(F, x, S, A, names)

    def rewards(x):  # a point: rewards the planner can take
        R = directions(x)
        return R if F is None else check_reward_scale(R, limit, F, x, names)

    def loss_and_grad(x, rows):
        loss, y = objective.loss_and_grad(rewards(x), rows)
        y = y.reshape(len(rows), S * A)
        return loss, (y if F is None else rows_matmul(y, F))

    def residual_jacobian(x, rows):
        return objective.residual_jacobian(rewards(x), rows, np.eye(S * A) if F is None else dense_features(F))

    def linearize(x, rows):
        lin = objective.linearize(rewards(x), rows)

        def jvp(V):  # weight directions (r, p) -> reward directions F v_i
            return lin.jvp(directions(V))

        def vjp(U):
            y = lin.vjp(U).reshape(len(U), S * A)
            return y if F is None else rows_matmul(y, F)

        return Linearization(lin.loss, lin.residual, jvp, vjp)

    def hessian(x, rows):  # the objective's Hessian with respect to the weights, at a point just evaluated
        return objective.hessian(rewards(x), rows, np.eye(S * A) if F is None else dense_features(F))

    ls = objective.least_squares
    return StepProblem(
        loss_and_grad=loss_and_grad,
        residual_jacobian=residual_jacobian if ls else None,
        linearize=linearize if ls else None,
        hessian=hessian if has_hessian(objective) else None,
        n_evaluations=lambda: objective.n_evaluations,
        n_rows=objective.n_tasks,
        n_params=p,
    )


def dictionary_problem(objective: Any, coefficients: NDArray[np.float64], base_features: Any = None,
                       unit_norm: bool = False) -> StepProblem:
    """One-row problem over the dictionary ``vec(D)`` (1, p*k) with ``H`` fixed (eqs. 10-11).

    Parameters
    ----------
    objective : Objective
    coefficients : ndarray, shape (n, k)
        ``H``, tasks on the leading axis.
    base_features : ndarray, shape (S*A, p), or StateBroadcast, optional
        ``Phi``: rewards ``R_i = Phi D h_i`` with ``D`` of shape (p, k). None: tabular, p = S*A.
    unit_norm : bool, default=False
        Use the primitives at unit norm: rewards ``R_i = Phi D~ h_i`` with
        ``D~ = D diag(1 / ||D[:, l]||)``, so the step cannot trade the scale of D against that
        of H (needed when H carries a penalty such as L1). The gradient is then
        ``(G - D~ diag(sum_j D~_jl G_jl)) diag(1 / ||D[:, l]||)`` with ``G`` the gradient at ``D~``.

    Returns
    -------
    StepProblem
        One row of ``p * k`` parameters.
    """
    if isinstance(base_features, TaskFeatures):
        return task_dictionary_problem(objective, coefficients, base_features, unit_norm)
    if hasattr(objective, "dictionary_problem"):  # evaluated where its tasks are (objectives.shard_problems)
        return objective.dictionary_problem(coefficients, base_features, unit_norm)
    mdp = objective.mdp
    S, A = mdp.n_states, mdp.n_actions
    H = np.asarray(coefficients, dtype=np.float64)
    n, k = H.shape
    Phi = base_features
    if Phi is not None and not isinstance(Phi, StateBroadcast):
        Phi = np.asarray(Phi, dtype=np.float64)
    p = S * A if Phi is None else Phi.shape[1]
    names = ("dictionary" if Phi is None else "features @ dictionary", "coefficients")
    limit = reward_limit(objective)

    def rewards(D):
        return linear_rewards(D if Phi is None else Phi @ D, H, S, A, names)

    def check(R, D):
        return check_reward_scale(R, limit, D if Phi is None else Phi @ D, H, names)

    def gradient(y):
        """``Phi^T sum_i y_i h_i^T`` (eq. 11), (p, k)."""
        g = y.reshape(n, S * A).T @ H
        return g if Phi is None else Phi.T @ g

    return alternating_dictionary_problem(objective, n, p, k, unit_norm, rewards, gradient, check)


def task_weights_problem(objective: Any, features: TaskFeatures) -> StepProblem:
    """:func:`weights_problem` with one feature matrix per task: ``R_i = Phi_i w_i``, w (n, p).

    Parameters
    ----------
    objective : MultiEnvironmentObjective
        Over the tasks of ``features`` (one environment each; see
        :mod:`factirl_opt.objectives.environments`).
    features : TaskFeatures
        ``Phi_i`` (or ``Phi_i D`` in the H-step, :meth:`TaskFeatures.times`).

    Returns
    -------
    StepProblem
        n rows, p parameters each; the gradient is ``Phi_i^T y_i`` (docs/maths.md §7) and the
        least-squares residuals are padded to the largest ``S_i * A``.
    """
    tf, limit = features, reward_limit(objective)

    def rewards(x, rows):  # a point: rewards the planners can take
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported, naming the inputs
            R = tf.rewards(x, rows)
        return check_reward_scale(R, limit, tf, x, ("features", "weights"))

    def loss_and_grad(x, rows):
        loss, y = objective.loss_and_grad(rewards(x, rows), rows)
        return loss, tf.pull(y, rows)

    def residual_jacobian(x, rows):
        return objective.residual_jacobian(rewards(x, rows), rows, tf.dense(rows))

    def linearize(x, rows):
        lin = objective.linearize(rewards(x, rows), rows)
        return Linearization(lin.loss, lin.residual, lambda V: lin.jvp(tf.rewards(V, rows)),
                             lambda U: tf.pull(lin.vjp(U), rows))

    def hessian(x, rows):
        return objective.hessian(rewards(x, rows), rows, tf.dense(rows))

    ls = objective.least_squares
    return StepProblem(
        loss_and_grad=loss_and_grad,
        residual_jacobian=residual_jacobian if ls else None,
        linearize=linearize if ls else None,
        hessian=hessian if has_hessian(objective) else None,
        n_evaluations=lambda: objective.n_evaluations,
        n_rows=objective.n_tasks,
        n_params=tf.n_features,
    )


def task_dictionary_problem(objective: Any, coefficients: NDArray[np.float64], features: TaskFeatures,
                            unit_norm: bool = False) -> StepProblem:
    """:func:`dictionary_problem` with one feature matrix per task: ``R_i = Phi_i D h_i``.

    The gradient is ``sum_i Phi_i^T y_i h_i^T`` (eq. 11, :meth:`TaskFeatures.dictionary_gradient`);
    ``unit_norm`` as in :func:`dictionary_problem`. Least-squares residuals are the tasks'
    padded residuals (n, max S_i*A) as one row.
    """
    tf, H = features, np.asarray(coefficients, dtype=np.float64)
    n, k = H.shape
    p = tf.n_features

    limit = reward_limit(objective)

    def rewards(D):
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported by ``check``
            return tf.rewards(H @ D.T)

    def check(R, D):
        return check_reward_scale(R, limit, tf, H @ D.T, ("features", "dictionary @ coefficients"))

    def gradient(y):
        return tf.pull(y).T @ H

    return alternating_dictionary_problem(objective, n, p, k, unit_norm, rewards, gradient, check)

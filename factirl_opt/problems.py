"""Step problems: what the learners hand to a step solver, built on any objective.

- :func:`weights_problem`: rows are tasks, ``x_i = w_i`` with ``R_i = F w_i`` (tabular when
  ``F`` is None); used by GradIRL, FactIRL's H-step (``F = Phi D``, eq. 12) and transfer.
- :func:`dictionary_problem`: one row, ``x = vec(D)`` with every task's ``R_i = Phi D h_i``,
  loss ``J_Xi = sum_i J_i`` (eq. 10) and gradient ``Phi^T sum_i y_i h_i^T`` (eq. 11; DESIGN
  section 8).

Gradients come from the objective's ``dJ/dR`` (``y_i``) by the chain rule; least-squares
objectives also provide residuals, Jacobians (for the QP steps, k columns) and Jacobian-vector
products (for matrix-free Gauss-Newton on the dictionary).
"""

import numpy as np

from solvers import Linearization, StepProblem

from .synthetic import task_rewards

__all__ = ["weights_problem", "dictionary_problem"]


def weights_problem(objective, features=None):
    """Problem over per-task weights ``w`` (n, p), rewards ``R_i = F w_i``.

    Parameters
    ----------
    objective : Objective
    features : ndarray, shape (S*A, p), optional
        Shared features (``Phi D`` in FactIRL's H-step). None: tabular rewards, p = S*A.
    """
    mdp = objective.mdp
    S, A = mdp.n_states, mdp.n_actions
    F = None if features is None else np.asarray(features, dtype=np.float64)
    p = S * A if F is None else F.shape[1]

    def rewards(x):
        return x.reshape(-1, S, A) if F is None else task_rewards(F, x, S, A)

    def loss_and_grad(x, rows):
        loss, y = objective.loss_and_grad(rewards(x), rows)
        y = y.reshape(len(rows), S * A)
        return loss, (y if F is None else y @ F)

    def residual_jacobian(x, rows):
        return objective.residual_jacobian(rewards(x), rows, np.eye(S * A) if F is None else F)

    def linearize(x, rows):
        lin = objective.linearize(rewards(x), rows)

        def jvp(V):  # weight directions (r, p) -> reward directions F v_i
            return lin.jvp(rewards(V))

        def vjp(U):
            y = lin.vjp(U).reshape(len(U), S * A)
            return y if F is None else y @ F

        return Linearization(lin.loss, lin.residual, jvp, vjp)

    ls = objective.least_squares
    return StepProblem(
        loss_and_grad=loss_and_grad,
        residual_jacobian=residual_jacobian if ls else None,
        linearize=linearize if ls else None,
        n_evaluations=lambda: objective.n_evaluations,
        n_rows=objective.n_tasks,
        n_params=p,
    )


def dictionary_problem(objective, coefficients, base_features=None, unit_norm=False):
    """One-row problem over the dictionary ``vec(D)`` (1, p*k) with ``H`` fixed (eqs. 10-11).

    Parameters
    ----------
    objective : Objective
    coefficients : ndarray, shape (n, k)
        ``H``, tasks on the leading axis.
    base_features : ndarray, shape (S*A, p), optional
        ``Phi``: rewards ``R_i = Phi D h_i`` with ``D`` of shape (p, k). None: tabular, p = S*A.
    unit_norm : bool, default=False
        Use the primitives at unit norm: rewards ``R_i = Phi D~ h_i`` with
        ``D~ = D diag(1 / ||D[:, l]||)``, so the step cannot trade the scale of D against that
        of H (needed when H carries a penalty such as L1). The gradient is then
        ``(G - D~ diag(sum_j D~_jl G_jl)) diag(1 / ||D[:, l]||)`` with ``G`` the gradient at ``D~``.
    """
    mdp = objective.mdp
    S, A = mdp.n_states, mdp.n_actions
    H = np.asarray(coefficients, dtype=np.float64)
    n, k = H.shape
    Phi = None if base_features is None else np.asarray(base_features, dtype=np.float64)
    p = S * A if Phi is None else Phi.shape[1]
    all_rows = np.arange(n)

    def effective(x):
        """The dictionary the rewards use (unit-norm columns if asked) and the column norms."""
        D = x.reshape(p, k)
        norms = np.where((nrm := np.linalg.norm(D, axis=0)) > 0, nrm, 1.0) if unit_norm else np.ones(k)
        return D / norms, norms

    def normalisation_map(D, norms, G):
        """Derivative of ``D -> D~`` applied to G (it is symmetric): ``(G - D~ diag(D~^T G)) / norms``."""
        return (G - D * np.sum(D * G, axis=0)) / norms if unit_norm else G

    def rewards(D):
        return task_rewards(D if Phi is None else Phi @ D, H, S, A)

    def pull(y, D, norms):
        """``Phi^T sum_i y_i h_i^T`` (eq. 11) through the normalisation: (1, p*k)."""
        g = y.reshape(n, S * A).T @ H
        return normalisation_map(D, norms, g if Phi is None else Phi.T @ g).reshape(1, -1)

    def loss_and_grad(x, rows):
        D, norms = effective(x)
        loss, y = objective.loss_and_grad(rewards(D), all_rows)
        return np.array([loss.sum()]), pull(y, D, norms)

    def linearize(x, rows):
        D, norms = effective(x)
        lin = objective.linearize(rewards(D), all_rows)

        def jvp(V):  # one direction dD (p, k) -> every task's dr_i, as one row (1, n*m)
            dD = normalisation_map(D, norms, V.reshape(p, k))
            return lin.jvp(rewards(dD)).reshape(1, -1)

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

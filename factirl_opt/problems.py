"""Step problems built on eq. (5): what the learners hand to a step solver.

- :func:`weights_problem`: rows are tasks, ``x_i = w_i`` with ``R_i = F w_i`` (tabular when
  ``F`` is None); used by GradIRL, FactIRL's H-step (``F = D``, eq. 12) and transfer.
- :func:`dictionary_problem`: one row, ``x = vec(D)`` with every task's ``R_i = D h_i``,
  loss ``J_Xi = sum_i J_i`` (eq. 10) and gradient ``sum_i y_i h_i^T`` (eq. 11).
"""

import numpy as np

from solvers._base import StepProblem  # the submodule: `import solvers` first must not cycle

__all__ = ["weights_problem", "dictionary_problem"]


def weights_problem(objective, features=None):
    """Problem over per-task weights ``w`` (n, p), rewards ``R_i = F w_i``.

    Parameters
    ----------
    objective : PolicyMatchingObjective
    features : ndarray, shape (S*A, p), optional
        Shared features (the dictionary). None: tabular rewards, p = S*A.
    """
    mdp = objective.mdp
    S, A = mdp.n_states, mdp.n_actions
    F = None if features is None else np.asarray(features, dtype=np.float64)
    p = S * A if F is None else F.shape[1]

    def rewards(x):
        return (x if F is None else x @ F.T).reshape(-1, S, A)

    def loss_and_grad(x, rows):
        ev = objective.evaluate(rewards(x), rows)
        y = ev.grad.reshape(len(rows), S * A)
        return ev.loss, (y if F is None else y @ F)

    def residual_jacobian(x, rows):
        feats = np.eye(S * A) if F is None else F
        ev = objective.evaluate(rewards(x), rows, grad=False, features=feats)
        return ev.loss, ev.residual, ev.jacobian

    return StepProblem(
        loss_and_grad=loss_and_grad,
        residual_jacobian=residual_jacobian,
        n_evaluations=lambda: objective.n_evaluations,
        n_rows=objective.n_tasks,
        n_params=p,
    )


def dictionary_problem(objective, coefficients):
    """One-row problem over the dictionary ``vec(D)`` (1, S*A*k) with ``H`` fixed (eqs. 10-11).

    Parameters
    ----------
    objective : PolicyMatchingObjective
    coefficients : ndarray, shape (n, k)
        ``H``, tasks on the leading axis.
    """
    mdp = objective.mdp
    S, A = mdp.n_states, mdp.n_actions
    H = np.asarray(coefficients, dtype=np.float64)
    n, k = H.shape
    all_rows = np.arange(n)

    def loss_and_grad(x, rows):
        D = x.reshape(S * A, k)
        ev = objective.evaluate((H @ D.T).reshape(n, S, A), all_rows)
        g = ev.grad.reshape(n, S * A).T @ H  # (S*A, k): sum_i y_i h_i^T, eq. (11)
        return np.array([ev.loss.sum()]), g.reshape(1, -1)

    return StepProblem(
        loss_and_grad=loss_and_grad,
        n_evaluations=lambda: objective.n_evaluations,
        n_rows=1,
        n_params=S * A * k,
    )

"""The residual model between flat and factorial: ``R_i = Phi_i (D h_i + delta_i)`` (docs/maths.md §8a).

Each task's feature weights are ``w_i = D h_i + delta_i``: the dictionary's part and a task
residual ``delta_i`` (p,), penalised by ``lambda ||delta_i||^2``. The objective of a fit is

    J(D, H, Delta) = sum_i [ J_i(Phi_i w_i) + lambda ||delta_i||^2 ],   w_i = D h_i + delta_i,

``lambda = inf`` forcing ``delta = 0`` (the paper's factorial model, eq. 10) and ``lambda = 0``
leaving every ``w_i`` free (the flat model). Both blocks are the flat learner's problem
(:func:`factirl_opt.objectives.problems.weights_problem`, over ``w``) composed with a linear map, so every
objective, planner, reward basis (tabular, state rewards, features, per-task features,
:mod:`factirl_opt.tasks.basis`) and sharded evaluation of the flat problem serves them unchanged:

- :func:`residual_weights_problem`: rows are tasks, ``x_i = [h_i, delta_i]`` (k + p), the
  H-step of the fit and transfer. With ``g_i = dJ_i/dw_i = Phi_i^T y_i`` (the flat gradient)
  the gradient is ``[D^T g_i, g_i + 2 lambda delta_i]``; least squares: the residuals
  ``[r_i, sqrt(lambda) delta_i]``, the Jacobian ``[[J_i D, J_i], [0, sqrt(lambda) I]]``,
  declared a ridge block (``StepProblem.ridge_params``) so that the Gauss-Newton QP solver
  eliminates ``delta_i`` from its steps in closed form (:func:`solvers.gn_subproblem.eliminate_ridge`).
- :func:`residual_dictionary_problem`: one row ``vec(D)`` with ``H`` and ``Delta`` fixed (the
  D-step); the gradient ``sum_i g_i h_i^T`` (eq. 11 with the residuals in ``w_i``); the
  penalty is constant there and left out.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from solvers import Linearization, StepProblem

from .._batched import rows_matmul
from ..exceptions import ValidationError
from .problems import effective_dictionary, unit_norm_map, weights_problem

__all__ = ["residual_weights_problem", "residual_dictionary_problem", "check_residual_penalty", "residual_weights",
           "RESIDUAL_AUTO"]

#: the value of ``residual_penalty`` that chooses lambda by validation
RESIDUAL_AUTO = "auto"


def check_residual_penalty(value: Any, allow_auto: bool = True) -> float | str:
    """``residual_penalty``: ``np.inf`` (no residuals), a float ``>= 0``, or ``"auto"``.

    Raises
    ------
    ValidationError
        Naming the bad value.
    """
    if isinstance(value, str):
        if allow_auto and value == RESIDUAL_AUTO:
            return value
        raise ValidationError(f"residual_penalty must be a number >= 0, np.inf{' or ' + repr(RESIDUAL_AUTO) if allow_auto else ''}; "
                              f"got {value!r}")
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValidationError(f"residual_penalty must be a number >= 0, np.inf or {RESIDUAL_AUTO!r}; got {value!r} "
                              f"({type(value).__name__})")
    value = float(value)
    if not value >= 0.0:
        raise ValidationError(f"residual_penalty must be >= 0 (np.inf: no residuals); got {value!r}")
    return value


def residual_weights(D: NDArray[np.float64], H: NDArray[np.float64], Delta: NDArray[np.float64] | None) -> NDArray[np.float64]:
    """Every task's feature weights ``w_i = D h_i + delta_i``, (n, p); ``Delta`` None is zero."""
    W = rows_matmul(np.asarray(H, dtype=np.float64), np.asarray(D, dtype=np.float64).T)
    return W if Delta is None else W + Delta


def residual_weights_problem(objective: Any, features: Any, dictionary: NDArray[np.float64], penalty: float,
                             names: tuple[str, str] = ("features", "weights")) -> StepProblem:
    """Problem over ``x_i = [h_i, delta_i]`` (n, k + p) with the dictionary fixed (module docstring).

    Parameters
    ----------
    objective : Objective
        Over the n tasks (also a sharded or multi-environment one).
    features : RewardBasis
        ``Phi_i`` (:mod:`factirl_opt.tasks.basis`; the older forms, None for tabular rewards
        with p = S*A, as :func:`factirl_opt.objectives.problems.weights_problem` reads them).
    dictionary : ndarray, shape (p, k)
    penalty : float
        ``lambda``, finite and >= 0.
    names : (str, str)
        For the message of an overflow (:func:`factirl_opt.tasks.features.linear_rewards`).

    Returns
    -------
    StepProblem
        n rows of ``k + p`` parameters; loss ``J_i(Phi_i w_i) + lambda ||delta_i||^2``.
    """
    flat = weights_problem(objective, features, names)
    D = np.asarray(dictionary, dtype=np.float64)
    p, k = D.shape
    if flat.n_params != p:
        raise ValidationError(f"the dictionary has p = {p} rows but the features {flat.n_params} columns")
    lam = float(penalty)
    root = np.sqrt(lam)

    def split(x):
        return x[:, :k], x[:, k:]

    def weights(x):
        h, d = split(x)
        return rows_matmul(h, D.T) + d

    def ridge(x):
        d = split(x)[1]
        return lam * np.einsum("np,np->n", d, d)

    def pull(g, x):
        return np.concatenate([rows_matmul(g, D), g + 2.0 * lam * split(x)[1]], axis=1)

    def loss_and_grad(x, rows):
        loss, g = flat.loss_and_grad(weights(x), rows)
        return loss + ridge(x), pull(g, x)

    def residual_jacobian(x, rows):
        loss, r, J = flat.residual_jacobian(weights(x), rows)  # J (r, m, p) with respect to w
        n, m = J.shape[:2]
        full = np.zeros((n, m + p, k + p))  # [[J D, J], [0, sqrt(lambda) I]], written in place
        np.matmul(J, D, out=full[:, :m, :k])
        full[:, :m, k:] = J
        full[:, m + np.arange(p), k + np.arange(p)] = root
        return loss + ridge(x), np.concatenate([r, root * split(x)[1]], axis=1), full

    def linearize(x, rows):
        lin = flat.linearize(weights(x), rows)
        m = lin.residual.shape[1]

        def jvp(V):
            Vh, Vd = split(V)
            return np.concatenate([lin.jvp(rows_matmul(Vh, D.T) + Vd), root * Vd], axis=1)

        def vjp(U):
            g = lin.vjp(U[:, :m])
            return np.concatenate([rows_matmul(g, D), g + root * U[:, m:]], axis=1)

        return Linearization(lin.loss + ridge(x), np.concatenate([lin.residual, root * split(x)[1]], axis=1), jvp, vjp)

    return StepProblem(
        loss_and_grad=loss_and_grad,
        residual_jacobian=None if flat.residual_jacobian is None else residual_jacobian,
        linearize=None if flat.linearize is None else linearize,
        n_evaluations=flat.n_evaluations,
        n_rows=flat.n_rows,
        n_params=k + p,
        ridge_params=p,
        ridge_penalty=lam,
    )


def residual_dictionary_problem(objective: Any, features: Any, coefficients: NDArray[np.float64],
                                residuals: NDArray[np.float64], unit_norm: bool = False) -> StepProblem:
    """One-row problem over ``vec(D)`` (1, p*k) with ``H`` and ``Delta`` fixed (module docstring).

    Parameters
    ----------
    objective : Objective
    features : RewardBasis
    coefficients : ndarray, shape (n, k)
    residuals : ndarray, shape (n, p)
    unit_norm : bool
        Primitives at unit norm, as in :func:`factirl_opt.objectives.problems.dictionary_problem`.

    Returns
    -------
    StepProblem
        Loss ``sum_i J_i(Phi_i (D h_i + delta_i))`` (the residuals' penalty is constant here).
    """
    flat = weights_problem(objective, features, ("features @ dictionary", "coefficients"))
    H = np.asarray(coefficients, dtype=np.float64)
    Delta = np.asarray(residuals, dtype=np.float64)
    n, k = H.shape
    p = flat.n_params
    all_rows = np.arange(n)

    def pull(G, D, norms):
        return unit_norm_map(D, norms, G.T @ H, unit_norm).reshape(1, -1)

    def loss_and_grad(x, rows):
        D, norms = effective_dictionary(x, p, k, unit_norm)
        loss, G = flat.loss_and_grad(residual_weights(D, H, Delta), all_rows)
        return np.array([loss.sum()]), pull(G, D, norms)

    def linearize(x, rows):
        D, norms = effective_dictionary(x, p, k, unit_norm)
        lin = flat.linearize(residual_weights(D, H, Delta), all_rows)

        def jvp(V):  # one direction dD (p, k) -> every task's dr_i, as one row (1, n*m)
            return lin.jvp(residual_weights(unit_norm_map(D, norms, V.reshape(p, k), unit_norm), H, None)).reshape(1, -1)

        def vjp(U):
            return pull(lin.vjp(U.reshape(n, -1)), D, norms)

        return Linearization(np.array([lin.loss.sum()]), lin.residual.reshape(1, -1), jvp, vjp)

    return StepProblem(
        loss_and_grad=loss_and_grad,
        linearize=None if flat.linearize is None else linearize,
        n_evaluations=flat.n_evaluations,
        n_rows=1,
        n_params=p * k,
    )

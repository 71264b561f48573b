"""Approximate leave-one-task-out validation: the one-step dictionaries and the search route built on them."""

import warnings

import numpy as np
import pytest
from scipy.optimize import minimize

import factirl_opt as fo
from factirl_opt.exceptions import ConvergenceWarning, ValidationError
from factirl_opt.learners.approximate_cv import (
    check_approximate_cv, leave_task_out_dictionaries, task_curvature_factors,
)
from factirl_opt.learners.selection import ROUTES, SharingSearch
from factirl_opt.tasks.basis import TabularBasis
from factirl_opt.tasks.task_set import task_set


class LinearObjective:
    """``J_i(w) = ||A_i w - b_i||^2``: a least-squares objective without planning, whose leave-one-out
    refits are well defined (smooth, and an exact optimum reached by L-BFGS)."""

    name, least_squares, builds_problems, has_hessian, n_evaluations = "linear", True, False, False, 0

    def __init__(self, A, b):
        self.A, self.b, self.n_tasks = A, b, len(A)

    def reward_limit(self):
        return np.inf

    def residual_jacobian(self, rewards, rows, features):
        w = np.asarray(rewards).reshape(len(rows), -1)
        r = np.einsum("imp,ip->im", self.A[rows], w) - self.b[rows]
        return np.sum(r * r, axis=1), r, self.A[rows] @ features


def _linear_problem(seed=0, n=12, p=8, m=6):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, m, p))
    D0, H0 = rng.standard_normal((p, 3)), rng.standard_normal((n, 3))
    b = np.einsum("imp,ip->im", A, H0 @ D0.T) + 0.3 * rng.standard_normal((n, m))
    return A, b, rng


def _exact_fit(A, b, idx, k, lam, x0):
    """The minimiser of ``sum_i ||A_i (D h_i + delta_i) - b_i||^2 + lam ||delta_i||^2`` over tasks ``idx``."""
    p, m = A.shape[2], len(idx)

    def f(x):
        D, H = x[:p * k].reshape(p, k), x[p * k:p * k + m * k].reshape(m, k)
        Dl = x[p * k + m * k:].reshape(m, p) if np.isfinite(lam) else 0.0
        r = np.einsum("imp,ip->im", A[idx], H @ D.T + Dl) - b[idx]
        G = 2.0 * np.einsum("imp,im->ip", A[idx], r)
        value, parts = np.sum(r * r), [(G.T @ H).ravel(), (G @ D).ravel()]
        if np.isfinite(lam):
            value += lam * np.sum(Dl * Dl)
            parts.append((G + 2.0 * lam * Dl).ravel())
        return value, np.concatenate(parts)

    x = minimize(f, x0, jac=True, method="L-BFGS-B", options=dict(maxiter=50000, gtol=1e-12, ftol=1e-16, maxcor=50)).x
    return x[:p * k].reshape(p, k), x[p * k:p * k + m * k].reshape(m, k), (x[p * k + m * k:].reshape(m, p)
                                                                          if np.isfinite(lam) else None)


def _gauge_distance(X, Y):
    """``min_M ||Y - X M|| / ||Y||``: dictionaries compared up to the model's invariance ``D -> D M``."""
    M = np.linalg.lstsq(X, Y, rcond=None)[0]
    return float(np.linalg.norm(Y - X @ M) / np.linalg.norm(Y))


@pytest.mark.parametrize("curvature", ["leave-out", "full"])
@pytest.mark.parametrize("lam", [np.inf, 1.0])
def test_the_one_step_dictionary_is_closer_to_the_exact_leave_one_out_refit_than_the_full_fit(lam, curvature):
    A, b, rng = _linear_problem()
    n, p, k = A.shape[0], A.shape[2], 2
    x0 = 0.5 * rng.standard_normal(p * k + n * k + (n * p if np.isfinite(lam) else 0))
    D, H, Delta = _exact_fit(A, b, np.arange(n), k, lam, x0)
    steps = leave_task_out_dictionaries(LinearObjective(A, b), TabularBasis(2, p // 2), D, H, Delta, lam,
                                        damping=1e-6, curvature=curvature)
    full, step = [], []
    for t in range(n):
        keep = np.setdiff1d(np.arange(n), [t])
        start = np.concatenate([D.ravel(), H[keep].ravel()] + ([Delta[keep].ravel()] if Delta is not None else []))
        exact = _exact_fit(A, b, keep, k, lam, start)[0]
        full.append(_gauge_distance(D, exact))
        step.append(_gauge_distance(steps[t], exact))
    full, step = np.array(full), np.array(step)
    assert np.mean(step) < np.mean(full)
    assert np.sum(step < full) >= 0.75 * n


def test_the_curvature_factors_are_the_profiled_gauss_newton_hessian_of_each_task(rng):
    n, m, p, k = 3, 5, 7, 2
    J = rng.standard_normal((n, m, p))
    J[0, 1] = 0.0  # an unvisited state's row
    D = rng.standard_normal((p, k))
    for lam in (np.inf, 0.5):
        M = task_curvature_factors(J, D, lam)
        for i in range(n):
            G = 2.0 * J[i].T @ J[i]
            Gt = G if np.isinf(lam) else G @ np.linalg.solve(G + 2.0 * lam * np.eye(p), 2.0 * lam * np.eye(p))
            P = Gt - Gt @ D @ np.linalg.pinv(D.T @ Gt @ D) @ D.T @ Gt
            np.testing.assert_allclose(M[i] @ M[i].T, P, atol=1e-9 * np.abs(P).max())
            np.testing.assert_allclose(M[i].T @ D, 0.0, atol=1e-9 * np.abs(M[i]).max())  # P_i D = 0: the gauge


@pytest.mark.parametrize("curvature", ["leave-out", "full"])
def test_the_step_is_the_damped_newton_step_off_the_gauge(rng, curvature):
    A, b, _ = _linear_problem(seed=1, n=5, p=6, m=4)
    n, p, k = A.shape[0], A.shape[2], 2
    D, H = rng.standard_normal((p, k)), rng.standard_normal((n, k))  # any point: the step of an inexact fit
    objective, damping = LinearObjective(A, b), 1e-2
    steps = leave_task_out_dictionaries(objective, TabularBasis(2, p // 2), D, H, damping=damping, tol=1e-13,
                                        curvature=curvature, inexact=True)
    optimum = leave_task_out_dictionaries(objective, TabularBasis(2, p // 2), D, H, damping=damping, tol=1e-13,
                                          curvature=curvature, inexact=False)
    r = np.einsum("imp,ip->im", A, H @ D.T) - b
    g = 2.0 * np.einsum("imp,im->ip", A, r)
    M = task_curvature_factors(A, D, np.inf)
    blocks = [np.kron(np.outer(H[i], H[i]), M[i] @ M[i].T) for i in range(n)]  # on vec(D), columns stacked
    mu = damping * np.trace(sum(blocks)) / (p * k)
    off = np.kron(np.eye(k), np.eye(p) - D @ np.linalg.pinv(D))
    for t in range(n):
        K = sum(blocks[i] for i in range(n) if i != t or curvature == "full") + mu * np.eye(p * k)
        grad = sum(np.outer(g[i], H[i]) for i in range(n) if i != t)
        expected = D - np.linalg.solve(K, off @ grad.T.ravel()).reshape(k, p).T
        np.testing.assert_allclose(steps[t], expected, atol=1e-8 * np.abs(expected).max())
        # at an exact optimum sum_i g_i h_i^T = 0: the step is task t's own gradient, with the sign it has there
        expected = D + np.linalg.solve(K, off @ np.outer(g[t], H[t]).T.ravel()).reshape(k, p).T
        np.testing.assert_allclose(optimum[t], expected, atol=1e-8 * np.abs(expected).max())
        np.testing.assert_allclose(np.linalg.pinv(D) @ (steps[t] - D), 0.0, atol=1e-9)


def test_without_a_penalty_the_dictionary_plays_no_part(rng):
    A, b, _ = _linear_problem(n=4, p=6, m=3)
    D, H = rng.standard_normal((6, 2)), rng.standard_normal((4, 2))
    out = leave_task_out_dictionaries(LinearObjective(A, b), TabularBasis(2, 3), D, H, np.zeros((4, 6)), 0.0, tasks=[2, 0])
    assert out.shape == (2, 6, 2) and np.array_equal(out[0], D) and np.array_equal(out[1], D)


def test_leave_task_out_dictionaries_refuses_bad_inputs(rng):
    A, b, _ = _linear_problem(n=4, p=6, m=3)
    objective, basis = LinearObjective(A, b), TabularBasis(2, 3)
    D, H = rng.standard_normal((6, 2)), rng.standard_normal((4, 2))
    with pytest.raises(ValidationError, match="equal k"):
        leave_task_out_dictionaries(objective, basis, D, H[:, :1])
    with pytest.raises(ValidationError, match="describe 3 tasks"):
        leave_task_out_dictionaries(objective, basis, D, H[:3])
    with pytest.raises(ValidationError, match="p = 5 rows"):
        leave_task_out_dictionaries(objective, basis, D[:5], H)
    with pytest.raises(ValidationError, match="residuals must have shape"):
        leave_task_out_dictionaries(objective, basis, D, H, np.zeros((4, 5)), 1.0)
    with pytest.raises(ValidationError, match="residual_penalty"):
        leave_task_out_dictionaries(objective, basis, D, H, None, -1.0)
    with pytest.raises(ValidationError, match="damping must be > 0"):
        leave_task_out_dictionaries(objective, basis, D, H, damping=0.0)
    with pytest.raises(ValidationError, match="curvature must be one of"):
        leave_task_out_dictionaries(objective, basis, D, H, curvature="diagonal")
    with pytest.raises(ValidationError, match="tasks must be indices"):
        leave_task_out_dictionaries(objective, basis, D, H, tasks=[4])
    objective.least_squares = False
    with pytest.raises(ValidationError, match="least-squares objective"):
        leave_task_out_dictionaries(objective, basis, D, H)


@pytest.fixture(scope="module")
def data():
    """Six tasks on a 3x3 grid from 2 primitives of 4 state features, 3 demonstrations each."""
    mdp = fo.GridWorld(size=3, p_success=0.7, gamma=0.9)
    rng = np.random.default_rng(5)
    F = rng.random((9, 4))
    D, H = rng.normal(size=(4, 2)), 3.0 * rng.normal(size=(6, 2))
    R = np.repeat((H @ D.T) @ F.T, 4, axis=1).reshape(6, 9, 4)
    return mdp, F, fo.sample_demonstrations(mdp, R, 3, 6, rng=rng)


def _auto(F, **params):
    search = SharingSearch(route="approx-loo", n_primitives_grid=(1, 2), residual_penalty_grid=(np.inf, 1.0, 0.0))
    return fo.FactIRL(n_primitives="auto", residual_penalty="auto", features=F, max_iter=3, rng=0,
                      sharing_search=search, **params)


def test_the_approx_loo_route_scores_every_task_as_held_out(data):
    mdp, F, demos = data
    assert ROUTES["approx-loo"][0] == "approx-loo"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        model = _auto(F).fit(mdp, demos)
    res = model.cv_results_
    assert "split0_test_score" in res and "split1_test_score" not in res and np.all(res["n_splits_scored"] == 1)
    tasks = np.column_stack([res[f"task{j}_test_score"] for j in range(6)])
    assert np.all(np.isfinite(tasks)) and int(np.sum(res["chosen"])) == 1
    assert {(p["n_primitives"], p["residual_penalty"]) for p in res["params"]} >= {(1, np.inf), (2, 1.0), (1, 0.0)}
    chosen = res["params"][int(np.flatnonzero(res["chosen"])[0])]
    assert (model.n_primitives_, model.residual_penalty_) == (chosen["n_primitives"], chosen["residual_penalty"])


def test_the_approx_loo_route_refuses_what_it_does_not_support(data):
    mdp, F, demos = data
    with pytest.raises(ValidationError, match="'policy-matching' objective"):
        _auto(F, objective="mce").fit(mdp, demos)
    with pytest.raises(ValidationError, match="unconstrained H-solver"):
        check_approximate_cv(fo.FactIRL(solver="armijo-nonneg"), task_set(mdp, demos, F))
    with pytest.raises(ValidationError, match="free dictionary"):
        check_approximate_cv(fo.FactIRL(dictionary_constraint="nonneg"), task_set(mdp, demos, F))
    with pytest.raises(ValidationError, match="at least 3 tasks"):
        check_approximate_cv(fo.FactIRL(), task_set(mdp, demos[:2], F))
    grids = [mdp, fo.GridWorld(size=4, p_success=0.7, gamma=0.9), mdp]
    two = [demos[0], fo.sample_demonstrations(grids[1], np.zeros((16, 4)), 2, 4, rng=0)[0], demos[2]]
    features = [F, np.random.default_rng(0).random((16, 4)), F]
    with pytest.raises(ValidationError, match="one MDP"):
        check_approximate_cv(fo.FactIRL(), task_set(grids, two, features))

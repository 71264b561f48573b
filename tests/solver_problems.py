"""Step problems with known solutions, shared by the solver tests (``from solver_problems import ...``)."""

import itertools

import numpy as np
from scipy.optimize import nnls

import solvers

ALL = solvers.available_solvers()
GN = [name for name in ALL if name.startswith("gn-qp-")]
N, M, K = 6, 9, 4


def least_squares_problem(residual, jacobian, n, k):
    """A StepProblem from ``residual(x, rows) (r, m)`` and an explicit ``jacobian(x, rows)
    (r, m, k)``, loss ``||r_i||^2``, with all three derivative callables (``linearize``'s
    products use the explicit Jacobian); counts evaluations (one per call)."""
    count = [0]

    def residual_jacobian(x, rows):
        count[0] += 1
        r = residual(x, rows)
        return np.sum(r * r, axis=1), r, jacobian(x, rows)

    def loss_and_grad(x, rows):
        loss, r, J = residual_jacobian(x, rows)
        return loss, 2.0 * np.einsum("nmk,nm->nk", J, r)

    def linearize(x, rows):
        loss, r, J = residual_jacobian(x, rows)
        return solvers.Linearization(
            loss=loss, residual=r, jvp=lambda V: np.einsum("nmk,nk->nm", J, V), vjp=lambda U: np.einsum("nmk,nm->nk", J, U)
        )

    return solvers.StepProblem(
        loss_and_grad=loss_and_grad,
        residual_jacobian=residual_jacobian,
        linearize=linearize,
        n_evaluations=lambda: count[0],
        n_rows=n,
        n_params=k,
    )


def linear_problem(rng, n=N, m=M, k=K):
    """A StepProblem with ``r_i = A_i h_i - y_i``, loss ``||r_i||^2``; counts evaluations."""
    A = rng.standard_normal((n, m, k))
    y = rng.standard_normal((n, m))
    y[: n // 2] += 3.0 * np.einsum("nmk,nk->nm", A[: n // 2], np.abs(rng.standard_normal((n // 2, k))))
    problem = least_squares_problem(lambda x, rows: np.einsum("nmk,nk->nm", A[rows], x) - y[rows], lambda x, rows: A[rows].copy(), n, k)
    return problem, A, y


def exp_problem(rng, n=N, m=M, k=K):
    """A nonlinear least squares ``r_i = exp(A_i h_i) - y_i`` (y > 0 reachable for half the rows)."""
    A = 0.5 * rng.standard_normal((n, m, k))
    y = np.exp(np.einsum("nmk,nk->nm", A, rng.standard_normal((n, k))))
    y[n // 2 :] *= rng.uniform(0.5, 2.0, size=(n - n // 2, m))

    def residual(x, rows):
        return np.exp(np.einsum("nmk,nk->nm", A[rows], x)) - y[rows]

    def jacobian(x, rows):
        return np.exp(np.einsum("nmk,nk->nm", A[rows], x))[:, :, None] * A[rows]

    return least_squares_problem(residual, jacobian, n, k), A, y


def sparse_reference(Mx, c, alpha):
    """``argmin_z ||Mx z - c||^2 + alpha ||z||_1`` by enumerating all 3^k sign patterns.

    For a pattern s in {-1, 0, 1}^k the stationary point with ``z_j = 0`` where ``s_j = 0`` is
    a least-squares solve; it is a candidate if its signs match s. The objective is strictly
    convex, so the optimum is the best candidate.
    """
    k = Mx.shape[1]
    best, best_val = None, np.inf
    for signs in itertools.product((-1.0, 0.0, 1.0), repeat=k):
        s = np.array(signs)
        free = s != 0
        z = np.zeros(k)
        if free.any():
            Mf = Mx[:, free]
            z[free] = np.linalg.solve(Mf.T @ Mf, Mf.T @ c - 0.5 * alpha * s[free])
            if np.any(np.sign(z[free]) != s[free]):
                continue
        val = np.sum((Mx @ z - c) ** 2) + alpha * np.abs(z).sum()
        if val < best_val:
            best, best_val = z, val
    return best


def exact_step(A, y, h, lam, constraint, alpha):
    """Exact solution z of the damped subproblem of every row (the reference)."""
    out = np.empty_like(h)
    for i in range(h.shape[0]):
        r = A[i] @ h[i] - y[i]
        Mx = np.vstack([A[i], np.sqrt(lam[i]) * np.eye(h.shape[1])])
        c = Mx @ h[i] - np.concatenate([r, np.zeros(h.shape[1])])
        if constraint == "none":
            out[i] = np.linalg.lstsq(Mx, c, rcond=None)[0]
        elif constraint == "nonneg":
            out[i] = nnls(Mx, c)[0]
        else:
            out[i] = sparse_reference(Mx, c, alpha)
    return out


def feasible(solver, x):
    if solver.constraint == "nonneg":
        return np.min(x) >= -1e-8
    return np.all(np.isfinite(x))

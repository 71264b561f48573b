"""The reduced subproblem of a Gauss-Newton / Levenberg-Marquardt QP step (docs/maths.md §5).

For one task (row) with residuals ``r`` (m,), Jacobian ``J`` (m, k), coefficients ``h`` (k,) and
damping ``lam``, the damped least squares over the new coefficients ``z = h + delta``,

    ||r + J (z - h)||^2 + lam ||z - h||^2,

is reduced before any QP solver sees it to a k x k triangular factor: with
``[J; sqrt(lam) I] = Q R`` (reduced QR) and ``c = Q^T [r; 0]`` it equals
``||R z - b||^2 + const`` with ``b = R h - c`` (:func:`reduce_least_squares`). Here also: the
rescaling of every row's reduced problem to unit size (:func:`rescale_subproblems`), the
length of the unconstrained damped step used by the step bound
(:func:`unconstrained_step_norm`), the safe proximal-gradient step taken when every QP
QP solver failed (:func:`safe_step`), and the per-thread cache of compiled block QPs
(:func:`compiled_block_qp`). The solver that uses them is
:class:`solvers.gauss_newton.GaussNewtonSolver`.
"""

from __future__ import annotations

import collections
import threading
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "COMPILED_CACHE_SIZE",
    "compiled_block_qp",
    "reduce_least_squares",
    "rescale_subproblems",
    "safe_step",
    "unconstrained_step_norm",
]


#: compiled block QPs kept per thread (see :func:`compiled_block_qp`)
COMPILED_CACHE_SIZE = 16
_compiled = threading.local()


def compiled_block_qp(interface: str, n: int, k: int, constraint: str) -> Any:
    """The block QP of ``n`` tasks x ``k`` coefficients, compiled once per thread and shape.

    Compiling is expensive (cvxpy canonicalises the parametrised problem on its first solve,
    which costs far more than a later solve with new parameter values), and every new solver
    object (one per ``GradIRL``/``FactIRL`` fit) would pay it again. The problems
    only hold parameter values between calls, so one compiled problem serves every solver of
    a thread in turn; each thread has its own (no sharing between concurrent fits). The
    ``COMPILED_CACHE_SIZE`` most recently built shapes are kept.
    """
    cache = getattr(_compiled, "problems", None)
    if cache is None:
        cache = _compiled.problems = collections.OrderedDict()
    key = (interface, n, k, constraint)
    if key in cache:
        cache.move_to_end(key)
        return cache[key]
    if interface == "cvxpy":
        from .qp_cvxpy import CvxpyBlockQP

        cache[key] = CvxpyBlockQP(n, k, constraint)
    else:
        from .qp_direct import DirectBlockQP

        cache[key] = DirectBlockQP(n, k, constraint)
    while len(cache) > COMPILED_CACHE_SIZE:
        cache.popitem(last=False)
    return cache[key]


def reduce_least_squares(
    jacobian: NDArray[np.float64], residual: NDArray[np.float64], coefficients: NDArray[np.float64], lam: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Reduce each row's damped least squares to a k x k triangular factor (QR).

    ``||r + J (z - h)||^2 + lam ||z - h||^2 = ||R z - b||^2 + ||r_perp||^2`` for all z, with
    ``[J; sqrt(lam) I] = Q R`` and ``b = R h - Q^T [r; 0]``.

    Parameters
    ----------
    jacobian : ndarray, shape (n, m, k)
    residual : ndarray, shape (n, m)
    coefficients : ndarray, shape (n, k)
        ``h``.
    lam : ndarray, shape (n,)
        Damping (>= 0).

    Returns
    -------
    R : ndarray, shape (n, k, k)
        Upper triangular.
    b : ndarray, shape (n, k)
    """
    n, m, k = jacobian.shape
    M = np.concatenate([jacobian, np.sqrt(lam)[:, None, None] * np.eye(k)[None]], axis=1)
    Q, R = np.linalg.qr(M)  # batched, reduced: Q (n, m+k, k), R (n, k, k)
    c = np.einsum("nmk,nm->nk", Q[:, :m], residual)
    b = np.einsum("nij,nj->ni", R, coefficients) - c
    return R, b


def safe_step(R: NDArray[np.float64], b: NDArray[np.float64], coefficients: ArrayLike, constraint: str = "none", alpha: float = 0.0) -> NDArray[np.float64]:
    """One proximal-gradient step on ``||R z - b||^2 [+ alpha ||z||_1]`` from ``h`` (no QP solver).

    With step ``1 / L``, ``L = 2 ||R||_2^2`` (the gradient's Lipschitz constant), the step cannot
    increase the (damped) model; it is the fallback when every QP solver failed.

    Returns
    -------
    z : ndarray, shape (n, k)
        Feasible for ``constraint``.
    """
    h = np.asarray(coefficients, dtype=np.float64)
    L = 2.0 * np.linalg.norm(R, ord=2, axis=(1, 2)) ** 2
    L = np.where(L > 0, L, 1.0)
    grad = 2.0 * np.einsum("nji,nj->ni", R, np.einsum("nij,nj->ni", R, h) - b)
    z = h - grad / L[:, None]
    if constraint == "nonneg":
        z = np.maximum(z, 0.0)
    elif constraint == "sparse":
        z = np.sign(z) * np.maximum(np.abs(z) - alpha / L[:, None], 0.0)
    return z


def unconstrained_step_norm(R: NDArray[np.float64], b: NDArray[np.float64], x: NDArray[np.float64]) -> NDArray[np.float64]:
    """``||R_i^{-1} b_i - x_i||`` per row: the length of the unconstrained damped step (inf
    where it cannot be computed)."""
    with np.errstate(all="ignore"):
        try:
            z = np.linalg.solve(R, b[..., None])[..., 0]
        except np.linalg.LinAlgError:  # an exactly singular row: solve row by row
            z = np.full_like(x, np.inf)
            for i in range(x.shape[0]):
                try:
                    z[i] = np.linalg.solve(R[i], b[i])
                except np.linalg.LinAlgError:
                    pass
        norm = np.linalg.norm(z - x, axis=1)
    return np.where(np.isfinite(norm), norm, np.inf)



def rescale_subproblems(
    R: NDArray[np.float64], b: NDArray[np.float64], alpha: ArrayLike = 0.0
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Scale every row's reduced subproblem to unit size, without changing its minimiser.

    With ``s_i = max|R_i|`` (1 where zero), ``||R_i z - b_i||^2 + a_i ||z||_1 = s_i^2 (||R_i z / s_i
    - b_i / s_i||^2 + (a_i / s_i^2) ||z||_1)``, so the QP solvers' absolute tolerances mean the
    same thing for a tiny Jacobian (near a fit). The scaled L1 weight is capped at
    ``2 ||(R_i / s_i)^T (b_i / s_i)||_inf``, the smallest weight for which ``z = 0`` is the
    minimiser: every larger weight has the same minimiser (zero), so the cap changes nothing
    but keeps the weight finite when ``s_i`` is tiny.

    Parameters
    ----------
    R : ndarray, shape (n, k, k)
    b : ndarray, shape (n, k)
    alpha : float or ndarray, shape (n,)
        L1 weight (0 for the smooth variants).

    Returns
    -------
    Rs : ndarray, shape (n, k, k)
    bs : ndarray, shape (n, k)
    alphas : ndarray, shape (n,)
    """
    s = np.max(np.abs(R), axis=(1, 2))
    s[~(s > 0)] = 1.0
    Rs, bs = R / s[:, None, None], b / s[:, None]
    a = np.broadcast_to(np.asarray(alpha, dtype=np.float64), s.shape)
    zero_at = 2.0 * np.max(np.abs(np.einsum("nji,nj->ni", Rs, bs)), axis=1)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        alphas = np.where(a > 0, np.minimum(a / s**2, zero_at), 0.0)
    return Rs, bs, alphas

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
QP solver failed (:func:`safe_step`), the per-thread cache of compiled block QPs
(:func:`compiled_block_qp`), and the closed-form elimination of a ridge-penalised block of
parameters (:func:`eliminate_ridge`). The solver that uses them is
:class:`solvers.gauss_newton.GaussNewtonSolver`.

Eliminating a ridge block. When each row's parameters are ``x = [h, d]`` (k + q) and the
residuals are ``[r(x), sqrt(lambda) d]`` (m + q; the Jacobian's last q rows ``[0, sqrt(lambda)
I]``: the residual model of FactIRL, q = p reward parameters), the damped least squares over
the new ``[h', d']`` is, with ``A = dr/dh`` (m, k), ``B = dr/dd`` (m, q) and ``nu = lambda + lam``,

    ||r + A (h' - h) + B (d' - d)||^2 + lambda ||d'||^2 + lam ||h' - h||^2 + lam ||d' - d||^2.

For fixed ``h'`` it is minimised by ``d' = G^-1 (lam d - B^T e)`` with ``G = B^T B + nu I`` and
``e = r + A (h' - h) - B d``; putting it back leaves (Woodbury, ``W = B B^T + nu I``)

    ||r~ + A~ (h' - h)||^2 + lam ||h' - h||^2 + const,
    A~ = sqrt(nu) W^-1/2 A,  r~ = sqrt(nu) W^-1/2 (r - (lambda / nu) B d),

a damped least squares over the k coefficients alone, reduced as any other
(:func:`reduce_least_squares`). Only the Jacobian's nonzero rows count (a residual whose row
is zero moves with no parameter: the unvisited states of a demonstration), so with ``m'``
such rows the factorisations are of ``[B^T; sqrt(nu) I]`` ((q + m') x m', when m' <= q) or
``[B; sqrt(nu) I]`` ((m' + q) x q), never of the stacked (m + q + k) x (k + q) system.
"""

from __future__ import annotations

import collections
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "COMPILED_CACHE_SIZE",
    "RidgeElimination",
    "compiled_block_qp",
    "eliminate_ridge",
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


@dataclass(frozen=True)
class RidgeElimination:
    """The reduced subproblem of every row with its ridge block eliminated (:func:`eliminate_ridge`).

    Attributes
    ----------
    R : ndarray, shape (n, k, k)
        Upper triangular: ``||R h' - b||^2`` is the damped model over the kept coefficients
        ``h'``, up to a constant (the ridge block at its minimiser for ``h'``).
    b : ndarray, shape (n, k)
    """

    R: NDArray[np.float64]
    b: NDArray[np.float64]
    _A: NDArray[np.float64]  # (n, m', k), the Jacobian's nonzero rows over h
    _B: NDArray[np.float64]  # (n, m', q), over d
    _r: NDArray[np.float64]  # (n, m'), the residuals of those rows
    _x: NDArray[np.float64]  # (n, k + q), the current parameters
    _lam: NDArray[np.float64]  # (n,), the damping
    _nu: NDArray[np.float64]  # (n,), lambda + lam
    _factor: NDArray[np.float64]  # (n, m', m') or (n, q, q): upper triangular, of W or G
    _small_rows: bool  # whether _factor is W's (m' <= q) or G's

    def block(self, kept: NDArray[np.float64]) -> NDArray[np.float64]:
        """The eliminated block's minimiser ``d'`` (n, q) for the kept coefficients ``h'`` (n, k)."""
        k = self.R.shape[1]
        h, d = self._x[:, :k], self._x[:, k:]
        e = self._r + _bmv(self._A, kept - h) - _bmv(self._B, d)
        v = self._lam[:, None] * d - _bmtv(self._B, e)
        if self._small_rows:  # G^-1 v = (v - B^T W^-1 B v) / nu
            return (v - _bmtv(self._B, _cho_solve(self._factor, _bmv(self._B, v)))) / self._nu[:, None]
        return _cho_solve(self._factor, v)

    def minimiser(self) -> NDArray[np.float64]:
        """Every row's unconstrained minimiser ``[h', d']`` (n, k + q) of the damped model;
        NaN in a row whose factor is singular."""
        with np.errstate(all="ignore"):
            try:
                kept = np.asarray(np.linalg.solve(self.R, self.b[..., None])[..., 0], dtype=np.float64)
            except np.linalg.LinAlgError:
                kept = np.full_like(self.b, np.nan)
            return np.concatenate([kept, self.block(kept)], axis=1)


def _bmv(M, v):
    """``M_i v_i`` for a batch: (n, a, b) x (n, b) -> (n, a)."""
    return np.matmul(M, v[..., None])[..., 0]


def _bmtv(M, v):
    """``M_i^T v_i`` for a batch: (n, a, b) x (n, a) -> (n, b)."""
    return np.matmul(v[:, None, :], M)[:, 0]


def _cho_solve(U, v):
    """``(U_i^T U_i)^-1 v_i`` for a batch of upper triangular U (n, a, a) and v (n, a)."""
    y = np.linalg.solve(np.swapaxes(U, 1, 2), v[..., None])
    return np.linalg.solve(U, y)[..., 0]


def _qr_r(M):
    """The upper triangular factor of a batched reduced QR (n, a, b) -> (n, b, b), a >= b."""
    return np.linalg.qr(M, mode="r")


def eliminate_ridge(
    jacobian: NDArray[np.float64], residual: NDArray[np.float64], x: NDArray[np.float64], lam: NDArray[np.float64],
    size: int, penalty: float,
) -> RidgeElimination:
    """Each row's damped least squares with its ridge block eliminated in closed form (module docstring).

    The same subproblem as :func:`reduce_least_squares` on the stacked ``jacobian`` (its
    minimiser over ``[h', d']`` is the same up to round-off), reduced to the k kept
    coefficients; :meth:`RidgeElimination.block` gives the block's part of a solution.

    Parameters
    ----------
    jacobian : ndarray, shape (n, m + q, k + q)
        Stacked: the last q rows are ``[0, sqrt(penalty) I]`` (not read).
    residual : ndarray, shape (n, m + q)
        The last q entries are ``sqrt(penalty) d`` (not read).
    x : ndarray, shape (n, k + q)
        ``[h, d]``, the current parameters.
    lam : ndarray, shape (n,)
        Damping (> 0, or ``penalty`` > 0).
    size : int
        q, the ridge block's size (the last q parameters).
    penalty : float
        ``lambda`` >= 0.

    Returns
    -------
    RidgeElimination
    """
    n, mq, kq = jacobian.shape
    q, k = int(size), kq - int(size)
    m = mq - q
    top, r_top = jacobian[:, :m], residual[:, :m]
    if m == 0:  # residuals of the ridge only: one zero row stands for the rest
        top, r_top = np.zeros((n, 1, kq)), np.zeros((n, 1))
    live = np.any(top != 0.0, axis=2)  # (n, m): the rows some parameter moves
    m1 = max(int(live.sum(axis=1).max(initial=0)), 1)
    order = np.argsort(~live, axis=1, kind="stable")[:, :m1]  # each row's live rows first
    keep = np.take_along_axis(live, order, axis=1)
    J = np.take_along_axis(top, order[..., None], axis=1) * keep[..., None]
    r = np.take_along_axis(r_top, order, axis=1) * keep
    A, B = J[:, :, :k], J[:, :, k:]
    lam = np.asarray(lam, dtype=np.float64)
    nu = float(penalty) + lam
    d = x[:, k:]
    s = r - (float(penalty) / nu)[:, None] * _bmv(B, d)
    small = m1 <= q
    if small:  # W = B B^T + nu I = U^T U from the QR of [B^T; sqrt(nu) I] ((q + m') x m')
        U = _qr_r(np.concatenate([np.swapaxes(B, 1, 2), np.sqrt(nu)[:, None, None] * np.eye(m1)], axis=1))
        Lt = np.swapaxes(U, 1, 2)
        A_red = np.sqrt(nu)[:, None, None] * np.linalg.solve(Lt, A)
        r_red = np.sqrt(nu)[:, None] * np.linalg.solve(Lt, s[..., None])[..., 0]
    else:  # G = B^T B + nu I = U^T U from the QR of [B; sqrt(nu) I] ((m' + q) x q); nu W^-1 = I - Q1 Q1^T
        Q, U = np.linalg.qr(np.concatenate([B, np.sqrt(nu)[:, None, None] * np.eye(q)], axis=1))
        Q1 = Q[:, :m1]
        A_red = np.concatenate([A - np.matmul(Q1, np.matmul(np.swapaxes(Q1, 1, 2), A)),
                                -np.matmul(Q[:, m1:], np.matmul(np.swapaxes(Q1, 1, 2), A))], axis=1)
        proj = _bmtv(Q1, s)
        r_red = np.concatenate([s - _bmv(Q1, proj), -_bmv(Q[:, m1:], proj)], axis=1)
    R, b = reduce_least_squares(A_red, r_red, x[:, :k], lam)
    return RidgeElimination(R, b, A, B, r, np.asarray(x, dtype=np.float64), lam, nu, U, small)


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

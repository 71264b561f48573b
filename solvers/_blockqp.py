"""The block-separable QP of one Gauss-Newton H-step, shared by every QP solver (docs/maths.md §5).

After the per-task QR reduction (see :func:`solvers.gn_subproblem.reduce_least_squares`) the
subproblem of task ``i`` over its new coefficients ``z_i`` (k,) is

    minimise  ||R_i z_i - b_i||^2  [+ alpha_i ||z_i||_1]     subject to  [z_i >= 0]

with ``R_i`` (k, k) upper triangular. All tasks of an H-step are solved together as one
problem over ``z`` (n, k) whose objective is the sum of the tasks' objectives; the problem is
block-separable, so its solution is each task's solution. Every module that solves it (one route to the QP solvers) takes the
stacked data ``R`` (n, k, k), ``b`` (n, k) and returns a :class:`BlockQPResult`.

Both routes pose the least squares with an auxiliary ``t = R z - b`` (objective ``||t||^2``), the
form cvxpy's QP canonicalisation produces, so the direct and the cvxpy routes solve the same
problem and neither forms ``R^T R`` (which would square the condition number).
"""

from dataclasses import dataclass

import numpy as np

from .exceptions import SolverOptionError

__all__ = [
    "CONSTRAINTS",
    "QP_SOLVERS",
    "DATA_LIMIT",
    "BlockQPResult",
    "check_constraint",
    "check_qp_solver",
    "check_block_data",
    "check_alpha",
    "refine_active_set",
]

#: constraint variants of the H-step
CONSTRAINTS = ("none", "nonneg", "sparse")
#: the QP solvers (a Gauss-Newton solver's ``qp_solver``); each is also the name of the module (and pip package) it needs
QP_SOLVERS = ("osqp", "clarabel")
#: cvxpy solver names of the QP solvers
CVXPY_NAMES = {"osqp": "OSQP", "clarabel": "CLARABEL"}
#: largest magnitude of block QP data: OSQP takes bounds beyond 1e30 for infinite (and prints
#: an error when an equality bound is beyond it), so data must stay far below
DATA_LIMIT = 1e20


@dataclass
class BlockQPResult:
    """Solution of one block QP.

    Attributes
    ----------
    z : ndarray, shape (n, k) or None
        New coefficients (None when the QP solver returned no point).
    status : str
        The QP solver's status, mapped to cvxpy's vocabulary (``"optimal"``,
        ``"optimal_inaccurate"``, ``"user_limit"``, ``"solver_error"``, ...).
    ok : bool
        Whether ``z`` may be used: only an ``"optimal"`` status counts. Inaccurate solutions
        and iteration limits fill ``z`` in anyway; they are failures all the same.
    solve_time : float
        Wall time of the call, seconds (parameter update, QP solver's solve, retrieval).
    qp_solver : str
        ``"osqp"`` or ``"clarabel"``.
    """

    z: np.ndarray | None
    status: str
    ok: bool
    solve_time: float
    qp_solver: str


def check_constraint(constraint):
    if not isinstance(constraint, str) or constraint not in CONSTRAINTS:
        raise SolverOptionError(f"constraint must be one of {CONSTRAINTS}; got {constraint!r}")
    return constraint


def check_qp_solver(qp_solver):
    if not isinstance(qp_solver, str) or qp_solver not in QP_SOLVERS:
        raise SolverOptionError(f"qp_solver must be one of {QP_SOLVERS}; got {qp_solver!r}")
    return qp_solver


def check_block_data(R, b, n, k):
    """Validate stacked subproblem data against the compiled shape (n, k).

    Raises
    ------
    SolverOptionError
        When a shape is wrong, an entry is not finite or exceeds :data:`DATA_LIMIT` in
        magnitude, or ``R`` is not upper triangular.
    """
    R = np.asarray(R, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if R.shape != (n, k, k) or b.shape != (n, k):
        raise SolverOptionError(f"block QP data must have shapes R ({n}, {k}, {k}) and b ({n}, {k}); got {R.shape} and {b.shape}")
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(b))):
        raise SolverOptionError("block QP data R and b must be finite")
    big = max(float(np.max(np.abs(R), initial=0.0)), float(np.max(np.abs(b), initial=0.0)))
    if big > DATA_LIMIT:
        raise SolverOptionError(f"block QP data must be at most {DATA_LIMIT:g} in magnitude (rescale them); got {big:.3g}")
    if np.any(np.tril(R, -1) != 0):
        raise SolverOptionError("block QP factors R must be upper triangular (from the QR reduction)")
    return R, b


def check_alpha(alpha, n):
    """The L1 weight of every row, shape (n,), from a scalar or an (n,) array (>= 0)."""
    a = np.asarray(alpha, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.shape != (n,) or not np.all(np.isfinite(a)) or np.any(a < 0) or np.any(a > DATA_LIMIT):
        raise SolverOptionError(f"the block QP's L1 weights must be finite, in [0, {DATA_LIMIT:g}], one per task (shape ({n},)); got {alpha!r}")
    return a


def block_structure(n, k):
    """Index arrays of the upper-triangular entries of every task's ``R_i`` in a stacked layout.

    Returns
    -------
    task, row, col : ndarray of intp, shape (n * k (k + 1) / 2,)
    """
    r, c = np.triu_indices(k)
    task = np.repeat(np.arange(n), r.size)
    return task, np.tile(r, n), np.tile(c, n)


def refine_active_set(R, b, z, constraint, alpha=0.0, snap=1e-6, kkt_tol=1e-7):
    """Make a QP solution exact on its active set (exact zeros), when the KKT conditions allow.

    First-order methods and interior-point methods leave the zero coefficients of the
    nonneg/sparse variants at ~1e-8 instead of 0. For each row, coefficients with
    ``|z_j| <= snap (1 + max|z|)`` are set to zero, the others keep their sign ``s``; the
    least squares ``||R_F z_F - b||^2 + alpha s_F^T z_F`` over the free set F is solved exactly
    (QR of ``R_F``), and the result replaces ``z`` only if it satisfies the optimality
    conditions: the signs of the free part are kept, and on the zero set the gradient
    ``g = 2 R^T (R z - b)`` satisfies ``g_j >= -tol`` (nonneg) or ``|g_j| <= alpha + tol``
    (sparse), ``tol = kkt_tol (1 + max|g|)``. Rows are grouped by sign pattern and solved
    batched.

    Parameters
    ----------
    R : ndarray, shape (n, k, k)
    b : ndarray, shape (n, k)
    z : ndarray, shape (n, k)
        A QP solver's solution.
    constraint : {"nonneg", "sparse"}
        Any other value returns ``z`` unchanged.
    alpha : float or ndarray, shape (n,)
        L1 weight (sparse), one per row or shared.

    Returns
    -------
    z : ndarray, shape (n, k)
    refined : ndarray of bool, shape (n,)
        Rows replaced by their exact active-set solution.
    """
    n, k = z.shape
    refined = np.zeros(n, dtype=bool)
    if constraint not in ("nonneg", "sparse"):
        return z, refined
    z = z.copy()
    lin_all = check_alpha(alpha, n) if constraint == "sparse" else np.zeros(n)
    scale = 1.0 + np.max(np.abs(z), axis=1, keepdims=True)
    signs = np.where(np.abs(z) <= snap * scale, 0.0, np.sign(z))
    if constraint == "nonneg":
        signs = np.maximum(signs, 0.0)
    codes = (signs + 1.0) @ (3.0 ** np.arange(k))
    for code in np.unique(codes):
        rows = np.flatnonzero(codes == code)
        s = signs[rows[0]]
        free = s != 0
        cand = np.zeros((rows.size, k))
        if free.any():
            Rf = R[rows][:, :, free]  # (g, k, f)
            Q, T = np.linalg.qr(Rf)
            rhs = np.einsum("gkf,gk->gf", Q, b[rows])
            if constraint == "sparse":  # T z = Q^T b - (alpha / 2) T^{-T} s_F
                sF = np.broadcast_to(s[free], (rows.size, free.sum()))[..., None]
                rhs = rhs - 0.5 * lin_all[rows, None] * np.linalg.solve(np.swapaxes(T, 1, 2), sF)[..., 0]
            cand[:, free] = np.linalg.solve(T, rhs[..., None])[..., 0]
        grad = 2.0 * np.einsum("gji,gj->gi", R[rows], np.einsum("gij,gj->gi", R[rows], cand) - b[rows])
        tol = kkt_tol * (1.0 + np.max(np.abs(grad), axis=1))
        ok = np.all(np.sign(cand[:, free]) == s[free], axis=1)
        if (~free).any():
            gz = grad[:, ~free]
            bound = (gz >= -tol[:, None]) if constraint == "nonneg" else (np.abs(gz) <= lin_all[rows, None] + tol[:, None])
            ok &= np.all(bound, axis=1)
        ok &= np.all(np.isfinite(cand), axis=1)
        z[rows[ok]] = cand[ok]
        refined[rows[ok]] = True
    return z, refined

"""The Gauss-Newton block QP through cvxpy, compiled once per shape (DPP parameters).

One :class:`CvxpyBlockQP` holds a ``cp.Problem`` over ``z`` (n*k,) for a fixed number of tasks
``n``, coefficient size ``k`` and constraint variant. Its data enter as ``cp.Parameter``s:

- ``r_entries`` (n k (k+1)/2,): the upper-triangular entries of every task's ``R_i``;
- ``b`` (n k,): the stacked right-hand sides;
- ``alpha`` (n k,), nonnegative: the L1 weight of each coefficient (the sparse variant; one
  weight per task, repeated k times, so that tasks can be rescaled independently).

``R z`` is written ``G @ multiply(r_entries, E @ z)`` with constant 0/1 matrices ``E`` (picks
``z_i[col]`` for each entry) and ``G`` (sums each entry into ``row`` of its task): a
parameter times a parameter-free affine expression, so the problem is DPP and cvxpy
canonicalises it once; every later ``solve`` only maps the new parameter values to the
QP solver's data (and, for OSQP, updates the cached factorisation). A fresh ``cp.Problem`` per
task per step would pay the canonicalisation every time; the block form pays it once per
shape (measured by ``python -m factirl_opt.lab.bench solvers``). The maths: docs/maths.md §5.
"""

import time
import warnings

import numpy as np
import scipy.sparse as sp

from .exceptions import SolverError

from ._blockqp import CVXPY_NAMES, BlockQPResult, block_structure, check_alpha, check_qp_solver, check_block_data, check_constraint

__all__ = ["CvxpyBlockQP", "qp_solver_options", "DEFAULT_TOLERANCE"]


#: default accuracy of each QP solver: OSQP's eps_abs = eps_rel (<= 1e-5, with polishing) and
#: Clarabel's gap and feasibility tolerances (an interior-point method needs ~1e-10 for the
#: step to match the exact one to ~1e-7 when constraints are weakly active; 2 extra iterations)
DEFAULT_TOLERANCE = {"osqp": 1e-6, "clarabel": 1e-10}


def qp_solver_options(qp_solver, tolerance=None, max_iter=10000):
    """Solver keyword arguments for a QP solver, accurate enough for a Gauss-Newton step.

    Parameters
    ----------
    qp_solver : {"osqp", "clarabel"}
    tolerance : float, optional
        OSQP: ``eps_abs = eps_rel`` (polishing on); Clarabel: ``tol_gap_abs = tol_gap_rel =
        tol_feas``. Default :data:`DEFAULT_TOLERANCE`.
    max_iter : int
        Iteration limit (Clarabel: capped at 500; it needs ~20).
    """
    check_qp_solver(qp_solver)
    tol = DEFAULT_TOLERANCE[qp_solver] if tolerance is None else float(tolerance)
    if qp_solver == "osqp":
        import osqp

        polish = "polish" if int(osqp.__version__.split(".")[0]) < 1 else "polishing"
        return {"eps_abs": tol, "eps_rel": tol, polish: True, "max_iter": int(max_iter)}
    return {"tol_gap_abs": tol, "tol_gap_rel": tol, "tol_feas": tol, "max_iter": int(min(max_iter, 500))}


class CvxpyBlockQP:
    """All tasks' Gauss-Newton subproblems of one H-step as one compiled cvxpy problem.

    Parameters
    ----------
    n_tasks, n_coefficients : int
        ``n`` and ``k``.
    constraint : {"none", "nonneg", "sparse"}
    """

    def __init__(self, n_tasks, n_coefficients, constraint="none"):
        import cvxpy as cp

        self.n, self.k = int(n_tasks), int(n_coefficients)
        self.constraint = check_constraint(constraint)
        n, k = self.n, self.k
        task, row, col = block_structure(n, k)
        m = task.size
        self._triu = np.triu_indices(k)
        E = sp.csr_matrix((np.ones(m), (np.arange(m), task * k + col)), shape=(m, n * k))
        G = sp.csr_matrix((np.ones(m), (task * k + row, np.arange(m))), shape=(n * k, m))
        self.z = cp.Variable(n * k, name="z")
        self.r_entries = cp.Parameter(m, name="r_entries")
        self.b = cp.Parameter(n * k, name="b")
        self.alpha = cp.Parameter(n * k, nonneg=True, name="alpha", value=np.zeros(n * k))
        objective = cp.sum_squares(G @ cp.multiply(self.r_entries, E @ self.z) - self.b)
        constraints = []
        if self.constraint == "nonneg":
            constraints.append(self.z >= 0)
        elif self.constraint == "sparse":
            objective = objective + self.alpha @ cp.abs(self.z)
        self.problem = cp.Problem(cp.Minimize(objective), constraints)
        if not self.problem.is_dcp(dpp=True):  # pragma: no cover - a construction invariant
            raise SolverError("the Gauss-Newton block QP is not DPP")

    def solve(self, R, b, qp_solver="osqp", alpha=0.0, tolerance=None, max_iter=10000, fresh=False):
        """Solve every task's subproblem with new data (re-using the compiled problem).

        Parameters
        ----------
        R : ndarray, shape (n, k, k)
            Upper-triangular factors.
        b : ndarray, shape (n, k)
        qp_solver : {"osqp", "clarabel"}
        alpha : float or ndarray, shape (n,)
            L1 weight (sparse variant only), shared or one per task.
        tolerance : float, optional
            QP solver accuracy (see :func:`qp_solver_options`).
        max_iter : int
        fresh : bool
            Do not warm-start the QP solver from the previous solve (the first solve of a solver
            that shares this compiled problem with others: its result then does not depend on
            what they solved before).

        Returns
        -------
        BlockQPResult

        Raises
        ------
        cvxpy.error.SolverError
            When the QP solver fails outright (the caller decides what to do about it).
        """
        check_qp_solver(qp_solver)
        R, b = check_block_data(R, b, self.n, self.k)
        t0 = time.perf_counter()
        self.r_entries.value = R[:, self._triu[0], self._triu[1]].ravel()
        self.b.value = b.ravel()
        self.alpha.value = np.repeat(check_alpha(alpha, self.n), self.k)
        with warnings.catch_warnings():  # the status is checked below and reported by the caller
            warnings.filterwarnings("ignore", message="Solution may be inaccurate", category=UserWarning)
            self.problem.solve(solver=CVXPY_NAMES[qp_solver], warm_start=not fresh, verbose=False,
                               **qp_solver_options(qp_solver, tolerance, max_iter))
        status = str(self.problem.status)
        value = self.z.value
        z = None if value is None else np.asarray(value, dtype=np.float64).reshape(self.n, self.k)
        ok = status == "optimal" and z is not None and bool(np.all(np.isfinite(z)))
        return BlockQPResult(z=z, status=status, ok=ok, solve_time=time.perf_counter() - t0, qp_solver=qp_solver)


def __getattr__(name):
    """The former name ``backend_options`` of :func:`qp_solver_options` (deprecated)."""
    if name == "backend_options":
        from ._validation import deprecated

        deprecated("solvers.qp_cvxpy.backend_options was renamed qp_solver_options; the old name will be removed "
                   "in the next release")
        return qp_solver_options
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

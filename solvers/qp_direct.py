"""The Gauss-Newton block QP handed to OSQP or Clarabel directly, without cvxpy.

Same problem as :mod:`solvers.qp_cvxpy` (see :mod:`solvers._blockqp`), in the same
auxiliary-variable form cvxpy produces, over ``x = [z (nk), t (nk), u (nk, sparse only)]``:

    minimise   ||t||^2 [+ sum_i alpha_i sum(u_i)]
    subject to R z - t = b,   [z >= 0]   [u - z >= 0, u + z >= 0]

The sparsity pattern depends only on (n, k, constraint); OSQP is set up once and later calls
only update the matrix values and bounds (``OSQP.update``), re-using its workspace. Clarabel
is set up per call (its data-update interface differs across versions; its setup is cheap
at these sizes). This module is the baseline the benchmark compares the cvxpy route with,
and a ``interface="direct"`` option of the Gauss-Newton solvers.
"""

import time

import numpy as np
import scipy.sparse as sp

from ._blockqp import BlockQPResult, block_structure, check_alpha, check_qp_solver, check_block_data, check_constraint
from .qp_cvxpy import qp_solver_options

__all__ = ["DirectBlockQP"]

_OSQP_STATUS = {
    1: "optimal",
    2: "optimal_inaccurate",
    3: "infeasible",
    4: "infeasible_inaccurate",
    5: "unbounded",
    6: "unbounded_inaccurate",
    7: "user_limit",
    8: "user_limit",
}
_CLARABEL_STATUS = {
    "Solved": "optimal",
    "AlmostSolved": "optimal_inaccurate",
    "MaxIterations": "user_limit",
    "MaxTime": "user_limit",
    "PrimalInfeasible": "infeasible",
    "DualInfeasible": "unbounded",
    "AlmostPrimalInfeasible": "infeasible_inaccurate",
    "AlmostDualInfeasible": "unbounded_inaccurate",
}


class DirectBlockQP:
    """All tasks' subproblems of one H-step as one OSQP / Clarabel problem, built by hand.

    Parameters
    ----------
    n_tasks, n_coefficients : int
        ``n`` and ``k``.
    constraint : {"none", "nonneg", "sparse"}
    """

    def __init__(self, n_tasks, n_coefficients, constraint="none"):
        self.n, self.k = int(n_tasks), int(n_coefficients)
        self.constraint = check_constraint(constraint)
        n, k = self.n, self.k
        nk = n * k
        self.nx = nk * (3 if constraint == "sparse" else 2)
        task, row, col = block_structure(n, k)
        self._triu = np.triu_indices(k)
        m = task.size
        # equality rows R z - t = b: the m entries of R first, then -I on t
        rows = [task * k + row, np.arange(nk)]
        cols = [task * k + col, nk + np.arange(nk)]
        vals = [np.zeros(m), -np.ones(nk)]
        n_rows = nk
        if constraint == "nonneg":  # z >= 0 (OSQP: l <= A x; Clarabel: -z + s = 0, s >= 0)
            rows.append(n_rows + np.arange(nk))
            cols.append(np.arange(nk))
            vals.append(np.ones(nk))
            n_rows += nk
        elif constraint == "sparse":  # u - z >= 0 and u + z >= 0
            for sign in (-1.0, 1.0):
                rows += [n_rows + np.arange(nk), n_rows + np.arange(nk)]
                cols += [2 * nk + np.arange(nk), np.arange(nk)]
                vals += [np.ones(nk), np.full(nk, sign)]
                n_rows += nk
        rows, cols, vals = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
        # build with markers 1..N so that the CSC order of every entry is known
        A = sp.csc_matrix((np.arange(1.0, rows.size + 1), (rows, cols)), shape=(n_rows, self.nx))
        A.sort_indices()
        order = A.data.astype(np.intp) - 1  # A.data[j] is entry order[j]
        self._fixed = vals[order]
        self._r_pos = np.empty(m, dtype=np.intp)  # A.data position of each R entry
        is_r = order < m
        self._r_pos[order[is_r]] = np.flatnonzero(is_r)
        self._A = A
        self.n_eq = nk
        self.n_ineq = n_rows - nk
        P = sp.diags(np.concatenate([np.zeros(nk), 2.0 * np.ones(nk), np.zeros(self.nx - 2 * nk)])).tocsc()
        self._P = sp.triu(P, format="csc")
        self._osqp = None

    def _matrix(self, R):
        data = self._fixed.copy()
        data[self._r_pos] = R[:, self._triu[0], self._triu[1]].ravel()
        return data

    def _q(self, alpha):
        q = np.zeros(self.nx)
        if self.constraint == "sparse":
            q[2 * self.n * self.k :] = np.repeat(alpha, self.k)
        return q

    def solve(self, R, b, qp_solver="osqp", alpha=0.0, tolerance=None, max_iter=10000, fresh=False):
        """Solve every task's subproblem; same contract as :meth:`CvxpyBlockQP.solve`.

        Raises
        ------
        Exception
            Whatever the QP solver raises when it fails outright.
        """
        check_qp_solver(qp_solver)
        R, b = check_block_data(R, b, self.n, self.k)
        t0 = time.perf_counter()
        Ax = self._matrix(R)
        if qp_solver == "osqp":
            if fresh:  # no warm start from another solver's last solution
                self._osqp = None
            z, status = self._solve_osqp(Ax, b.ravel(), check_alpha(alpha, self.n), tolerance, max_iter)
        else:
            z, status = self._solve_clarabel(Ax, b.ravel(), check_alpha(alpha, self.n), tolerance, max_iter)
        if z is not None:
            z = z[: self.n * self.k].reshape(self.n, self.k)
        ok = status == "optimal" and z is not None and bool(np.all(np.isfinite(z)))
        return BlockQPResult(z=z, status=status, ok=ok, solve_time=time.perf_counter() - t0, qp_solver=qp_solver)

    def _solve_osqp(self, Ax, b, alpha, tolerance, max_iter):
        import osqp

        l = np.concatenate([b, np.zeros(self.n_ineq)])
        u = np.concatenate([b, np.full(self.n_ineq, np.inf)])
        q = self._q(alpha)
        settings = qp_solver_options("osqp", tolerance, max_iter)
        if self._osqp is None:
            A = self._A.copy()
            A.data = Ax
            solver = osqp.OSQP()
            solver.setup(self._P, q, A, l, u, verbose=False, **settings)
            self._osqp = solver
        else:
            self._osqp.update(q=q, l=l, u=u, Ax=Ax)
            self._osqp.update_settings(**{k: v for k, v in settings.items()})
        res = self._osqp.solve(raise_error=False)
        status = _OSQP_STATUS.get(int(res.info.status_val), "solver_error")
        z = None if res.x is None or not np.all(np.isfinite(res.x)) else np.array(res.x)
        return z, status

    def _solve_clarabel(self, Ax, b, alpha, tolerance, max_iter):
        import clarabel

        A = self._A.copy()
        A.data = Ax.copy()
        # Clarabel: A x + s = rhs, s in cones; OSQP rows "l <= A x" become "-A x + s = -l, s >= 0"
        sign = np.concatenate([np.ones(self.n_eq), -np.ones(self.n_ineq)])
        A = (sp.diags(sign) @ A).tocsc()
        rhs = np.concatenate([b, np.zeros(self.n_ineq)])
        cones = [clarabel.ZeroConeT(self.n_eq)]
        if self.n_ineq:
            cones.append(clarabel.NonnegativeConeT(self.n_ineq))
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        for key, value in qp_solver_options("clarabel", tolerance, max_iter).items():
            setattr(settings, key, value)
        solver = clarabel.DefaultSolver(self._P, self._q(alpha), A, rhs, cones, settings)
        sol = solver.solve()
        status = _CLARABEL_STATUS.get(str(sol.status).split(".")[-1], "solver_error")
        x = np.asarray(sol.x, dtype=float)
        return (x if x.size == self.nx and np.all(np.isfinite(x)) else None), status

"""Low-rank (Woodbury) updates of a sparse factorisation, verified solve by solve (docs/maths.md §4).

A deterministic policy that differs from a factorised one in a few states changes a few rows of
``M = I - gamma P_pi``; instead of a new LU, :class:`UpdatedFactor` corrects the old one's solves.
Used by the sparse planner (:mod:`factirl_opt.planning.sparse_lu`) for policies differing from
their hint in at most :data:`UPDATE_MAX_RANK` states.
"""

from __future__ import annotations

import weakref
from typing import Any

import numpy as np
import scipy.linalg as sla
from numpy.typing import NDArray

from ..exceptions import FactIRLError

__all__ = ["UpdatedFactor", "UPDATE_MAX_RANK", "RESIDUAL_TOL", "REFINE_ABOVE"]

#: a policy differing from a factorised one in at most this many states is solved by a low-rank update
UPDATE_MAX_RANK = 16
#: relative residual every low-rank-updated solve is checked against
RESIDUAL_TOL = 1e-12
#: one step of iterative refinement when the first relative residual exceeds this
REFINE_ABOVE = 1e-14


class UpdatedFactor:
    """A policy differing from a factorised one in k states, by a rank-k (Woodbury) update.

    ``M' = M + U W`` with ``U`` the k unit columns of the changed states and ``W`` (k, S) the
    change of their rows, ``-gamma (P'_rows - P_rows)``. With ``Z = M^-1 U`` (k solves) and the
    capacitance ``C = I + W Z`` (k, k): ``M'^-1 b = y - Z C^-1 W y`` (``y = M^-1 b``) and
    ``M'^-T b = M^-T (b - W^T C^-T Z^T b)``. Every solve is checked against ``M'`` itself:
    one step of iterative refinement if the relative residual exceeds :data:`REFINE_ABOVE`, and a
    fresh factorisation (``planner.factor``) if it still exceeds :data:`RESIDUAL_TOL` (not
    observed in the tests, gamma up to 0.99).

    Parameters
    ----------
    planner : SparseLUPlanner
        Supplies the state order, the augmented ``P`` (``augmented``, ``augmented_transpose``,
        ``row_block``) and fresh factorisations (``factor``). Held by a weak reference: the
        planner's factorisation caches hold this update, and a strong reference back would make
        a reference cycle that keeps the planner and its factorisations (C memory) alive until
        the next full garbage collection. Whoever solves with an update holds its planner (a
        :class:`~factirl_opt.planning.sparse_lu.FactorSystem`).
    base : TaskFactor
        The factorisation of a nearby deterministic policy (``base.policy``).
    policy : ndarray of intp, shape (S,)
    changed : ndarray of int
        Positions, in the planner's order, where ``policy`` differs from ``base.policy``.
    """

    def __init__(self, planner: Any, base: Any, policy: NDArray[np.intp], changed: NDArray[np.intp]) -> None:
        self._planner, self.base, self.policy = weakref.ref(planner), base, policy
        self.gamma, self.augmented, self.augmented_transpose = planner.gamma, planner.augmented, planner.augmented_transpose
        q, A, k = planner.order, planner.A, len(changed)
        self.sel = q * A + policy[q]  # the rows of the augmented P that M' uses, in the planner's order
        old_rows = q[changed] * A + base.policy[q[changed]]
        self.W = planner.gamma * (planner.row_block(old_rows) - planner.row_block(self.sel[changed]))  # (k, S) CSR
        E = np.zeros((len(q), k))
        E[changed, np.arange(k)] = 1.0
        self.Z = base.solve(E)
        # C = I + W Z is nonsingular (det C = det M' / det M); its accuracy is checked by every solve
        self.C = sla.lu_factor(np.eye(k) + self.W @ self.Z)
        self.fresh: Any = None
        self.nbytes = self.Z.nbytes + self.sel.nbytes + 12 * self.W.nnz

    def _raw(self, b: NDArray[np.float64], transpose: bool) -> NDArray[np.float64]:
        if transpose:
            t = sla.lu_solve(self.C, self.Z.T @ b, trans=1)
            return self.base.solve(b - self.W.T @ t, True)
        y = self.base.solve(b)
        return y - self.Z @ sla.lu_solve(self.C, self.W @ y)

    def _residual(self, x: NDArray[np.float64], b: NDArray[np.float64], transpose: bool) -> tuple[float, NDArray[np.float64]]:
        """Largest relative residual over the columns of ``b - M' x`` (or ``M'^T``), and the residual."""
        if transpose:
            y = np.zeros((self.augmented.shape[0],) + x.shape[1:])
            y[self.sel] = x
            r = b - (x - self.gamma * (self.augmented_transpose @ y))
        else:
            r = b - (x - self.gamma * (self.augmented @ x)[self.sel])
        scale = np.linalg.norm(b, axis=0)
        return np.max(np.linalg.norm(r, axis=0) / np.where(scale > 0, scale, 1.0)), r

    def solve(self, b: NDArray[np.float64], transpose: bool = False) -> NDArray[np.float64]:
        """``M'^-1 b`` (or ``M'^-T b``) for b (S,) or (S, k), in the planner's order."""
        if self.fresh is None:
            x = self._raw(b, transpose)
            res, r = self._residual(x, b, transpose)
            if res > REFINE_ABOVE:
                x = x + self._raw(r, transpose)
                res, _ = self._residual(x, b, transpose)
            if res <= RESIDUAL_TOL:
                return x
            planner = self._planner()
            if planner is None:
                raise FactIRLError("a low-rank update needs a fresh factorisation, but its planner was freed "
                                   "(solve through the planner's system, which holds it)")
            self.fresh = planner.factor(self.policy)
        return self.fresh.solve(b, transpose)

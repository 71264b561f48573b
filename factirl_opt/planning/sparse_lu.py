"""The sparse planner: one sparse LU (SuperLU) per policy, cached and updated (docs/maths.md §4).

Memory and time per task grow like the factorisation of ``M = I - gamma P_pi``, about
``S log S`` on grids. See :class:`SparseLUPlanner`.
"""

from __future__ import annotations

import contextlib
import threading
import weakref
from collections.abc import Iterator
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import NDArray

from ..exceptions import FactIRLError
from .allocator import mapped_allocations, release_free_memory
from .base import Planner, PolicySystem
from .cache import CACHE_GROUPS_PER_TASK, FactorCache, scoped_cache
from .lowrank import UPDATE_MAX_RANK, UpdatedFactor

__all__ = ["SparseLUPlanner", "FactorSystem", "TaskFactor", "greedy_actions",
           "FIXED_ORDER_MAX_DENSITY", "WARMUP_MAX_CHANGES", "WARMUP_MAX_SWEEPS", "TRIM_BYTES"]

#: the sparse planner orders states once when the actions' union pattern is at most this much denser than one action's
FIXED_ORDER_MAX_DENSITY = 1.5
#: the sparse planner's value-iteration sweeps (cold start and between exact evaluations) stop once the
#: greedy policies change in at most WARMUP_MAX_CHANGES states per task, after at most WARMUP_MAX_SWEEPS
WARMUP_MAX_CHANGES = 4
WARMUP_MAX_SWEEPS = 100
#: the sparse planner returns the heap's free pages to the OS after this many bytes of new factorisations (per thread):
#: at most about this much freed memory stays resident between two returns. Every return makes the pages that
#: numpy's temporaries and the next factorisations write fault in again: at 16 MiB, 1.8 million page faults and
#: 11% of the CPU of `bench mce`'s default MCE fit (30 tasks, S = 1024; 304 returns), at 64 MiB 1.0 million and
#: 7%, for a peak resident size of 490-509 MB instead of 435-440 (``results/defaults/README.md`` §11)
TRIM_BYTES = 64 * 2**20


def greedy_actions(Q: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """First maximiser and maximum over the leading action axis of Q (A, S, n): (S, n) each (as argmax/max)."""
    best = np.zeros(Q.shape[1:], dtype=np.intp)
    top, mask = Q[0].copy(), np.empty(Q.shape[1:], dtype=bool)
    for a in range(1, Q.shape[0]):
        np.greater(Q[a], top, out=mask)
        np.copyto(best, a, where=mask)
        np.maximum(top, Q[a], out=top)
    return best, top


#: SuperLU's panel size (columns factorised together): 1 instead of SuperLU's default of 10, whose panels cost
#: more than they save on these matrices of a few nonzeros per column (36% faster factorisations measured on
#: ``bench mce``'s draw, results/defaults/README.md §11 and §13); the factors differ from the default's at
#: rounding level, and the planners still agree to the audited tolerances (tests/test_audit_planners.py)
PANEL_SIZE = 1


def lu(MT: sp.csc_matrix, permc_spec: str) -> Any:
    """SuperLU of a CSC matrix ``M^T`` (diagonally dominant: diagonal pivots, see :class:`SparseLUPlanner`)."""
    try:
        with mapped_allocations():
            return spla.splu(MT, permc_spec=permc_spec, diag_pivot_thresh=0.0, panel_size=PANEL_SIZE,
                             options={"SymmetricMode": True})
    except RuntimeError as exc:  # singular: impossible for gamma < 1 and a stochastic P
        raise FactIRLError(f"sparse LU of I - gamma P_pi failed: {exc}") from None


class TaskFactor:
    """Sparse LU of one policy's ``M = I - gamma P_pi`` (in the planner's state ordering).

    SuperLU factors ``M^T`` (given as CSC: the CSR arrays of ``M``, no conversion), so
    ``M x = b`` is its transposed solve and ``M^T x = b`` its plain one.
    """

    def __init__(self, MT: sp.csc_matrix, permc_spec: str, policy: NDArray[np.intp] | None = None) -> None:
        self.lu = lu(MT, permc_spec)
        self.policy = policy
        self.nbytes = 16 * self.lu.nnz  # measured resident size of a SuperLU factorisation: 14-16 bytes per entry

    @property
    def base(self) -> TaskFactor:
        """The factorisation itself (a property, not an attribute: no reference cycle that would
        keep a freed factorisation's C memory alive until the next garbage collection)."""
        return self

    def solve(self, b: NDArray[np.float64], transpose: bool = False) -> NDArray[np.float64]:
        return self.lu.solve(b, trans="N" if transpose else "T")


class FactorSystem(PolicySystem):
    """One sparse solver per task (:class:`TaskFactor` or :class:`UpdatedFactor`), in the
    planner's state ordering: right-hand sides are permuted in, solutions permuted back."""

    solvers: list[Any]

    def __init__(self, planner: SparseLUPlanner, solvers: list[Any]) -> None:
        self.planner, self.solvers, self.n = planner, list(solvers), len(solvers)

    def _solve(self, B: NDArray[np.float64], transpose: bool) -> NDArray[np.float64]:
        q, qinv = self.planner.order, self.planner.inverse_order
        # B[:, q] as a C-contiguous array (the subscript's is not: its blocks were copied one by one),
        # in C-contiguous blocks: a low-rank update's products (BLAS) round differently with the layout
        Bq = np.take(B, q, axis=1)
        X = np.empty(Bq.shape)
        for j, solver in enumerate(self.solvers):
            X[j] = solver.solve(np.ascontiguousarray(Bq[j]), transpose)
        # the subscript's layout (Fortran order for (n, S)): the sums over the solutions downstream
        # depend on it in their last bits, and so would a fit's results
        return X[:, qinv]

    def solve(self, B: NDArray[np.float64]) -> NDArray[np.float64]:
        return self._solve(B, False)

    def solve_transpose(self, B: NDArray[np.float64]) -> NDArray[np.float64]:
        return self._solve(B, True)


class SparseLUPlanner(Planner):
    """One sparse LU per policy (SuperLU), reused for values, adjoint and Jacobian solves.

    Arithmetic. ``M = I - gamma P_pi`` is strictly diagonally dominant by rows
    (``1 - gamma P_ss > gamma (1 - P_ss)``), a property kept by symmetric permutations and by
    Gaussian elimination, so SuperLU runs with diagonal pivots (``diag_pivot_thresh=0``,
    symmetric mode: growth factor <= 2, relative residuals ~1e-16) and the fill of a fixed
    symmetric ordering.

    Ordering. When the union of the actions' successor patterns is not much denser than one
    action's (ratio <= :data:`FIXED_ORDER_MAX_DENSITY`; every grid world with
    ``p_success < 1``), one minimum-degree ordering of that union (``MMD_AT_PLUS_A``) is
    computed once and every policy's matrix is built directly in that order: the fill of any
    policy is then a subset of the union's. Otherwise each policy is ordered on its own.

    Reuse. Factorisations are cached by policy, one cache per thread (:attr:`factor_cache`,
    :class:`~factirl_opt.planning.cache.FactorCache`: up to ``FACTOR_CACHE_BYTES``, and
    ``CACHE_GROUPS_PER_TASK`` per task of the largest batch planned), so a
    warm-started evaluation at an unchanged greedy policy costs only solves. A policy that
    differs from a factorised one (its hint, e.g. the previous policy-iteration sweep) in
    at most :data:`UPDATE_MAX_RANK` states is solved by a verified low-rank update of that
    factorisation (:class:`UpdatedFactor`; measured break-even with a new LU: 24-28 states
    at S = 1024 and 10,000). The cache is grouped by factorisation (an LU and its latest
    update) and evicts whole groups, least recently used first.

    Policy iteration. A cold start runs value-iteration sweeps first (:meth:`initial_policy`)
    and, between exact evaluations, :meth:`refine_policy` runs more (modified policy
    iteration): a batched sweep costs one sparse product for all tasks, far less than a
    factorisation per task, and a 100-task fit needs about a third of the factorisations of
    plain policy iteration. Every result is still an exactly evaluated, verified optimum.

    Memory. SuperLU allocates with ``malloc``; see :mod:`factirl_opt.planning.allocator` for how
    its blocks are returned to the OS on glibc.
    """

    name = "sparse-lu"

    def __init__(self, mdp):
        super().__init__(mdp)
        self.P = mdp.csr()
        self.PT = self.P.T.tocsr()
        # rows in action-major order (a * S + s): value sweeps work on (A, S, n) blocks
        self._P_actions = self.P[(np.arange(self.S)[None, :] * self.A + np.arange(self.A)[:, None]).ravel()]
        self.order, self.permc_spec = self._ordering()
        self.inverse_order = np.argsort(self.order)
        self._augmented()
        self._pattern = None if self._union_nnz is None else self._stochastic_pattern()
        self._local = threading.local()  # this thread's FactorCache and bytes factorised since the last trim
        self._caches: weakref.WeakSet[FactorCache] = weakref.WeakSet()  # every live thread's cache
        self._caches_lock = threading.Lock()

    def _ordering(self):
        """State ordering ``q`` (new index i is state ``q[i]``) and SuperLU's permc_spec."""
        S, A = self.S, self.A
        union = sp.csr_matrix((np.ones(self.P.nnz), self.P.indices, self.P.indptr), shape=(S * A, S))
        union = (sp.csr_matrix((np.ones(S * A), (np.arange(S * A) // A, np.arange(S * A))), shape=(S, S * A)) @ union)
        union = (union + sp.identity(S, format="csr")).tocsr()
        density = (union.nnz / S) / ((self.P.nnz + S * A) / (S * A))
        self._union_nnz = None
        if density > FIXED_ORDER_MAX_DENSITY:
            return np.arange(S), "MMD_AT_PLUS_A"
        union.data[:] = 1.0
        union = sp.diags(1.0 / np.asarray(union.sum(axis=1)).ravel()) @ union
        union_lu = lu(sp.csc_matrix(sp.identity(S) - self.gamma * union), "MMD_AT_PLUS_A")
        self._union_nnz = int(union_lu.nnz)  # any policy's fill in this order is a subset of the union's
        return np.argsort(union_lu.perm_c), "NATURAL"

    def _augmented(self):
        """``P`` with columns in the planner's order and an explicit diagonal entry in every row."""
        S, A = self.S, self.A
        qinv = self.inverse_order
        rows = np.repeat(np.arange(S * A), np.diff(self.P.indptr))
        own = qinv[np.arange(S * A) // A]  # the diagonal column of row s*A + a, in the new order
        Paug = sp.csr_matrix((np.concatenate([self.P.data, np.zeros(S * A)]),
                              (np.concatenate([rows, np.arange(S * A)]), np.concatenate([qinv[self.P.indices], own]))),
                             shape=(S * A, S))
        Paug.sort_indices()
        rows = np.repeat(np.arange(S * A), np.diff(Paug.indptr))
        # offset of each row's diagonal entry within the row (exactly one per row)
        self.augmented, self._diag_offset = Paug, np.flatnonzero(Paug.indices == own[rows]) - Paug.indptr[:-1]
        self.augmented_transpose = Paug.T.tocsr()

    def backup(self, V):
        if V.ndim == 3:  # k directions: (n, S, k) -> (n, S*A, k)
            n, _, k = V.shape
            out = self.P @ np.moveaxis(V, 0, 1).reshape(self.S, n * k)
            return np.moveaxis(out.reshape(self.S * self.A, n, k), 1, 0)
        return (self.P @ np.ascontiguousarray(V.T)).T.reshape(V.shape[0], self.S, self.A)

    def q_from_values(self, R, V):
        """``Q = R + gamma P V`` (:meth:`Planner.q_from_values`, the same values): the product
        (S*A, n) scaled in place and added to ``R`` from that layout, without an (n, S, A) copy of it."""
        X = self.P @ np.ascontiguousarray(V.T)
        X *= self.gamma
        return np.add(R, X.T.reshape(V.shape[0], self.S, self.A), out=np.empty(np.shape(R)))

    def pullback(self, G):
        return (self.PT @ np.ascontiguousarray(G.reshape(G.shape[0], self.S * self.A).T)).T

    def _rows(self, rows):
        """CSR arrays (data, indices, indptr) of the given rows of the augmented ``P``."""
        Paug = self.augmented
        start, length = Paug.indptr[rows], Paug.indptr[rows + 1] - Paug.indptr[rows]
        indptr = np.zeros(len(rows) + 1, dtype=Paug.indptr.dtype)
        np.cumsum(length, out=indptr[1:])
        gather = np.repeat(start - indptr[:-1], length) + np.arange(indptr[-1])
        return Paug.data[gather], Paug.indices[gather], indptr

    def row_block(self, rows):
        """The given rows of ``P`` (rows ``s * A + a``), columns in the planner's order, as CSR."""
        return sp.csr_matrix(self._rows(rows), shape=(len(rows), self.S))

    def matrix_transpose(self, policy_i):
        """``M^T = (I - gamma P_pi)^T`` (S, S) as CSC (the CSR arrays of ``M``), in the planner's
        state order, of one deterministic (S,) or stochastic (S, A) policy (given in the MDP's order)."""
        S, A, q = self.S, self.A, self.order
        if policy_i.ndim == 2 and self._union_nnz is not None:
            return self._stochastic_matrix_transpose(policy_i)
        if policy_i.ndim == 2:
            Pi = sp.csr_matrix((policy_i[q].ravel(), (np.repeat(np.arange(S), A), (q[:, None] * A + np.arange(A)).ravel())),
                               shape=(S, S * A))
            M = (sp.identity(S, format="csr") - self.gamma * (Pi @ self.augmented)).tocsr()
            M.sort_indices()
            return sp.csc_matrix((M.data, M.indices, M.indptr), shape=(S, S))
        sel = q * A + policy_i[q]
        data, indices, indptr = self._rows(sel)
        data = -self.gamma * data
        data[indptr[:-1] + self._diag_offset[sel]] += 1.0
        return sp.csc_matrix((data, indices, indptr), shape=(S, S))

    def _stochastic_pattern(self):
        """The CSR pattern (indices, indptr) of every stochastic policy's ``M`` in the fixed order
        (the actions' union with the diagonal), the position of each row's diagonal entry in it,
        and the sparse map ``W`` (nnz, S*A) with ``(W pi)[k] = (P_pi)`` at entry ``k`` (``pi``
        raveled as ``s * A + a``, the MDP's order); built with the planner (with the fixed order)."""
        S, A, Paug = self.S, self.A, self.augmented
        rows = np.repeat(np.arange(S * A), np.diff(Paug.indptr))  # row s * A + a of each entry
        new_row = self.inverse_order[rows // A]
        keys = new_row.astype(np.int64) * S + Paug.indices  # (row, column) of M in the fixed order
        unique = np.unique(keys)
        indices = (unique % S).astype(Paug.indices.dtype)
        indptr = np.searchsorted(unique, np.arange(S + 1, dtype=np.int64) * S).astype(Paug.indptr.dtype)
        W = sp.csr_matrix((Paug.data, (np.searchsorted(unique, keys), rows)), shape=(unique.size, S * A))
        W.sum_duplicates()
        diag = np.searchsorted(unique, np.arange(S, dtype=np.int64) * (S + 1))
        return indices, indptr, diag, W

    def _stochastic_matrix_transpose(self, policy_i):
        """:meth:`matrix_transpose` of a stochastic policy in the fixed order: ``M``'s entries on
        the union pattern by one sparse product (``M = I - gamma W pi``), no sparse-matrix algebra
        (5x faster at S = 1024; 8x at S = 576 for a soft policy with 2,107 zeros of 2,880). The
        same matrix, bit for bit, as the sparse product ``I - gamma Pi P`` it replaces: the same
        sums, in the same order, and the same pattern: with no zero in the policy no product
        vanishes, and for a policy with zeros (a soft policy whose probabilities underflow) the
        entries that vanish exactly are dropped, as that product drops them."""
        indices, indptr, diag, W = self._pattern
        pi = np.ascontiguousarray(policy_i, dtype=np.float64).reshape(-1)
        data = W @ pi
        data *= -self.gamma
        data[diag] += 1.0
        if not pi.min() > 0.0:  # the product's pattern: without the entries that vanish (never a diagonal one)
            keep = data != 0.0
            if not keep.all():
                before = np.zeros(keep.size + 1, dtype=indptr.dtype)  # entries kept before each position
                np.cumsum(keep, out=before[1:])
                data, indices, indptr = data[keep], indices[keep], before[indptr]
        MT = sp.csc_matrix((self.S, self.S))
        MT.data, MT.indices, MT.indptr = data, indices, indptr
        return MT

    def policy_matrix(self, policy_i):
        """``M = I - gamma P_pi`` (S, S) CSR, in the planner's state order (see :meth:`matrix_transpose`)."""
        return self.matrix_transpose(policy_i).T

    def initial_policy(self, R):
        """Greedy policy after value-iteration sweeps (batched sparse backups, cheap next to a
        factorisation), stopped once no task's greedy policy changes in more than
        :data:`WARMUP_MAX_CHANGES` states per sweep (at most :data:`WARMUP_MAX_SWEEPS` sweeps):
        policy iteration from there needs about one factorisation per task, then low-rank updates.
        """
        Rt = np.ascontiguousarray(np.transpose(R, (2, 1, 0)))  # (A, S, n): one SpMM per sweep, actions outermost
        return self._value_sweeps(Rt, *greedy_actions(Rt))

    def refine_policy(self, R, Q, policy, previous):
        """Value-iteration sweeps from ``V_1 = max_a Q`` (``Q`` exact for the ``previous`` policy
        ``pi``), stopped as in :meth:`initial_policy` (modified policy iteration); none when the
        greedy step changed at most :data:`UPDATE_MAX_RANK` states per task (the next exact
        evaluation is then a cheap low-rank update). Each
        sweep's greedy policy ``pi_k`` satisfies ``V^{pi_k} >= V_k >= V^pi`` (``T V_k >= V_k``
        holds from ``V_0 = V^pi`` on), so policy iteration still improves monotonically and ends
        only on an exactly verified optimum, with far fewer factorisations than one per greedy step."""
        if np.count_nonzero(policy != previous, axis=1).max() <= UPDATE_MAX_RANK:
            return policy
        Rt = np.ascontiguousarray(np.transpose(R, (2, 1, 0)))
        _, V = greedy_actions(np.transpose(Q, (2, 1, 0)))
        return self._value_sweeps(Rt, np.ascontiguousarray(policy.T), V)

    def _value_sweeps(self, Rt, pol, V):
        """Greedy policy (n, S) after value-iteration sweeps from ``V`` (S, n) on rewards ``Rt`` (A, S, n)."""
        A, S, n = Rt.shape
        for _ in range(WARMUP_MAX_SWEEPS):
            Q = (self._P_actions @ V).reshape(A, S, n)
            Q *= self.gamma
            Q += Rt
            new, V = greedy_actions(Q)
            stable = np.count_nonzero(new != pol, axis=0).max() <= WARMUP_MAX_CHANGES
            pol = new
            if stable:
                break
        return np.ascontiguousarray(pol.T)

    @property
    def factor_cache(self) -> FactorCache:
        """This thread's :class:`~factirl_opt.planning.cache.FactorCache` (created on first use;
        dropped with the thread or the planner); inside :meth:`transient_cache` the block's, and
        else inside :func:`~factirl_opt.planning.cache.isolated_caches` the isolated call's."""
        transient = getattr(self._local, "transient", None)
        if transient is not None:
            return transient
        scoped = scoped_cache(self)
        if scoped is not None:
            return scoped
        cache = getattr(self._local, "cache", None)
        if cache is None:
            cache = self._local.cache = FactorCache()
            with self._caches_lock:
                self._caches.add(cache)
        return cache

    def _solver(self, policy_i: NDArray[np.intp], hint: Any) -> Any:
        """A solver for one deterministic policy: a low-rank update of ``hint``'s factorisation
        when the policies differ in at most :data:`UPDATE_MAX_RANK` states, else a new LU."""
        base = None if hint is None else hint.base
        if base is not None and base.policy is not None:
            changed = np.flatnonzero(base.policy[self.order] != policy_i[self.order])
            if 0 < changed.size <= UPDATE_MAX_RANK:
                return UpdatedFactor(self, base, policy_i, changed)
        return self.factor(policy_i)

    def factor(self, policy_i: NDArray[Any]) -> TaskFactor:
        """A new LU of a deterministic (S,) or stochastic (S, A) policy; frees heap pages now and then."""
        factor = TaskFactor(self.matrix_transpose(policy_i), self.permc_spec, policy_i if policy_i.ndim == 1 else None)
        since_trim = getattr(self._local, "since_trim", 0) + factor.nbytes
        if since_trim >= TRIM_BYTES:
            release_free_memory()
            since_trim = 0
        self._local.since_trim = since_trim
        return factor

    def clear_thread_cache(self) -> None:
        """Forget this thread's cached factorisations (other threads keep theirs), and those of
        the isolated call it is in (:func:`~factirl_opt.planning.cache.isolated_caches`)."""
        for cache in (getattr(self._local, "cache", None), scoped_cache(self)):
            if cache is not None:
                cache.clear()

    @contextlib.contextmanager
    def transient_cache(self) -> Iterator[None]:
        """Inside the block, this thread's factorisations are cached in a fresh
        :class:`~factirl_opt.planning.cache.FactorCache` (the thread's own is neither read nor
        written), dropped on exit: once the caller drops its systems, their memory is freed."""
        previous = getattr(self._local, "transient", None)
        self._local.transient = FactorCache()
        try:
            yield
        finally:
            self._local.transient = previous

    def task_bytes(self) -> int:
        """Estimated planning memory of one task during an evaluation: ``CACHE_GROUPS_PER_TASK + 1``
        factorisations (the cached groups and the one in use) at 16 bytes per entry, each at most
        the fill of the actions' union pattern in the fixed ordering, else SuperLU's own first
        estimate ``20 nnz(M)``."""
        nnz = self._union_nnz if self._union_nnz is not None else 20 * (self.P.nnz // self.A + self.S)
        return (CACHE_GROUPS_PER_TASK + 1) * 16 * nnz

    def clear_cache(self) -> None:
        """Forget the cached factorisations of every thread."""
        with self._caches_lock:
            caches = list(self._caches)
        for cache in caches:
            cache.clear()

    def solver_system(self, solvers: list[Any]) -> FactorSystem:
        return FactorSystem(self, solvers)

    def system(self, policy: NDArray[Any], hints: list[Any] | None = None) -> FactorSystem:
        """Solvers of n deterministic (n, S) or stochastic (n, S, A) policies.

        ``hints`` (deterministic policies only): one earlier solver (or None) per task, whose
        factorisation a nearby policy may update instead of factorising anew. Solvers of
        deterministic policies are cached in this thread's :attr:`factor_cache`.
        """
        if policy.ndim == 3:
            return FactorSystem(self, [self.factor(p) for p in policy])
        cache = self.factor_cache
        cache.note_batch(len(policy))
        solvers = []
        for j, pol in enumerate(policy):
            key = np.ascontiguousarray(pol, dtype=np.intp).tobytes()
            solver = cache.get(key)
            if solver is None:
                # the solver keeps a view of its own key, not of the caller's (n, S) batch
                solver = self._solver(np.frombuffer(key, dtype=np.intp), None if hints is None else hints[j])
                cache.remember(key, solver)
            solvers.append(solver)
        return FactorSystem(self, solvers)

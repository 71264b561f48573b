"""The planning engine: the one place that solves Bellman systems (DESIGN sections 3 and 7).

Everything that plans goes through a *planner* bound to an MDP: exact ``Q*`` and a greedy policy
by policy iteration (:func:`optimal_q`), policy evaluation for deterministic and stochastic
policies (:func:`policy_evaluation`), and, for the objectives, the systems
``M = I - gamma P_pi`` of a batch of policies, solved with one or many right-hand sides and
transposed (adjoints). Batches keep tasks on the leading axis: rewards (n, S, A), values (n, S),
deterministic policies (n, S) of action indices, stochastic policies (n, S, A).

Planners (``planner=`` by name everywhere; :func:`available_planners`):

``"dense"``
    Batched dense LU (``numpy.linalg.solve`` on (n, S, S) systems, built in chunks of tasks
    that fit in 256 MiB), Howard's policy iteration from the immediate-reward greedy policy.
    Best for small S; refuses sparse models whose dense copy would not fit.
``"sparse-lu"``
    One sparse LU (SuperLU) per policy with diagonal pivots in a fixed fill-reducing order,
    reused for the policy's values, the transposed (adjoint) solve and the Jacobian's
    right-hand sides, cached between calls, and updated by a verified low-rank correction
    for a policy that differs in a few states; Bellman backups are one sparse x dense product
    for all tasks; policy iteration is modified by value-iteration sweeps between exact
    evaluations (see :class:`SparseLUPlanner`). Memory and time per task grow like its
    factorisation, about ``S log S`` on grids.
``"auto"`` (default)
    ``"dense"`` up to :data:`AUTO_DENSE_MAX_STATES` states, ``"sparse-lu"`` above. The
    crossover was measured on GridWorld with 100 tasks (``python -m factirl_opt.bench scale``
    and 20-iteration GradIRL fits, 2-core machine): at 10x10 the dense planner is as fast or
    faster, at 12x12 (S = 144) both take the same time, at 14x14 the sparse one is 3x faster,
    at 16x16 5x. The paper's 10x10 grid therefore keeps today's dense arithmetic.

Both are direct solvers: relative residuals are at the level of floating point (~1e-15), below
the 1e-12 the library promises; the sparse planner's low-rank updates check every solve's
residual against the policy's own matrix.
"""

import collections
import contextlib
import dataclasses

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ._threads import blas_limited
from ._validation import check_array, check_beta, check_stochastic_policy, check_int, check_mdp, check_policy, check_real, check_rewards
from .exceptions import FactIRLError, ValidationError

__all__ = [
    "available_planners",
    "get_planner",
    "clear_caches",
    "optimal_q",
    "policy_evaluation",
    "boltzmann_policy",
    "value_iteration",
    "PlanResult",
    "plan",
    "adjoint",
    "tangent",
    "AUTO_DENSE_MAX_STATES",
]

#: ``planner="auto"`` uses the dense planner up to this many states (the measured crossover, 12x12)
AUTO_DENSE_MAX_STATES = 144
#: memory for one chunk of dense (c, S, S) systems
DENSE_CHUNK_BYTES = 256 * 2**20
#: the sparse planner's cache of factorisations of recent policies (estimated bytes)
FACTOR_CACHE_BYTES = 768 * 2**20
#: ... and at most this many factorisations (with their latest updates) per task of the largest batch seen
CACHE_GROUPS_PER_TASK = 2
#: a policy differing from a factorised one in at most this many states is solved by a low-rank update
UPDATE_MAX_RANK = 16
#: the sparse planner orders states once when the actions' union pattern is at most this much denser than one action's
FIXED_ORDER_MAX_DENSITY = 1.5
#: the sparse planner's value-iteration sweeps (cold start and between exact evaluations) stop once the
#: greedy policies change in at most WARMUP_MAX_CHANGES states per task, after at most WARMUP_MAX_SWEEPS
WARMUP_MAX_CHANGES = 4
WARMUP_MAX_SWEEPS = 100
#: the sparse planner returns the heap's free pages to the OS after this many bytes of new factorisations
TRIM_BYTES = 16 * 2**20
#: relative residual every low-rank-updated solve is checked against
RESIDUAL_TOL = 1e-12


class PolicySystem:
    """``M = I - gamma P_pi`` for a batch of n policies: solve ``M X = B`` and ``M^T X = B``.

    Right-hand sides ``B`` are (n, S) or (n, S, k). Built by :meth:`Planner.system`.
    """

    n: int
    #: per-task solvers (sparse planners), or None
    solvers = None

    def solve(self, B):  # pragma: no cover - interface
        raise NotImplementedError

    def solve_transpose(self, B):  # pragma: no cover - interface
        raise NotImplementedError


class _DenseSystem(PolicySystem):
    """Dense systems built chunk by chunk from the policies (never all n (S, S) at once)."""

    def __init__(self, planner, policy):
        self.planner, self.policy, self.n = planner, policy, policy.shape[0]

    def _solve(self, B, transpose):
        S = self.planner.S
        chunk = max(1, DENSE_CHUNK_BYTES // (8 * S * S))
        out = np.empty_like(B, dtype=np.float64)
        for lo in range(0, self.n, chunk):
            sl = slice(lo, lo + chunk)
            M = np.eye(S)[None] - self.planner.gamma * self.planner.policy_matrix(self.policy[sl])
            b = B[sl]
            x = np.linalg.solve(np.swapaxes(M, 1, 2) if transpose else M, b[..., None] if b.ndim == 2 else b)
            out[sl] = x[..., 0] if b.ndim == 2 else x
        return out

    def solve(self, B):
        return self._solve(B, False)

    def solve_transpose(self, B):
        return self._solve(B, True)


class _FactorSystem(PolicySystem):
    """One sparse solver per task (:class:`_TaskFactor` or :class:`_UpdatedFactor`), in the
    planner's state ordering: right-hand sides are permuted in, solutions permuted back."""

    def __init__(self, planner, solvers):
        self.planner, self.solvers, self.n = planner, list(solvers), len(solvers)

    def _solve(self, B, transpose):
        q, qinv = self.planner.order, self.planner.inverse_order
        Bq = B[:, q]
        X = np.stack([s.solve(np.ascontiguousarray(b), transpose) for s, b in zip(self.solvers, Bq)])
        return X[:, qinv]

    def solve(self, B):
        return self._solve(B, False)

    def solve_transpose(self, B):
        return self._solve(B, True)


class Planner:
    """Base class: a planner bound to one MDP. Use :func:`get_planner`.

    Attributes
    ----------
    name : str
    S, A : int
    gamma : float
    """

    name = "base"

    def __init__(self, mdp):
        self.mdp, self.S, self.A, self.gamma = mdp, mdp.n_states, mdp.n_actions, mdp.gamma

    def backup(self, V):
        """``(P V)[n, s, a] = sum_s' P(s'|s, a) V[n, s']``: (n, S) -> (n, S, A).

        With k directions, (n, S, k) -> (n, S*A, k) (row ``s * A + a``).
        """
        raise NotImplementedError  # pragma: no cover

    def pullback(self, G):
        """``(P^T G)[n, s'] = sum_{s,a} P(s'|s, a) G[n, s, a]``: (n, S, A) -> (n, S)."""
        raise NotImplementedError  # pragma: no cover

    def system(self, policy, hints=None):
        """:class:`PolicySystem` of deterministic (n, S) int or stochastic (n, S, A) policies.

        ``hints``: per task, a solver of a nearby policy (``PolicySystem.solvers``) that a
        planner may reuse; planners without reuse ignore it.
        """
        raise NotImplementedError  # pragma: no cover

    def clear_cache(self):
        """Forget any factorisations kept between calls (no-op for planners that keep none)."""

    def q_from_values(self, R, V):
        """``Q = R + gamma P V``: R (n, S, A), V (n, S) -> (n, S, A)."""
        return R + self.gamma * self.backup(V)

    def initial_policy(self, R):
        """Where policy iteration starts without a warm start: greedy on the immediate reward."""
        return np.argmax(R, axis=2)

    def refine_policy(self, R, Q, policy, previous):
        """The next policy of policy iteration, given the improved (greedy) ``policy`` on the
        exact ``Q`` (n, S, A) of the ``previous`` one. This planner takes it as is (Howard's
        policy iteration); see :meth:`SparseLUPlanner.refine_policy`."""
        return policy


class DensePlanner(Planner):
    """Batched dense LU on (n, S, S) systems (today's planner; best for small S)."""

    name = "dense"

    def __init__(self, mdp):
        super().__init__(mdp)
        if mdp.is_sparse and 8 * self.S * self.S * self.A > DENSE_CHUNK_BYTES * 2:
            raise ValidationError(
                f"the dense planner needs the (S, A, S) = ({self.S}, {self.A}, {self.S}) transitions "
                f"({8 * self.S * self.S * self.A / 2**30:.2f} GiB) of this sparse model; use planner='sparse-lu' or 'auto'"
            )
        self.P3 = mdp.transitions
        self.P2 = self.P3.reshape(self.S * self.A, self.S)

    def backup(self, V):
        if V.ndim == 3:  # k directions: (n, S, k) -> (n, S*A, k)
            return self.P2 @ V
        return (V @ self.P2.T).reshape(V.shape[0], self.S, self.A)

    def pullback(self, G):
        return G.reshape(G.shape[0], self.S * self.A) @ self.P2

    def policy_matrix(self, policy):
        """``P_pi`` (n, S, S) of deterministic (n, S) or stochastic (n, S, A) policies."""
        if policy.ndim == 2:
            return self.P3[np.arange(self.S)[None, :], policy]
        return np.einsum("nsa,sat->nst", policy, self.P3)

    def system(self, policy, hints=None):
        return _DenseSystem(self, policy)


def _greedy_actions(Q):
    """First maximiser and maximum over the leading action axis of Q (A, S, n): (S, n) each (as argmax/max)."""
    best = np.zeros(Q.shape[1:], dtype=np.intp)
    top, mask = Q[0].copy(), np.empty(Q.shape[1:], dtype=bool)
    for a in range(1, Q.shape[0]):
        np.greater(Q[a], top, out=mask)
        np.copyto(best, a, where=mask)
        np.maximum(top, Q[a], out=top)
    return best, top


_GLIBC = []  # [the C library if it is glibc, else None], looked up once
_M_MMAP_THRESHOLD = -3  # glibc's mallopt parameter number


def _glibc():
    """The C library when it is glibc (for ``mallopt`` and ``malloc_trim``), else None."""
    if not _GLIBC:
        import ctypes
        import platform

        lib = None
        if platform.libc_ver()[0] == "glibc":
            lib = ctypes.CDLL(None)
            lib.mallopt.argtypes, lib.mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
            lib.malloc_trim.argtypes, lib.malloc_trim.restype = (ctypes.c_size_t,), ctypes.c_int
        _GLIBC.append(lib)
    return _GLIBC[0]


@contextlib.contextmanager
def _mapped_allocations():
    """glibc only: inside the ``with`` block, new allocations of 64 KiB or more are memory-mapped.

    Why (the sparse planner's memory). SuperLU sizes each factorisation's storage from an
    estimate, 20 nnz(M): four blocks of 3.4 MB at S = 1024 and 34 MB at S = 10,000, about ten
    times what it fills. A block is resident only where it is written, unless glibc carves it
    from heap memory written before (glibc serves any request from the heap's free chunks
    when it has some, whatever its mmap threshold). So the planner (1) maps SuperLU's blocks
    when the heap has no room for them (mapped blocks return to the OS when freed) and (2)
    after building factorisations returns the heap's free pages to the OS
    (:func:`_release_free_memory`), so that a block carved from them stays unresident where
    SuperLU never writes. Measured on a 20-iteration fit of 100 tasks at 32x32: see the
    README's planning figures. On exit the threshold is 32 MiB, the ceiling glibc's own
    dynamic threshold reaches (numpy's temporaries raise it there); without glibc this does
    nothing.
    """
    lib = _glibc()
    if lib is None:
        yield
        return
    lib.mallopt(_M_MMAP_THRESHOLD, 64 * 2**10)
    try:
        yield
    finally:
        lib.mallopt(_M_MMAP_THRESHOLD, 32 * 2**20)


def _release_free_memory():
    """glibc only: return the heap's free pages to the OS (``malloc_trim(0)``); see :func:`_mapped_allocations`."""
    lib = _glibc()
    if lib is not None:
        lib.malloc_trim(0)


def _lu(MT, permc_spec):
    """SuperLU of a CSC matrix ``M^T`` (diagonally dominant: diagonal pivots, see :class:`SparseLUPlanner`)."""
    try:
        with _mapped_allocations():
            return spla.splu(MT, permc_spec=permc_spec, diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    except RuntimeError as exc:  # singular: impossible for gamma < 1 and a stochastic P
        raise FactIRLError(f"sparse LU of I - gamma P_pi failed: {exc}") from None


class _TaskFactor:
    """Sparse LU of one policy's ``M = I - gamma P_pi`` (in the planner's state ordering).

    SuperLU factors ``M^T`` (given as CSC: the CSR arrays of ``M``, no conversion), so
    ``M x = b`` is its transposed solve and ``M^T x = b`` its plain one.
    """

    def __init__(self, MT, permc_spec, policy=None):
        self.lu = _lu(MT, permc_spec)
        self.policy = policy
        self.nbytes = 16 * self.lu.nnz  # measured resident size of a SuperLU factorisation: 14-16 bytes per entry

    @property
    def base(self):
        """The factorisation itself (a property, not an attribute: no reference cycle that would
        keep a freed factorisation's C memory alive until the next garbage collection)."""
        return self

    def solve(self, b, transpose=False):
        return self.lu.solve(b, trans="N" if transpose else "T")


class _UpdatedFactor:
    """A policy differing from a factorised one in k states, by a rank-k (Woodbury) update.

    ``M' = M + U W`` with ``U`` the k unit columns of the changed states and ``W`` (k, S) the
    change of their rows, ``-gamma (P'_rows - P_rows)``. With ``Z = M^-1 U`` (k solves) and the
    capacitance ``C = I + W Z`` (k, k): ``M'^-1 b = y - Z C^-1 W y`` (``y = M^-1 b``) and
    ``M'^-T b = M^-T (b - W^T C^-T Z^T b)``. Every solve is checked against ``M'`` itself:
    one step of iterative refinement if the relative residual exceeds 1e-14, and a fresh
    factorisation if it still exceeds :data:`RESIDUAL_TOL` (not observed in the tests, gamma up to 0.99).
    """

    def __init__(self, planner, base, policy, changed):
        import scipy.linalg as sla

        self.planner, self.base, self.policy = planner, base, policy
        q, A, k = planner.order, planner.A, len(changed)
        self.sel = q * A + policy[q]  # the rows of the augmented P that M' uses, in the planner's order
        old_rows = q[changed] * A + base.policy[q[changed]]
        self.W = planner.gamma * (planner.row_block(old_rows) - planner.row_block(self.sel[changed]))  # (k, S) CSR
        E = np.zeros((len(q), k))
        E[changed, np.arange(k)] = 1.0
        self.Z = base.solve(E)
        # C = I + W Z is nonsingular (det C = det M' / det M); its accuracy is checked by every solve
        self.C, self._lu_solve, self._fresh = sla.lu_factor(np.eye(k) + self.W @ self.Z), sla.lu_solve, None
        self.nbytes = self.Z.nbytes + self.sel.nbytes + 12 * self.W.nnz

    def _raw(self, b, transpose):
        if transpose:
            t = self._lu_solve(self.C, self.Z.T @ b, trans=1)
            return self.base.solve(b - self.W.T @ t, True)
        y = self.base.solve(b)
        return y - self.Z @ self._lu_solve(self.C, self.W @ y)

    def _residual(self, x, b, transpose):
        """Largest relative residual over the columns of ``b - M' x`` (or ``M'^T``), and the residual."""
        pl = self.planner
        if transpose:
            y = np.zeros((pl._Paug.shape[0],) + x.shape[1:])
            y[self.sel] = x
            r = b - (x - pl.gamma * (pl._PaugT @ y))
        else:
            r = b - (x - pl.gamma * (pl._Paug @ x)[self.sel])
        scale = np.linalg.norm(b, axis=0)
        return np.max(np.linalg.norm(r, axis=0) / np.where(scale > 0, scale, 1.0)), r

    def solve(self, b, transpose=False):
        if self._fresh is None:
            x = self._raw(b, transpose)
            res, r = self._residual(x, b, transpose)
            if res > 1e-14:
                x = x + self._raw(r, transpose)
                res, _ = self._residual(x, b, transpose)
            if res <= RESIDUAL_TOL:
                return x
            self._fresh = self.planner._factor(self.policy)
        return self._fresh.solve(b, transpose)


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

    Reuse. Factorisations are cached by policy (up to :data:`FACTOR_CACHE_BYTES`, and
    :data:`CACHE_GROUPS_PER_TASK` per task of the largest batch planned), so a
    warm-started evaluation at an unchanged greedy policy costs only solves. A policy that
    differs from a factorised one (its hint, e.g. the previous policy-iteration sweep) in
    at most :data:`UPDATE_MAX_RANK` states is solved by a verified low-rank update of that
    factorisation (:class:`_UpdatedFactor`; measured break-even with a new LU: 24-28 states
    at S = 1024 and 10,000). The cache is grouped by factorisation (an LU and its latest
    update) and evicts whole groups, least recently used first.

    Policy iteration. A cold start runs value-iteration sweeps first (:meth:`initial_policy`)
    and, between exact evaluations, :meth:`refine_policy` runs more (modified policy
    iteration): a batched sweep costs one sparse product for all tasks, far less than a
    factorisation per task, and a 100-task fit needs about a third of the factorisations of
    plain policy iteration. Every result is still an exactly evaluated, verified optimum.

    Memory. SuperLU allocates with ``malloc``; see :func:`_mapped_allocations` for how its
    blocks are returned to the OS on glibc.
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
        self._cache, self._groups, self._cache_bytes, self._max_batch = {}, collections.OrderedDict(), 0, 1
        self._since_trim = 0

    def _ordering(self):
        """State ordering ``q`` (new index i is state ``q[i]``) and SuperLU's permc_spec."""
        S, A = self.S, self.A
        union = sp.csr_matrix((np.ones(self.P.nnz), self.P.indices, self.P.indptr), shape=(S * A, S))
        union = (sp.csr_matrix((np.ones(S * A), (np.arange(S * A) // A, np.arange(S * A))), shape=(S, S * A)) @ union)
        union = (union + sp.identity(S, format="csr")).tocsr()
        density = (union.nnz / S) / ((self.P.nnz + S * A) / (S * A))
        if density > FIXED_ORDER_MAX_DENSITY:
            return np.arange(S), "MMD_AT_PLUS_A"
        union.data[:] = 1.0
        union = sp.diags(1.0 / np.asarray(union.sum(axis=1)).ravel()) @ union
        lu = _lu(sp.csc_matrix(sp.identity(S) - self.gamma * union), "MMD_AT_PLUS_A")
        return np.argsort(lu.perm_c), "NATURAL"

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
        self._Paug, self._diag_offset = Paug, np.flatnonzero(Paug.indices == own[rows]) - Paug.indptr[:-1]
        self._PaugT = Paug.T.tocsr()

    def backup(self, V):
        if V.ndim == 3:  # k directions: (n, S, k) -> (n, S*A, k)
            n, _, k = V.shape
            out = self.P @ np.moveaxis(V, 0, 1).reshape(self.S, n * k)
            return np.moveaxis(out.reshape(self.S * self.A, n, k), 1, 0)
        return (self.P @ np.ascontiguousarray(V.T)).T.reshape(V.shape[0], self.S, self.A)

    def pullback(self, G):
        return (self.PT @ np.ascontiguousarray(G.reshape(G.shape[0], self.S * self.A).T)).T

    def _rows(self, rows):
        """CSR arrays (data, indices, indptr) of the given rows of the augmented ``P``."""
        Paug = self._Paug
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
        if policy_i.ndim == 2:
            Pi = sp.csr_matrix((policy_i[q].ravel(), (np.repeat(np.arange(S), A), (q[:, None] * A + np.arange(A)).ravel())),
                               shape=(S, S * A))
            M = (sp.identity(S, format="csr") - self.gamma * (Pi @ self._Paug)).tocsr()
            M.sort_indices()
            return sp.csc_matrix((M.data, M.indices, M.indptr), shape=(S, S))
        sel = q * A + policy_i[q]
        data, indices, indptr = self._rows(sel)
        data = -self.gamma * data
        data[indptr[:-1] + self._diag_offset[sel]] += 1.0
        return sp.csc_matrix((data, indices, indptr), shape=(S, S))

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
        return self._value_sweeps(Rt, *_greedy_actions(Rt))

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
        _, V = _greedy_actions(np.transpose(Q, (2, 1, 0)))
        return self._value_sweeps(Rt, np.ascontiguousarray(policy.T), V)

    def _value_sweeps(self, Rt, pol, V):
        """Greedy policy (n, S) after value-iteration sweeps from ``V`` (S, n) on rewards ``Rt`` (A, S, n)."""
        A, S, n = Rt.shape
        for _ in range(WARMUP_MAX_SWEEPS):
            Q = (self._P_actions @ V).reshape(A, S, n)
            Q *= self.gamma
            Q += Rt
            new, V = _greedy_actions(Q)
            stable = np.count_nonzero(new != pol, axis=0).max() <= WARMUP_MAX_CHANGES
            pol = new
            if stable:
                break
        return np.ascontiguousarray(pol.T)

    def _solver(self, policy_i, hint):
        """A solver for one deterministic policy: a low-rank update of ``hint``'s factorisation
        when the policies differ in at most :data:`UPDATE_MAX_RANK` states, else a new LU."""
        base = None if hint is None else hint.base
        if base is not None and base.policy is not None:
            changed = np.flatnonzero(base.policy[self.order] != policy_i[self.order])
            if 0 < changed.size <= UPDATE_MAX_RANK:
                return _UpdatedFactor(self, base, policy_i, changed)
        return self._factor(policy_i)

    def _factor(self, policy_i):
        """A new LU of a deterministic (S,) or stochastic (S, A) policy; frees heap pages now and then."""
        factor = _TaskFactor(self.matrix_transpose(policy_i), self.permc_spec, policy_i if policy_i.ndim == 1 else None)
        self._since_trim += factor.nbytes
        if self._since_trim >= TRIM_BYTES:
            _release_free_memory()
            self._since_trim = 0
        return factor

    def _remember(self, key, solver):
        """Cache ``solver`` under ``key``. Entries are grouped by the factorisation they use: an LU
        and its latest low-rank update (which replaces an older one: the next warm start is the
        latest policy). The least recently used group goes first, so every eviction frees memory."""
        base = solver.base
        group = self._groups.get(id(base))  # a cached base is alive, so its id is unique
        if group is None:
            group = self._groups[id(base)] = [base, [], None]
            self._cache_bytes += base.nbytes
        if solver is base:
            group[1].append(key)
        else:
            if group[2] is not None:
                self._cache_bytes -= self._cache.pop(group[2]).nbytes
            group[2] = key
            self._cache_bytes += solver.nbytes
        self._cache[key] = solver
        self._groups.move_to_end(id(base))
        while len(self._groups) > 1 and (self._cache_bytes > FACTOR_CACHE_BYTES
                                         or len(self._groups) > CACHE_GROUPS_PER_TASK * self._max_batch):
            _, (old, keys, update) = self._groups.popitem(last=False)
            for k in keys:
                del self._cache[k]
            if update is not None:
                self._cache_bytes -= self._cache.pop(update).nbytes
            self._cache_bytes -= old.nbytes

    def clear_cache(self):
        """Forget the cached factorisations."""
        self._cache.clear()
        self._groups.clear()
        self._cache_bytes = 0

    def system(self, policy, hints=None):
        """Solvers of n deterministic (n, S) or stochastic (n, S, A) policies.

        ``hints`` (deterministic policies only): one earlier solver (or None) per task, whose
        factorisation a nearby policy may update instead of factorising anew.
        """
        if policy.ndim == 3:
            return _FactorSystem(self, [self._factor(p) for p in policy])
        self._max_batch = max(self._max_batch, len(policy))
        solvers = []
        for j, pol in enumerate(policy):
            key = np.ascontiguousarray(pol, dtype=np.intp).tobytes()
            solver = self._cache.get(key)
            if solver is None:
                # the solver keeps a view of its own key, not of the caller's (n, S) batch
                solver = self._solver(np.frombuffer(key, dtype=np.intp), None if hints is None else hints[j])
                self._remember(key, solver)
            else:
                self._groups.move_to_end(id(solver.base))
            solvers.append(solver)
        return _FactorSystem(self, solvers)


PLANNERS = {"dense": DensePlanner, "sparse-lu": SparseLUPlanner}


def available_planners():
    """Names accepted by ``planner=``: ``"auto"`` and every registered planner."""
    return ["auto", *PLANNERS]


def clear_caches(mdp):
    """Forget the factorisations kept by every planner bound to ``mdp``.

    The sparse planner keeps the factorisations of recent policies for the MDP's lifetime (up
    to :data:`FACTOR_CACHE_BYTES`, see :class:`SparseLUPlanner`); this frees them.
    """
    for planner in mdp.__dict__.get("_planners", {}).values():
        planner.clear_cache()


def get_planner(mdp, planner="auto"):
    """The planner named ``planner`` bound to ``mdp`` (cached on the MDP), or a Planner as is."""
    if isinstance(planner, Planner):
        if planner.mdp is not mdp:
            raise ValidationError("this planner is bound to another MDP")
        return planner
    if not isinstance(planner, str) or planner not in available_planners():
        raise ValidationError(f"unknown planner {planner!r}; available: {', '.join(available_planners())}")
    if planner == "auto":
        planner = "dense" if mdp.n_states <= AUTO_DENSE_MAX_STATES else "sparse-lu"
    cache = mdp.__dict__.setdefault("_planners", {})
    if planner not in cache:
        cache[planner] = PLANNERS[planner](mdp)
    return cache[planner]


@dataclasses.dataclass
class PlanResult:
    """Exact optimal planning of a batch of tasks (internal to the engine's users).

    Attributes
    ----------
    Q : ndarray, shape (n, S, A)
    policy : ndarray of intp, shape (n, S)
        Greedy on ``Q``.
    V : ndarray, shape (n, S)
    system : PolicySystem
        ``I - gamma P_pi`` of ``policy``, ready for more solves (adjoint, Jacobian).
    """

    Q: np.ndarray
    policy: np.ndarray
    V: np.ndarray
    system: PolicySystem


def _greedy_values(planner, R, policy, hints=None):
    """Values of deterministic policies and their system: solve (I - gamma P_pi) V = R_pi."""
    system = planner.system(policy, hints)
    R_pi = np.take_along_axis(R, policy[:, :, None], axis=2)[:, :, 0]
    return system.solve(R_pi), system


def plan(planner, R, policy=None, max_iter=1000):
    """Exact ``Q*`` of every task by policy iteration (unvalidated; see :func:`optimal_q`).

    Each sweep evaluates the active tasks' policies exactly; a sparse planner is handed each
    task's previous solver as a hint (:meth:`Planner.system`).

    Returns
    -------
    PlanResult
    """
    n, S, A = R.shape
    pol = planner.initial_policy(R) if policy is None else np.array(policy, dtype=np.intp, copy=True)
    Q, V = np.empty_like(R), np.empty((n, S))
    active, solvers = np.arange(n), [None] * n
    for _ in range(max_iter):
        Ra, pa = R[active], pol[active]
        Va, sys_a = _greedy_values(planner, Ra, pa, [solvers[i] for i in active])
        Qa = planner.q_from_values(Ra, Va)
        best = np.argmax(Qa, axis=2)
        q_cur = np.take_along_axis(Qa, pa[:, :, None], axis=2)[:, :, 0]
        q_best = np.take_along_axis(Qa, best[:, :, None], axis=2)[:, :, 0]
        tol = 1e-12 * np.maximum(1.0, np.abs(Qa).max(axis=(1, 2)))[:, None]
        improve = q_best > q_cur + tol
        Q[active], V[active] = Qa, Va
        changed = improve.any(axis=1)
        pol[active] = np.where(improve, best, pa)
        if sys_a.solvers is not None:
            for j, i in enumerate(active):
                solvers[i] = sys_a.solvers[j]
        if not changed.any():
            system = planner.system(pol) if sys_a.solvers is None else _FactorSystem(planner, solvers)
            return PlanResult(Q, pol, V, system)
        pol[active[changed]] = planner.refine_policy(Ra[changed], Qa[changed], pol[active[changed]], pa[changed])
        active = active[changed]
    raise FactIRLError(f"policy iteration did not converge in {max_iter} sweeps")


def _policy_weights(policy, shape):
    """``w[n, s, a]`` = 1[a = pi(s)] for deterministic (n, S) policies, ``pi(a|s)`` for stochastic ones."""
    if policy.ndim == 3:
        return policy
    w = np.zeros(shape)
    np.put_along_axis(w, policy[:, :, None], 1.0, axis=2)
    return w


def adjoint(planner, system, policy, G):
    """``dL/dR`` from ``G = dL/dQ`` for ``Q = R + gamma P V``, ``V`` the values of ``policy``.

    For a greedy (deterministic) policy ``V(s) = Q(s, pi(s))`` (``Q*``, DESIGN section 3); for a
    stochastic one ``dV(s) = sum_a pi(a|s) dQ(s, a)`` (the soft Bellman equation, section 9).
    One transposed solve per task: ``(I - gamma P_pi^T) z = P^T G``, then
    ``dL/dR = G + gamma w z`` with ``w`` the policy's weights (``w[s, pi(s)] = 1``).

    Parameters
    ----------
    planner : Planner
    system : PolicySystem
        Of ``policy`` (e.g. ``PlanResult.system``).
    policy : ndarray, (n, S) int or (n, S, A) float
    G : ndarray, shape (n, S, A)

    Returns
    -------
    ndarray, shape (n, S, A)
    """
    z = system.solve_transpose(planner.pullback(G))
    if policy.ndim == 3:
        return G + planner.gamma * policy * z[:, :, None]
    y = G.copy()
    n, S = policy.shape
    y[np.arange(n)[:, None], np.arange(S)[None, :], policy] += planner.gamma * z
    return y


def tangent(planner, system, policy, dR):
    """Forward-mode derivative ``dQ`` of ``Q = R + gamma P V^pi`` along ``dR`` (policy fixed).

    ``dV = (I - gamma P_pi)^-1 dR_pi`` with ``dR_pi(s) = sum_a w(a|s) dR(s, a)``, then
    ``dQ = dR + gamma P dV`` (eq. 9 in forward mode; DESIGN sections 3 and 10).

    Parameters
    ----------
    dR : ndarray, shape (n, S, A) or, for k directions at once, (n, S, A, k)

    Returns
    -------
    dQ : ndarray, shape (n, S, A) or (n, S, A, k)
    """
    n, S, A = dR.shape[:3]
    w = _policy_weights(policy, (n, S, A))
    if dR.ndim == 3:
        dV = system.solve(np.einsum("nsa,nsa->ns", w, dR))
        return dR + planner.gamma * planner.backup(dV)
    if policy.ndim == 2:  # pick the greedy rows (no product with zeros)
        dR_pi = np.take_along_axis(dR, policy[:, :, None, None], axis=2)[:, :, 0]
    else:
        dR_pi = np.einsum("nsa,nsak->nsk", w, dR)
    dV = system.solve(dR_pi)
    return dR + planner.gamma * planner.backup(dV).reshape(dR.shape)


@blas_limited
def policy_evaluation(mdp, rewards, policy, planner="auto"):
    """Exact value of deterministic or stochastic policies (Bellman equation, paper eq. 1).

    Parameters
    ----------
    mdp : TabularMDP
    rewards : array_like, shape (S, A) or (n, S, A)
    policy : array_like
        Deterministic: int actions (S,) or (n, S). Stochastic: probabilities ``pi(a|s)``,
        float (S, A) or (n, S, A), rows summing to 1.
    planner : str, default="auto"
        See :func:`available_planners`.

    Returns
    -------
    V : ndarray, shape (S,) or (n, S)
        ``V = (I - gamma P_pi)^-1 R_pi`` with ``R_pi(s) = sum_a pi(a|s) R(s, a)``.
    """
    check_mdp(mdp)
    R, single = check_rewards(mdp, rewards)
    if policy is None:
        raise ValidationError("policy must be given (deterministic (S,)/(n, S) or stochastic (S, A)/(n, S, A))")
    pl = get_planner(mdp, planner)
    arr = np.asarray(policy)
    stochastic = arr.dtype.kind == "f" and arr.ndim in (2, 3) and arr.shape[-2:] == (mdp.n_states, mdp.n_actions)
    if not stochastic:
        V, _ = _greedy_values(pl, R, check_policy(mdp, policy, R.shape[0]))
    else:
        pi = check_stochastic_policy(mdp, policy, R.shape[0])
        V = pl.system(pi).solve(np.sum(pi * R, axis=2))
    return V[0] if single else V


@blas_limited
def optimal_q(mdp, rewards, policy=None, max_iter=1000, planner="auto"):
    """Exact optimal action values Q* and a greedy policy, by policy iteration.

    Policy iteration (Howard) evaluates each policy exactly, so the result is exact up to
    floating point; warm-started from ``policy`` (e.g. the greedy policy of a nearby reward,
    as in a line search) it usually converges in one or two evaluations. Ties in the greedy
    step keep the current action unless another is better by more than a relative 1e-12,
    so the iteration cannot cycle.

    Parameters
    ----------
    mdp : TabularMDP
    rewards : array_like, shape (S, A) or (n, S, A)
        One reward or a batch of rewards (tasks on the leading axis).
    policy : array_like of int, shape (S,) or (n, S), optional
        Initial deterministic policy (warm start). Default: greedy on the immediate reward.
    max_iter : int, default=1000
        Maximum policy-iteration sweeps (never reached in practice: the number of policies
        is finite and each sweep strictly improves).
    planner : str, default="auto"
        See :func:`available_planners`.

    Returns
    -------
    Q : ndarray, shape (S, A) or (n, S, A)
        ``Q*`` (paper eq. 3).
    policy : ndarray of intp, shape (S,) or (n, S)
        A greedy policy on ``Q*``.
    """
    check_mdp(mdp)
    R, single = check_rewards(mdp, rewards)
    pol = check_policy(mdp, policy, R.shape[0])
    res = plan(get_planner(mdp, planner), R, pol, check_int(max_iter, "max_iter", minimum=1))
    if single:
        return res.Q[0], res.policy[0]
    return res.Q, res.policy


def boltzmann_policy(Q, beta):
    """Boltzmann (softmax) policy ``pi(a|s) ∝ exp(beta Q(s, a))`` (paper eq. 7).

    Numerically stable: the maximum over actions is subtracted before exponentiating, so no
    overflow occurs for any finite ``beta * Q``.

    Parameters
    ----------
    Q : array_like, shape (..., S, A)
        Finite action values.
    beta : float
        Inverse temperature, > 0.

    Returns
    -------
    pi : ndarray, shape (..., S, A)
        Rows sum to 1.
    """
    Q = check_array(Q, "Q")
    if Q.ndim < 1:
        raise ValidationError(f"Q must have an action axis; got shape {Q.shape}")
    beta = check_beta(beta)
    z = beta * (Q - Q.max(axis=-1, keepdims=True))
    np.exp(z, out=z)
    z /= z.sum(axis=-1, keepdims=True)
    return z


@blas_limited
def value_iteration(mdp, rewards, tol=1e-12, max_iter=100000, planner="auto"):
    """Q* by value iteration (paper eq. 3): a slow, simple reference for tests.

    Parameters
    ----------
    mdp : TabularMDP
    rewards : array_like, shape (S, A) or (n, S, A)
    tol : float
        Stop when the sup-norm change of Q is below ``tol``.
    max_iter : int
        Sweeps allowed; reaching it without meeting ``tol`` raises :class:`FactIRLError` (the
        error of an unconverged Q can be large: at gamma 0.9999 it needs ~3e5 sweeps for 1e-12).

    Returns
    -------
    Q : ndarray, shape (S, A) or (n, S, A)
    """
    check_mdp(mdp)
    R, single = check_rewards(mdp, rewards)
    tol = check_real(tol, "tol", low=0.0, low_open=True)
    max_iter = check_int(max_iter, "max_iter", minimum=1)
    pl = get_planner(mdp, planner)
    Q = R.copy()
    for _ in range(max_iter):
        Q_new = pl.q_from_values(R, Q.max(axis=2))
        delta = np.max(np.abs(Q_new - Q))
        Q = Q_new
        if delta < tol:
            return Q[0] if single else Q
    raise FactIRLError(f"value iteration did not reach tol={tol:g} in {max_iter} sweeps (last change {delta:.3g}); "
                       "raise max_iter or use optimal_q (exact policy iteration)")

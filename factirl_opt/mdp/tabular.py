"""Tabular Markov decision processes: :class:`TabularMDP` and the paper's :class:`GridWorld`.

Conventions (docs/maths.md §1): dynamics ``P(s' | s, a)`` either dense, an array
``P[s, a, s']`` of shape (S, A, S), or sparse, a ``scipy.sparse`` matrix of shape (S*A, S) whose
row ``s * A + a`` is ``P(. | s, a)``; rows sum to one. Rewards ``R[..., s, a]``; a tabular reward
parameter ``theta`` is ``R`` flattened in C order, so ``d = S * A`` and index ``s * A + a``.

Models are immutable: every attribute is set once, by the constructor, and the dynamics arrays
are read-only, so whatever the library caches about a model (its planners and factorisations,
:mod:`factirl_opt.planning.cache`) can never go stale. To change a model, build a new one.
Models pickle and deep-copy without those caches.
"""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray


from .._validation import check_int, check_probability, check_real, check_real_dtype
from ..exceptions import ValidationError
from .successors import check_index_base, successor_lists, successor_matrix

__all__ = ["TabularMDP", "GridWorld", "check_signature", "SIGNATURE_KEYS", "from_successors", "to_successors"]

#: the keys of :meth:`TabularMDP.signature`, in the order they are compared and reported
SIGNATURE_KEYS = ("n_states", "n_actions", "gamma", "transitions_sha256")

_ROW_SUM_TOL = 1e-9
#: largest dense (S, A, S) copy that ``transitions`` builds for a sparse model, in bytes
DENSE_COPY_LIMIT = 512 * 2**20


def _check_dense(transitions):
    try:
        raw = np.asarray(transitions)
        check_real_dtype(raw)
        P = np.array(raw, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"transitions must be a numeric array of shape (S, A, S) or a scipy.sparse (S*A, S) matrix: {exc}") from None
    if P.ndim != 3:
        raise ValidationError(f"transitions must have shape (S, A, S) (or be a scipy.sparse (S*A, S) matrix); got ndim={P.ndim}, shape {P.shape}")
    S, A, S2 = P.shape
    if S == 0 or A == 0:
        raise ValidationError(f"transitions must have at least one state and one action; got shape {P.shape}")
    if S2 != S:
        raise ValidationError(f"transitions must have shape (S, A, S); got {P.shape} (last axis {S2} != {S} states)")
    for bad, what in ((~np.isfinite(P), "finite"), (P < 0, "nonnegative")):
        if np.any(bad):
            idx = tuple(int(i) for i in np.argwhere(bad)[0])
            raise ValidationError(f"transitions must be {what}; found {P[idx]} at index {idx}")
    err = np.abs(P.sum(axis=2) - 1.0)
    if np.any(err > _ROW_SUM_TOL):
        s, a = np.unravel_index(np.argmax(err), err.shape)
        raise ValidationError(
            f"each row transitions[s, a, :] must sum to 1 (within {_ROW_SUM_TOL}); row (s={s}, a={a}) sums to {float(P[s, a].sum())!r}"
        )
    P.setflags(write=False)
    return P


def _read_only(*arrays):
    for arr in arrays:
        arr.setflags(write=False)


def _freeze_csr(P):
    """Make the CSR's arrays read-only owners of their data (a read-only view of a writable
    array could be made writable again through ``setflags``)."""
    P.data, P.indices, P.indptr = P.data.copy(), P.indices.copy(), P.indptr.copy()
    _read_only(P.data, P.indices, P.indptr)


def _frozen_view(arr):
    """A read-only view of a read-only array owned by a model: ``setflags(write=True)`` on it fails."""
    view = arr.view()
    view.setflags(write=False)
    return view


def _csr_view(P):
    """A new CSR object over the model's read-only arrays.

    Reassigning its ``data``/``indices``/``indptr``, ``resize`` or re-sorting it changes the
    copy only, never the model (whose dynamics and caches would otherwise go stale).
    """
    view = sp.csr_matrix((_frozen_view(P.data), _frozen_view(P.indices), _frozen_view(P.indptr)), shape=P.shape, copy=False)
    view.has_sorted_indices = True
    view.has_canonical_format = True
    return view


def _check_sparse(transitions):
    """A validated canonical CSR copy (S*A, S) of a scipy.sparse matrix, never densified."""
    if transitions.dtype.kind not in "biuf":  # complex would lose its imaginary part with a mere warning
        raise ValidationError(f"sparse transitions must be real (float or integer); got dtype {transitions.dtype}")
    P = sp.csr_matrix(transitions, dtype=np.float64, copy=True)
    P.sum_duplicates()
    P.eliminate_zeros()
    P.sort_indices()
    rows, S = P.shape
    if S == 0 or rows == 0 or rows % S:
        raise ValidationError(f"sparse transitions must have shape (S*A, S) with S, A >= 1; got {P.shape}")
    A = rows // S
    row_of = np.repeat(np.arange(rows), np.diff(P.indptr))
    for bad, what in ((~np.isfinite(P.data), "finite"), (P.data < 0, "nonnegative")):
        if np.any(bad):
            j = int(np.argmax(bad))
            r = int(row_of[j])
            raise ValidationError(f"transitions must be {what}; found {P.data[j]} in row {r} (s={r // A}, a={r % A}), column {P.indices[j]}")
    sums = np.asarray(P.sum(axis=1)).ravel()
    err = np.abs(sums - 1.0)
    if np.any(err > _ROW_SUM_TOL):
        r = int(np.argmax(err > _ROW_SUM_TOL))
        raise ValidationError(f"each row of the (S*A, S) transitions must sum to 1 (within {_ROW_SUM_TOL}); "
                              f"row {r} (s={r // A}, a={r % A}) sums to {float(sums[r])!r}")
    _freeze_csr(P)
    return P, A


class TabularMDP:
    """A finite MDP with known dynamics and discount, validated on construction.

    Parameters
    ----------
    transitions : array_like of shape (S, A, S), or scipy.sparse matrix of shape (S*A, S)
        Dense: ``transitions[s, a, s']`` is the probability of reaching ``s'`` after taking
        action ``a`` in state ``s``. Sparse: row ``s * A + a`` holds ``P(. | s, a)``; it is
        kept sparse (CSR) and validated without densifying. Entries must be finite and
        nonnegative, and each row must sum to 1 within 1e-9 (errors name the first bad row).
    gamma : float
        Discount factor, ``0 <= gamma < 1``.

    Attributes
    ----------
    transition_matrix : ndarray or scipy.sparse.csr_matrix, shape (S*A, S)
        The dynamics as one (S*A, S) matrix, row ``s * A + a``: a read-only dense array for a
        dense model, a CSR matrix for a sparse one. This is what the planning engine uses.
    transitions : ndarray of float64, shape (S, A, S)
        Dense models: a read-only copy of the transitions. Sparse models: a dense copy built on
        request (for inspection of small models), refused above 512 MiB; the library never uses it.
    is_sparse : bool
    gamma : float
    n_states, n_actions : int
    n_params : int
        ``S * A``, the size of a tabular reward parameter.

    Raises
    ------
    ValidationError
        With a message naming the bad shape or value; also on any attempt to set or delete an
        attribute after construction (models are immutable: build a new one).

    Notes
    -----
    Immutable and picklable: the dynamics arrays (the dense array, the CSR's ``data``,
    ``indices`` and ``indptr``) are read-only, attributes cannot be set, and ``pickle`` and
    ``copy.deepcopy`` carry the model without its lazy caches (CSR or dense copies, sampling
    tables) or planners, which a copy rebuilds on use and plans with identically.
    """

    #: the attributes that define a model (with the public ones); the other private ones are lazy caches
    _STATE = ("_P", "_dense", "_shape")
    _P: sp.csr_matrix  # sparse models: the validated CSR (S*A, S) dynamics
    _dense: np.ndarray  # dense models: the validated (S, A, S) dynamics
    _shape: tuple[int, int]
    _dense_cache: np.ndarray
    _csr_cache: sp.csr_matrix
    gamma: float

    def __init__(self, transitions: Any, gamma: float) -> None:
        if sp.issparse(transitions):
            P, A = _check_sparse(transitions)
            self._init("_P", P)
            self._init("_shape", (P.shape[1], A))
        else:
            dense = _check_dense(transitions)
            self._init("_dense", dense)
            self._init("_shape", dense.shape[:2])
        self._init("gamma", check_real(gamma, "gamma", 0.0, 1.0, high_open=True))

    def _init(self, name: str, value: Any) -> None:
        """Set an attribute in a constructor or a lazy cache (the only way: models are immutable)."""
        object.__setattr__(self, name, value)

    def __setattr__(self, name: str, value: Any) -> None:
        raise ValidationError(f"{type(self).__name__} is immutable: cannot set {name!r}; "
                              "build a new model with the values you want (e.g. TabularMDP(transitions, gamma=...))")

    def __delattr__(self, name: str) -> None:
        raise ValidationError(f"{type(self).__name__} is immutable: cannot delete {name!r}; build a new model instead")

    def __getstate__(self) -> dict[str, Any]:
        """The defining attributes only: lazy caches are not pickled or deep-copied."""
        return {k: v for k, v in self.__dict__.items() if not k.startswith("_") or k in self._STATE}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        if "_P" in state:
            _read_only(self._P.data, self._P.indices, self._P.indptr)
        if "_dense" in state:
            _read_only(self._dense)

    @property
    def is_sparse(self) -> bool:
        return hasattr(self, "_P")

    @property
    def n_states(self) -> int:
        return self._shape[0]

    @property
    def n_actions(self) -> int:
        return self._shape[1]

    @property
    def n_params(self) -> int:
        return self._shape[0] * self._shape[1]

    @property
    def transitions(self) -> np.ndarray:
        if not self.is_sparse:
            return _frozen_view(self._dense)
        size = self.n_states * self.n_params * 8
        if size > DENSE_COPY_LIMIT:
            raise ValidationError(
                f"this sparse model's dense (S, A, S) transitions would take {size / 2**30:.1f} GiB; "
                "use mdp.transition_matrix (CSR, (S*A, S))"
            )
        if "_dense_cache" not in self.__dict__:
            dense = self._P.toarray().reshape(self.n_states, self.n_actions, self.n_states).copy()  # owns its data
            _read_only(dense)
            self._init("_dense_cache", dense)
        return _frozen_view(self._dense_cache)

    @property
    def transition_matrix(self) -> Any:
        return _csr_view(self._P) if self.is_sparse else _frozen_view(self._dense).reshape(self.n_params, self.n_states)

    @property
    def transitions_flat(self) -> np.ndarray:
        """Dense models: transitions reshaped to (S * A, S), rows indexed by ``s * A + a``."""
        if self.is_sparse:
            raise ValidationError("transitions_flat is for dense models; a sparse model's (S*A, S) matrix is mdp.transition_matrix")
        return self.transition_matrix

    def csr(self) -> sp.csr_matrix:
        """The dynamics as a CSR (S*A, S) matrix (built once and cached for a dense model)."""
        if self.is_sparse:
            return _csr_view(self._P)
        if "_csr_cache" not in self.__dict__:
            P = sp.csr_matrix(self.transition_matrix)
            P.eliminate_zeros()
            P.sort_indices()
            _freeze_csr(P)
            self._init("_csr_cache", P)
        return _csr_view(self._csr_cache)

    def signature(self) -> dict[str, Any]:
        """What identifies this MDP: a JSON-able dict of S, A, gamma and a digest of the dynamics
        (keys :data:`SIGNATURE_KEYS`).

        Learners record it at ``fit`` (``mdp_signature_``), saved models carry it, and a model
        refuses an MDP whose signature differs (:func:`check_signature`). The digest is the
        SHA-256 of the transitions as a canonical CSR matrix (float64, sorted indices, explicit
        zeros removed), so a dense and a sparse copy of the same dynamics share it.
        """
        P = self.csr()
        h = hashlib.sha256()
        for part in (np.asarray(P.shape, dtype=np.int64), P.indptr.astype(np.int64), P.indices.astype(np.int64), P.data):
            h.update(np.ascontiguousarray(part).tobytes())
        values = (int(self.n_states), int(self.n_actions), float(self.gamma), h.hexdigest())
        return dict(zip(SIGNATURE_KEYS, values))

    def __repr__(self) -> str:
        return f"{type(self).__name__}(n_states={self.n_states}, n_actions={self.n_actions}, gamma={self.gamma})"

    @classmethod
    def from_successors(cls, sa_s: ArrayLike, sa_p: ArrayLike, gamma: float, index_base: int = 0) -> TabularMDP:
        """A sparse :class:`TabularMDP` from successor lists (S, A, K), summing repeated successors.

        The dynamics of Levine's IRL toolkit and ELIRL (``index_base=1`` for their MATLAB
        data); see :func:`from_successors`, which this calls, for the
        parameters and errors. Always returns a :class:`TabularMDP` (also when called on a
        subclass).
        """
        return from_successors(sa_s, sa_p, gamma, index_base=index_base)


def from_successors(sa_s: ArrayLike, sa_p: ArrayLike, gamma: float, index_base: int = 0) -> TabularMDP:
    """A sparse :class:`TabularMDP` from successor lists, summing repeated successors.

    Parameters
    ----------
    sa_s : array_like of int, shape (S, A, K)
        ``sa_s[s, a, k]``: the k-th successor state of action ``a`` in state ``s``, numbered
        from ``index_base``. Integral floats are accepted (MATLAB stores them as doubles).
        Entries whose probability is 0 carry no mass and are not checked (padding).
    sa_p : array_like of float, shape (S, A, K)
        ``sa_p[s, a, k]``: its probability; finite, nonnegative, each ``sa_p[s, a, :]`` summing
        to 1 within 1e-9.
    gamma : float
        Discount factor in [0, 1).
    index_base : {0, 1}, default=0
        Number of the first state in ``sa_s``: 1 for MATLAB data (the toolkit's ``sa_s``).

    Returns
    -------
    mdp : TabularMDP
        Sparse dynamics, a CSR (S*A, S) matrix whose row ``s * A + a`` holds
        ``P(s' | s, a) = sum_{k : sa_s[s, a, k] = s'} sa_p[s, a, k]`` (docs/maths.md §1;
        :func:`factirl_opt.mdp.successors.successor_matrix`).

    Raises
    ------
    ValidationError
        Naming the bad shape, or the first bad entry ``(s, a, k)`` (0-based indices into the
        arrays) and its value: a successor that is not an integer or is out of range, a
        negative or non-finite probability, a list whose probabilities do not sum to 1.
    """
    check_index_base(index_base)
    gamma = check_real(gamma, "gamma", 0.0, 1.0, high_open=True)
    return TabularMDP(successor_matrix(sa_s, sa_p, index_base), gamma)


def to_successors(mdp: TabularMDP, index_base: int = 0) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Successor lists (S, A, K) of an MDP, the inverse of :func:`from_successors`.

    ``K`` is the largest number of distinct successors of a state-action pair; shorter lists
    are padded by repeating their last successor with probability 0, so
    ``from_successors(*to_successors(mdp), mdp.gamma)`` has the dynamics of ``mdp`` exactly.

    Parameters
    ----------
    mdp : TabularMDP
    index_base : {0, 1}, default=0
        Number the states from 1 for MATLAB.

    Returns
    -------
    sa_s : ndarray of int64, shape (S, A, K)
        Successors in increasing state order.
    sa_p : ndarray of float64, shape (S, A, K)
    """
    if not isinstance(mdp, TabularMDP):
        raise ValidationError(f"mdp must be a TabularMDP; got {type(mdp).__name__}")
    index_base = check_index_base(index_base)
    return successor_lists(mdp.csr(), mdp.n_states, mdp.n_actions, index_base)


def check_signature(expected: Any, mdp: TabularMDP, what: str = "this model") -> None:
    """Raise :class:`ValidationError` unless ``mdp`` has the signature ``expected``.

    Parameters
    ----------
    expected : dict
        A :meth:`TabularMDP.signature` (e.g. a learner's ``mdp_signature_``).
    mdp : TabularMDP
    what : str
        Names the owner of ``expected`` in the message.
    """
    got = mdp.signature()
    if not isinstance(expected, dict) or set(expected) != set(got):
        raise ValidationError(f"{what} carries no valid MDP signature (got {expected!r})")
    diffs = [k for k in SIGNATURE_KEYS if expected[k] != got[k]]
    if diffs:
        detail = ", ".join("the transitions differ" if k == "transitions_sha256" else f"{k}: fitted {expected[k]!r}, given {got[k]!r}"
                           for k in diffs)
        raise ValidationError(f"{what} was fitted on another MDP ({detail}); use the MDP it was fitted on")


class GridWorld(TabularMDP):
    """The paper's grid world (section 4; docs/maths.md §9).

    States are the cells of a ``size x size`` grid, numbered row-major: ``s = row * size + col``
    (row 0 at the top). Actions are the four moves ``0: up, 1: down, 2: left, 3: right``.

    Dynamics: from state ``s`` let ``F(s)`` be the feasible moves
    (those that stay on the grid). A feasible requested move succeeds with probability
    ``p_success``; with probability ``1 - p_success`` the agent makes a move drawn uniformly
    from ``F(s)`` (the requested one included). An infeasible request (into a wall) gives a
    move drawn uniformly from ``F(s)``.

    Parameters
    ----------
    size : int, default=10
        Side of the grid (>= 2).
    p_success : float, default=0.7
        Probability that a feasible move succeeds, in [0, 1].
    gamma : float, default=0.9
        Discount factor.
    """

    ACTIONS = ("up", "down", "left", "right")
    size: int
    p_success: float
    #: (row, column) displacement of each action, in the order of ``ACTIONS``
    MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))

    def __init__(self, size: int = 10, p_success: float = 0.7, gamma: float = 0.9) -> None:
        self._init("size", check_int(size, "size", minimum=2))
        p = check_probability(p_success, "p_success")
        self._init("p_success", p)
        super().__init__(self._build(self.size, p), gamma)

    @classmethod
    def _build(cls, size, p):
        """Sparse (S*A, S) dynamics, vectorised over cells (time and memory linear in S)."""
        S, A = size * size, len(cls.MOVES)
        r, c = np.divmod(np.arange(S), size)
        moves = np.array(cls.MOVES)
        tr, tc = r[:, None] + moves[:, 0], c[:, None] + moves[:, 1]  # (S, A) target cells
        feasible = (tr >= 0) & (tr < size) & (tc >= 0) & (tc < size)
        target = np.where(feasible, tr * size + tc, -1)
        nf = feasible.sum(axis=1)  # >= 2 on a grid of side >= 2
        # uniform part: request a, land on every feasible move m; (1 - p)/nf if a is feasible, else 1/nf
        uniform = np.where(feasible, (1.0 - p) / nf[:, None], 1.0 / nf[:, None])  # (S, a)
        rows = np.broadcast_to((np.arange(S)[:, None] * A + np.arange(A))[:, :, None], (S, A, A))
        cols = np.broadcast_to(target[:, None, :], (S, A, A))
        vals = np.broadcast_to(uniform[:, :, None], (S, A, A))
        keep = np.broadcast_to(feasible[:, None, :], (S, A, A))
        succ = feasible  # the requested feasible move also succeeds with probability p
        row = np.concatenate([rows[keep], (np.arange(S)[:, None] * A + np.arange(A))[succ]])
        col = np.concatenate([cols[keep], target[succ]])
        val = np.concatenate([vals[keep], np.full(int(succ.sum()), p)])
        return sp.csr_matrix((val, (row, col)), shape=(S * A, S))

    def state_to_cell(self, state: ArrayLike) -> Any:
        """(row, col) of a state index, or arrays of them for an array of states."""
        state = np.asarray(state)
        if not np.issubdtype(state.dtype, np.integer) or np.any((state < 0) | (state >= self.n_states)):
            raise ValidationError(f"states must be integers in [0, {self.n_states}); got {state!r}")
        r, c = np.divmod(state, self.size)
        if r.ndim == 0:
            return int(r), int(c)
        return r, c

    def cell_to_state(self, row: ArrayLike, col: ArrayLike) -> Any:
        """State index of cell (row, col) (scalars or arrays)."""
        row, col = np.asarray(row), np.asarray(col)
        for name, v in (("row", row), ("col", col)):
            if not np.issubdtype(v.dtype, np.integer) or np.any((v < 0) | (v >= self.size)):
                raise ValidationError(f"{name} must be integers in [0, {self.size}); got {v!r}")
        s = row * self.size + col
        return int(s) if s.ndim == 0 else s

    def __repr__(self) -> str:
        return f"GridWorld(size={self.size}, p_success={self.p_success}, gamma={self.gamma})"

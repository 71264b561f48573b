"""Dynamics given as successor lists (Levine's IRL toolkit, ELIRL), as arrays.

Levine's MATLAB toolkit and ELIRL describe the dynamics of an MDP with ``S`` states and ``A``
actions by two arrays of shape (S, A, K): ``sa_s[s, a, k]`` is the k-th possible next state
after action ``a`` in state ``s`` and ``sa_p[s, a, k]`` its probability. A successor may appear
several times in one list: at a wall every blocked move lands back on ``s``, so ``s`` is listed
once per such move, each time with its own share of the probability. The importer
(:func:`successor_matrix`, behind :func:`~factirl_opt.mdp.from_successors`) *sums* the repeated entries (dropping all but one would lose their
mass and leave rows that do not sum to one). The toolkit numbers states and actions from 1
(``index_base=1``); this library numbers them from 0 (docs/maths.md §1).

This module works on arrays only; :func:`~factirl_opt.mdp.from_successors` and
:func:`~factirl_opt.mdp.to_successors` (in :mod:`factirl_opt.mdp.tabular`, beside the model they
build and read) are the public entry points.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from .._validation import check_array
from ..exceptions import ValidationError

__all__ = ["successor_matrix", "successor_lists", "check_index_base"]

#: tolerance on ``sum_k sa_p[s, a, k] - 1`` (the one :class:`TabularMDP` applies)
ROW_SUM_TOL = 1e-9


def _check_lists(sa_s: ArrayLike, sa_p: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``sa_s`` and ``sa_p`` as float arrays of the same shape (S, A, K), all sizes >= 1."""
    succ = check_array(sa_s, "sa_s")
    prob = check_array(sa_p, "sa_p")
    if succ.ndim != 3:
        raise ValidationError(f"sa_s must have shape (S, A, K) (K successors per state-action pair); got shape {succ.shape}")
    if prob.shape != succ.shape:
        raise ValidationError(f"sa_p must have the shape of sa_s {succ.shape}; got {prob.shape}")
    if 0 in succ.shape:
        raise ValidationError(f"sa_s must have at least one state, action and successor; got shape {succ.shape}")
    return succ, prob


def _first(mask: NDArray[np.bool_]) -> tuple[int, int, int]:
    return tuple(int(i) for i in np.argwhere(mask)[0])  # type: ignore[return-value]


def check_index_base(index_base: object) -> int:
    """``index_base`` as 0 or 1 (1 for MATLAB data), else a :class:`ValidationError`."""
    if isinstance(index_base, bool) or index_base not in (0, 1):
        raise ValidationError(f"index_base must be 0 or 1 (1 for MATLAB data); got {index_base!r}")
    return int(index_base)


def successor_matrix(sa_s: ArrayLike, sa_p: ArrayLike, index_base: int = 0) -> sp.csr_matrix:
    """The (S*A, S) transition matrix of successor lists, summing repeated successors.

    Parameters
    ----------
    sa_s : array_like of int, shape (S, A, K)
        ``sa_s[s, a, k]``: the k-th successor state of action ``a`` in state ``s``, numbered
        from ``index_base``. Integral floats are accepted (MATLAB stores them as doubles).
        Entries whose probability is 0 carry no mass and are not checked (padding).
    sa_p : array_like of float, shape (S, A, K)
        ``sa_p[s, a, k]``: its probability; finite, nonnegative, each ``sa_p[s, a, :]`` summing
        to 1 within 1e-9.
    index_base : {0, 1}, default=0
        Number of the first state in ``sa_s``: 1 for MATLAB data (the toolkit's ``sa_s``).

    Returns
    -------
    P : scipy.sparse.csr_matrix, shape (S*A, S)
        Sparse dynamics whose row ``s * A + a`` holds
        ``P(s' | s, a) = sum_{k : sa_s[s, a, k] = s'} sa_p[s, a, k]`` (docs/maths.md §1).

    Raises
    ------
    ValidationError
        Naming the bad shape, or the first bad entry ``(s, a, k)`` (0-based indices into the
        arrays) and its value: a successor that is not an integer or is out of range, a
        negative or non-finite probability, a list whose probabilities do not sum to 1.
    """
    index_base = check_index_base(index_base)
    succ, prob = _check_lists(sa_s, sa_p)
    S, A, K = succ.shape
    if np.any(prob < 0):
        idx = _first(prob < 0)
        raise ValidationError(f"sa_p must be nonnegative; sa_p{idx} = {prob[idx]!r}")
    live = prob > 0
    state = succ - index_base
    bad = live & (state != np.round(state))
    if bad.any():
        idx = _first(bad)
        raise ValidationError(f"sa_s must hold integer states; sa_s{idx} = {succ[idx]!r} (indices (s, a, k))")
    bad = live & ((state < 0) | (state >= S))
    if bad.any():
        idx = _first(bad)
        hi = S - 1 + index_base
        raise ValidationError(
            f"successor state out of range at (s, a, k) = {idx}: sa_s{idx} = {succ[idx]!r}, states are numbered "
            f"{index_base}..{hi} with index_base={index_base}"
        )
    err = np.abs(prob.sum(axis=2) - 1.0)
    if np.any(err > ROW_SUM_TOL):
        s, a = np.unravel_index(np.argmax(err), err.shape)
        raise ValidationError(
            f"the successor probabilities sa_p[s, a, :] must sum to 1 (within {ROW_SUM_TOL}); (s, a) = ({s}, {a}) "
            f"sums to {float(prob[s, a].sum())!r}"
        )
    rows = np.broadcast_to(np.arange(S * A).reshape(S, A, 1), (S, A, K))[live]
    cols = state[live].astype(np.int64)
    return sp.coo_matrix((prob[live], (rows, cols)), shape=(S * A, S)).tocsr()  # duplicates summed


def successor_lists(P: sp.csr_matrix, n_states: int, n_actions: int,
                    index_base: int = 0) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Successor lists (S, A, K) of an (S*A, S) CSR transition matrix, the inverse of :func:`successor_matrix`.

    ``K`` is the largest number of distinct successors of a state-action pair; shorter lists
    are padded by repeating their last successor with probability 0, so
    ``successor_matrix(*successor_lists(P, S, A))`` equals ``P`` exactly.

    Returns
    -------
    sa_s : ndarray of int64, shape (S, A, K)
        Successors in increasing state order, numbered from ``index_base``.
    sa_p : ndarray of float64, shape (S, A, K)
    """
    nnz = np.diff(P.indptr)
    K = max(int(nnz.max()), 1)
    pos = np.arange(K)[None, :]
    take = P.indptr[:-1, None] + np.minimum(pos, np.maximum(nnz[:, None] - 1, 0))
    sa_p = np.where(pos < nnz[:, None], P.data[take], 0.0)
    sa_s = P.indices[take].astype(np.int64) + index_base
    S, A = n_states, n_actions
    return sa_s.reshape(S, A, K), sa_p.reshape(S, A, K)

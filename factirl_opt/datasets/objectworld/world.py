"""The Objectworld grid: states, actions, sparse dynamics and the placement of the objects.

Index conventions: see :mod:`factirl_opt.datasets.objectworld`.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from ..._validation import RNGLike, as_rng, check_int, check_real
from ...exceptions import ValidationError
from ...mdp.tabular import TabularMDP

__all__ = ["ACTIONS", "MOVES", "N_ACTIONS", "ObjectWorld", "make_objectworld", "objectworld_transitions", "check_world"]

#: The action names, in the order of the model's actions.
ACTIONS = ("stay", "up", "down", "left", "right")
#: (d_row, d_col) displacement of each action, in the order of ``ACTIONS``
MOVES = np.array([(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)])
N_ACTIONS = len(ACTIONS)


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class ObjectWorld:
    """An Objectworld: grid, objects and sparse dynamics. Build it with :func:`make_objectworld`.

    Attributes
    ----------
    size : int
        ``N``, the side of the grid; ``S = N * N`` states.
    n_inner, n_outer : int
        ``c1`` and ``c2``, the numbers of inner and outer colours.
    objects : ndarray of intp, shape (m, 4)
        One read-only row ``(row, col, inner, outer)`` per object, sorted by state.
    transitions : scipy.sparse.csr_matrix, shape (S*A, S)
        Row ``s*A + a`` is ``P(. | s, a)`` (see :mod:`factirl_opt.datasets.objectworld` for the dynamics).
    gamma : float
        Discount factor in [0, 1).
    determinism : float
        Probability of the intended move.
    object_density : float or None
        Probability that a cell holds an object; None for a world built from given ``objects``.
    """

    size: int
    n_inner: int
    n_outer: int
    objects: np.ndarray
    transitions: sp.csr_matrix
    gamma: float
    determinism: float
    object_density: float | None

    @property
    def n_states(self) -> int:
        """``S = size ** 2``."""
        return self.size * self.size

    @property
    def n_actions(self) -> int:
        """``A = 5`` (see :data:`ACTIONS`)."""
        return N_ACTIONS

    @property
    def n_features(self) -> int:
        """Number of discrete features, ``(N - 1) * (n_inner + n_outer)``."""
        return (self.size - 1) * (self.n_inner + self.n_outer)

    def mdp(self) -> TabularMDP:
        """The world as a :class:`~factirl_opt.mdp.tabular.TabularMDP` with sparse (S*A, S) dynamics."""
        return TabularMDP(self.transitions, self.gamma)

    def __repr__(self) -> str:
        return (
            f"ObjectWorld(size={self.size}, n_inner={self.n_inner}, n_outer={self.n_outer}, "
            f"n_objects={len(self.objects)}, determinism={self.determinism}, gamma={self.gamma})"
        )


def objectworld_transitions(size: int, determinism: float = 0.7) -> sp.csr_matrix:
    """Sparse Objectworld dynamics, built vectorised in time and memory linear in ``S``.

    Parameters
    ----------
    size : int
        Side ``N`` of the grid, >= 2.
    determinism : float, default=0.7
        Probability of the intended move, in [0, 1]; each of the other four actions' moves
        happens with probability ``(1 - determinism) / 4``. Moves into a wall stay in place.

    Returns
    -------
    transitions : scipy.sparse.csr_matrix of float64, shape (S*A, S)
        Row ``s*A + a`` is ``P(. | s, a)``, states row-major and actions as in :data:`ACTIONS`.
        Duplicate landings (e.g. "stay" and a move into a wall) are summed, explicit zeros
        removed, indices sorted; every row sums to 1 up to rounding (<= 1e-15).
    """
    size = check_int(size, "size", minimum=2)
    p = check_real(determinism, "determinism", 0.0, 1.0)
    S, A = size * size, N_ACTIONS
    rows, cols = np.divmod(np.arange(S), size)
    land_r = np.clip(rows[:, None] + MOVES[:, 0], 0, size - 1)
    land_c = np.clip(cols[:, None] + MOVES[:, 1], 0, size - 1)
    landing = land_r * size + land_c  # (S, M): cell reached by move m from s
    prob = np.full((A, A), (1.0 - p) / 4.0)  # prob[a, m]: move m happens when a is intended
    np.fill_diagonal(prob, p)
    shape = (S, A, A)  # (s, a, m)
    data = np.broadcast_to(prob[None], shape).ravel()
    row_idx = np.broadcast_to((np.arange(S * A).reshape(S, A))[:, :, None], shape).ravel()
    col_idx = np.broadcast_to(landing[:, None, :], shape).ravel()
    P = sp.csr_matrix((data, (row_idx, col_idx)), shape=(S * A, S))
    P.sum_duplicates()
    P.eliminate_zeros()
    return P


def _covering_colours(n_colours, m, rng):
    """``m`` colours in range(n_colours), each present at least once (needs ``m >= n_colours``).

    ``n_colours`` objects chosen uniformly at random get the colours ``0..n_colours-1`` once
    each; every other object gets a uniform colour.
    """
    colours = np.concatenate([np.arange(n_colours), rng.integers(0, n_colours, size=m - n_colours)])
    return rng.permutation(colours)


def _place_objects(size, n_inner, n_outer, density, rng):
    """Random objects (m, 4) with every inner and every outer colour present.

    Each cell holds an object with probability ``density`` (independently). If fewer than
    ``max(n_inner, n_outer)`` cells are occupied, objects are added in uniformly chosen empty
    cells up to that number; then colours are drawn by :func:`_covering_colours`, inner and
    outer independently of each other and of the positions.
    """
    S = size * size
    occupied = np.flatnonzero(rng.random(S) < density)
    need = max(n_inner, n_outer)
    if occupied.size < need:
        empty = np.setdiff1d(np.arange(S), occupied)
        extra = rng.choice(empty, size=need - occupied.size, replace=False)
        occupied = np.sort(np.concatenate([occupied, extra]))
    m = occupied.size
    inner = _covering_colours(n_inner, m, rng)
    outer = _covering_colours(n_outer, m, rng)
    rows, cols = np.divmod(occupied, size)
    return np.column_stack([rows, cols, inner, outer]).astype(np.intp)


def _check_objects(objects, size, n_inner, n_outer):
    """Hand-given objects as a sorted int (m, 4) array, validated."""
    arr = np.asarray(objects)
    if arr.size == 0:
        arr = arr.reshape(0, 4)
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ValidationError(f"objects must have shape (m, 4), rows (row, col, inner, outer); got {arr.shape}")
    if arr.dtype.kind not in "iu" and arr.size:
        raise ValidationError(f"objects must hold integers (row, col, inner, outer); got dtype {arr.dtype}")
    arr = arr.astype(np.intp)
    limits = (("row", size), ("col", size), ("inner colour", n_inner), ("outer colour", n_outer))
    for j, (name, hi) in enumerate(limits):
        bad = (arr[:, j] < 0) | (arr[:, j] >= hi)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValidationError(f"objects[{i}] = {arr[i].tolist()}: {name} {arr[i, j]} is out of range [0, {hi})")
    states = arr[:, 0] * size + arr[:, 1]
    order = np.argsort(states, kind="stable")
    dup = np.flatnonzero(np.diff(states[order]) == 0)
    if dup.size:
        cell = divmod(int(states[order][dup[0]]), size)
        raise ValidationError(f"objects must hold at most one object per cell; cell (row, col) = {cell} has two")
    return arr[order]


def make_objectworld(size: int = 32, n_inner: int = 5, n_outer: int = 2, object_density: float = 0.05, determinism: float = 0.7,
                     gamma: float = 0.9, rng: RNGLike = None, objects: ArrayLike | None = None) -> ObjectWorld:
    """Build an Objectworld (defaults: ELIRL's multi-task benchmark).

    Parameters
    ----------
    size : int, default=32
        Side ``N`` of the grid, >= 2.
    n_inner, n_outer : int, default=5, 2
        ``c1`` and ``c2``, numbers of inner and outer colours, each >= 1 and at most ``N * N``.
    object_density : float, default=0.05
        Probability that a cell holds an object, in (0, 1]. Every inner and every outer colour
        is guaranteed to appear (so every reward is defined): if fewer than
        ``max(n_inner, n_outer)`` cells are drawn, objects are added in uniformly random empty
        cells; then ``n_inner`` objects chosen at random get the inner colours once each and
        the others a uniform inner colour (the same, independently, for the outer colours).
        For ``object_density * N**2`` well above ``c1`` this differs from i.i.d. uniform
        colours only by the guarantee.
    determinism : float, default=0.7
        Probability of the intended move, in [0, 1] (see :func:`objectworld_transitions`).
    gamma : float, default=0.9
        Discount factor, in [0, 1).
    rng : numpy.random.Generator or int or SeedSequence or None
        Source of the object layout (same seed, same world). Validated even with ``objects``.
    objects : array_like of int, shape (m, 4), optional
        A hand-built layout, rows ``(row, col, inner, outer)``; replaces the random placement
        (``object_density`` is then ignored and stored as None; colours may be missing, their
        distances are then ``inf``).

    Returns
    -------
    world : ObjectWorld

    Raises
    ------
    ValidationError
        Naming the bad argument and value.
    """
    size = check_int(size, "size", minimum=2)
    for name, value in (("n_inner", n_inner), ("n_outer", n_outer)):
        check_int(value, name, minimum=1)
        if value > size * size:
            raise ValidationError(f"{name} must be at most the number of cells {size * size}; got {value}")
    n_inner, n_outer = int(n_inner), int(n_outer)
    density: float | None = check_real(object_density, "object_density", 0.0, 1.0, low_open=True)
    det = check_real(determinism, "determinism", 0.0, 1.0)
    gamma = check_real(gamma, "gamma", 0.0, 1.0, high_open=True)
    rng = as_rng(rng)
    if objects is None:
        objs = _place_objects(size, n_inner, n_outer, density, rng)
    else:
        objs, density = _check_objects(objects, size, n_inner, n_outer), None
    objs.setflags(write=False)
    P = objectworld_transitions(size, det)
    return ObjectWorld(size, n_inner, n_outer, objs, P, gamma, det, density)


def check_world(world: object) -> ObjectWorld:
    """``world`` if it is an :class:`ObjectWorld`; otherwise a ValidationError naming its type."""
    if not isinstance(world, ObjectWorld):
        raise ValidationError(f"world must be an ObjectWorld (see make_objectworld); got {type(world).__name__}")
    return world

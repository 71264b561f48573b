"""Where the objects are: distances from every cell to each colour, and Levine's features.

Index conventions: see :mod:`factirl_opt.datasets.objectworld`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import DTypeLike, NDArray
from scipy.spatial import cKDTree

from ..._validation import check_bool
from .world import ObjectWorld, check_world

__all__ = ["objectworld_distances", "objectworld_features", "squared_distances"]


def squared_distances(world: ObjectWorld) -> NDArray[np.float64]:
    """Squared distances (S, c1 + c2) to the nearest object of each colour, exact, inf if none.

    One k-d tree per colour over that colour's objects, queried by all cells; the squared
    distance is recomputed in integers from the nearest object's cell, so it is exact.
    """
    N, c1 = world.size, world.n_inner
    cells = np.column_stack(np.divmod(np.arange(N * N), N))  # (S, 2): (row, col)
    palette = [(2, c) for c in range(c1)] + [(3, c) for c in range(world.n_outer)]
    out = np.full((N * N, len(palette)), np.inf)
    for j, (field, colour) in enumerate(palette):
        pts = world.objects[world.objects[:, field] == colour, :2]
        if len(pts) == 0:
            continue
        _, nearest = cKDTree(pts).query(cells)
        diff = cells - pts[nearest]
        out[:, j] = np.einsum("ij,ij->i", diff, diff)
    return out


def objectworld_distances(world: ObjectWorld) -> NDArray[np.float64]:
    """Euclidean distance from every cell to the nearest object of each colour.

    Parameters
    ----------
    world : ObjectWorld

    Returns
    -------
    distances : ndarray of float64, shape (S, c1 + c2)
        ``distances[s, c]`` for inner colour ``c``, ``distances[s, c1 + c]`` for outer colour
        ``c``, measured between cell indices ``(row, col)`` (an object's own cell is at 0);
        ``inf`` for a colour without objects. Exact: the square root of an integer.
    """
    return np.sqrt(squared_distances(check_world(world)))


def objectworld_features(world: ObjectWorld, continuous: bool = False, dtype: DTypeLike = np.float64) -> NDArray:
    """Levine's state features: discrete distance thresholds or the distances themselves.

    Parameters
    ----------
    world : ObjectWorld
    continuous : bool, default=False
        False: the ``(N-1)(c1+c2)`` binary features ``1[distance to colour j < d]`` for
        ``d = 1..N-1``, column ``j * (N-1) + (d - 1)`` (colour-major: inner colours
        ``j = 0..c1-1`` first, then outer colours ``j = c1 + c``; distance ascending within a
        colour). A colour without objects has all-zero features.
        True: the ``c1 + c2`` distances of :func:`objectworld_distances`, in the same colour
        order, with a missing colour's ``inf`` replaced by ``sqrt(2) * N`` (the toolkit's
        value, larger than any distance on the grid) so the features stay finite.
    dtype : numpy dtype, default=float64
        Output dtype; the discrete features take ``S * (N-1)(c1+c2) * itemsize`` bytes
        (554 MB in float64 for a 100 x 100 world with 7 colours: pass ``bool`` or ``float32``
        there).

    Returns
    -------
    features : ndarray, shape (S, (N-1)(c1+c2)) or (S, c1+c2)
        State features, one row per state (row-major cells).
    """
    world = check_world(world)
    continuous = check_bool(continuous, "continuous")
    dsq = squared_distances(world)
    N = world.size
    if continuous:
        dist = np.sqrt(dsq)
        dist[np.isinf(dist)] = np.sqrt(2.0) * N
        return dist.astype(dtype)
    thresholds = np.arange(1, N, dtype=np.float64) ** 2  # distance < d  <=>  squared < d**2
    binary = dsq[:, :, None] < thresholds[None, None, :]  # (S, colours, N-1)
    return binary.reshape(N * N, -1).astype(dtype)

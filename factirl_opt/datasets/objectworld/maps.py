"""Objectworld with a map per task, as ELIRL's benchmark draws it (Mendez et al. 2018).

ELIRL builds every task on its *own* Objectworld map: the objects are placed anew for each
task, and the task's reward is ``r_i(s) = sum_c h_ic 1[distance(s, inner colour c) < 3]`` on
that map, with coefficients ``h_i`` drawn as in :func:`~factirl_opt.datasets.objectworld.multitask_rewards`.
All maps have the same size and colours, so their feature columns mean the same thing
("closer than d to colour j"): a reward ``Phi_i w`` learnt on one map can be carried to any
other (docs/maths.md §7, §8). ELIRL scores a learnt reward on the task's own map and on a
freshly drawn map of the same task (same ``h_i``, new objects): :func:`fresh_maps`.

Maps of the same size share their dynamics (moves do not depend on the objects), so
:func:`objectworld_maps` gives every task the *same* :class:`TabularMDP` object, and the
learners plan all tasks as one batch; only the features differ. With ``n_blocked > 0`` each
map also gets a few blocked cells that the agent cannot enter (:func:`block_cells`), so the
dynamics differ per map too and every task has its own MDP object.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from ..._validation import as_rng, check_array, check_bool, check_int
from ...exceptions import ValidationError
from ...mdp.tabular import TabularMDP
from .features import objectworld_features
from .rewards import multitask_primitives, multitask_rewards
from .world import ObjectWorld, make_objectworld

__all__ = ["ObjectWorldMaps", "objectworld_maps", "fresh_maps", "block_cells"]


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class ObjectWorldMaps:
    """Tasks each on its own Objectworld map (build with :func:`objectworld_maps`).

    Attributes
    ----------
    worlds : tuple of n ObjectWorld
        Task ``i``'s map (objects, and its dynamics when cells are blocked).
    mdps : tuple of n TabularMDP
        Task ``i``'s MDP: one shared object when the dynamics are the same on every map.
    features : tuple of n ndarrays, shape (S, p)
        State features of each map, the same columns on every map (``p = (N-1)(c1+c2)``
        discrete or ``c1 + c2`` continuous, plus a last column of ones with ``bias``).
    rewards : ndarray of float64, shape (n, S)
        True state rewards, ``rewards[i] = primitives[i] @ coefficients[i]``.
    coefficients : ndarray of float64, shape (n, c1)
        ``h_i``, the task's weights on the true primitives (the same on a fresh map).
    primitives : tuple of n ndarrays, shape (S, c1)
        ``1[distance to inner colour c < 3]`` on each map.
    blocked : tuple of n ndarrays of intp
        The blocked cells (states) of each map; empty without ``n_blocked``.
    params : dict
        The construction parameters, reused by :func:`fresh_maps`.
    """

    worlds: tuple[ObjectWorld, ...]
    mdps: tuple[TabularMDP, ...]
    features: tuple[NDArray[Any], ...]
    rewards: NDArray[np.float64]
    coefficients: NDArray[np.float64]
    primitives: tuple[NDArray[np.float64], ...]
    blocked: tuple[NDArray[np.intp], ...]
    params: dict

    @property
    def n_tasks(self) -> int:
        return len(self.worlds)

    def __repr__(self) -> str:
        p = self.params
        return (f"ObjectWorldMaps(n_tasks={self.n_tasks}, size={p['size']}, n_inner={p['n_inner']}, n_outer={p['n_outer']}, "
                f"n_blocked={p['n_blocked']}, shared_dynamics={len({id(m) for m in self.mdps}) == 1})")


def block_cells(transitions: Any, cells: ArrayLike) -> sp.csr_matrix:
    """Dynamics in which the given cells cannot be entered: such a move stays in place.

    Parameters
    ----------
    transitions : scipy.sparse matrix, shape (S*A, S)
        Row ``s * A + a`` is ``P(. | s, a)`` (e.g. :func:`~factirl_opt.datasets.objectworld.objectworld_transitions`).
    cells : array_like of int
        The blocked states. From another state, the probability of landing in one of them is
        moved to the state itself (as a wall does); from a blocked state the moves are
        unchanged (it is never reached from elsewhere, but may be a start state).

    Returns
    -------
    transitions : scipy.sparse.csr_matrix, shape (S*A, S)
        Rows still sum to one; duplicates summed, explicit zeros removed, indices sorted.
    """
    if not sp.issparse(transitions) and not (isinstance(transitions, np.ndarray) and transitions.ndim == 2):
        hint = ("; pass the model's transition_matrix (mdp.transition_matrix, world.mdp().transition_matrix)"
                if hasattr(transitions, "transition_matrix") or hasattr(transitions, "mdp") else "")
        raise ValidationError(f"transitions must be a scipy.sparse (S*A, S) matrix; got {type(transitions).__name__}{hint}")
    P = sp.coo_matrix(transitions)
    rows, S = P.shape
    if S == 0 or rows % S:
        raise ValidationError(f"transitions must have shape (S*A, S); got {P.shape}")
    cells = np.asarray(cells)
    if cells.size and (cells.dtype.kind not in "iu" or cells.min() < 0 or cells.max() >= S):
        raise ValidationError(f"blocked cells must be states in [0, {S}); got {cells.tolist()}")
    mask = np.zeros(S, dtype=bool)
    mask[cells.astype(np.intp)] = True
    src = P.row // (rows // S)
    col = np.where(mask[P.col] & (P.col != src), src, P.col)
    out = sp.csr_matrix((P.data, (P.row, col)), shape=P.shape)
    out.sum_duplicates()
    out.eliminate_zeros()
    out.sort_indices()
    return out


def _check_coefficients(coefficients: ArrayLike, n_tasks: int, n_inner: int) -> NDArray[np.float64]:
    H = check_array(coefficients, "coefficients", ndim=2)
    if H.shape != (n_tasks, n_inner):
        raise ValidationError(f"coefficients must have shape (n_tasks, n_inner) = ({n_tasks}, {n_inner}); got {H.shape}")
    return H


def _blocked_world(world: ObjectWorld, n_blocked: int, rng: np.random.Generator) -> tuple[ObjectWorld, NDArray[np.intp]]:
    """The world with ``n_blocked`` uniformly drawn object-free cells blocked."""
    N = world.size
    free = np.setdiff1d(np.arange(N * N), world.objects[:, 0] * N + world.objects[:, 1])
    if n_blocked > free.size:
        raise ValidationError(f"n_blocked={n_blocked} exceeds the {free.size} object-free cells of a map")
    cells = np.sort(rng.choice(free, size=n_blocked, replace=False)).astype(np.intp)
    cells.setflags(write=False)
    return dataclasses.replace(world, transitions=block_cells(world.transitions, cells)), cells


def objectworld_maps(n_tasks: int, size: int = 32, n_inner: int = 5, n_outer: int = 2, object_density: float = 0.05,
                     determinism: float = 0.7, gamma: float = 0.9, continuous: bool = False, bias: bool = False,
                     n_blocked: int = 0, coefficients: ArrayLike | None = None, rng: Any = None,
                     dtype: Any = np.float64) -> ObjectWorldMaps:
    """Draw ``n_tasks`` Objectworld maps, one per task, with ELIRL's rewards on each.

    Parameters
    ----------
    n_tasks : int
        Number of tasks (= maps), >= 1.
    size, n_inner, n_outer, object_density, determinism, gamma
        As in :func:`~factirl_opt.datasets.objectworld.make_objectworld` (defaults: ELIRL's benchmark,
        32 x 32, 5 inner and 2 outer colours); every map is drawn with them.
    continuous : bool, default=False
        Features of :func:`~factirl_opt.datasets.objectworld.objectworld_features` (discrete
        thresholds, or the distances).
    bias : bool, default=False
        Append a column of ones to every map's features (ELIRL's learner does).
    n_blocked : int, default=0
        Blocked cells per map (drawn among its object-free cells; :func:`block_cells`): the
        dynamics then differ per map, and every task gets its own MDP object.
    coefficients : array_like, shape (n_tasks, n_inner), optional
        The tasks' weights ``h_i`` on the true primitives; drawn by ELIRL's rule
        (:func:`~factirl_opt.datasets.objectworld.multitask_rewards`) when None. Give the coefficients
        of other maps to put the same tasks on new maps (see :func:`fresh_maps`).
    rng : numpy.random.Generator or int or SeedSequence or None
        Source of the maps and of the coefficients (two independent streams spawned from it),
        so the same seed gives the same maps whether or not coefficients are given.
    dtype : numpy dtype, default=float64
        Of the features (the discrete ones of 100 maps at 32 x 32 take 178 MB in float64).

    Returns
    -------
    maps : ObjectWorldMaps
    """
    n = check_int(n_tasks, "n_tasks", minimum=1)
    n_blocked = check_int(n_blocked, "n_blocked", minimum=0)
    continuous, bias = check_bool(continuous, "continuous"), check_bool(bias, "bias")
    H = None if coefficients is None else _check_coefficients(coefficients, n, check_int(n_inner, "n_inner", minimum=1))
    map_rng, task_rng = as_rng(rng).spawn(2)
    worlds, blocked = [], []
    for _ in range(n):
        world = make_objectworld(size, n_inner, n_outer, object_density, determinism, gamma, rng=map_rng)
        cells = np.empty(0, dtype=np.intp)
        if n_blocked:
            world, cells = _blocked_world(world, n_blocked, map_rng)
        worlds.append(world)
        blocked.append(cells)
    primitives = tuple(multitask_primitives(w) for w in worlds)
    if H is None:
        H = np.concatenate([multitask_rewards(w, 1, rng=task_rng)[1] for w in worlds])
    rewards = np.stack([prim @ h for prim, h in zip(primitives, H)])
    shared = worlds[0].mdp() if not n_blocked else None
    mdps = tuple(shared if shared is not None else w.mdp() for w in worlds)
    features = []
    for w in worlds:
        F = objectworld_features(w, continuous=continuous, dtype=dtype)
        features.append(np.hstack([F, np.ones((F.shape[0], 1), dtype=F.dtype)]) if bias else F)
    params = dict(size=worlds[0].size, n_inner=worlds[0].n_inner, n_outer=worlds[0].n_outer, object_density=object_density,
                  determinism=determinism, gamma=gamma, continuous=continuous, bias=bias, n_blocked=n_blocked, dtype=dtype)
    H.setflags(write=False)
    rewards.setflags(write=False)
    return ObjectWorldMaps(tuple(worlds), mdps, tuple(features), rewards, H, primitives, tuple(blocked), params)


def fresh_maps(maps: ObjectWorldMaps, rng: Any = None) -> ObjectWorldMaps:
    """The same tasks (same coefficients ``h_i``) on newly drawn maps, with the same parameters.

    This is how ELIRL and Levine's toolkit score transfer: the learnt feature weights of task
    ``i`` are applied to the features of a map never seen in training, and the resulting
    policy is scored against the task's true reward on that map.

    Parameters
    ----------
    maps : ObjectWorldMaps
    rng : numpy.random.Generator or int or SeedSequence or None
        Use another seed than the one of ``maps`` (the same seed gives the same maps).
    """
    if not isinstance(maps, ObjectWorldMaps):
        raise ValidationError(f"maps must be ObjectWorldMaps (see objectworld_maps); got {type(maps).__name__}")
    return objectworld_maps(maps.n_tasks, coefficients=maps.coefficients, rng=rng, **maps.params)

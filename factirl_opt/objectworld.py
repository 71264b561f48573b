"""Objectworld (Levine, Popovic & Koltun 2011) and its multi-task version (ELIRL; Mendez et al. 2018).

An ``N x N`` grid whose cells may hold an object with an *inner* and an *outer* colour. The
features describe where the objects are (Euclidean distance to the nearest object of each
colour); the rewards depend on a few of those distances, so a learner that finds the right
features can explain many tasks at once. References:

- S. Levine, Z. Popovic, V. Koltun, "Nonlinear inverse reinforcement learning with Gaussian
  processes", NIPS 2011 (the single-task benchmark; its MATLAB "IRL toolkit" code fixes the
  details the paper leaves open).
- J. A. Mendez, S. Shivkumar, E. Eaton, "Lifelong inverse reinforcement learning", NeurIPS
  2018 (ELIRL; the multi-task benchmark: 32 x 32, c1 = 5 inner colours, c2 = 2 outer colours).

Conventions (every index order used in this module)
---------------------------------------------------
- **States** are cells numbered row-major, ``s = row * N + col``, row 0 at the top, column 0 on
  the left; ``S = N * N``.
- **Actions** (``A = 5``, :data:`ACTIONS`): ``0`` stay, ``1`` up (row - 1), ``2`` down
  (row + 1), ``3`` left (col - 1), ``4`` right (col + 1). (The MATLAB toolkit orders them stay,
  +y, +x, -y, -x; the dynamics are symmetric, so only the labels differ.)
- **Dynamics**: the intended move happens with probability ``determinism``; otherwise one of
  the *other four* actions' moves happens, each with probability ``(1 - determinism) / 4``. A
  move into a wall leaves the agent in place (as the toolkit's clipping does; this differs from
  the paper's :class:`~factirl_opt.mdp.GridWorld`, which redraws among feasible moves).
  ``transitions`` is a ``scipy.sparse.csr_matrix`` of shape (S*A, S) whose row ``s*A + a`` is
  ``P(. | s, a)``; when two moves land on the same cell their probabilities are summed.
- **Colours**: the ``c1 = n_inner`` inner colours ``0..c1-1`` carry the rewards; the
  ``c2 = n_outer`` outer colours ``0..c2-1`` are distractors. The naming follows ELIRL (its
  ``c1`` colours carry the rewards). Levine's toolkit draws its ``c1`` colours as the objects'
  *rings*, which is why the 2011 paper calls the reward-carrying colours "outer"; here they are
  the inner colours, and :func:`plot_objectworld` draws them as the dots.
- **Objects**: an int array of shape (m, 4), one row ``(row, col, inner, outer)`` per object,
  sorted by state; at most one object per cell.
- **Distances** (:func:`objectworld_distances`): shape (S, c1 + c2), column ``c`` is the
  Euclidean distance (in cells) to the nearest object of inner colour ``c``, column ``c1 + c``
  to the nearest object of outer colour ``c``; ``inf`` when there is no such object.
- **Discrete features** (:func:`objectworld_features`): shape (S, (N-1)(c1+c2)), column
  ``j * (N-1) + (d - 1)`` is ``1[distance column j < d]`` for ``d = 1..N-1`` (colour-major,
  inner colours first, then distance). The toolkit orders the same columns distance-major.
- **Rewards** are state rewards of shape (S,) (or (n, S) for n tasks); use
  :func:`state_action_rewards` for the (S, A) / (n, S, A) layout of the learners.
"""

import dataclasses

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ._validation import as_rng, check_bool, check_int, check_real
from .exceptions import ValidationError
from .mdp import TabularMDP

__all__ = [
    "ACTIONS",
    "MOVES",
    "ObjectWorld",
    "make_objectworld",
    "objectworld_transitions",
    "objectworld_distances",
    "objectworld_features",
    "levine_reward",
    "multitask_primitives",
    "multitask_rewards",
    "state_action_rewards",
    "plot_objectworld",
]

ACTIONS = ("stay", "up", "down", "left", "right")
#: (d_row, d_col) displacement of each action, in the order of ``ACTIONS``
MOVES = np.array([(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)])
N_ACTIONS = len(ACTIONS)
ELIRL_RADIUS = 3  # a colour is "near" when its distance is < 3 (ELIRL's rew_dist)
ELIRL_SCALE = 5.0  # ELIRL's R_SCALE: weights 5 * (3u - 2), in [-10, 5)


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
        Row ``s*A + a`` is ``P(. | s, a)`` (see the module docstring for the dynamics).
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
    def n_states(self):
        """``S = size ** 2``."""
        return self.size * self.size

    @property
    def n_actions(self):
        """``A = 5`` (see :data:`ACTIONS`)."""
        return N_ACTIONS

    @property
    def n_features(self):
        """Number of discrete features, ``(N - 1) * (n_inner + n_outer)``."""
        return (self.size - 1) * (self.n_inner + self.n_outer)

    def mdp(self):
        """The world as a :class:`~factirl_opt.mdp.TabularMDP` with sparse (S*A, S) dynamics."""
        return TabularMDP(self.transitions, self.gamma)

    def __repr__(self):
        return (
            f"ObjectWorld(size={self.size}, n_inner={self.n_inner}, n_outer={self.n_outer}, "
            f"n_objects={len(self.objects)}, determinism={self.determinism}, gamma={self.gamma})"
        )


def objectworld_transitions(size, determinism=0.7):
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


def make_objectworld(size=32, n_inner=5, n_outer=2, object_density=0.05, determinism=0.7, gamma=0.9, rng=None, objects=None):
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
    density = check_real(object_density, "object_density", 0.0, 1.0, low_open=True)
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


def _check_world(world):
    if not isinstance(world, ObjectWorld):
        raise ValidationError(f"world must be an ObjectWorld (see make_objectworld); got {type(world).__name__}")
    return world


def _squared_distances(world):
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


def objectworld_distances(world):
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
    return np.sqrt(_squared_distances(_check_world(world)))


def objectworld_features(world, continuous=False, dtype=np.float64):
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
    world = _check_world(world)
    continuous = check_bool(continuous, "continuous")
    dsq = _squared_distances(world)
    N = world.size
    if continuous:
        dist = np.sqrt(dsq)
        dist[np.isinf(dist)] = np.sqrt(2.0) * N
        return dist.astype(dtype)
    thresholds = np.arange(1, N, dtype=np.float64) ** 2  # distance < d  <=>  squared < d**2
    binary = dsq[:, :, None] < thresholds[None, None, :]  # (S, colours, N-1)
    return binary.reshape(N * N, -1).astype(dtype)


def levine_reward(world, positive=1.0, negative=-1.0):
    """Levine et al.'s single-task reward, as a state reward.

    ``r(s) = positive`` if the distance to inner colour 0 is < 3 **and** the distance to inner
    colour 1 is < 2; ``negative`` if the distance to inner colour 0 is < 3 but the distance to
    inner colour 1 is not < 2; ``0`` elsewhere. This is the paper's rule ("positive within
    distance 3 of colour 1 and distance 2 of colour 2, negative within distance 3 of colour 1,
    zero otherwise", colours 1 and 2 being the toolkit's first two ``c1`` colours, which this
    library calls inner colours 0 and 1 — see the module docstring). "Within distance d" is
    the strict ``< d`` of the toolkit's features, so ``r`` is a function of two discrete
    features (inner colour 0 at ``d = 3``, inner colour 1 at ``d = 2``).

    Parameters
    ----------
    world : ObjectWorld
        Needs ``n_inner >= 2``.
    positive, negative : float, default=1.0, -1.0
        The two nonzero reward values. The paper gives only their signs; the MATLAB toolkit
        scales its reward tree by ``R_SCALE = 5`` (leaf values +1 and -2 in the versions we
        checked), i.e. ``positive=5.0, negative=-10.0``.

    Returns
    -------
    reward : ndarray of float64, shape (S,)
    """
    world = _check_world(world)
    if world.n_inner < 2:
        raise ValidationError(f"levine_reward needs at least 2 inner colours; the world has n_inner={world.n_inner}")
    pos, neg = check_real(positive, "positive"), check_real(negative, "negative")
    dsq = _squared_distances(world)
    near0, near1 = dsq[:, 0] < 9.0, dsq[:, 1] < 4.0
    return np.where(near0 & near1, pos, np.where(near0, neg, 0.0))


def multitask_primitives(world):
    """ELIRL's true reward primitives ``1[distance to inner colour c < 3]``.

    Parameters
    ----------
    world : ObjectWorld

    Returns
    -------
    primitives : ndarray of float64, shape (S, c1)
        Column ``c`` for inner colour ``c``; equal to discrete feature column ``c * (N-1) + 2``
        of :func:`objectworld_features` (``d = 3``) when ``N >= 4``.
    """
    dsq = _squared_distances(_check_world(world))
    return (dsq[:, : world.n_inner] < float(ELIRL_RADIUS**2)).astype(np.float64)


def multitask_rewards(world, n_tasks, rng=None):
    """ELIRL's multi-task rewards and their coefficients on the true primitives.

    For each task, independently: draw ``k`` uniformly in {2, 3, 4} (capped at ``c1``), choose
    ``k`` distinct inner colours uniformly without replacement, give each chosen colour ``c``
    the weight ``w_c = 5 * (3 u_c - 2)`` with ``u_c ~ U[0, 1)`` (so ``w_c`` in [-10, 5),
    nonzero almost surely) and every other colour 0. The reward is
    ``r(s) = sum_c w_c 1[distance(s, inner colour c) < 3]`` (ELIRL's ``objectworld2``
    defaults, ``R_SCALE = 5``, ``rew_dist = 3``).

    Parameters
    ----------
    world : ObjectWorld
    n_tasks : int
        Number of tasks ``n``, >= 1.
    rng : numpy.random.Generator or int or SeedSequence or None

    Returns
    -------
    rewards : ndarray of float64, shape (n, S)
        State rewards, ``rewards = coefficients @ primitives.T`` exactly (computed that way).
    coefficients : ndarray of float64, shape (n, c1)
        ``coefficients[i, c] = w_c`` of task ``i``.
    primitives : ndarray of float64, shape (S, c1)
        :func:`multitask_primitives`, the "ground truth features".
    """
    world = _check_world(world)
    check_int(n_tasks, "n_tasks", minimum=1)
    rng = as_rng(rng)
    c1 = world.n_inner
    H = np.zeros((int(n_tasks), c1))
    for i in range(int(n_tasks)):
        k = min(int(rng.integers(2, 5)), c1)
        chosen = rng.choice(c1, size=k, replace=False)
        H[i, chosen] = ELIRL_SCALE * (3.0 * rng.random(k) - 2.0)
    primitives = multitask_primitives(world)
    return H @ primitives.T, H, primitives


def state_action_rewards(rewards, n_actions=N_ACTIONS):
    """State rewards (..., S) repeated over actions: (..., S, A), a new C-contiguous array.

    ``out[..., s, a] = rewards[..., s]``, the layout the learners take (``R[s, a]``).
    """
    r = np.asarray(rewards, dtype=np.float64)
    if r.ndim == 0:
        raise ValidationError(f"rewards must have shape (S,) or (n, S); got a scalar {rewards!r}")
    check_int(n_actions, "n_actions", minimum=1)
    return np.repeat(r[..., None], int(n_actions), axis=-1)


def _check_values(values, N):
    v = np.asarray(values, dtype=np.float64)
    if v.shape not in ((N * N,), (N, N)):
        raise ValidationError(f"values must have shape (S,) = ({N * N},) or (N, N) = ({N}, {N}); got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValidationError("values must be finite")
    return v.reshape(N, N)


def plot_objectworld(world, ax=None, values=None, cmap="viridis"):
    """Draw the grid, optionally over a value map, with the objects (matplotlib, lazily imported).

    Each object is a dot filled with its inner colour and ringed with its outer colour. The
    colours follow the toolkit's order (inner colours ``0..c1-1``, then the outer ones) in
    matplotlib's ``tab10`` (``tab20`` beyond 10 colours, cycling beyond 20): inner colour ``c``
    is ``tab10(c)``, outer colour ``c`` is ``tab10(c1 + c)``. Row 0 is at the top, as in the
    state numbering; grid lines are drawn up to ``N = 40``.

    Parameters
    ----------
    world : ObjectWorld
    ax : matplotlib Axes, optional
        Where to draw; a new square figure when None.
    values : array_like, shape (S,) or (N, N), optional
        A finite map drawn as the background (e.g. a reward or value function), state ``s`` at
        cell ``divmod(s, N)``, with a colour bar.
    cmap : str or Colormap, default="viridis"
        Colour map of ``values``.

    Returns
    -------
    ax : matplotlib Axes
    """
    world = _check_world(world)
    N = world.size
    grid = None if values is None else _check_values(values, N)
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=(6, 6))
    from matplotlib import colormaps

    if grid is not None:
        image = ax.imshow(grid, cmap=cmap, origin="upper", interpolation="nearest", extent=(-0.5, N - 0.5, N - 0.5, -0.5))
        ax.figure.colorbar(image, ax=ax, fraction=0.046, pad=0.04)
    ticks = np.arange(-0.5, N, 1.0)
    ax.set_xticks(ticks, minor=True)
    ax.set_yticks(ticks, minor=True)
    ax.grid(which="minor", color="0.8", linewidth=0.5 if N <= 40 else 0.0)
    ax.tick_params(which="both", length=0, labelbottom=False, labelleft=False)
    n_colours = world.n_inner + world.n_outer
    palette = colormaps["tab10" if n_colours <= 10 else "tab20"]
    objs = world.objects
    fig_w, fig_h = ax.figure.get_size_inches()
    box = ax.get_position()
    cell_pt = 72.0 * min(fig_w * box.width, fig_h * box.height) / N
    ax.scatter(
        objs[:, 1], objs[:, 0], s=(0.5 * cell_pt) ** 2,
        c=[palette(int(c) % palette.N) for c in objs[:, 2]],
        edgecolors=[palette(int(world.n_inner + c) % palette.N) for c in objs[:, 3]],
        linewidths=max(0.5, 0.18 * cell_pt), zorder=3,
    )
    ax.set_xlim(-0.5, N - 0.5)
    ax.set_ylim(N - 0.5, -0.5)
    ax.set_aspect("equal")
    return ax

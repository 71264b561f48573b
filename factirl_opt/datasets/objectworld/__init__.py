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
  the paper's :class:`~factirl_opt.mdp.tabular.GridWorld`, which redraws among feasible moves).
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
- **Rewards** are state rewards of shape (S,) (or (n, S) for n tasks), accepted as they are by
  every function that takes rewards (repeated over the actions); :func:`state_action_rewards`
  gives the (S, A) / (n, S, A) layout explicitly.

Modules
-------
- :mod:`~factirl_opt.datasets.objectworld.world`: the grid, its dynamics and the object placement
  (:class:`ObjectWorld`, :func:`make_objectworld`, :func:`objectworld_transitions`);
- :mod:`~factirl_opt.datasets.objectworld.features`: distances to the colours and Levine's features;
- :mod:`~factirl_opt.datasets.objectworld.rewards`: the single-task and the multi-task (ELIRL) rewards;
- :mod:`~factirl_opt.datasets.objectworld.plotting`: :func:`plot_objectworld`.

Every public name is importable from ``factirl_opt.datasets.objectworld`` (and the main ones from
``factirl_opt``).
"""

from .features import objectworld_distances, objectworld_features
from .maps import ObjectWorldMaps, block_cells, fresh_maps, objectworld_maps
from .plotting import plot_objectworld
from .rewards import ELIRL_RADIUS, ELIRL_SCALE, levine_reward, multitask_primitives, multitask_rewards, state_action_rewards
from .world import ACTIONS, MOVES, N_ACTIONS, ObjectWorld, make_objectworld, objectworld_transitions

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
    "ObjectWorldMaps",
    "objectworld_maps",
    "fresh_maps",
    "block_cells",
]

"""Tabular models of MiniGrid/BabyAI layouts, read from the simulator's own ``step``.

Conventions (every index order used by :mod:`factirl_opt.adapters.minigrid`)
-------------------------------------------------------------------
- **States** are the agent's ``(x, y, direction)`` reachable in an episode from its start
  under the navigation actions (terminal states are entered, not left). From another start
  in the same layout fewer states may be reachable (e.g. a corner whose only entrance faces
  the target), never more; ``x`` is the column and ``y`` the row of MiniGrid's grid (``y`` grows
  downwards) and ``direction`` is MiniGrid's: 0 east (+x), 1 south (+y), 2 west, 3 north.
  They are numbered in row-major order, sorted by ``(y, x, direction)``.
- **Actions** (:data:`ACTIONS`): MiniGrid's first three, 0 turn left, 1 turn right, 2 move
  forward. Pick-up, drop, toggle and done are not modelled.
- **Dynamics** are deterministic: the (S * A, S) CSR matrix of the :class:`TabularMDP` puts
  probability 1, in row ``s * A + a``, on the state the environment's ``step`` reached.
- **Terminal states.** A state the environment enters with ``terminated=True`` (BabyAI's
  verifier saying "success" or "failure", MiniGrid's goal or lava) is *absorbing*: its three
  actions loop back to it. This matches the episodic environment provided termination
  depends only on the state entered, which is checked: a state entered once with and once
  without termination is refused. ``success[s]`` records that entering ``s`` pays a positive
  reward (the mission is done); ``terminal[s]`` that the episode ends there. Truncation at
  ``max_steps`` is a time limit, not part of the model. A start state that is itself
  terminal is refused (the environment would not end the episode there, the model would).

Navigation is assumed deterministic, as MiniGrid's is: each (state, action) is probed once.
The simulator is probed on a deep copy of ``env.unwrapped`` (with its observation rendering
switched off), so the caller's environment is never modified. minigrid is an optional
dependency: ``pip install "minigrid>=3.0"``, or ``pip install -e ".[minigrid]"`` in a clone.
"""

from __future__ import annotations

import copy
import dataclasses
import importlib
from collections import deque
from types import ModuleType
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..._validation import check_real
from ...exceptions import MissingDependencyError, ValidationError
from ...mdp.tabular import TabularMDP
from .features import DEFAULT_THRESHOLDS, grid_objects, minigrid_feature_names, minigrid_features

__all__ = ["ACTIONS", "DIRECTIONS", "INSTALL_HINT", "MiniGridModel", "from_minigrid", "require_minigrid", "make_env",
           "base_env"]

#: The modelled actions, in MiniGrid's numbering.
ACTIONS = ("left", "right", "forward")
#: MiniGrid's directions: (dx, dy) of ``direction`` 0..3.
DIRECTIONS = ((1, 0), (0, 1), (-1, 0), (0, -1))
#: How to install the ``minigrid`` extra.
INSTALL_HINT = 'pip install "minigrid>=3.0" "gymnasium>=0.29" (or, in a clone of factirl-opt: pip install -e ".[minigrid]")'


def require_minigrid(what: str = "this function") -> ModuleType:
    """Import minigrid (which registers its environments with gymnasium), or raise.

    Raises
    ------
    MissingDependencyError
        minigrid is not installed; the message gives the pip command.
    """
    try:
        return importlib.import_module("minigrid")
    except ImportError as exc:
        raise MissingDependencyError(f"{what} needs minigrid, which is not installed: {INSTALL_HINT}") from exc


def make_env(env_id: Any, name: str = "env", what: str = "running MiniGrid episodes") -> Any:
    """A new environment of a registered MiniGrid/BabyAI id (``gymnasium.make``), minigrid imported first.

    Parameters
    ----------
    env_id : str
        A gymnasium id, e.g. ``"BabyAI-GoToLocal-v0"``.
    name : str
        The caller's parameter, named in the errors.
    what : str
        What needs minigrid, named when it is not installed.

    Raises
    ------
    ValidationError
        ``env_id`` is not a string, or not a registered id (the message names it, with
        gymnasium's own reason, e.g. its closest registered name).
    MissingDependencyError
        minigrid is not installed.
    """
    require_minigrid(what)
    if not isinstance(env_id, str):
        raise ValidationError(f"{name} must be a registered environment id (a str); got {type(env_id).__name__}")
    gym = importlib.import_module("gymnasium")
    try:
        return gym.make(env_id)
    except gym.error.Error as exc:  # NameNotFound, VersionNotFound, NamespaceNotFound, DeprecatedEnv, ...
        raise ValidationError(f"{name}={env_id!r} is not a registered environment id: {exc}") from None


def base_env(env: Any) -> Any:
    """``env.unwrapped``, checked to be a MiniGrid environment that has been reset."""
    base = getattr(env, "unwrapped", env)
    for attr in ("grid", "agent_pos", "agent_dir", "step", "max_steps"):
        if not hasattr(base, attr):
            raise ValidationError(f"env must be a MiniGrid/BabyAI environment; {type(base).__name__} has no {attr!r}")
    if base.agent_pos is None or base.grid is None:
        raise ValidationError("env has not been reset: call env.reset(seed=...) before reading its model")
    return base


def agent_state(base: Any) -> tuple[int, int, int]:
    """The agent's ``(x, y, direction)`` in an unwrapped MiniGrid environment."""
    return int(base.agent_pos[0]), int(base.agent_pos[1]), int(base.agent_dir)


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class MiniGridModel:
    """One MiniGrid layout as a tabular MDP with features. Build it with :func:`from_minigrid`.

    Attributes
    ----------
    mdp : TabularMDP
        Sparse deterministic dynamics over the reachable states, A = 3 (left, right, forward).
    states : ndarray of int64, shape (S, 3)
        Row ``s`` is ``(x, y, direction)`` of state ``s`` (read-only), sorted by (y, x, direction).
    start : int
        The start state's number.
    features : ndarray of float64, shape (S, p)
        See :func:`~factirl_opt.adapters.minigrid.features.minigrid_features`; same columns in every layout.
    feature_names : tuple of str, length p
    terminal, success : ndarray of bool, shape (S,)
        Absorbing states where the episode ends, and those of them where it ends with a
        positive reward (see the module docstring).
    mission : str
        The environment's mission string ("" if it has none).
    objects : ndarray of int64, shape (m, 4)
        The layout's objects, rows ``(x, y, colour, type)`` (indices into
        :data:`~factirl_opt.adapters.minigrid.features.COLOURS` and ``OBJECT_TYPES``).
    grid_size : tuple of int
        ``(width, height)`` of the grid.
    lookup : dict
        ``(x, y, direction) -> state number`` (what :meth:`index` reads).
    """

    mdp: TabularMDP
    states: np.ndarray
    start: int
    features: np.ndarray
    feature_names: tuple[str, ...]
    terminal: np.ndarray
    success: np.ndarray
    mission: str
    objects: np.ndarray
    grid_size: tuple[int, int]
    lookup: dict = dataclasses.field(repr=False)

    @property
    def n_states(self) -> int:
        """S, the number of reachable states."""
        return int(self.states.shape[0])

    def index(self, x: int, y: int, direction: int) -> int:
        """The number of state ``(x, y, direction)``; ValidationError if it is not in the model."""
        key = (int(x), int(y), int(direction))
        s = self.lookup.get(key)
        if s is None:
            raise ValidationError(
                f"(x, y, direction) = {key} is not a state of this model (a wall, an object's cell, a cell "
                f"outside the {self.grid_size[0]} x {self.grid_size[1]} grid, or not reachable from the start)"
            )
        return s

    def state_of(self, env: Any) -> int:
        """The number of the state an environment's agent is in now."""
        return self.index(*agent_state(base_env(env)))

    def __repr__(self) -> str:
        return (f"MiniGridModel(n_states={self.n_states}, n_features={self.features.shape[1]}, "
                f"grid_size={self.grid_size}, mission={self.mission!r})")


def _probe(sim: Any, state: tuple[int, int, int], action: int) -> tuple[tuple[int, int, int], bool, float]:
    """One call of the simulator's ``step`` from ``state``: (next state, terminated, reward)."""
    sim.agent_pos = (state[0], state[1])
    sim.agent_dir = state[2]
    sim.step_count = 0  # no truncation, and the reward of success is 1
    _, reward, terminated, _, _ = sim.step(action)
    return agent_state(sim), bool(terminated), float(reward)


def _explore(sim: Any, start: tuple[int, int, int]) -> tuple[list, dict, dict]:
    """Breadth-first search of the reachable states through ``sim.step``.

    Returns the transitions ``(state, action, next_state)``, and per state entered whether it
    was entered with termination and whether with a positive reward. Terminal states are not
    expanded (they are made absorbing).
    """
    seen = {start}
    queue = deque([start])
    edges: list = []
    ended: dict = {}
    paid: dict = {}
    while queue:
        state = queue.popleft()
        for action in range(len(ACTIONS)):
            nxt, done, reward = _probe(sim, state, action)
            edges.append((state, action, nxt))
            if ended.setdefault(nxt, done) != done:
                raise ValidationError(
                    f"termination depends on more than the agent's (x, y, direction): state {nxt} is entered both "
                    "with and without the episode ending; this level cannot be modelled by navigation states"
                )
            paid[nxt] = paid.get(nxt, False) or reward > 0
            if nxt not in seen:
                seen.add(nxt)
                if not done:
                    queue.append(nxt)
    return edges, ended, paid


def _check_static(sim: Any, before: np.ndarray, states: list, terminal: set) -> None:
    """Refuse layouts whose grid changes under navigation or is closed by doors."""
    if not np.array_equal(sim.grid.encode(), before) or sim.carrying is not None:
        raise ValidationError("the grid changed while the agent only navigated (moving obstacles?); "
                              "only levels whose grid is static under left/right/forward are supported")
    width, height = sim.grid.width, sim.grid.height
    for x, y, d in states:
        if (x, y, d) in terminal:
            continue
        fx, fy = x + DIRECTIONS[d][0], y + DIRECTIONS[d][1]
        cell = sim.grid.get(fx, fy) if 0 <= fx < width and 0 <= fy < height else None
        if cell is not None and cell.type == "door" and not cell.is_open:
            kind = "locked" if cell.is_locked else "closed"
            raise ValidationError(
                f"a {kind} {cell.color} door at (x, y) = ({fx}, {fy}) borders the reachable region; opening it changes "
                "the grid, which navigation states cannot model (choose a level with open doors, e.g. BabyAI-GoToOpen-v0)"
            )


def _transition_matrix(edges: list, lookup: dict, absorbing: np.ndarray) -> sp.csr_matrix:
    S, A = len(lookup), len(ACTIONS)
    rows = [lookup[s] * A + a for s, a, _ in edges]
    cols = [lookup[n] for _, _, n in edges]
    for s in np.flatnonzero(absorbing):
        rows.extend(int(s) * A + a for a in range(A))
        cols.extend([int(s)] * A)
    return sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(S * A, S))


def from_minigrid(env: Any, gamma: float = 0.9, thresholds: tuple[float, ...] = DEFAULT_THRESHOLDS) -> MiniGridModel:
    """The tabular model of one MiniGrid/BabyAI layout, read from the environment's ``step``.

    Parameters
    ----------
    env : gymnasium.Env
        A MiniGrid or BabyAI environment after ``env.reset(seed=...)`` (wrappers are looked
        through with ``env.unwrapped``). It is not modified: the simulator is probed on a copy.
    gamma : float, default=0.9
        Discount factor of the MDP, in [0, 1); MiniGrid defines none, 0.9 is the library's
        usual value (the paper's grid world).
    thresholds : tuple of float, default=DEFAULT_THRESHOLDS
        The ``d`` of the distance indicators ``1[distance < d]`` (see
        :func:`~factirl_opt.adapters.minigrid.features.minigrid_features`).

    Returns
    -------
    model : MiniGridModel
        States, sparse deterministic dynamics with absorbing terminal states, features.

    Raises
    ------
    MissingDependencyError
        minigrid is not installed.
    ValidationError
        ``env`` is not a reset MiniGrid environment; or the level is not modelled by
        navigation states: its grid changes while the agent navigates, a closed or locked door
        borders the reachable region, termination depends on more than the state entered, no
        reachable state ends the episode (e.g. the mission needs pick-up or toggle), or the
        agent starts in a terminal state.
    """
    require_minigrid("from_minigrid")
    base = base_env(env)
    gamma = check_real(gamma, "gamma", 0.0, 1.0, high_open=True)
    sim = copy.deepcopy(base)
    sim.render_mode = None
    sim.gen_obs = lambda: None  # observations are not needed to probe the dynamics
    before = sim.grid.encode()
    start = agent_state(base)
    edges, ended, paid = _explore(sim, start)
    terminal_set = {s for s, done in ended.items() if done}
    keys = sorted({start} | set(ended), key=lambda s: (s[1], s[0], s[2]))
    _check_static(sim, before, keys, terminal_set)
    if not terminal_set:
        raise ValidationError(f"no reachable state ends the episode of mission {getattr(base, 'mission', '')!r} by "
                              "navigation alone (left/right/forward); pick-up, toggle or done would be needed")
    if start in terminal_set:
        raise ValidationError(f"the agent starts in a terminal state {start} (e.g. already facing its target); "
                              "the model would end the episode where the environment does not: choose another seed")
    lookup = {s: i for i, s in enumerate(keys)}
    states = np.array(keys, dtype=np.int64).reshape(-1, 3)
    terminal = np.array([s in terminal_set for s in keys])
    success = np.array([paid.get(s, False) and s in terminal_set for s in keys])
    mdp = TabularMDP(_transition_matrix(edges, lookup, terminal), gamma)
    objects = grid_objects(base.grid)
    features = minigrid_features(states, objects, base.grid, thresholds)
    for arr in (states, terminal, success, objects, features):
        arr.setflags(write=False)
    return MiniGridModel(mdp, states, lookup[start], features, tuple(minigrid_feature_names(thresholds)), terminal, success,
                         str(getattr(base, "mission", "")), objects, (int(base.grid.width), int(base.grid.height)), lookup)

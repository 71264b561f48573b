"""from_minigrid: models read from the simulator, checked against MiniGrid's documented rules."""

import copy
import subprocess
import sys

import numpy as np
import pytest

minigrid = pytest.importorskip("minigrid")
gym = pytest.importorskip("gymnasium")

import factirl_opt as fo  # noqa: E402
from factirl_opt.exceptions import MissingDependencyError, ValidationError  # noqa: E402
from factirl_opt.adapters.minigrid import from_minigrid, parse_goto_mission  # noqa: E402
from factirl_opt.adapters.minigrid.features import COLOURS, OBJECT_TYPES  # noqa: E402

DIRS = [(1, 0), (0, 1), (-1, 0), (0, -1)]  # MiniGrid's DIR_TO_VEC


def layout(name="BabyAI-GoToLocal-v0", seed=0):
    env = gym.make(name)
    env.reset(seed=seed)
    return env


def reference_next(grid, state, action):
    """MiniGrid's documented navigation: turn left/right, forward onto an empty/overlappable cell."""
    x, y, d = state
    if action == 0:
        return x, y, (d - 1) % 4
    if action == 1:
        return x, y, (d + 1) % 4
    fx, fy = x + DIRS[d][0], y + DIRS[d][1]
    cell = grid.get(fx, fy)
    return (fx, fy, d) if cell is None or cell.can_overlap() else (x, y, d)


def targets_faced(model, base):
    """Terminal states of a GoTo mission by its text: facing an object of the named colour and type."""
    colour, kind = parse_goto_mission(model.mission)
    out = np.zeros(model.n_states, dtype=bool)
    for s, (x, y, d) in enumerate(model.states):
        cell = base.grid.get(x + DIRS[d][0], y + DIRS[d][1])
        out[s] = cell is not None and cell.type == kind and (colour is None or cell.color == colour)
    return out


@pytest.mark.parametrize("name, seed", [("BabyAI-GoToLocal-v0", 0), ("BabyAI-GoToLocal-v0", 7), ("BabyAI-GoToOpen-v0", 3)])
def test_model_matches_documented_dynamics_and_mission(name, seed):
    env = layout(name, seed)
    base = env.unwrapped
    m = from_minigrid(env)
    S = m.n_states
    assert m.mdp.is_sparse and m.mdp.n_actions == 3 and m.states.shape == (S, 3)
    assert m.features.shape == (S, len(m.feature_names))
    keys = [(y, x, d) for x, y, d in m.states.tolist()]
    assert keys == sorted(keys) and len(set(keys)) == S  # row-major numbering, no duplicates
    assert all(m.index(*st) == s for s, st in enumerate(m.states.tolist()))
    assert tuple(m.states[m.start]) == (*base.agent_pos, base.agent_dir)
    P = m.mdp.transition_matrix
    assert np.array_equal(np.diff(P.indptr), np.ones(3 * S)) and np.all(P.data == 1.0)  # deterministic
    np.testing.assert_array_equal(m.terminal, targets_faced(m, base))
    np.testing.assert_array_equal(m.success, m.terminal)  # GoTo: every terminal state is a success
    for s, st in enumerate(m.states.tolist()):
        for a in range(3):
            expected = tuple(st) if m.terminal[s] else reference_next(base.grid, st, a)
            assert tuple(m.states[P.indices[s * 3 + a]]) == expected
    assert m.mission == base.mission and m.grid_size == (base.width, base.height)


def test_env_is_left_unmodified_and_wrappers_are_looked_through():
    env = layout()
    base = env.unwrapped
    before = (tuple(base.agent_pos), base.agent_dir, base.step_count, base.grid.encode().copy())
    witness = copy.deepcopy(base)
    a = from_minigrid(env)
    b = from_minigrid(base)
    assert (tuple(base.agent_pos), base.agent_dir, base.step_count) == before[:3]
    np.testing.assert_array_equal(base.grid.encode(), before[3])
    assert a.mdp.signature() == b.mdp.signature() and np.array_equal(a.features, b.features)
    for action in (2, 1, 2):  # the env still behaves as an untouched copy of itself
        o1, r1, t1, _, _ = base.step(action)
        o2, r2, t2, _, _ = witness.step(action)
        assert (r1, t1) == (r2, t2) and np.array_equal(o1["image"], o2["image"])


def test_gamma_default_and_validation():
    env = layout()
    assert from_minigrid(env).mdp.gamma == 0.9
    assert from_minigrid(env, gamma=0.99).mdp.gamma == 0.99
    with pytest.raises(ValidationError, match="gamma"):
        from_minigrid(env, gamma=1.0)


def test_minigrid_goal_and_lava_are_absorbing():
    empty = from_minigrid(layout("MiniGrid-Empty-5x5-v0"))
    gx, gy = 3, 3  # the goal of Empty-5x5
    on_goal = (empty.states[:, 0] == gx) & (empty.states[:, 1] == gy)
    np.testing.assert_array_equal(empty.terminal, on_goal)
    np.testing.assert_array_equal(empty.success, on_goal)
    lava = from_minigrid(layout("MiniGrid-LavaGapS5-v0"))
    base = layout("MiniGrid-LavaGapS5-v0").unwrapped
    types = [base.grid.get(x, y).type if base.grid.get(x, y) else None for x, y, _ in lava.states.tolist()]
    np.testing.assert_array_equal(lava.terminal, [t in ("lava", "goal") for t in types])
    np.testing.assert_array_equal(lava.success, [t == "goal" for t in types])
    P = lava.mdp.transition_matrix
    for s in np.flatnonzero(lava.terminal):
        assert P.indices[3 * s:3 * s + 3].tolist() == [s, s, s]


def test_index_of_unknown_state_raises():
    m = from_minigrid(layout())
    with pytest.raises(ValidationError, match=r"\(0, 0, 0\) is not a state"):
        m.index(0, 0, 0)  # a wall
    assert m.state_of(layout()) == m.start
    assert "GoTo" not in repr(m) and "n_states=" in repr(m)


def test_refuses_closed_doors():
    with pytest.raises(ValidationError, match="closed .* door at"):
        from_minigrid(layout("BabyAI-GoTo-v0", 0))


def test_refuses_missions_that_navigation_cannot_complete():
    with pytest.raises(ValidationError, match="no reachable state ends the episode of mission 'pick up"):
        from_minigrid(layout("BabyAI-PickupLoc-v0", 0))


def test_refuses_termination_that_depends_on_history():
    with pytest.raises(ValidationError, match="termination depends on more than"):
        from_minigrid(layout("MiniGrid-Dynamic-Obstacles-5x5-v0", 0))


class _TerminatesOnLeft(minigrid.envs.EmptyEnv):
    """Ends the episode on every left turn: termination depends on the action, not the state."""

    def step(self, action):
        obs, reward, terminated, truncated, info = super().step(action)
        return obs, reward, terminated or action == 0, truncated, info


class _MovesAWall(minigrid.envs.EmptyEnv):
    """Changes its grid at every step, without ever ending the episode."""

    def step(self, action):
        x = 1 + self.step_count % 2
        self.grid.set(x, self.height - 2, minigrid.core.world_object.Wall())
        return super().step(action)


def test_refuses_history_dependent_termination_and_changing_grids():
    env = _TerminatesOnLeft(size=5)
    env.reset(seed=0)
    with pytest.raises(ValidationError, match="termination depends on more than"):
        from_minigrid(env)
    env = _MovesAWall(size=6)
    env.reset(seed=0)
    with pytest.raises(ValidationError, match="grid changed while the agent only navigated"):
        from_minigrid(env)


def test_refuses_a_terminal_start():
    env = layout()
    m = from_minigrid(env)
    x, y, d = m.states[np.flatnonzero(m.terminal)[0]]
    env.unwrapped.agent_pos, env.unwrapped.agent_dir = (int(x), int(y)), int(d)
    with pytest.raises(ValidationError, match="starts in a terminal state"):
        from_minigrid(env)


def test_refuses_non_minigrid_and_unreset_envs():
    with pytest.raises(ValidationError, match="MiniGrid/BabyAI environment"):
        from_minigrid(gym.make("FrozenLake-v1"))
    with pytest.raises(ValidationError, match="has not been reset"):
        from_minigrid(gym.make("BabyAI-GoToLocal-v0"))


def test_missing_minigrid_raises_with_the_pip_command(monkeypatch):
    env = layout()
    monkeypatch.setitem(sys.modules, "minigrid", None)  # import minigrid now raises ImportError
    with pytest.raises(MissingDependencyError, match=r'pip install -e "\.\[minigrid\]"'):
        from_minigrid(env)


def test_import_factirl_opt_does_not_import_minigrid():
    code = ("import sys, factirl_opt as fo; assert 'minigrid' not in sys.modules; "
            "assert 'minigrid' in dir(fo) and 'from_minigrid' in fo.minigrid.__all__; "
            "f = fo.minigrid.from_minigrid; assert 'minigrid' in sys.modules; "
            "import factirl_opt.adapters.minigrid as m; assert f is m.from_minigrid")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_public_names():
    assert fo.minigrid.from_minigrid is from_minigrid
    for name in ("MiniGridModel", "minigrid_feature_names", "parse_goto_mission", "bot_demonstration",
                 "BotDemonstration", "run_policy", "PolicyRun"):
        assert name in fo.minigrid.__all__ and name not in fo.__all__
    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        fo.nonexistent  # noqa: B018
    assert COLOURS == tuple(sorted(minigrid.core.constants.COLOR_TO_IDX, key=minigrid.core.constants.COLOR_TO_IDX.get))
    assert set(OBJECT_TYPES) <= set(minigrid.core.constants.OBJECT_TO_IDX)

"""MiniGrid features (checked against the agent's own observation and brute-force distances) and
the GoTo mission parser."""

import copy

import numpy as np
import pytest

minigrid = pytest.importorskip("minigrid")
gym = pytest.importorskip("gymnasium")

from minigrid.core.constants import IDX_TO_COLOR, IDX_TO_OBJECT  # noqa: E402

from factirl_opt.exceptions import ValidationError  # noqa: E402
from factirl_opt.adapters.minigrid import from_minigrid, minigrid_feature_names, minigrid_features, parse_goto_mission  # noqa: E402
from factirl_opt.adapters.minigrid.features import COLOURS, DEFAULT_THRESHOLDS, OBJECT_TYPES, grid_objects  # noqa: E402


def layout(name="BabyAI-GoToLocal-v0", seed=0):
    env = gym.make(name)
    env.reset(seed=seed)
    return env


def observed_front(base, state):
    """(type, colour) of the cell in front, read from the agent's egocentric observation."""
    sim = copy.deepcopy(base)
    sim.agent_pos, sim.agent_dir = (int(state[0]), int(state[1])), int(state[2])
    image = sim.gen_obs()["image"]
    view = image.shape[0]
    t, c, _ = image[view // 2, view - 2]  # the agent sits at (view // 2, view - 1) facing "up"
    return IDX_TO_OBJECT[int(t)], IDX_TO_COLOR[int(c)]


@pytest.mark.parametrize("name, seed", [("BabyAI-GoToLocal-v0", 0), ("BabyAI-GoToLocal-v0", 5), ("MiniGrid-LavaGapS5-v0", 0)])
def test_front_features_match_the_observation(name, seed):
    env = layout(name, seed)
    m = from_minigrid(env)
    names = m.feature_names
    F = m.features
    kinds = F[:, :7]
    assert np.all(kinds.sum(axis=1) == 1)
    for s, state in enumerate(m.states):
        kind, colour = observed_front(env.unwrapped, state)
        on = {names[j] for j in np.flatnonzero(F[s, :37])}
        if kind in OBJECT_TYPES:
            assert on == {f"front={kind}", f"front colour={colour}", f"front={colour} {kind}"}
        else:
            expected = {"empty": "front=empty", "floor": "front=empty", "wall": "front=wall"}.get(kind, "front=other")
            assert on == {expected}


def test_distance_features_match_brute_force():
    env = layout("BabyAI-GoToOpen-v0", 1)
    base = env.unwrapped
    m = from_minigrid(env)
    cells = [(x, y, base.grid.get(x, y)) for x in range(base.width) for y in range(base.height)]
    objs = [(x, y, o.color, o.type) for x, y, o in cells if o is not None and o.type in OBJECT_TYPES]
    T = len(DEFAULT_THRESHOLDS)
    for s, (x, y, _) in enumerate(m.states[::7]):
        for j, what in enumerate(COLOURS + OBJECT_TYPES):
            dists = [np.hypot(x - ox, y - oy) for ox, oy, c, t in objs if what in (c, t)]
            nearest = min(dists, default=np.inf)
            got = m.features[7 * s, 37 + j * T: 37 + (j + 1) * T]
            np.testing.assert_array_equal(got, [nearest < d for d in DEFAULT_THRESHOLDS])
            assert m.feature_names[37 + j * T] == f"near {what}<{DEFAULT_THRESHOLDS[0]:g}"


def test_same_columns_in_every_layout_and_absent_colours():
    a = from_minigrid(layout("BabyAI-GoToLocal-v0", 0))
    b = from_minigrid(layout("BabyAI-GoToOpen-v0", 0))
    assert a.feature_names == b.feature_names == tuple(minigrid_feature_names())
    assert a.features.shape[1] == b.features.shape[1] == 7 + 6 + 24 + 10 * len(DEFAULT_THRESHOLDS) == 127
    assert set(np.unique(a.features)) <= {0.0, 1.0}
    base = layout("BabyAI-GoToLocal-v0", 0).unwrapped
    objects = grid_objects(base.grid)
    absent = [c for c in range(len(COLOURS)) if c not in objects[:, 2]]
    none = np.zeros((0, 4), dtype=np.int64)  # a layout without objects: no distance indicator set
    F = minigrid_features(a.states, none, base.grid, thresholds=(2, 5))
    assert F.shape == (a.n_states, 37 + 20) and not F[:, 37:].any()
    for c in absent:
        assert not a.features[:, 37 + c * len(DEFAULT_THRESHOLDS): 37 + (c + 1) * len(DEFAULT_THRESHOLDS)].any()


@pytest.mark.parametrize("bad", [(), (2, 2), (3, 1), (0, 1), (-1,), ("x",), 5, (np.inf,)])
def test_bad_thresholds_raise(bad):
    with pytest.raises(ValidationError, match="threshold"):
        minigrid_feature_names(bad)


@pytest.mark.parametrize("mission, expected", [
    ("go to the red key", ("red", "key")),
    ("go to a purple ball", ("purple", "ball")),
    ("go to the grey door", ("grey", "door")),
    ("  go to the yellow box ", ("yellow", "box")),
    ("go to the ball", (None, "ball")),
])
def test_parse_goto_mission(mission, expected):
    assert parse_goto_mission(mission) == expected


@pytest.mark.parametrize("mission", [
    "pick up the red key", "go to the red key on your left", "go to the pink key", "go to the red lamp",
    "go to the red key and go to the blue ball", "Go to the red key", "go to red key", "",
])
def test_parse_goto_mission_refuses_other_missions(mission):
    with pytest.raises(ValidationError, match="not a BabyAI GoTo mission"):
        parse_goto_mission(mission)


def test_parse_goto_mission_refuses_non_strings():
    with pytest.raises(ValidationError, match="mission must be a string"):
        parse_goto_mission(None)


@pytest.mark.parametrize("name", ["BabyAI-GoToLocal-v0", "BabyAI-GoToOpen-v0"])
def test_generated_missions_parse_and_name_an_object_of_the_layout(name):
    env = gym.make(name)
    for seed in range(15):
        env.reset(seed=seed)
        colour, kind = parse_goto_mission(env.unwrapped.mission)
        objects = grid_objects(env.unwrapped.grid)
        match = (objects[:, 3] == OBJECT_TYPES.index(kind)) & (colour is None or objects[:, 2] == COLOURS.index(colour))
        assert match.any()

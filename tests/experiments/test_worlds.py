"""The worlds of the experiments: the multi-task Objectworld's ground truth, and presets that name a world."""

import dataclasses

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError
from factirl_opt.lab.experiments import PRESETS, WORLDS, Preset, make_ground_truth
from factirl_opt.lab.experiments.presets import LATER_FIELDS

OW = PRESETS["objectworld-tiny"]


def _world(gt, preset):
    """The ObjectWorld of a ground truth, rebuilt from the objects it records for figure 3."""
    extras = gt.map_extras
    return fo.objectworld.make_objectworld(preset.grid_size, extras["n_inner"], extras["n_outer"], objects=extras["objects"],
                               determinism=preset.p_success, gamma=preset.gamma)


def test_objectworld_is_a_world():
    assert set(WORLDS) == {"grid", "objectworld", "objectworld-per-task", "babyai", "babyai-large"}
    for name in ("objectworld", "objectworld-quick", "objectworld-tiny"):
        p = PRESETS[name]
        assert (p.world, p.lineup, p.n_primitives, p.n_outer_colours, p.p_success, p.gamma) == (
            "objectworld", "objectworld", 5, 2, 0.7, 0.9)
    full = PRESETS["objectworld"]
    assert (full.grid_size, full.default_tasks, full.default_demos, full.demo_length, full.n_test_tasks) == (32, 100, 32, 16, 100)
    assert full.object_density == 0.05 and full.n_seeds >= 3 and full.tasks_sweep == (10, 20, 50, 100)


def test_objectworld_ground_truth_follows_elirls_rule():
    gt = make_ground_truth(OW, 6, 4, seed=3)
    world = _world(gt, OW)
    S, A, N = world.n_states, 5, OW.grid_size
    assert gt.mdp.signature() == world.mdp().signature()  # the same dynamics, rebuilt from the recorded objects
    primitives = fo.objectworld.multitask_primitives(world)
    np.testing.assert_array_equal(gt.dictionary, primitives)
    np.testing.assert_array_equal(gt.features, fo.objectworld.objectworld_features(world))
    assert gt.features.shape == (S, (N - 1) * (5 + 2))
    for R in (gt.train_rewards, gt.test_rewards):
        assert R.shape[1:] == (S, A)
        np.testing.assert_array_equal(R, np.repeat(R[:, :, :1], A, axis=2))  # state rewards
        w = np.linalg.lstsq(primitives, R[:, :, 0].T, rcond=None)[0].T  # the rewards lie in the primitives' span
        np.testing.assert_allclose(w @ primitives.T, R[:, :, 0], atol=1e-9)
    assert len(gt.train_demos) == 6 and gt.train_demos[0].shape == (4, OW.demo_length, 2)
    assert len(gt.test_demos) == OW.n_test_tasks and gt.test_demos[0].shape == (1, OW.demo_length, 2)
    # the experts are greedy on the true rewards
    Q, _ = fo.optimal_q(gt.mdp, gt.train_rewards)
    for i, demo in enumerate(gt.train_demos):
        s, a = demo[..., 0].ravel(), demo[..., 1].ravel()
        assert np.all(Q[i, s, a] >= Q[i, s].max(axis=1) - 1e-9)
    assert gt.map_extras["moves"][1] == [-1, 0] and len(gt.map_extras["moves"]) == 5  # "up" is row - 1


def test_objectworld_streams_are_shared_across_points():
    a, b, c = make_ground_truth(OW, 3, 2, seed=5), make_ground_truth(OW, 6, 4, seed=5), make_ground_truth(OW, 3, 2, seed=6)
    assert a.map_extras == b.map_extras and a.map_extras != c.map_extras  # one world per seed
    np.testing.assert_array_equal(a.train_rewards, b.train_rewards[:3])  # nested training tasks
    np.testing.assert_array_equal(a.test_rewards, b.test_rewards)
    np.testing.assert_array_equal(np.stack(a.test_demos), np.stack(b.test_demos))
    again = make_ground_truth(OW, 3, 2, seed=5)
    np.testing.assert_array_equal(np.stack(a.train_demos), np.stack(again.train_demos))


def test_the_grid_has_no_features_or_extras():
    gt = make_ground_truth(PRESETS["tiny"], 4, 2, seed=0)
    assert gt.features is None and gt.map_extras == {}


def test_objectworld_fields_keep_the_papers_fingerprint():
    paper = PRESETS["paper"]
    assert {f: getattr(paper, f) for f in LATER_FIELDS} == LATER_FIELDS
    assert paper.fingerprint() == "ea9fc43e51"
    for field, value in (("n_outer_colours", 3), ("object_density", 0.1), ("world", "objectworld")):
        assert dataclasses.replace(paper, **{field: value}).fingerprint() != paper.fingerprint()


@pytest.mark.parametrize("bad, match", [
    (dict(world="objectworld", n_outer_colours=0), "n_outer_colours"),
    (dict(world="objectworld", object_density=0.0), "object_density"),
    (dict(world="objectworld", object_density=1.5), "object_density"),
    (dict(lineup="objectworld"), "the line-up 'objectworld' runs in the world\\(s\\) objectworld; got world 'grid'"),
    (dict(lineup="objectworld+mce"), "runs in the world"),
    (dict(world="mars"), "world must be one of grid, objectworld"),
])
def test_objectworld_preset_validation(bad, match):
    with pytest.raises(ValidationError, match=match):
        Preset(name="bad", **bad)


def test_the_papers_lineup_runs_in_objectworld_too():
    p = Preset(name="ow-paper", world="objectworld", grid_size=6, n_test_tasks=2, object_density=0.2)
    gt = make_ground_truth(p, 3, 2, seed=0)
    assert gt.dictionary.shape == (36, 5) and gt.train_rewards.shape == (3, 36, 5)

"""Objectworld rewards: Levine's single-task rule and ELIRL's multi-task rewards."""

import numpy as np
import pytest

from factirl_opt.exceptions import ValidationError
from factirl_opt.datasets.objectworld import (
    levine_reward,
    make_objectworld,
    multitask_primitives,
    objectworld_distances,
    multitask_rewards,
    objectworld_features,
    state_action_rewards,
)

# ---------------------------------------------------------------- rewards


def test_levine_reward_on_a_hand_built_map():
    # inner 0 at (2, 2), inner 1 at (2, 3) on a 6 x 6 grid
    world = make_objectworld(6, n_inner=2, n_outer=1, objects=[(2, 2, 0, 0), (2, 3, 1, 0)])
    r = levine_reward(world)
    assert r.shape == (36,)
    assert r[2 * 6 + 2] == 1.0  # on colour 0, colour 1 at 1
    assert r[0 * 6 + 2] == -1.0  # colour 0 at 2 (< 3), colour 1 at sqrt5 (not < 2)
    assert r[2 * 6 + 1] == -1.0  # colour 1 at exactly 2: not < 2
    assert r[2 * 6 + 5] == 0.0  # colour 0 at exactly 3: not < 3
    assert r[5 * 6 + 5] == 0.0
    D = objectworld_distances(world)
    expected = np.where((D[:, 0] < 3) & (D[:, 1] < 2), 1.0, np.where(D[:, 0] < 3, -1.0, 0.0))
    np.testing.assert_array_equal(r, expected)
    np.testing.assert_array_equal(levine_reward(world, positive=5.0, negative=-10.0), 5.0 * (r > 0) - 10.0 * (r < 0))


def test_levine_reward_is_a_function_of_two_discrete_features():
    world = make_objectworld(16, rng=11)
    F, r = objectworld_features(world), levine_reward(world)
    near0, near1 = F[:, 0 * 15 + 2] == 1, F[:, 1 * 15 + 1] == 1  # inner 0 at d = 3, inner 1 at d = 2
    np.testing.assert_array_equal(r, np.where(near0 & near1, 1.0, np.where(near0, -1.0, 0.0)))
    assert (r == 1).any() or (r == -1).any()


def test_multitask_rule():
    world = make_objectworld(12, rng=0)
    rewards, H, prims = multitask_rewards(world, 300, rng=1)
    assert rewards.shape == (300, 144) and H.shape == (300, 5) and prims.shape == (144, 5)
    counts = (H != 0).sum(axis=1)
    assert set(counts) == {2, 3, 4}
    w = H[H != 0]
    assert w.min() >= -10.0 and w.max() < 5.0 and w.min() < -5.0 and w.max() > 2.0
    np.testing.assert_array_equal(rewards, H @ prims.T)
    D = objectworld_distances(world)
    for i in range(0, 300, 37):  # the rule, summed colour by colour
        ref = sum(H[i, c] * (D[:, c] < 3) for c in range(5))
        np.testing.assert_allclose(rewards[i], ref, rtol=0, atol=1e-12)
    # every chosen colour is used about equally often
    freq = (H != 0).mean(axis=0)
    assert np.all(np.abs(freq - freq.mean()) < 0.1)


def test_multitask_primitives_are_feature_columns_at_distance_3():
    world = make_objectworld(8, rng=4)
    F, prims = objectworld_features(world), multitask_primitives(world)
    np.testing.assert_array_equal(prims, F[:, [c * 7 + 2 for c in range(5)]])


def test_multitask_rewards_are_seeded_and_cap_the_number_of_colours():
    world = make_objectworld(6, n_inner=1, n_outer=1, rng=0)
    _, H, _ = multitask_rewards(world, 20, rng=2)
    assert np.all(H != 0)  # a single inner colour: always chosen
    big = make_objectworld(6, rng=0)
    a, b = multitask_rewards(big, 4, rng=9), multitask_rewards(big, 4, rng=9)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def test_state_action_rewards():
    r = np.arange(6.0).reshape(2, 3)
    out = state_action_rewards(r)
    assert out.shape == (2, 3, 5) and out.flags.c_contiguous
    np.testing.assert_array_equal(out, np.broadcast_to(r[..., None], (2, 3, 5)))
    assert state_action_rewards(r[0], n_actions=2).shape == (3, 2)



def test_reward_function_validation():
    world = make_objectworld(4, n_inner=2, n_outer=1, rng=0)
    for fn in (levine_reward, multitask_primitives):
        with pytest.raises(ValidationError, match="world must be an ObjectWorld"):
            fn("not a world")
    with pytest.raises(ValidationError, match="levine_reward needs at least 2 inner colours"):
        levine_reward(make_objectworld(4, n_inner=1, n_outer=1, rng=0))
    with pytest.raises(ValidationError, match="positive must be a finite number"):
        levine_reward(world, positive=float("inf"))
    with pytest.raises(ValidationError, match="n_tasks must be an integer >= 1"):
        multitask_rewards(world, 0)
    with pytest.raises(ValidationError, match="rng must be a numpy Generator"):
        multitask_rewards(world, 2, rng=1.5)
    with pytest.raises(ValidationError, match="rewards must have shape"):
        state_action_rewards(1.0)

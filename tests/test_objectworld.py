"""Objectworld: sparse dynamics, object placement, features and the single- and multi-task rewards."""

import math

import numpy as np
import pytest
import scipy.sparse as sp

from factirl_opt.exceptions import ValidationError
from factirl_opt.mdp import TabularMDP
from factirl_opt.objectworld import (
    ACTIONS,
    ObjectWorld,
    levine_reward,
    make_objectworld,
    multitask_primitives,
    multitask_rewards,
    objectworld_distances,
    objectworld_features,
    objectworld_transitions,
    plot_objectworld,
    state_action_rewards,
)

STAY, UP, DOWN, LEFT, RIGHT = range(5)


def _row(P, s, a):
    return P[s * 5 + a].toarray().ravel()


def _dense(size, pairs):
    out = np.zeros(size * size)
    for cell, p in pairs.items():
        out[cell] += p
    return out


# ---------------------------------------------------------------- dynamics


def test_action_labels():
    assert ACTIONS == ("stay", "up", "down", "left", "right")


@pytest.mark.parametrize(
    "s, a, expected",
    [
        # corner (0, 0): up and left hit walls and stay in place
        (0, STAY, {0: 0.7 + 0.075 + 0.075, 3: 0.075, 1: 0.075}),
        (0, DOWN, {3: 0.7, 0: 3 * 0.075, 1: 0.075}),
        (0, UP, {0: 0.7 + 0.075 + 0.075, 3: 0.075, 1: 0.075}),
        # top edge (0, 1): up hits the wall
        (1, STAY, {1: 0.7 + 0.075, 4: 0.075, 0: 0.075, 2: 0.075}),
        (1, RIGHT, {2: 0.7, 1: 0.075 + 0.075, 4: 0.075, 0: 0.075}),
        # centre (1, 1): five distinct cells
        (4, STAY, {4: 0.7, 1: 0.075, 7: 0.075, 3: 0.075, 5: 0.075}),
        (4, UP, {1: 0.7, 4: 0.075, 7: 0.075, 3: 0.075, 5: 0.075}),
        (4, LEFT, {3: 0.7, 4: 0.075, 1: 0.075, 7: 0.075, 5: 0.075}),
        # bottom-right corner (2, 2): down and right hit walls
        (8, RIGHT, {8: 0.7 + 0.075 + 0.075, 5: 0.075, 7: 0.075}),
    ],
)
def test_transitions_3x3_hand_checked_rows(s, a, expected):
    P = objectworld_transitions(3, 0.7)
    np.testing.assert_allclose(_row(P, s, a), _dense(3, expected), rtol=0, atol=1e-15)


def _reference_transitions(size, p):
    """Cell-by-cell dense construction straight from the rule, for comparison."""
    moves = [(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)]
    S = size * size
    P = np.zeros((S * 5, S))
    for s in range(S):
        r, c = divmod(s, size)
        for a in range(5):
            for m, (dr, dc) in enumerate(moves):
                rr, cc = r + dr, c + dc
                if not (0 <= rr < size and 0 <= cc < size):
                    rr, cc = r, c
                P[s * 5 + a, rr * size + cc] += p if m == a else (1 - p) / 4
    return P


@pytest.mark.parametrize("size, p", [(2, 0.7), (4, 0.35), (5, 1.0), (3, 0.0)])
def test_transitions_match_cell_by_cell_reference(size, p):
    P = objectworld_transitions(size, p)
    assert sp.isspmatrix_csr(P) and P.shape == (size * size * 5, size * size)
    np.testing.assert_allclose(P.toarray(), _reference_transitions(size, p), rtol=0, atol=1e-15)


@pytest.mark.parametrize("size", [2, 3, 7, 16])
def test_transitions_are_canonical_stochastic_and_have_the_expected_nnz(size):
    P = objectworld_transitions(size, 0.7)
    assert P.has_canonical_format  # duplicates summed, indices sorted
    assert np.all(P.data > 0)
    assert np.max(np.abs(np.asarray(P.sum(axis=1)).ravel() - 1.0)) <= 1e-12
    # a row reaches its own cell plus each in-grid neighbour: nnz = A * (S + 2 * #edges)
    n_edges = 2 * size * (size - 1)
    assert P.nnz == 5 * (size * size + 2 * n_edges)


def test_deterministic_dynamics_have_one_entry_per_row():
    P = objectworld_transitions(4, 1.0)
    assert P.nnz == 16 * 5 and np.all(P.data == 1.0)
    assert _row(P, 5, RIGHT)[6] == 1.0 and _row(P, 5, UP)[1] == 1.0 and _row(P, 3, RIGHT)[3] == 1.0


def test_large_world_builds_with_the_right_shapes():
    world = make_objectworld(100, rng=0)
    S = 100 * 100
    assert world.transitions.shape == (S * 5, S)
    assert world.transitions.nnz == 5 * (S + 4 * 100 * 99)
    assert objectworld_distances(world).shape == (S, 7)
    assert world.n_features == 99 * 7 and world.n_states == S and world.n_actions == 5


# ---------------------------------------------------------------- objects


def test_same_seed_same_world_and_different_seeds_differ():
    a, b = make_objectworld(12, rng=3), make_objectworld(12, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(a.objects, b.objects)
    assert (a.transitions != b.transitions).nnz == 0
    c = make_objectworld(12, rng=4)
    assert a.objects.shape != c.objects.shape or np.any(a.objects != c.objects)


def test_objects_layout_is_sorted_one_per_cell_and_read_only():
    world = make_objectworld(20, object_density=0.3, rng=1)
    objs = world.objects
    states = objs[:, 0] * 20 + objs[:, 1]
    assert np.all(np.diff(states) > 0)
    assert objs[:, 2].min() >= 0 and objs[:, 2].max() < 5 and objs[:, 3].min() >= 0 and objs[:, 3].max() < 2
    assert not objs.flags.writeable
    assert world.object_density == 0.3


@pytest.mark.parametrize("size, density, n_inner, n_outer", [(3, 0.01, 5, 2), (3, 1.0, 5, 2), (4, 0.05, 3, 7)])
def test_every_colour_is_present_even_in_tiny_or_full_worlds(size, density, n_inner, n_outer):
    for seed in range(5):
        world = make_objectworld(size, n_inner, n_outer, object_density=density, rng=seed)
        assert set(world.objects[:, 2]) == set(range(n_inner))
        assert set(world.objects[:, 3]) == set(range(n_outer))
        if density == 1.0:
            assert len(world.objects) == size * size


def test_hand_built_objects_are_sorted_and_density_is_none():
    world = make_objectworld(4, 2, 1, objects=[(3, 3, 1, 0), (0, 1, 0, 0)], rng=0)
    np.testing.assert_array_equal(world.objects, [[0, 1, 0, 0], [3, 3, 1, 0]])
    assert world.object_density is None


# ---------------------------------------------------------------- distances and features

# 5 x 5, inner colours {0, 1}, outer colour {0}:
#   inner 0 at (0, 0) and (2, 3); inner 1 at (4, 4); all outer 0.
HAND = [(0, 0, 0, 0), (4, 4, 1, 0), (2, 3, 0, 0)]


def _hand_world():
    return make_objectworld(5, n_inner=2, n_outer=1, objects=HAND)


def test_hand_built_distances():
    D = objectworld_distances(_hand_world())
    assert D.shape == (25, 3)
    np.testing.assert_array_equal(D[0], [0.0, math.sqrt(32), 0.0])  # cell (0, 0)
    np.testing.assert_array_equal(D[4], [math.sqrt(5), 4.0, math.sqrt(5)])  # (0, 4)
    np.testing.assert_array_equal(D[24], [math.sqrt(5), 0.0, 0.0])  # (4, 4)
    np.testing.assert_array_equal(D[20], [math.sqrt(13), 4.0, math.sqrt(13)])  # (4, 0): (2,3) vs (0,0)


def test_hand_built_discrete_features():
    F = objectworld_features(_hand_world())
    assert F.shape == (25, 4 * 3) and F.dtype == np.float64
    # columns: inner 0 (d = 1..4), inner 1 (d = 1..4), outer 0 (d = 1..4)
    np.testing.assert_array_equal(F[0], [1, 1, 1, 1, 0, 0, 0, 0, 1, 1, 1, 1])
    np.testing.assert_array_equal(F[4], [0, 0, 1, 1, 0, 0, 0, 0, 0, 0, 1, 1])  # sqrt5, 4 (not < 4), sqrt5
    np.testing.assert_array_equal(F[20], [0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 1])  # sqrt13 < 4 only
    np.testing.assert_array_equal(F[13], [1, 1, 1, 1, 0, 0, 1, 1, 1, 1, 1, 1])  # (2, 3): inner 1 at sqrt5
    np.testing.assert_array_equal(F[19], [0, 1, 1, 1, 0, 1, 1, 1, 0, 1, 1, 1])  # (3, 4): all at 1 or sqrt2


def test_discrete_features_are_thresholds_of_the_distances():
    world = make_objectworld(9, n_inner=3, n_outer=2, object_density=0.1, rng=5)
    D, F = objectworld_distances(world), objectworld_features(world, dtype=bool)
    assert F.dtype == bool and F.shape == (81, 8 * 5)
    for j in range(5):
        for d in range(1, 9):
            np.testing.assert_array_equal(F[:, j * 8 + d - 1], D[:, j] < d)


def test_distances_match_a_brute_force_loop():
    world = make_objectworld(13, n_inner=4, n_outer=3, object_density=0.08, rng=7)
    N, objs = 13, world.objects
    expected = np.full((N * N, 7), np.inf)
    for s in range(N * N):
        r, c = divmod(s, N)
        for orow, ocol, inner, outer in objs:
            d = math.sqrt((r - orow) ** 2 + (c - ocol) ** 2)
            expected[s, inner] = min(expected[s, inner], d)
            expected[s, 4 + outer] = min(expected[s, 4 + outer], d)
    np.testing.assert_array_equal(objectworld_distances(world), expected)


def test_missing_colour_has_inf_distance_zero_features_and_capped_continuous_value():
    world = make_objectworld(4, n_inner=2, n_outer=2, objects=[(1, 1, 0, 0)])
    D = objectworld_distances(world)
    assert np.all(np.isinf(D[:, 1])) and np.all(np.isinf(D[:, 3])) and np.all(np.isfinite(D[:, [0, 2]]))
    F = objectworld_features(world)
    assert not F[:, 3:6].any() and not F[:, 9:12].any() and F[:, 0:3].any()
    C = objectworld_features(world, continuous=True)
    assert C.shape == (16, 4) and np.all(np.isfinite(C))
    np.testing.assert_array_equal(C[:, [0, 2]], D[:, [0, 2]])
    np.testing.assert_array_equal(C[:, 1], np.full(16, math.sqrt(2) * 4))


def test_continuous_features_are_the_distances_when_every_colour_exists():
    world = make_objectworld(10, rng=2)
    np.testing.assert_array_equal(objectworld_features(world, continuous=True), objectworld_distances(world))


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


# ---------------------------------------------------------------- MDP and plotting


def test_transitions_reshape_to_a_valid_dense_tabular_mdp():
    world = make_objectworld(5, rng=0)
    dense = TabularMDP(world.transitions.toarray().reshape(25, 5, 25), world.gamma)
    np.testing.assert_array_equal(dense.transitions_flat, world.transitions.toarray())


def test_world_mdp():
    world = make_objectworld(6, rng=0, gamma=0.8)
    mdp = world.mdp()
    assert mdp.n_states == 36 and mdp.n_actions == 5 and mdp.gamma == 0.8
    assert mdp.is_sparse and (mdp.transition_matrix != world.transitions).nnz == 0


def test_plot_objectworld_draws_objects_and_values():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    world = make_objectworld(8, rng=0)
    ax = plot_objectworld(world, values=levine_reward(world))
    assert len(ax.images) == 1 and ax.images[0].get_array().shape == (8, 8)
    offsets = ax.collections[-1].get_offsets()
    np.testing.assert_array_equal(np.asarray(offsets), world.objects[:, [1, 0]])
    plt.close(ax.figure)
    fig, ax2 = plt.subplots()
    assert plot_objectworld(world, ax=ax2) is ax2 and len(ax2.images) == 0
    plt.close(fig)


# ---------------------------------------------------------------- validation


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(size=1), "size must be an integer >= 2"),
        (dict(size=2.5), "size must be an integer >= 2"),
        (dict(size=True), "size must be an integer >= 2"),
        (dict(determinism=-0.1), r"determinism must be a finite number in \[0, 1\]"),
        (dict(determinism=1.5), r"determinism must be a finite number in \[0, 1\]"),
        (dict(determinism=float("nan")), r"determinism must be a finite number in \[0, 1\]"),
        (dict(determinism="high"), "determinism must be a finite number"),
        (dict(object_density=0.0), r"object_density must be a finite number in \(0, 1\]"),
        (dict(object_density=1.2), r"object_density must be a finite number in \(0, 1\]"),
        (dict(n_inner=0), "n_inner must be an integer >= 1"),
        (dict(n_inner=2.0), "n_inner must be an integer"),
        (dict(n_outer=0), "n_outer must be an integer >= 1"),
        (dict(size=2, n_inner=5), "n_inner must be at most the number of cells 4"),
        (dict(gamma=1.0), r"gamma must be a finite number in \[0, 1\)"),
        (dict(rng="seed"), "rng must be a numpy Generator"),
        (dict(objects=[(0, 0, 0)]), r"objects must have shape \(m, 4\)"),
        (dict(objects=[(0.0, 0.0, 0.0, 0.0)]), "objects must hold integers"),
        (dict(objects=[(0, 32, 0, 0)]), r"objects\[0\] = \[0, 32, 0, 0\]: col 32 is out of range \[0, 32\)"),
        (dict(objects=[(1, 1, 0, 0), (0, 0, 5, 0)]), r"inner colour 5 is out of range \[0, 5\)"),
        (dict(objects=[(1, 1, 0, 2)]), r"outer colour 2 is out of range \[0, 2\)"),
        (dict(objects=[(1, 1, 0, 0), (1, 1, 1, 1)]), r"one object per cell; cell \(row, col\) = \(1, 1\)"),
    ],
)
def test_make_objectworld_validation(kwargs, match):
    with pytest.raises(ValidationError, match=match):
        make_objectworld(**kwargs)


def test_function_validation():
    world = make_objectworld(4, n_inner=2, n_outer=1, rng=0)
    for fn in (objectworld_distances, objectworld_features, levine_reward, multitask_primitives, plot_objectworld):
        with pytest.raises(ValidationError, match="world must be an ObjectWorld"):
            fn("not a world")
    with pytest.raises(ValidationError, match="continuous must be True or False"):
        objectworld_features(world, continuous="yes")
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
    with pytest.raises(ValidationError, match=r"values must have shape \(S,\) = \(16,\)"):
        plot_objectworld(world, values=np.zeros(5))
    with pytest.raises(ValidationError, match="values must be finite"):
        plot_objectworld(world, values=np.full(16, np.nan))
    with pytest.raises(ValidationError, match=r"determinism must be a finite number in \[0, 1\]"):
        objectworld_transitions(3, 2.0)
    assert isinstance(world, ObjectWorld) and "n_objects=" in repr(world)

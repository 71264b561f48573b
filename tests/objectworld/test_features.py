"""Objectworld distances to the colours and Levine's discrete and continuous features."""

import math

import numpy as np
import pytest

from factirl_opt.exceptions import ValidationError
from factirl_opt.datasets.objectworld import make_objectworld, objectworld_distances, objectworld_features

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



def test_feature_function_validation():
    world = make_objectworld(4, n_inner=2, n_outer=1, rng=0)
    for fn in (objectworld_distances, objectworld_features):
        with pytest.raises(ValidationError, match="world must be an ObjectWorld .*; got str"):
            fn("not a world")
    with pytest.raises(ValidationError, match="continuous must be True or False"):
        objectworld_features(world, continuous="yes")

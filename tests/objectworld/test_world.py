"""Objectworld grid: sparse dynamics, object placement, the MDP and the construction checks."""

import numpy as np
import pytest
import scipy.sparse as sp

from factirl_opt.exceptions import ValidationError
from factirl_opt.mdp.tabular import TabularMDP
from factirl_opt.datasets.objectworld import ACTIONS, ObjectWorld, make_objectworld, objectworld_distances, objectworld_transitions

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


# ---------------------------------------------------------------- MDP


def test_transitions_reshape_to_a_valid_dense_tabular_mdp():
    world = make_objectworld(5, rng=0)
    dense = TabularMDP(world.transitions.toarray().reshape(25, 5, 25), world.gamma)
    np.testing.assert_array_equal(dense.transitions_flat, world.transitions.toarray())


def test_world_mdp():
    world = make_objectworld(6, rng=0, gamma=0.8)
    mdp = world.mdp()
    assert mdp.n_states == 36 and mdp.n_actions == 5 and mdp.gamma == 0.8
    assert mdp.is_sparse and (mdp.transition_matrix != world.transitions).nnz == 0


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



def test_transitions_and_world_checks():
    with pytest.raises(ValidationError, match=r"determinism must be a finite number in \[0, 1\]"):
        objectworld_transitions(3, 2.0)
    world = make_objectworld(4, n_inner=2, n_outer=1, rng=0)
    assert isinstance(world, ObjectWorld) and "n_objects=" in repr(world)


def test_every_public_name_importable_from_the_package_and_the_library():
    import factirl_opt
    import factirl_opt.datasets.objectworld as objectworld
    from factirl_opt.datasets.objectworld import features, maps, plotting, rewards, world

    homes = {name: module for module in (world, features, rewards, plotting, maps) for name in module.__all__}
    for name in objectworld.__all__:
        assert getattr(objectworld, name) is getattr(homes[name], name)
        assert factirl_opt.objectworld is objectworld  # the namespace
    assert set(objectworld.__all__) <= set(homes)

"""Objectworld with a map per task (ELIRL's protocol) and maps whose dynamics differ."""

import numpy as np
import pytest
import scipy.sparse as sp

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError
from factirl_opt.objectives.environments import multi_environment_objective
from factirl_opt.datasets.objectworld import ELIRL_SCALE, objectworld_transitions
from factirl_opt.datasets.objectworld.maps import ObjectWorldMaps, block_cells, fresh_maps, objectworld_maps

SMALL = dict(size=8, n_inner=3, n_outer=2, object_density=0.1)


def test_maps_are_drawn_per_task_with_shared_dynamics_and_comparable_features():
    maps = objectworld_maps(4, rng=3, **SMALL)
    assert isinstance(maps, ObjectWorldMaps) and maps.n_tasks == 4 and "shared_dynamics=True" in repr(maps)
    assert all(m is maps.mdps[0] for m in maps.mdps)  # one object: planned as one batch
    assert maps.mdps[0].signature() == fo.TabularMDP(objectworld_transitions(8, 0.7), 0.9).signature()
    layouts = {w.objects.tobytes() for w in maps.worlds}
    assert len(layouts) == 4  # placements drawn per task
    for w, F, prim in zip(maps.worlds, maps.features, maps.primitives):
        assert F.shape == (64, 7 * 5)
        np.testing.assert_array_equal(F, fo.objectworld.objectworld_features(w))
        np.testing.assert_array_equal(prim, fo.objectworld.multitask_primitives(w))
    for i in range(4):
        np.testing.assert_allclose(maps.rewards[i], maps.primitives[i] @ maps.coefficients[i], rtol=0, atol=1e-12)
        nonzero = np.flatnonzero(maps.coefficients[i])
        assert 2 <= nonzero.size <= 3  # k in {2, 3, 4}, capped at c1 = 3
        assert np.all((maps.coefficients[i, nonzero] >= -2 * ELIRL_SCALE) & (maps.coefficients[i, nonzero] < ELIRL_SCALE))
    assert not maps.rewards.flags.writeable and not maps.coefficients.flags.writeable


def test_deterministic_in_rng_and_independent_of_given_coefficients():
    a, b, c = objectworld_maps(3, rng=7, **SMALL), objectworld_maps(3, rng=7, **SMALL), objectworld_maps(3, rng=8, **SMALL)
    for x, y in zip(a.worlds, b.worlds):
        np.testing.assert_array_equal(x.objects, y.objects)
    np.testing.assert_array_equal(a.rewards, b.rewards)
    assert any(x.objects.shape != y.objects.shape or np.any(x.objects != y.objects) for x, y in zip(a.worlds, c.worlds))
    given = objectworld_maps(3, coefficients=np.ones((3, 3)), rng=7, **SMALL)
    for x, y in zip(a.worlds, given.worlds):  # the maps come from their own stream
        np.testing.assert_array_equal(x.objects, y.objects)
    np.testing.assert_array_equal(given.coefficients, np.ones((3, 3)))


def test_fresh_maps_keep_the_tasks_and_redraw_the_objects():
    maps = objectworld_maps(3, continuous=True, bias=True, rng=1, **SMALL)
    new = fresh_maps(maps, rng=2)
    np.testing.assert_array_equal(new.coefficients, maps.coefficients)
    assert new.params == maps.params and new.features[0].shape == (64, 5 + 1)
    np.testing.assert_array_equal(new.features[1][:, -1], 1.0)
    assert any(x.objects.shape != y.objects.shape or np.any(x.objects != y.objects) for x, y in zip(maps.worlds, new.worlds))
    for i in range(3):
        np.testing.assert_allclose(new.rewards[i], new.primitives[i] @ maps.coefficients[i], rtol=0, atol=1e-12)


def test_blocked_cells_give_per_map_dynamics():
    maps = objectworld_maps(3, n_blocked=4, rng=5, **SMALL)
    assert len({id(m) for m in maps.mdps}) == 3 and "shared_dynamics=False" in repr(maps)
    base = objectworld_transitions(8, 0.7).toarray().reshape(64, 5, 64)
    for w, mdp, cells in zip(maps.worlds, maps.mdps, maps.blocked):
        assert cells.size == 4 and not np.isin(cells, w.objects[:, 0] * 8 + w.objects[:, 1]).any()
        P = mdp.transitions
        np.testing.assert_allclose(P.sum(axis=2), 1.0, rtol=0, atol=1e-12)
        others = np.setdiff1d(np.arange(64), cells)
        assert np.all(P[np.ix_(others, np.arange(5), cells)] == 0)  # never entered from elsewhere
        ref = base.copy()  # dense reference: mass bound for a blocked cell stays at its origin
        for s in range(64):
            for c in cells:
                if c != s:
                    ref[s, :, s] += ref[s, :, c]
                    ref[s, :, c] = 0.0
        np.testing.assert_allclose(P, ref, rtol=0, atol=1e-15)
        untouched = np.flatnonzero(base[:, :, cells].sum(axis=(1, 2)) == 0)
        np.testing.assert_array_equal(P[untouched], base[untouched])
    assert maps.mdps[0].signature() != maps.mdps[1].signature()


def test_block_cells_moves_the_mass_onto_the_state_itself():
    P = objectworld_transitions(3, 1.0)  # deterministic moves: right of state 0 is state 1
    B = block_cells(P, [1])
    assert B[0 * 5 + 4, 0] == 1.0 and B[0 * 5 + 4, 1] == 0.0
    assert sp.isspmatrix_csr(B) or B.format == "csr"
    with pytest.raises(ValidationError, match=r"states in \[0, 9\)"):
        block_cells(P, [9])
    with pytest.raises(ValidationError, match="shape"):
        block_cells(sp.csr_matrix(np.ones((5, 3))), [0])


def test_maps_feed_the_multi_environment_objective():
    for n_blocked, n_groups in ((0, 1), (2, 3)):
        maps = objectworld_maps(3, n_blocked=n_blocked, rng=11, size=5, n_inner=2, n_outer=1)
        R = fo.objectworld.state_action_rewards(maps.rewards)
        demos = [fo.sample_demonstrations(m, R[i], 2, 4, rng=i)[0] for i, m in enumerate(maps.mdps)]
        objective = multi_environment_objective(list(maps.mdps), demos, 2.0)
        assert len(objective.objectives) == n_groups
        loss, grad = objective.loss_and_grad(R)
        assert loss.shape == (3,) and grad.shape == (3, 25, 5)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(n_tasks=0), "n_tasks"),
        (dict(n_tasks=2, n_blocked=-1), "n_blocked"),
        (dict(n_tasks=2, n_blocked=1000), "n_blocked=1000 exceeds"),
        (dict(n_tasks=2, coefficients=np.ones((3, 3))), r"coefficients must have shape \(n_tasks, n_inner\) = \(2, 3\)"),
        (dict(n_tasks=2, bias=1), "bias"),
    ],
)
def test_errors(kwargs, match):
    with pytest.raises(ValidationError, match=match):
        objectworld_maps(**{**SMALL, **kwargs})
    with pytest.raises(ValidationError, match="ObjectWorldMaps"):
        fresh_maps(fo.objectworld.make_objectworld(size=4, rng=0))

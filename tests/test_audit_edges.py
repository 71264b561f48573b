"""Audit: zero tasks, zero states and models given where a matrix is expected.

Every public function either handles such input (an empty result of the right shape) or
raises a ValidationError naming it; none raises numpy's IndexError/ValueError.
"""

import warnings

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError


@pytest.fixture
def statistics(grid3):
    demos = fo.sample_demonstrations(grid3, np.ones((1, 9, 4)), 1, 3, rng=0)
    mu, pi = fo.empirical_statistics(grid3, demos)
    return mu[:0], pi[:0]


def test_feature_rewards_without_tasks_is_a_clear_error():
    with pytest.raises(ValidationError, match=r"weights must have shape \(n, p\) with n >= 1.*\(0, 3\)"):
        fo.feature_rewards(np.ones((9, 3)), np.zeros((0, 3)))


@pytest.mark.parametrize("features", [np.zeros((0, 3)), [np.ones((4, 3)), np.zeros((0, 3))]])
def test_feature_rewards_refuses_features_without_rows(features):
    with pytest.raises(ValidationError, match="features of task [01] have no rows"):
        fo.feature_rewards(features, np.ones((2, 3)))


@pytest.mark.parametrize("model", ["grid", "objectworld"])
def test_block_cells_given_a_model_names_it_and_the_fix(model):
    world = fo.GridWorld(size=3) if model == "grid" else fo.objectworld.make_objectworld(size=4, rng=0)
    with pytest.raises(ValidationError, match=rf"got {type(world).__name__}; pass the model's transition_matrix"):
        fo.objectworld.block_cells(world, [1])


def test_block_cells_still_takes_sparse_and_dense_matrices(grid3):
    P = grid3.transition_matrix
    sparse, dense = fo.objectworld.block_cells(P, [4]), fo.objectworld.block_cells(P.toarray(), [4])
    np.testing.assert_array_equal(sparse.toarray(), dense.toarray())
    assert set(sparse[:, 4].nonzero()[0] // grid3.n_actions) <= {4}  # no other state reaches the blocked cell
    np.testing.assert_allclose(np.asarray(sparse.sum(axis=1)).ravel(), 1.0)


def test_value_iteration_of_no_tasks(grid3):
    try:
        Q = fo.value_iteration(grid3, np.zeros((0, 9, 4)))
    except ValidationError:
        return
    assert Q.shape == (0, 9, 4)


def test_policy_matching_grad_reference_of_no_tasks(grid3, statistics):
    try:
        loss, g = fo.objectives.policy_matching_grad_reference(grid3, np.zeros((0, 9, 4)), *statistics, beta=1.0)
    except ValidationError:
        return
    assert np.shape(loss) == (0,) and np.shape(g) == (0, 36)


@pytest.mark.parametrize("with_mdps", [False, True])
def test_feature_rewards_that_overflow_name_the_task_and_the_scales(grid3, with_mdps):
    features = [np.ones((9, 2)), np.ones((9, 2)) * 1e200]
    mdps = [grid3, grid3] if with_mdps else None
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy overflow warning either: the error says it
        with pytest.raises(ValidationError, match=r"task 1 overflow float64 \(largest \|features\| entry 1e\+200, "
                                                  r"largest \|weights\[1\]\| entry 1e\+200\)"):
            fo.feature_rewards(features, np.ones((2, 2)) * 1e200, mdps)


def test_an_overflowing_init_is_named(grid3):
    demos = fo.sample_demonstrations(grid3, np.ones((2, 9, 4)), 2, 4, rng=0)
    with pytest.raises(ValidationError, match=r"init D0.*1e\+200"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            fo.FactIRL(n_primitives=2, max_iter=2, init=(np.ones((36, 2)) * 1e200, np.ones((2, 2)))).fit(grid3, demos)


def test_a_rounding_level_first_step_is_a_stall_for_mce(grid3):
    demos = fo.sample_demonstrations(grid3, np.random.default_rng(0).normal(size=(2, 9, 4)), 2, 4, rng=0)
    with pytest.warns(fo.exceptions.ConvergenceWarning, match="stalled"):
        model = fo.GradIRL(beta=1e-8, max_iter=50, objective="mce").fit(grid3, demos)
    assert model.stop_reason_.startswith("stalled")

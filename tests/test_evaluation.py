"""Eq. (13) score and the deviation from the optimal score."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError


def test_true_reward_has_the_optimal_score(rng, grid4):
    R = rng.standard_normal((4, 16, 4))
    opt = fo.optimal_score(grid4, R)
    np.testing.assert_allclose(fo.score(grid4, R, R), opt, rtol=0, atol=1e-12)
    assert np.all(fo.deviation(grid4, R, R) == 0.0)
    # the greedy policy is invariant to positive scaling and shifts
    assert np.all(fo.deviation(grid4, R, 3.0 * R + 1.0) < 1e-12)


def test_optimal_score_is_mean_of_v_star(rng, grid4):
    R = rng.standard_normal((16, 4))
    Q = fo.value_iteration(grid4, R, tol=1e-13)
    assert fo.optimal_score(grid4, R) == pytest.approx(Q.max(axis=1).mean(), abs=1e-9)
    assert isinstance(fo.optimal_score(grid4, R), float)


def test_score_evaluates_the_learnt_greedy_policy_on_the_true_reward(rng, grid4):
    R_true = rng.standard_normal((16, 4))
    R_learnt = rng.standard_normal((16, 4))
    _, pol = fo.optimal_q(grid4, R_learnt)
    expected = fo.policy_evaluation(grid4, R_true, pol).mean()
    assert fo.score(grid4, R_true, R_learnt) == pytest.approx(expected, abs=1e-12)
    assert fo.deviation(grid4, R_true, R_learnt) == pytest.approx(fo.optimal_score(grid4, R_true) - expected, abs=1e-12)


def test_deviation_is_nonnegative_and_positive_for_bad_rewards(rng, grid4):
    R = rng.standard_normal((20, 16, 4))
    dev = fo.deviation(grid4, R, rng.standard_normal((20, 16, 4)))
    assert dev.shape == (20,) and np.all(dev >= 0)
    assert np.all(fo.deviation(grid4, R, -R) > 0)


def test_score_shapes_must_match(grid4):
    with pytest.raises(ValidationError, match=r"same number of tasks; got 2 true \(shape \(2, 16, 4\)\) and 3 learnt \(shape \(3, 16, 4\)\)"):
        fo.score(grid4, np.zeros((2, 16, 4)), np.zeros((3, 16, 4)))
    with pytest.raises(ValidationError, match=r"learnt_rewards must have shape .*got \(16, 5\)"):
        fo.deviation(grid4, np.zeros((16, 4)), np.zeros((16, 5)))
    with pytest.raises(ValidationError, match=r"true_rewards must be finite"):
        fo.optimal_score(grid4, np.full((16, 4), np.nan))

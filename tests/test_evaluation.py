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


# -- the soft (maximum causal entropy) value difference -----------------------------------------
def _soft_reference(mdp, R_true, R, beta, sweeps=2000):
    """mean_s V^{pi}_{R_true}(s), pi soft-optimal for R by plain soft value iteration, then a dense solve."""
    P, g = mdp.transitions, mdp.gamma
    V = np.zeros(mdp.n_states)
    for _ in range(sweeps):  # gamma**2000 ~ 1e-92: converged to round-off
        Q = R + g * P @ V
        m = Q.max(axis=1)
        V = m + np.log(np.exp(beta * (Q - m[:, None])).sum(axis=1)) / beta
    pi = np.exp(beta * (R + g * P @ V - V[:, None]))
    P_pi = np.einsum("sa,sat->st", pi, P)
    return np.linalg.solve(np.eye(mdp.n_states) - g * P_pi, (pi * R_true).sum(axis=1)).mean()


@pytest.mark.parametrize("beta", [0.5, 1.0, 4.0])
def test_soft_deviation_matches_soft_value_iteration(rng, random_mdp, grid4, beta):
    for mdp in (random_mdp, grid4):
        R_true = rng.standard_normal((mdp.n_states, mdp.n_actions))
        R_learnt = rng.standard_normal((mdp.n_states, mdp.n_actions))
        expected = _soft_reference(mdp, R_true, R_true, beta) - _soft_reference(mdp, R_true, R_learnt, beta)
        got = fo.soft_deviation(mdp, R_true, R_learnt, beta=beta)
        assert isinstance(got, float)
        assert got == pytest.approx(expected, rel=1e-10, abs=1e-12)


def test_soft_deviation_is_zero_for_the_true_reward_and_positive_for_a_wrong_one(rng, grid4):
    R = rng.standard_normal((5, 16, 4))
    assert np.all(fo.soft_deviation(grid4, R, R) == 0.0)
    assert np.all(fo.soft_deviation(grid4, R, -R) > 0)
    # scale matters (unlike the greedy deviation): a sharper copy of the true reward does better
    assert np.all(fo.soft_deviation(grid4, R, 10.0 * R) < 0)


def test_soft_deviation_tends_to_the_greedy_deviation(rng, grid4, tie_free_rewards):
    R_true = tie_free_rewards(rng, grid4, (3, 16, 4))
    R_learnt = tie_free_rewards(rng, grid4, (3, 16, 4))
    greedy = fo.deviation(grid4, R_true, R_learnt)
    gaps = [np.max(np.abs(fo.soft_deviation(grid4, R_true, R_learnt, beta=b) - greedy)) for b in (1.0, 1e2, 1e5)]
    assert gaps[0] > 1e-2 and gaps[1] < gaps[0] and gaps[2] < 1e-6


def test_soft_deviation_start_distribution(rng, grid4):
    R_true, R_learnt = rng.standard_normal((2, 16, 4)), rng.standard_normal((2, 16, 4))
    uniform = fo.soft_deviation(grid4, R_true, R_learnt)
    np.testing.assert_allclose(fo.soft_deviation(grid4, R_true, R_learnt, start=np.full(16, 1 / 16)), uniform, rtol=0, atol=1e-12)
    per_state = np.stack([fo.soft_deviation(grid4, R_true, R_learnt, start=s) for s in range(16)], axis=1)
    np.testing.assert_allclose(per_state.mean(axis=1), uniform, rtol=0, atol=1e-12)
    rho = rng.dirichlet(np.ones(16), size=2)
    np.testing.assert_allclose(fo.soft_deviation(grid4, R_true, R_learnt, start=rho), (per_state * rho).sum(axis=1),
                               rtol=0, atol=1e-12)


def test_soft_deviation_errors(grid4):
    R = np.zeros((2, 16, 4))
    with pytest.raises(ValidationError, match=r"beta"):
        fo.soft_deviation(grid4, R, R, beta=0.0)
    with pytest.raises(ValidationError, match=r"start must be None, a state index in \[0, 16\)"):
        fo.soft_deviation(grid4, R, R, start=np.ones(5) / 5)
    with pytest.raises(ValidationError, match=r"same number of tasks"):
        fo.soft_deviation(grid4, R, R[:1])
    with pytest.raises(ValidationError, match=r"learnt_rewards must have shape"):
        fo.soft_deviation(grid4, R, np.zeros((16, 5)))

"""The importance-sampled posterior of transferred tasks (factirl_opt.learners.particle_posterior)."""

import numpy as np
import pytest

import factirl_opt as fo
from helpers import transfer_tasks_on_a_grid, two_primitive_feature_tasks
from factirl_opt.exceptions import NotFittedError, ValidationError
from factirl_opt.learners.particle_posterior import ParticlePosterior, importance_posterior, particle_weights
from factirl_opt.learners.transfer import coefficient_prior
from factirl_opt.objectives.mce import soft_values
from factirl_opt.planning import boltzmann_policy, get_planner, plan

pytestmark = pytest.mark.filterwarnings("ignore::factirl_opt.exceptions.MaxIterWarning")  # short fits


@pytest.fixture(scope="module")
def tasks():
    return transfer_tasks_on_a_grid(4, 12, 3, 8, rng=3)


def _model(tasks, objective="policy-matching", **params):
    mdp, train, _ = tasks
    return fo.FactIRL(n_primitives=2, objective=objective, max_iter=4, rng=0, **params).fit(mdp, train.demos)


def _log_likelihood(mdp, R, demos, beta, objective):
    """sum over the demonstrated pairs of log pi(a|s) under the objective's policy of R (S, A), directly."""
    pl = get_planner(mdp)
    if objective == "mce":
        log_pi = soft_values(pl, R[None], beta)[2][0]
    else:
        log_pi = np.log(boltzmann_policy(plan(pl, R[None]).Q, beta)[0])
    pairs = np.asarray(demos).reshape(-1, 2)
    return float(log_pi[pairs[:, 0], pairs[:, 1]].sum())


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_weights_are_the_demonstrations_likelihood_of_each_prior_draw(tasks, objective):
    mdp, _, test = tasks
    model = _model(tasks, objective)
    model.transfer(mdp, test.demos)
    posts = importance_posterior(model, 40, rng=1)
    assert len(posts) == 3 and all(isinstance(p, ParticlePosterior) for p in posts)
    m, P = coefficient_prior(model.coefficients_)
    H = posts[0].coefficients
    assert H.shape == (40, 2) and all(p.coefficients is H for p in posts)  # one set of draws for every task
    # the draws come from the Laplace posterior's prior: reproduce them from the same generator
    L = np.linalg.cholesky(np.linalg.inv(P))
    np.testing.assert_allclose(H, m + np.random.default_rng(1).standard_normal((40, 2)) @ L.T, rtol=1e-12)
    for i, p in enumerate(posts):
        ll = np.array([_log_likelihood(mdp, p.rewards(h)[0], test.demos[i], model.beta, objective) for h in H])
        w = np.exp(ll - ll.max())
        np.testing.assert_allclose(p.weights, w / w.sum(), rtol=1e-8, atol=1e-14)
        assert p.weights.sum() == pytest.approx(1.0)
        assert 1.0 <= p.effective_sample_size <= 40.0


def test_regrets_are_the_deviation_of_the_acted_reward_under_each_draw(tasks):
    mdp, _, test = tasks
    model = _model(tasks)
    model.transfer(mdp, test.demos)
    posts = importance_posterior(model, 25, rng=2)
    for i, p in enumerate(posts):
        np.testing.assert_array_equal(p.acted_rewards, model.transfer_rewards_[i])
        R = p.rewards(p.coefficients)
        expected = fo.deviation(mdp, R, np.repeat(p.acted_rewards[None], len(R), axis=0))
        np.testing.assert_allclose(p.regrets, expected, rtol=1e-9, atol=1e-9)
        assert p.expected_regret() == pytest.approx(float(p.weights @ expected), rel=1e-9, abs=1e-12)
        # the primitives' rewards: R(h) = Phi D h on the task's MDP
        np.testing.assert_allclose(p.unit_rewards.reshape(2, -1).T, model.dictionary_, rtol=1e-12)
    # other acted rewards: the posterior means the Laplace posterior acts on
    means = np.stack([q.mean_rewards() for q in model.transfer_posterior_])
    other = importance_posterior(model, 25, rng=2, acted_rewards=means)
    for p, q, M in zip(posts, other, means):
        np.testing.assert_array_equal(p.weights, q.weights)
        np.testing.assert_allclose(q.regrets, fo.deviation(mdp, p.rewards(p.coefficients), np.repeat(M[None], 25, axis=0)),
                                   rtol=1e-9, atol=1e-9)


def test_a_task_posterior_depends_on_the_seed_only_not_on_the_other_tasks(tasks):
    mdp, _, test = tasks
    model = _model(tasks)
    model.transfer(mdp, test.demos)
    all3 = importance_posterior(model, 30, rng=7)
    again = importance_posterior(model, 30, rng=7)
    for p, q in zip(all3, again):
        np.testing.assert_array_equal(p.weights, q.weights)
        np.testing.assert_array_equal(p.regrets, q.regrets)
    model.transfer(mdp, test.demos[2:])
    alone = importance_posterior(model, 30, rng=7)[0]
    np.testing.assert_allclose(alone.weights, all3[2].weights, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(alone.regrets, all3[2].regrets, rtol=1e-9, atol=1e-12)
    other_seed = importance_posterior(model, 30, rng=8)[0]
    assert not np.array_equal(other_seed.coefficients, alone.coefficients)


def test_summaries_and_resampling():
    rng = np.random.default_rng(0)
    H = rng.normal(size=(6, 2))
    unit = rng.normal(size=(2, 3, 2))
    w = np.array([0.1, 0.0, 0.4, 0.2, 0.3, 0.0])
    regrets = np.array([5.0, 0.5, 1.0, 3.0, 2.0, 9.0])
    p = ParticlePosterior(H, w, regrets, unit, np.zeros((3, 2)), mdp=None)
    assert p.n_particles == 6
    assert p.effective_sample_size == pytest.approx(1.0 / np.sum(w ** 2))
    assert p.expected_regret() == pytest.approx(0.1 * 5 + 0.4 * 1 + 0.2 * 3 + 0.3 * 2)
    # weighted quantiles over the sorted regrets 0.5(0) 1(.4) 2(.3) 3(.2) 5(.1) 9(0)
    assert p.regret_quantile(0.3) == 1.0
    assert p.regret_quantile(0.5) == 2.0
    assert p.regret_quantile(0.9) == 3.0
    assert p.regret_quantile(0.95) == 5.0
    assert p.regret_quantile(1.0) == 5.0  # a draw of weight 0 is never the bound
    np.testing.assert_allclose(p.mean_rewards(), np.tensordot(w @ H, unit, axes=1))
    R = p.sample_rewards(200, rng=3)
    r = p.sample_regrets(200, rng=3)
    idx = np.random.default_rng(3).choice(6, size=200, p=w)
    np.testing.assert_allclose(R, np.tensordot(H[idx], unit, axes=1))
    np.testing.assert_array_equal(r, regrets[idx])
    assert not np.isin(r, [0.5, 9.0]).any()  # zero-weight draws are never resampled
    with pytest.raises(ValidationError, match="q"):
        p.regret_quantile(1.5)
    with pytest.raises(ValidationError, match="n"):
        p.sample_regrets(0)


def test_particle_weights_normalise_and_reject_non_finite_log_likelihoods():
    W = particle_weights([[0.0, np.log(3.0)], [-1000.0, -1000.0]])
    np.testing.assert_allclose(W, [[0.25, 0.75], [0.5, 0.5]])
    with pytest.raises(ValidationError, match="log_likelihoods"):
        particle_weights([[0.0, -np.inf]])


def test_per_task_mdps_each_plan_the_draws_on_their_own_mdp():
    mdp, F, _, demos = two_primitive_feature_tasks(8, 3, 0)
    model = fo.FactIRL(n_primitives=2, features=F, max_iter=4, rng=0).fit(mdp, demos[:6])
    other = fo.GridWorld(size=3, p_success=0.5, gamma=0.9)
    model.transfer([mdp, other], [demos[6][:1], demos[7][:1]])
    posts = importance_posterior(model, 20, rng=4)
    np.testing.assert_array_equal(posts[0].coefficients, posts[1].coefficients)
    for p, env in zip(posts, (mdp, other)):
        assert p.mdp is env
        R = p.rewards(p.coefficients)  # state features: the primitives' rewards repeated over the actions
        np.testing.assert_allclose(p.unit_rewards, np.repeat((F @ model.dictionary_).T[:, :, None], 4, axis=2), rtol=1e-12)
        np.testing.assert_allclose(p.regrets, fo.deviation(env, R, np.repeat(p.acted_rewards[None], 20, axis=0)),
                                   rtol=1e-9, atol=1e-9)
    assert not np.allclose(posts[0].regrets, posts[1].regrets)


def test_errors(tasks):
    mdp, _, test = tasks
    with pytest.raises(NotFittedError, match="fit the model and call transfer"):
        importance_posterior(fo.FactIRL(n_primitives=2))
    model = _model(tasks)
    with pytest.raises(NotFittedError, match="call transfer first"):
        importance_posterior(model)
    model.transfer(mdp, test.demos)
    with pytest.raises(ValidationError, match="n_particles"):
        importance_posterior(model, 0)
    with pytest.raises(ValidationError, match="one reward per transferred task"):
        importance_posterior(model, 5, acted_rewards=model.transfer_rewards_[:2])
    with pytest.raises(ValidationError, match=r"acted_rewards\[1\] must have the shape \(S, A\) = \(16, 4\)"):
        importance_posterior(model, 5, acted_rewards=[model.transfer_rewards_[0], np.zeros((16, 3)), model.transfer_rewards_[2]])
    residual = _model(tasks, residual_penalty=1.0)
    residual.transfer(mdp, test.demos)
    with pytest.raises(ValidationError, match="residual"):
        importance_posterior(residual, 5)
    flat = _model(tasks, residual_penalty=0.0)
    flat.transfer(mdp, test.demos)
    with pytest.raises(ValidationError, match="prior"):
        importance_posterior(flat, 5)

"""The Laplace posterior of transferred tasks (factirl_opt.learners.posterior)."""

import numpy as np
import pytest

import factirl_opt as fo
from helpers import transfer_tasks_on_a_grid
from factirl_opt.exceptions import ValidationError
from factirl_opt.learners.posterior import MAP_TOL, LaplacePosterior, laplace_posteriors, lowrank_solve
from factirl_opt.learners.transfer_likelihood import TransferProblem, demonstration_curvature, likelihood_scaling
from factirl_opt.learners.transfer import coefficient_prior
from factirl_opt.objectives.environments import MultiEnvironmentObjective
from factirl_opt.objectives.mce import MCEObjective, soft_values
from factirl_opt.objectives.policy_matching import PolicyMatchingObjective
from factirl_opt.persistence.posterior import posterior_arrays, posteriors_from_arrays
from factirl_opt.planning import boltzmann_policy, get_planner, plan

BETA = 2.0


def _model_statistics(mdp, R, objective, rng):
    """State frequencies (positive) and the model's own policy at rewards R (S, A): zero residual there."""
    pl = get_planner(mdp)
    if objective == "mce":
        pi = np.exp(soft_values(pl, R[None], BETA)[2][0])
    else:
        pi = boltzmann_policy(plan(pl, R[None]).Q, BETA)[0]
    mu = rng.uniform(0.5, 1.5, mdp.n_states)
    return mu / mu.sum(), pi


def _problem(mdp, objective, rng, k=3, lam=np.inf, features=None, x0=None):
    S, A = mdp.n_states, mdp.n_actions
    p = S * A if features is None else features.shape[1]
    D = rng.normal(size=(p, k))
    residual = np.isfinite(lam)
    d = k + (p if residual else 0)
    x = rng.normal(scale=0.5, size=d) if x0 is None else x0
    W = D @ x[:k] + (x[k:] if residual else 0.0)
    R = (W if features is None else features @ W).reshape(S, A)
    mu, pi = _model_statistics(mdp, R, objective, rng)
    cls = MCEObjective if objective == "mce" else PolicyMatchingObjective
    obj = cls(mdp, mu[None], pi[None], BETA)
    return TransferProblem(obj, [mdp], [features], D, lam, np.array([10.0])), x


def _fd_hessian(problem, x, eps=1e-6):
    d = x.size
    H = np.empty((d, d))
    for j in range(d):
        e = np.zeros(d)
        e[j] = eps
        gp = demonstration_curvature(problem, (x + e)[None])[1][0]
        gm = demonstration_curvature(problem, (x - e)[None])[1][0]
        H[:, j] = (gp - gm) / (2 * eps)
    return 0.5 * (H + H.T)


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_curvature_matches_finite_differences_of_the_gradient(grid4, rng, objective):
    # where the model's policy reproduces the demonstrations' statistics, the Gauss-Newton matrix
    # (policy matching) and the Fisher information (MCE) are the Hessian of the loss
    problem, x = _problem(grid4, objective, rng)
    loss, grad, G = demonstration_curvature(problem, x[None])
    assert loss[0] == pytest.approx(0.0, abs=1e-20) or objective == "mce"
    np.testing.assert_allclose(grad[0], 0.0, atol=1e-9)
    H = _fd_hessian(problem, x)
    np.testing.assert_allclose(G[0], H, rtol=1e-5, atol=1e-7 * np.abs(H).max())


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_curvature_with_residual_matches_finite_differences(grid3, rng, objective):
    problem, x = _problem(grid3, objective, rng, k=2, lam=0.5)
    _, _, G = demonstration_curvature(problem, x[None])
    assert G.shape == (1, x.size, x.size) and x.size == 2 + grid3.n_states * grid3.n_actions
    H = _fd_hessian(problem, x)
    np.testing.assert_allclose(G[0], H, rtol=1e-5, atol=1e-7 * np.abs(H).max())


def test_gradient_matches_finite_differences_of_the_loss(grid4, rng):
    problem, _ = _problem(grid4, "policy-matching", rng)
    x = rng.normal(size=3)  # away from the zero-residual point
    _, g, _ = demonstration_curvature(problem, x[None])
    eps = 1e-6
    fd = [(demonstration_curvature(problem, (x + eps * e)[None])[0][0]
           - demonstration_curvature(problem, (x - eps * e)[None])[0][0]) / (2 * eps) for e in np.eye(3)]
    np.testing.assert_allclose(g[0], fd, rtol=1e-5, atol=1e-9)


def test_curvature_refuses_points_of_another_shape(grid3, rng):
    problem, _ = _problem(grid3, "policy-matching", rng)
    with pytest.raises(ValidationError, match=r"x must have shape \(r, d\) = \(1, 3\)"):
        demonstration_curvature(problem, np.zeros((1, 4)))


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
@pytest.mark.parametrize("lam", [np.inf, 2.0])
def test_posterior_is_the_map_and_its_precision(grid3, rng, objective, lam):
    problem, _ = _problem(grid3, objective, rng, k=2, lam=lam)
    H = rng.normal(size=(12, 2))
    m, P = coefficient_prior(H)
    post = laplace_posteriors(problem, (m, P))[0]
    k, d = 2, post.mean.size
    s = post.scaling
    _, g, G = demonstration_curvature(problem, post.mean[None])
    prior_grad = np.zeros(d)
    prior_grad[:k] = P @ (post.mean[:k] - m)
    prec = np.zeros((d, d))
    prec[:k, :k] = P
    if np.isfinite(lam):
        prior_grad[k:] = 2 * s * lam * post.mean[k:]
        prec[k:, k:] = 2 * s * lam * np.eye(d - k)
    grad = s * g[0] + prior_grad  # stationary: its Newton decrement is at the stopping rule's scale
    assert grad @ post.covariance @ grad <= MAP_TOL
    np.testing.assert_allclose(np.linalg.inv(post.covariance), s * G[0] + prec, rtol=1e-8, atol=1e-8)
    assert post.has_residual == np.isfinite(lam)


def test_coefficient_prior_fits_the_training_coefficients(rng):
    H = rng.normal(loc=[1.0, -2.0], scale=[1.0, 3.0], size=(500, 2))
    m, P = coefficient_prior(H)
    np.testing.assert_allclose(m, H.mean(axis=0))
    C = np.cov(H, rowvar=False)
    np.testing.assert_allclose(np.linalg.inv(P), C + 1e-3 * np.trace(C) / 2 * np.eye(2))
    with pytest.raises(ValidationError, match="at least 2"):
        coefficient_prior(H[:1])


def test_likelihood_scaling():
    np.testing.assert_array_equal(likelihood_scaling("mce", [10, 20]), [10.0, 20.0])
    mu = [np.array([0.5, 0.5, 0.0])]
    pi = [np.array([[0.5, 0.5], [1.0, 0.0], [0.5, 0.5]])]  # sigma^2 = 0.5 * 0.5 / 1
    np.testing.assert_allclose(likelihood_scaling("policy-matching", [10], mu, pi), [10 / (2 * 0.25)])


@pytest.fixture(scope="module")
def fitted():
    return transfer_tasks_on_a_grid(4, 12, 3, 8, rng=3)


@pytest.mark.filterwarnings("ignore::factirl_opt.exceptions.MaxIterWarning")  # a short fit: the posterior needs none converged
@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_transfer_posterior_shapes_and_sampling(fitted, objective):
    mdp, train, test = fitted
    model = fo.FactIRL(n_primitives=2, objective=objective, max_iter=5, rng=0)
    model.fit(mdp, train.demos)
    with pytest.raises(AttributeError, match="transferred no tasks"):
        model.transfer_posterior_
    model.transfer(mdp, test.demos)
    posts = model.transfer_posterior_
    assert posts is model.transfer_posterior_  # built once
    assert len(posts) == 3
    for post in posts:
        assert post.mean.shape == (2,) and post.covariance.shape == (2, 2)
        np.testing.assert_allclose(post.covariance, post.covariance.T)
        assert np.all(np.linalg.eigvalsh(post.covariance) > 0)
        R = post.sample_rewards(5, 7)
        assert R.shape == (5, mdp.n_states, mdp.n_actions) == (5, *model.transfer_rewards_.shape[1:])
        np.testing.assert_array_equal(R, post.sample_rewards(5, np.random.default_rng(7)))
        assert not np.array_equal(R, post.sample_rewards(5, 8))
        reg = post.sample_regrets(6, 11)
        np.testing.assert_array_equal(reg, post.sample_regrets(6, 11))
        expected = fo.deviation(mdp, post.sample_rewards(6, 11), np.repeat(post.mean_rewards()[None], 6, axis=0))
        np.testing.assert_allclose(reg, expected, atol=1e-10)
        assert np.all(reg >= 0)


@pytest.mark.filterwarnings("ignore::factirl_opt.exceptions.MaxIterWarning")
def test_transfer_posterior_travels_with_the_estimator_and_a_refit_drops_it(fitted):
    import pickle

    mdp, train, test = fitted
    model = fo.FactIRL(n_primitives=2, max_iter=3, rng=0).fit(mdp, train.demos)
    model.transfer(mdp, test.demos)
    copy = pickle.loads(pickle.dumps(model))  # the transfer's tasks pickle with it, the posterior not yet built
    for a, b in zip(copy.transfer_posterior_, model.transfer_posterior_):
        np.testing.assert_array_equal(a.mean, b.mean)
        np.testing.assert_array_equal(a.covariance, b.covariance)
    model.set_params(n_primitives=3).fit(mdp, train.demos)
    with pytest.raises(AttributeError, match="transferred no tasks"):  # not the new dictionary with the old transfer
        model.transfer_posterior_
    model.transfer(mdp, test.demos[:2])
    assert [p.mean.shape for p in model.transfer_posterior_] == [(3,), (3,)]


def test_transfer_posterior_in_per_task_environments(rng):
    mdps = [fo.GridWorld(size=3, p_success=0.8, gamma=0.9), fo.GridWorld(size=4, p_success=0.9, gamma=0.9)]
    p = 4
    feats = [rng.normal(size=(m.n_states, p)) for m in mdps]
    D = rng.normal(size=(p, 2))
    R = [np.repeat((F @ D @ rng.normal(size=2))[:, None], m.n_actions, axis=1) for F, m in zip(feats, mdps)]
    demos = [fo.sample_demonstrations(m, r[None], 3, 6, rng=i)[0] for i, (m, r) in enumerate(zip(mdps, R))]
    model = fo.FactIRL(n_primitives=2, features=feats, max_iter=5, transfer_max_iter=20, rng=0)
    model.fit(mdps, demos)
    model.transfer(mdps, demos, features=feats)
    posts = model.transfer_posterior_
    assert [q.sample_rewards(2, 0).shape for q in posts] == [(2, 9, 4), (2, 16, 4)]
    assert all(q.sample_regrets(3, 0).shape == (3,) for q in posts)


def test_multi_environment_curvature_matches_the_one_environment_one(grid3, rng):
    problem, x = _problem(grid3, "mce", rng, k=2)
    obj = problem.objective
    multi = MultiEnvironmentObjective([grid3], obj.mu, obj.pi_hat, BETA, objective="mce")
    problem2 = TransferProblem(multi, [grid3], [None], problem.dictionary, np.inf, np.array([10.0]))
    np.testing.assert_allclose(demonstration_curvature(problem2, x[None])[2], demonstration_curvature(problem, x[None])[2],
                               rtol=1e-10)


def test_posterior_arrays_round_trip(grid3, rng):
    problem, _ = _problem(grid3, "policy-matching", rng, k=2)
    post = laplace_posteriors(problem, coefficient_prior(rng.normal(size=(5, 2))))
    spec, arrays = posterior_arrays(post + post)
    back = posteriors_from_arrays(spec, arrays)
    assert len(back) == 2 and back[0].mdp is back[1].mdp
    np.testing.assert_array_equal(back[1].covariance, post[0].covariance)
    np.testing.assert_array_equal(back[0].sample_rewards(3, 1), post[0].sample_rewards(3, 1))
    with pytest.raises(ValidationError, match="incomplete or malformed"):
        posteriors_from_arrays(spec, {k: v for k, v in arrays.items() if k != "mean"})


def test_posterior_of_a_degenerate_covariance_samples(grid3, rng):
    D = rng.normal(size=(grid3.n_params, 2))
    post = LaplacePosterior(np.zeros(2), np.array([[1.0, 1.0], [1.0, 1.0]]), D, None, grid3)  # rank 1: no Cholesky
    x = post.sample(50, 0)
    np.testing.assert_allclose(x[:, 0], x[:, 1], atol=1e-7)
    assert x[:, 0].std() > 0.5
    with pytest.raises(ValidationError, match="n"):
        post.sample(0, 0)


def test_lowrank_solve_is_the_dense_solve(rng):
    a, k, p, m = 3, 2, 7, 4
    A = rng.normal(size=(a, k, k))
    Ch = A @ np.swapaxes(A, 1, 2) + np.eye(k)
    cd = rng.uniform(0.1, 2.0, size=(a, p))
    Z = rng.normal(size=(a, m, k + p))
    b = rng.normal(size=(a, k + p))
    dense = np.array([Z[i].T @ Z[i] + np.block([[Ch[i], np.zeros((k, p))], [np.zeros((p, k)), np.diag(cd[i])]])
                      for i in range(a)])
    np.testing.assert_allclose(lowrank_solve(Ch, cd, Z, b), np.linalg.solve(dense, b[..., None])[..., 0], rtol=1e-10)
    B = rng.normal(size=(a, k + p, 3))
    np.testing.assert_allclose(lowrank_solve(Ch, cd, Z, B), np.linalg.solve(dense, B), rtol=1e-10)


def _demonstrated_problem(mdp, rng, n=3, k=2, lam=0.7, features=None):
    """A residual model's transfer problem of n tasks with a few demonstrated states each (the live rows)."""
    S, A = mdp.n_states, mdp.n_actions
    p = S * A if features is None else features.shape[1]
    D = rng.normal(size=(p, k))
    mu = rng.uniform(size=(n, S)) * (rng.uniform(size=(n, S)) < 0.4)
    mu[:, 0] += 0.1
    mu /= mu.sum(axis=1, keepdims=True)
    pi = rng.dirichlet(np.ones(A), size=(n, S))
    obj = PolicyMatchingObjective(mdp, mu, pi, BETA)
    return TransferProblem(obj, [mdp] * n, [features] * n, D, lam, rng.uniform(5, 20, n)), D


@pytest.mark.parametrize("tabular", [True, False])
def test_lowrank_posterior_matches_the_dense_one(grid3, rng, tabular):
    S, A = grid3.n_states, grid3.n_actions
    features = None if tabular else rng.normal(size=(S * A, 5))
    problem, D = _demonstrated_problem(grid3, rng, features=features)
    prior = coefficient_prior(rng.normal(size=(8, 2)))
    start = rng.normal(scale=0.3, size=(problem.n_tasks, 2 + problem.dictionary.shape[0]))
    for st in (None, start):
        low = laplace_posteriors(problem, prior, st, lowrank=True)
        dense = laplace_posteriors(problem, prior, st, lowrank=False)
        for a, b in zip(low, dense):
            np.testing.assert_allclose(a.mean, b.mean, rtol=1e-8, atol=1e-10)
            np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-8, atol=1e-10)
            assert a.scaling == pytest.approx(b.scaling, rel=1e-12)
    default = laplace_posteriors(problem, prior)  # low rank where it applies
    np.testing.assert_allclose(default[0].covariance, laplace_posteriors(problem, prior, lowrank=True)[0].covariance,
                               rtol=1e-10)


def test_lowrank_needs_a_residual_least_squares_problem(grid3, rng):
    problem, _ = _problem(grid3, "mce", rng, k=2, lam=1.0)
    prior = coefficient_prior(rng.normal(size=(5, 2)))
    with pytest.raises(ValidationError, match="lowrank"):
        laplace_posteriors(problem, prior, lowrank=True)
    np.testing.assert_allclose(laplace_posteriors(problem, prior)[0].covariance,  # dense where it does not apply
                               laplace_posteriors(problem, prior, lowrank=False)[0].covariance, rtol=1e-8)


def test_marginal_posterior_of_one_dictionary_is_the_conditional_one(grid3, rng):
    import dataclasses

    problem, _ = _problem(grid3, "policy-matching", rng, k=2)
    post = laplace_posteriors(problem, coefficient_prior(rng.normal(size=(5, 2))))[0]
    assert post.n_dictionaries == 1 and post.members == ()
    np.testing.assert_array_equal(post.sample_rewards(7, 3), post.sample_rewards(7, 3, marginal=False))
    np.testing.assert_array_equal(post.sample_regrets(7, 3), post.sample_regrets(7, 3, marginal=False))
    # members equal to the posterior itself: the mixture is the one Gaussian, drawn from one generator in turn
    twin = dataclasses.replace(post, members=(dataclasses.replace(post), dataclasses.replace(post)))
    assert twin.member_counts(7) == [3, 2, 2]
    np.testing.assert_allclose(twin.sample_rewards(7, 3), post.sample_rewards(7, 3), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(twin.sample_regrets(7, 3), post.sample_regrets(7, 3), rtol=1e-12, atol=1e-12)
    with pytest.raises(ValidationError, match="marginal"):
        twin.sample_rewards(3, 0, marginal=1)


def test_misfit_noise_levels_are_the_regression_estimate():
    from factirl_opt.learners.noise_levels import misfit_noise_levels

    got = misfit_noise_levels([0.1, 0.2, 0.3], [10, 20, 5], [4, 6, 1], 4, 2)
    np.testing.assert_allclose(got, [10 * 0.1 / (4 * 3 - 2), 20 * 0.2 / (6 * 3 - 2), 5 * 0.3 / 1.0])  # dof floored at 1


def test_noise_reference_scales_the_likelihood_by_the_misfit(grid3, rng):
    from factirl_opt.learners.noise_levels import NOISE_RATIO_MIN, misfit_noise_levels

    problem, _ = _problem(grid3, "policy-matching", rng, k=2)
    problem.objective.pi_hat[:] = np.eye(grid3.n_actions)[rng.integers(grid3.n_actions, size=(1, grid3.n_states))]
    prior = coefficient_prior(rng.normal(size=(5, 2)))
    base = laplace_posteriors(problem, prior)[0]
    loss = demonstration_curvature(problem, base.mean[None])[0]
    level = misfit_noise_levels(loss, problem.n_pairs, [grid3.n_states], grid3.n_actions, 2)[0]
    for reference in (level / 4.0, level * 4.0, level * 1e6):
        post = laplace_posteriors(problem, prior, noise_reference=reference)[0]
        np.testing.assert_array_equal(post.mean, base.mean)
        ratio = max(level / reference, NOISE_RATIO_MIN)
        assert post.scaling == pytest.approx(base.scaling / ratio)
        G = demonstration_curvature(problem, base.mean[None])[2][0]
        np.testing.assert_allclose(np.linalg.inv(post.covariance), post.scaling * G + prior[1], rtol=1e-6, atol=1e-8)
    mce, _ = _problem(grid3, "mce", rng, k=2)
    with pytest.raises(ValidationError, match="least-squares"):
        laplace_posteriors(mce, prior, noise_reference=1.0)
    for bad in (0.0, -1.0, np.nan):
        with pytest.raises(ValidationError, match="noise_reference"):
            laplace_posteriors(problem, prior, noise_reference=bad)

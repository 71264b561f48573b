"""State-only rewards ``reward="state"``: r(s) repeated over actions, at the cost of tabular rewards."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.learners.fitting import make_objective
from factirl_opt.objectives.problems import dictionary_problem, weights_problem
from factirl_opt.tasks.features import StateBroadcast
from helpers import central_difference

S, A, K = 9, 4, 2
KRON = np.kron(np.eye(S), np.ones((A, 1)))


@pytest.fixture
def data(rng, grid3):
    R = np.repeat(rng.standard_normal((4, S, 1)), A, axis=2) + 0.3 * rng.standard_normal((4, S, A))
    return grid3, fo.sample_demonstrations(grid3, R, 4, 6, rng)


def test_state_broadcast_applies_the_kronecker_matrix(rng):
    phi = StateBroadcast(S, A)
    M, Y, G, X = (rng.standard_normal(shape) for shape in ((S, 3), (5, S * A), (S * A, 3), (5, S)))
    assert phi.shape == KRON.shape and phi.T.shape == KRON.T.shape
    np.testing.assert_array_equal(phi.toarray(), KRON)
    np.testing.assert_allclose(phi @ M, KRON @ M, rtol=1e-15)
    np.testing.assert_allclose(Y @ phi, Y @ KRON, rtol=1e-14)
    np.testing.assert_allclose(phi.T @ G, KRON.T @ G, rtol=1e-14)
    np.testing.assert_allclose(X @ phi.T, X @ KRON.T, rtol=1e-15)


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_the_state_weights_gradient_matches_finite_differences_and_the_kron_features(data, objective):
    mdp, demos = data
    obj = make_objective(mdp, demos, 2.0, objective)
    problem = weights_problem(obj, StateBroadcast(S, A))
    assert problem.n_params == S
    W = np.random.default_rng(1).standard_normal((4, S)) * 0.5
    rows = np.arange(4)
    loss, grad = problem.loss_and_grad(W, rows)
    loss_k, grad_k = weights_problem(obj, KRON).loss_and_grad(W + 0.0, rows)
    np.testing.assert_allclose(loss, loss_k, rtol=1e-12)
    np.testing.assert_allclose(grad, grad_k, rtol=1e-10, atol=1e-13)
    for i in range(2):
        def f(w, i=i):
            Wi = W.copy()
            Wi[i] = w
            return problem.loss_and_grad(Wi, rows)[0][i]

        np.testing.assert_allclose(grad[i], central_difference(f, W[i]), rtol=1e-5, atol=1e-8)


def test_the_state_dictionary_problem_matches_the_kron_features(data):
    mdp, demos = data
    obj = make_objective(mdp, demos, 2.0)
    H = np.random.default_rng(2).standard_normal((4, K))
    x = np.random.default_rng(3).standard_normal((1, S * K)) * 0.5
    for unit_norm in (False, True):
        a = dictionary_problem(obj, H, StateBroadcast(S, A), unit_norm=unit_norm).loss_and_grad(x, np.arange(1))
        b = dictionary_problem(obj, H, KRON, unit_norm=unit_norm).loss_and_grad(x + 0.0, np.arange(1))
        np.testing.assert_allclose(a[0], b[0], rtol=1e-12)
        np.testing.assert_allclose(a[1], b[1], rtol=1e-10, atol=1e-13)


@pytest.mark.parametrize("solver,objective", [("armijo", "policy-matching"), ("lbfgs", "mce"),
                                              ("gn-qp-clarabel", "policy-matching")])
def test_gradirl_state_rewards_equal_the_kron_feature_fit(data, solver, objective):
    mdp, demos = data
    kw = dict(max_iter=15, solver=solver, objective=objective)
    state = fo.GradIRL(reward="state", **kw).fit(mdp, demos)
    kron = fo.GradIRL(features=KRON, **kw).fit(mdp, demos)
    assert state.weights_.shape == (4, S) and state.rewards_.shape == (4, S, A)
    np.testing.assert_array_equal(state.rewards_, np.repeat(state.weights_[:, :, None], A, axis=2))
    np.testing.assert_allclose(state.rewards_, kron.rewards_, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(state.loss_, kron.loss_, rtol=1e-8, atol=1e-12)
    assert "reward='state'" in repr(fo.GradIRL(reward="state"))


@pytest.mark.parametrize("init", ["pca", "random"])
def test_factirl_state_rewards_equal_the_kron_feature_fit(data, init):
    mdp, demos = data
    kw = dict(n_primitives=K, init=init, max_iter=6, flat_max_iter=10, rng=0)
    state = fo.FactIRL(reward="state", **kw).fit(mdp, demos)
    kron = fo.FactIRL(features=KRON, scheme=state.scheme_, **kw).fit(mdp, demos)  # "auto": joint on features
    assert state.dictionary_.shape == (S, K) and state.rewards_.shape == (4, S, A)
    assert state.features_sha256_ is None
    np.testing.assert_allclose(state.rewards_, kron.rewards_, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(state.rewards_, np.repeat((state.coefficients_ @ state.dictionary_.T)[:, :, None], A, 2),
                               rtol=1e-14)
    h_state = state.transfer(mdp, demos[:2], max_iter=8)
    h_kron = kron.transfer(mdp, demos[:2], max_iter=8)
    np.testing.assert_allclose(state.transfer_rewards_, kron.transfer_rewards_, rtol=1e-8, atol=1e-10)
    assert h_state.shape == h_kron.shape == (2, K)


def test_the_plain_functions_take_state_rewards(data):
    mdp, demos = data
    D0 = np.linalg.qr(np.random.default_rng(0).standard_normal((S, K)))[0]
    fit = fo.fit_factorial(mdp, demos, D0, np.full((4, K), 0.1), max_iter=3, reward="state")
    same = fo.fit_factorial(mdp, demos, D0, np.full((4, K), 0.1), max_iter=3, base_features=KRON)
    np.testing.assert_allclose(fit.dictionary, same.dictionary, rtol=1e-8, atol=1e-10)
    tr = fo.transfer_coefficients(mdp, demos[:2], fit.dictionary, max_iter=4, reward="state")
    assert tr.rewards.shape == (2, S, A) and np.all(tr.rewards == tr.rewards[:, :, :1])
    with pytest.raises(fo.exceptions.ValidationError, match="p = 9"):
        fo.fit_factorial(mdp, demos, np.ones((36, K)), np.ones((4, K)), reward="state")

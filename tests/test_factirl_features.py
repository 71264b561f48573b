"""FactIRL on base features (R_i = Phi D h_i), the plain functions under the estimator, and its
reliability guarantees (monotone fits, best point kept, MDP signatures, clear errors, warnings)."""

import warnings
from types import SimpleNamespace

import numpy as np
from helpers import central_difference
import pytest

import factirl_opt as fo
import solvers
from factirl_opt.exceptions import ConvergenceWarning, ValidationError
from factirl_opt.objectives import PolicyMatchingObjective
from factirl_opt.objectives.problems import dictionary_problem, weights_problem

K = 2


@pytest.fixture
def tasks(grid3):
    return fo.synthetic_tasks(grid3, 5, 4, 6, n_primitives=K, rng=3)


def _objective(mdp, demos, beta=5.0):
    mu, pi = fo.empirical_statistics(mdp, demos)
    return PolicyMatchingObjective(mdp, mu, pi, beta)


@pytest.mark.parametrize("unit_norm", [False, True])
def test_dictionary_gradient_on_features_matches_finite_differences(grid3, tasks, rng, unit_norm):
    Phi = rng.random((36, 4))
    obj = _objective(grid3, tasks.demos)
    H = rng.standard_normal((5, K))
    D = 0.5 * rng.standard_normal((4, K))
    prob = dictionary_problem(obj, H, Phi, unit_norm=unit_norm)
    loss, g = prob.loss_and_grad(D.reshape(1, -1), np.arange(1))
    fd = central_difference(lambda x: prob.loss_and_grad(x.reshape(1, -1), np.arange(1))[0][0], D.ravel())
    np.testing.assert_allclose(g[0], fd, rtol=1e-5, atol=1e-8)


def test_coefficient_gradient_on_features_matches_finite_differences(grid3, tasks, rng):
    Phi = rng.random((36, 4))
    D = rng.standard_normal((4, K))
    obj = _objective(grid3, tasks.demos)
    prob = weights_problem(obj, Phi @ D)
    H = rng.standard_normal((5, K))
    rows = np.arange(5)
    _, g = prob.loss_and_grad(H, rows)
    fd = central_difference(lambda x: prob.loss_and_grad(x, rows)[0].sum(), H)
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-8)


def test_identity_features_reproduce_the_tabular_route(grid3, tasks, rng):
    obj = _objective(grid3, tasks.demos)
    H, D = rng.standard_normal((5, K)), rng.standard_normal((36, K))
    tab = dictionary_problem(obj, H).loss_and_grad(D.reshape(1, -1), np.arange(1))
    feat = dictionary_problem(obj, H, np.eye(36)).loss_and_grad(D.reshape(1, -1), np.arange(1))
    np.testing.assert_allclose(feat[0], tab[0], rtol=1e-12)
    np.testing.assert_allclose(feat[1], tab[1], rtol=1e-10, atol=1e-14)
    a = fo.FactIRL(n_primitives=K, init="random", rng=0, max_iter=4).fit(grid3, tasks.demos)
    b = fo.FactIRL(n_primitives=K, init="random", rng=0, max_iter=4, features=np.eye(36), scheme=a.scheme_).fit(grid3, tasks.demos)
    np.testing.assert_allclose(b.rewards_, a.rewards_, rtol=1e-9, atol=1e-12)


def test_pca_init_on_features_is_the_pca_of_the_rewards_they_give(grid3, tasks, rng):
    Phi = rng.random((36, 6))
    Phi[:, 5] = Phi[:, 4] + Phi[:, 3]  # a dependent feature: the weights are not unique
    flat = fo.GradIRL(features=Phi, max_iter=5).fit(grid3, tasks.demos)
    model = fo.FactIRL(n_primitives=K, features=Phi, max_iter=0, pca_shrink=False).fit(grid3, tasks.demos,
                                                                                     flat_rewards=flat.rewards_)
    D, H = fo.pca_dictionary(flat.rewards_.reshape(5, -1), K)
    np.testing.assert_allclose(model.rewards_.reshape(5, -1), H @ D.T, atol=1e-9)
    assert model.dictionary_.shape == (6, K)
    tab = fo.FactIRL(n_primitives=K, max_iter=3).fit(grid3, tasks.demos, flat_rewards=flat.rewards_)
    eye = fo.FactIRL(n_primitives=K, features=np.eye(36), max_iter=3, scheme=tab.scheme_).fit(grid3, tasks.demos,
                                                                                        flat_rewards=flat.rewards_)
    # the same fit to rounding (the identity's products round otherwise than no product: 1.6e-12 measured)
    np.testing.assert_allclose(eye.rewards_, tab.rewards_, rtol=1e-9, atol=1e-11)


@pytest.mark.parametrize("init", ["pca", "random"])
def test_fit_and_transfer_on_state_features(grid3, tasks, rng, init):
    Phi = rng.random((9, 3))  # state features, repeated over actions
    model = fo.FactIRL(n_primitives=K, features=Phi, init=init, max_iter=5, flat_max_iter=5, rng=0).fit(grid3, tasks.demos)
    assert model.dictionary_.shape == (3, K) and model.coefficients_.shape == (5, K)
    F = np.repeat(Phi, 4, axis=0) @ model.dictionary_
    np.testing.assert_allclose(model.rewards_.reshape(5, -1), model.coefficients_ @ F.T, atol=1e-12)
    h = model.transfer(grid3, tasks.demos[:2], max_iter=5)
    assert h.shape == (2, K) and np.all(np.isfinite(model.transfer_rewards_))
    assert np.all(np.diff(model.loss_history_) <= 1e-10)


def test_features_validation(grid3, tasks):
    with pytest.raises(ValidationError, match=r"n_primitives=2 exceeds the reward dimension p=1"):
        fo.FactIRL(n_primitives=K, features=np.ones((9, 1))).fit(grid3, tasks.demos)
    with pytest.raises(ValidationError, match=r"features must be finite"):
        fo.FactIRL(n_primitives=K, features=np.full((9, 3), np.inf)).fit(grid3, tasks.demos)


def test_model_refuses_another_mdp(grid3, tasks):
    model = fo.FactIRL(n_primitives=K, max_iter=2, flat_max_iter=2).fit(grid3, tasks.demos)
    P = np.random.default_rng(0).dirichlet(np.ones(18), size=(18, 2))  # S*A = 36, like the grid's
    with pytest.raises(ValidationError, match=r"fitted on another MDP \(n_states: fitted 9, given 18"):
        model.transfer(fo.TabularMDP(P, 0.9), [np.array([[[0, 1]]])])
    with pytest.raises(ValidationError, match=r"the transitions differ"):
        model.transfer(fo.GridWorld(3, p_success=0.8), tasks.demos[:1])
    assert model.mdp_signature_ == grid3.signature()


def test_hand_set_dictionary_must_have_n_primitives_columns(grid3, tasks):
    model = fo.FactIRL(n_primitives=3)
    model.dictionary_ = np.ones((36, 2))
    with pytest.raises(ValidationError, match=r"dictionary_ has 2 primitives but n_primitives=3"):
        model.transfer(grid3, tasks.demos)


def test_nan_initialisation_is_refused(grid3, tasks):
    H0 = np.zeros((5, K))
    H0[0, 1] = np.nan
    with pytest.raises(ValidationError, match=r"init H0 must be finite; found nan at index \(0, 1\)"):
        fo.FactIRL(n_primitives=K, init=(np.ones((36, K)), H0)).fit(grid3, tasks.demos)


def test_pca_of_non_finite_parameters_is_refused_not_hung():
    X = np.ones((4, 10))
    X[0, 0] = np.inf
    with pytest.raises(ValidationError, match=r"parameters must be finite; found inf at index \(0, 0\)"):
        fo.pca_dictionary(X, 2)


@pytest.mark.parametrize("solver", ["gn-qp-clarabel-sparse", "gn-qp-osqp-sparse"])
def test_sparse_h_step_fit_is_monotone_and_ends_on_its_best_point(grid4, solver):
    t = fo.synthetic_tasks(grid4, 6, 5, 8, n_primitives=3, rng=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # QP solver fallbacks are reported by QPFallbackWarning
        model = fo.FactIRL(n_primitives=3, max_iter=15, solver=solver).fit(grid4, t.demos)
    h = np.asarray(model.loss_history_)
    assert np.all(np.diff(h) <= 1e-9 * np.abs(h[:-1])), h
    total = model.loss_.sum() + 0.01 * np.abs(model.coefficients_).sum()
    assert total <= h.min() + 1e-9
    np.testing.assert_allclose(np.linalg.norm(model.dictionary_, axis=0), 1.0)


class _Wandering(solvers.StepSolver):
    """A deliberately bad H-step: every step moves H by +1 (the loss usually rises)."""

    name = "wandering"

    def init_state(self, problem, x, previous=None):
        return SimpleNamespace(loss=problem.loss_and_grad(x, np.arange(problem.n_rows))[0])

    def update(self, problem, x, state):
        x = x + 1.0
        return x, SimpleNamespace(loss=problem.loss_and_grad(x, np.arange(problem.n_rows))[0]), True


def test_fit_ends_on_the_best_point_seen_even_when_steps_rise(grid3, tasks):
    seen = []
    model = fo.FactIRL(n_primitives=K, max_iter=6, flat_max_iter=5, solver=_Wandering(),
                       callback=lambda i, loss: seen.append((i, loss)))
    model.fit(grid3, tasks.demos)
    h = np.asarray(model.loss_history_)
    assert np.any(np.diff(h) > 0), "the test needs a rising step"
    mu, pi = fo.empirical_statistics(grid3, tasks.demos)
    final = fo.policy_matching_loss(grid3, model.rewards_, mu, pi, 5.0)[0]
    np.testing.assert_allclose(final.sum(), h.min(), rtol=1e-12)
    np.testing.assert_allclose(model.loss_, final, rtol=1e-12)
    assert [i for i, _ in seen] == list(range(1, model.n_iter_ + 1))
    np.testing.assert_allclose([loss for _, loss in seen], h[1:])


def test_stalled_fit_warns(grid3, tasks):
    D0 = 1e6 * fo.random_dictionary(36, K, rng=5)
    with pytest.warns(ConvergenceWarning, match="stalled at its first step"):
        model = fo.FactIRL(n_primitives=K, init=(D0, np.ones((5, K))), max_iter=3).fit(grid3, tasks.demos)
    assert model.status_ == "stalled"
    with pytest.warns(ConvergenceWarning, match="GradIRL.fit stalled"):
        fo.GradIRL(features=1e6 * fo.random_dictionary(36, 3, rng=5), max_iter=5).fit(grid3, tasks.demos)


def test_functions_match_the_estimator(grid3, tasks):
    model = fo.FactIRL(n_primitives=K, init="random", rng=0, max_iter=4).fit(grid3, tasks.demos)
    rng = np.random.default_rng(0)  # the estimator's random initialisation, drawn again
    D0 = rng.standard_normal((36, K))
    D0 /= np.linalg.norm(D0, axis=0)
    H0 = 0.3 * rng.standard_normal((5, K))
    # the functions keep the paper's defaults: given the estimator's, the same fit and transfer
    fit = fo.fit_factorial(grid3, tasks.demos, D0, H0, max_iter=4, d_solver=model.default_d_solver,
                           inner_steps=model.inner_steps, scheme=model.scheme_)
    np.testing.assert_array_equal(fit.dictionary, model.dictionary_)
    np.testing.assert_array_equal(fit.coefficients, model.coefficients_)
    tr = fo.transfer_coefficients(grid3, tasks.demos[:2], model.dictionary_, max_iter=5, stol=model.transfer_stol)
    np.testing.assert_array_equal(tr.coefficients, model.transfer(grid3, tasks.demos[:2], max_iter=5))


def test_callback_and_verbose_validation(grid3, tasks, capsys):
    with pytest.raises(ValidationError, match="callback must be callable"):
        fo.GradIRL(callback=3).fit(grid3, tasks.demos)
    with pytest.raises(ValidationError, match="verbose must be True or False"):
        fo.GradIRL(verbose="yes").fit(grid3, tasks.demos)
    calls = []
    g = fo.GradIRL(max_iter=3, verbose=True, callback=lambda i, loss: calls.append(i)).fit(grid3, tasks.demos)
    assert calls == list(range(1, g.n_iter_ + 1))
    assert "GradIRL" in capsys.readouterr().err

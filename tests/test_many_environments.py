"""Learners over tasks in several environments: a sequence of MDPs and one feature matrix per task."""

import io

import numpy as np
import pytest
from helpers import central_difference, rel_err

import factirl_opt as fo
from factirl_opt.learners.dictionary import feature_weights, metric_pca_dictionary, pca_dictionary
from factirl_opt.exceptions import NotFittedError, ValidationError
from factirl_opt.learners.fitting import task_objective
from factirl_opt.tasks.task_set import task_set
from factirl_opt.objectives.problems import dictionary_problem, weights_problem
from factirl_opt.tasks.features import TaskFeatures


@pytest.fixture(scope="module")
def worlds():
    """Three tasks on grids of 9, 16 and 9 states (the first and last the same object); state,
    state-action and state features (p = 3); two demonstrations of 5 steps each."""
    g3 = fo.GridWorld(size=3, p_success=0.7, gamma=0.9)
    g4 = fo.GridWorld(size=4, p_success=0.8, gamma=0.9)
    mdps = [g3, g4, g3]
    rng = np.random.default_rng(0)
    Phis = [rng.random((9, 3)), rng.random((16 * 4, 3)), rng.random((9, 3))]
    R = [rng.normal(size=(m.n_states, 4)) for m in mdps]
    demos = [fo.sample_demonstrations(m, r[None], 2, 5, rng=i)[0] for i, (m, r) in enumerate(zip(mdps, R))]
    return mdps, Phis, demos


@pytest.fixture(scope="module")
def shared():
    """Four tasks on one 3x3 grid with one feature matrix (p = 4)."""
    mdp = fo.GridWorld(size=3, p_success=0.7, gamma=0.9)
    rng = np.random.default_rng(1)
    Phi = rng.random((9, 4))
    demos = fo.sample_demonstrations(mdp, rng.normal(size=(4, 9, 4)), 3, 6, rng=1)
    return mdp, Phi, demos


# ----------------------------------------------------------------------------- flat learners


@pytest.mark.parametrize("solver, objective", [("armijo", "policy-matching"), ("armijo", "mce"),
                                               ("lbfgs", "policy-matching"), ("lbfgs", "mce")])
def test_flat_fit_equals_the_tasks_fitted_environment_by_environment(worlds, solver, objective):
    """Row-separable solvers: the multi-environment fit is each task's own fit (to 1e-10; tol=0: the
    stopping rule looks at the total loss)."""
    mdps, Phis, demos = worlds
    model = fo.GradIRL(features=Phis, max_iter=6, tol=0, solver=solver, objective=objective).fit(mdps, demos)
    assert model.weights_.shape == (3, 3) and [r.shape for r in model.rewards_] == [(9, 4), (16, 4), (9, 4)]
    assert isinstance(model.mdp_signature_, list) and model.features_sha256_ is None
    for i in range(3):
        alone = fo.GradIRL(features=Phis[i], max_iter=6, tol=0, solver=solver, objective=objective).fit(mdps[i], [demos[i]])
        np.testing.assert_allclose(model.weights_[i], alone.weights_[0], rtol=0, atol=1e-10)
        np.testing.assert_allclose(model.rewards_[i], alone.rewards_[0], rtol=0, atol=1e-10)
        assert abs(model.loss_[i] - alone.loss_[0]) < 1e-10


@pytest.mark.parametrize("solver", ["gn-qp-osqp", "gn-cg"])
def test_gauss_newton_flat_fits_through_padded_residuals(worlds, shared, solver):
    """GN on mixed sizes descends; one matrix per task
    equal to the shared one gives the shared fit."""
    mdps, Phis, demos = worlds
    model = fo.GradIRL(features=Phis, max_iter=4, solver=solver).fit(mdps, demos)
    assert model.loss_history_[-1] < model.loss_history_[0]
    mdp, Phi, sdemos = shared
    a = fo.GradIRL(features=Phi, max_iter=4, solver=solver).fit(mdp, sdemos)
    b = fo.GradIRL(features=[Phi] * 4, max_iter=4, solver=solver).fit(mdp, sdemos)
    np.testing.assert_allclose(b.weights_, a.weights_, rtol=0, atol=1e-10)


def test_one_shared_mdp_object_is_the_one_mdp_fit(shared):
    mdp, Phi, demos = shared
    a = fo.GradIRL(features=Phi, max_iter=5).fit(mdp, demos)
    b = fo.GradIRL(features=Phi, max_iter=5).fit([mdp] * 4, demos)
    assert a.weights_.tobytes() == b.weights_.tobytes() and a.mdp_signature_ == b.mdp_signature_
    kw = dict(n_primitives=2, max_iter=3, flat_max_iter=5, rng=0)
    c = fo.FactIRL(features=Phi, **kw).fit(mdp, demos)
    d = fo.FactIRL(features=Phi, **kw).fit([mdp] * 4, demos)
    assert c.rewards_.tobytes() == d.rewards_.tobytes() and c.loss_history_ == d.loss_history_


@pytest.mark.parametrize("init, h_solver, d_solver, objective", [
    ("random", "armijo", "armijo", "policy-matching"),
    ("pca", "armijo", "armijo", "policy-matching"),
    ("random", "lbfgs", "armijo", "mce"),
    ("pca", "gn-qp-osqp", "gn-cg", "policy-matching"),
])
def test_per_task_copies_of_one_matrix_give_the_shared_fit(shared, init, h_solver, d_solver, objective):
    """The per-task path (TaskFeatures, metric PCA) on n copies of Phi is the shared fit (to rounding)."""
    mdp, Phi, demos = shared
    kw = dict(n_primitives=2, max_iter=4, init=init, rng=0, solver=h_solver, d_solver=d_solver, objective=objective,
              flat_max_iter=5)
    a = fo.FactIRL(features=Phi, **kw).fit(mdp, demos)
    b = fo.FactIRL(features=[Phi] * 4, **kw).fit(mdp, demos)
    np.testing.assert_allclose(b.rewards_, a.rewards_, rtol=0, atol=1e-8)
    np.testing.assert_allclose(b.loss_history_, a.loss_history_, rtol=1e-10)


def test_metric_pca_is_the_reward_pca_for_one_matrix(rng):
    Phi, W = rng.random((36, 5)), rng.normal(size=(6, 5))
    D, H = metric_pca_dictionary(W, TaskFeatures([Phi] * 6, [9] * 6, 4), 3)
    Dr, Hr = pca_dictionary(W @ Phi.T, 3)
    np.testing.assert_allclose(np.abs(H), np.abs(Hr), rtol=0, atol=1e-10)
    np.testing.assert_allclose(Phi @ D @ H.T, Phi @ feature_weights(Phi, Dr) @ Hr.T, rtol=0, atol=1e-10)
    with pytest.raises(ValidationError, match="exceeds the rank 2"):
        metric_pca_dictionary(W[:, :2] @ np.eye(2, 5), TaskFeatures([Phi[:, :2] @ np.eye(2, 5)] * 6, [9] * 6, 4), 3)


@pytest.mark.parametrize("h_solver, d_solver, objective", [("armijo", "armijo", "policy-matching"),
                                                           ("lbfgs", "lbfgs", "mce"),
                                                           ("gn-qp-osqp", "gn-cg", "policy-matching")])
def test_factorial_fit_on_mixed_sizes(worlds, h_solver, d_solver, objective):
    mdps, Phis, demos = worlds
    model = fo.FactIRL(n_primitives=2, features=Phis, max_iter=3, flat_max_iter=5, solver=h_solver,
                       d_solver=d_solver, objective=objective).fit(mdps, demos)
    assert model.dictionary_.shape == (3, 2) and model.coefficients_.shape == (3, 2)
    assert [r.shape for r in model.rewards_] == [(9, 4), (16, 4), (9, 4)]
    assert model.loss_history_[-1] <= model.loss_history_[0]
    W = model.coefficients_ @ model.dictionary_.T
    for i, F in enumerate(TaskFeatures(Phis, [9, 16, 9], 4).dense()):
        np.testing.assert_allclose(model.rewards_[i].reshape(-1), F @ W[i], rtol=0, atol=1e-12)
    flat = fo.GradIRL(features=Phis, max_iter=5).fit(mdps, demos)
    again = fo.FactIRL(n_primitives=2, features=Phis, max_iter=0).fit(mdps, demos, flat_rewards=flat.rewards_)
    assert again.dictionary_.shape == (3, 2)


@pytest.mark.parametrize("h_solver", ["armijo-nonneg", "gn-qp-clarabel-nonneg", "gn-qp-osqp-sparse"])
def test_constrained_and_sparse_h_steps_on_mixed_sizes(worlds, h_solver):
    mdps, Phis, demos = worlds
    model = fo.FactIRL(n_primitives=2, features=Phis, max_iter=2, flat_max_iter=3, solver=h_solver).fit(mdps, demos)
    assert model.loss_history_[-1] < model.loss_history_[0]
    h = model.transfer(mdps, demos, features=Phis, max_iter=2)
    if h_solver.endswith("nonneg"):
        assert model.coefficients_.min() >= 0 and h.min() >= 0
    else:  # the L1 penalty keeps unit-norm primitives
        np.testing.assert_allclose(np.linalg.norm(model.dictionary_, axis=0), 1.0, rtol=1e-12)


# ----------------------------------------------------------------------------- gradients


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_problem_gradients_match_central_differences_on_mixed_sizes(worlds, rng, objective):
    mdps, Phis, demos = worlds
    envs = task_set(mdps, demos, Phis)
    obj = task_objective(envs, 2.0, objective)
    basis = envs.basis
    wp = weights_problem(obj, basis)
    W, rows = 0.5 * rng.normal(size=(2, 3)), np.array([2, 1])
    _, g = wp.loss_and_grad(W, rows)
    num = central_difference(lambda x: wp.loss_and_grad(x, rows)[0].sum(), W)
    assert rel_err(g, num) < 1e-6
    H, D = rng.normal(size=(3, 2)), 0.5 * rng.normal(size=(3, 2))
    for unit_norm in (False, True):
        dp = dictionary_problem(obj, H, basis, unit_norm)
        _, gD = dp.loss_and_grad(D.reshape(1, -1), None)
        num = central_difference(lambda x: dp.loss_and_grad(x, None)[0][0], D.reshape(1, -1))
        assert rel_err(gD, num) < 1e-6


def test_least_squares_pieces_match_central_differences(worlds, rng):
    """Residual Jacobian, jvp and vjp of the padded residuals, for weights and for the dictionary."""
    mdps, Phis, demos = worlds
    envs = task_set(mdps, demos, Phis)
    obj = task_objective(envs, 2.0)
    wp = weights_problem(obj, envs.basis)
    W, rows, V = 0.5 * rng.normal(size=(3, 3)), np.arange(3), rng.normal(size=(3, 3))
    _, res, jac = wp.residual_jacobian(W, rows)
    assert res.shape == (3, 64) and jac.shape == (3, 64, 3) and np.all(res[[0, 2], 36:] == 0)
    eps = 1e-6
    num = (wp.residual_jacobian(W + eps * V, rows)[1] - wp.residual_jacobian(W - eps * V, rows)[1]) / (2 * eps)
    assert rel_err(np.einsum("rmp,rp->rm", jac, V), num) < 1e-6
    lin = wp.linearize(W, rows)
    np.testing.assert_allclose(lin.jvp(V), np.einsum("rmp,rp->rm", jac, V), rtol=0, atol=1e-10)
    U = rng.normal(size=res.shape)
    np.testing.assert_allclose(np.sum(lin.vjp(U) * V), np.sum(U * lin.jvp(V)), rtol=1e-10)
    H, D, dD = rng.normal(size=(3, 2)), 0.5 * rng.normal(size=(3, 2)), rng.normal(size=(1, 6))
    lin = dictionary_problem(obj, H, envs.basis).linearize(D.reshape(1, -1), None)
    dp = dictionary_problem(obj, H, envs.basis)
    r = [dp.linearize(D.reshape(1, -1) + s * eps * dD, None).residual for s in (1, -1)]
    assert rel_err(lin.jvp(dD), (r[0] - r[1]) / (2 * eps)) < 1e-6
    U = rng.normal(size=lin.residual.shape)
    np.testing.assert_allclose(np.sum(lin.vjp(U) * dD), np.sum(U * lin.jvp(dD)), rtol=1e-10)


# ----------------------------------------------------------------------------- transfer


def test_transfer_to_new_environments(worlds):
    mdps, Phis, demos = worlds
    model = fo.FactIRL(n_primitives=2, features=Phis, max_iter=2, flat_max_iter=5).fit(mdps, demos)
    h = model.transfer(mdps, demos, features=Phis, max_iter=5)
    assert h.shape == (3, 2) and [r.shape for r in model.transfer_rewards_] == [(9, 4), (16, 4), (9, 4)]
    for i in range(3):  # the H-step with Armijo is row-separable
        hi = model.transfer(mdps[i], demos[i:i + 1], features=Phis[i], max_iter=5)
        np.testing.assert_allclose(hi[0], h[i], rtol=0, atol=1e-10)
    with pytest.raises(ValidationError, match="needs their features"):
        model.transfer(mdps, demos)
    with pytest.raises(ValidationError, match="p = 2 columns, but the dictionary is over p = 3"):
        model.transfer(mdps, demos, features=[F[:, :2] for F in Phis])
    chain = fo.TabularMDP(np.full((4, 2, 4), 0.25), 0.9)
    with pytest.raises(ValidationError, match="2 actions, but the model was fitted with 4"):
        model.transfer(chain, [np.zeros((1, 2, 2), dtype=int)], features=np.ones((4, 3)))
    with pytest.raises(NotFittedError):
        fo.FactIRL(n_primitives=2, features=Phis).transfer(mdps, demos, features=Phis)


def test_one_mdp_model_transfers_to_a_new_map_with_features(worlds):
    mdps, Phis, demos = worlds
    model = fo.FactIRL(n_primitives=2, features=Phis[0], max_iter=2, flat_max_iter=5).fit(mdps[0], [demos[0], demos[2]])
    assert model.transfer(mdps[1], demos[1:2], features=Phis[1], max_iter=3).shape == (1, 2)
    with pytest.raises(ValidationError, match="fitted on another MDP"):
        model.transfer(mdps[1], demos[1:2])
    tabular = fo.FactIRL(n_primitives=2, max_iter=1, flat_max_iter=2).fit(mdps[0], [demos[0], demos[2]])
    with pytest.raises(ValidationError, match="fitted without features"):
        tabular.transfer(mdps[1], demos[1:2], features=Phis[1])


def test_models_fitted_in_several_environments_save_and_load(worlds):
    mdps, Phis, demos = worlds
    for model in (fo.FactIRL(n_primitives=2, features=Phis, max_iter=2, flat_max_iter=3).fit(mdps, demos),
                  fo.GradIRL(features=Phis, max_iter=3).fit(mdps, demos)):
        model.transfer(mdps, demos, features=Phis, max_iter=2) if isinstance(model, fo.FactIRL) else None
        buf = io.BytesIO()
        fo.save_model(model, buf)
        buf.seek(0)
        loaded = fo.load_model(buf)
        assert loaded.mdp_signature_ == model.mdp_signature_ and len(loaded.features) == 3
        for a, b in zip(loaded.rewards_, model.rewards_):
            assert a.tobytes() == b.tobytes()
        if isinstance(model, fo.FactIRL):
            assert [r.shape for r in loaded.transfer_rewards_] == [(9, 4), (16, 4), (9, 4)]
            np.testing.assert_array_equal(loaded.transfer(mdps, demos, features=Phis, max_iter=2),
                                          model.transfer(mdps, demos, features=Phis, max_iter=2))


# ----------------------------------------------------------------------------- errors


def test_errors_name_the_bad_input(worlds):
    mdps, Phis, demos = worlds
    with pytest.raises(ValidationError, match="same number of columns p: task 1 has 2"):
        fo.GradIRL(features=[Phis[0], Phis[1][:, :2], Phis[2]]).fit(mdps, demos)
    with pytest.raises(ValidationError, match="got 2 MDPs for 3 tasks"):
        fo.GradIRL(features=Phis).fit(mdps[:2], demos)
    with pytest.raises(ValidationError, match="got 2 feature matrices for 3 tasks"):
        fo.FactIRL(n_primitives=2, features=Phis[:2]).fit(mdps, demos)
    with pytest.raises(ValidationError, match="features of task 1 must have S = 16 or S\\*A = 64 rows"):
        fo.GradIRL(features=[Phis[0], Phis[0], Phis[2]]).fit(mdps, demos)
    bad = [demos[0], demos[1], np.array([[[0, 0], [12, 1]]])]  # state 12 exists only in task 1's grid
    with pytest.raises(ValidationError, match="task 2"):
        fo.GradIRL(features=Phis).fit(mdps, bad)
    with pytest.raises(ValidationError, match="need features"):
        fo.GradIRL().fit(mdps, demos)
    with pytest.raises(ValidationError, match="reward='state'"):
        fo.FactIRL(n_primitives=2, reward="state").fit(mdps, demos)
    with pytest.raises(ValidationError, match="task 0 has S = 9 states, task 1 has 16"):
        fo.GradIRL(features=Phis[0]).fit(mdps, demos)
    chain = fo.TabularMDP(np.full((9, 2, 9), 1 / 9), 0.9)
    with pytest.raises(ValidationError, match="same number of actions: task 1 has 2"):
        fo.GradIRL(features=Phis).fit([mdps[0], chain, mdps[2]], demos)
    with pytest.raises(ValidationError, match="n_primitives=4 exceeds the reward dimension p=3"):
        fo.FactIRL(n_primitives=4, features=Phis).fit(mdps, demos)

"""The residual model R_i = Phi_i (D h_i + delta_i) with the penalty lambda ||delta_i||^2."""

import warnings

import numpy as np
import pytest
from helpers import central_difference, rel_err

import factirl_opt as fo
from factirl_opt.exceptions import ConvergenceWarning, ValidationError
from factirl_opt.learners.fitting import make_objective, task_objective
from factirl_opt.learners.start import FLAT_SOLVER
from factirl_opt.learners.transfer import TRANSFER_STOL
from factirl_opt.tasks.task_set import task_set
from factirl_opt.tasks.task_set import reward_features
from factirl_opt.objectives.problems import weights_problem
from factirl_opt.objectives.residuals import check_residual_penalty, residual_dictionary_problem, residual_weights_problem

LAM = 0.3


@pytest.fixture(scope="module")
def shared():
    """Five tasks on one 3x3 grid, state features p = 4, k = 2."""
    mdp = fo.GridWorld(size=3, p_success=0.7, gamma=0.9)
    rng = np.random.default_rng(5)
    demos = fo.sample_demonstrations(mdp, 2.0 * rng.normal(size=(5, 9, 4)), 3, 6, rng=rng)
    return mdp, rng.random((9, 4)), demos


@pytest.fixture(scope="module")
def worlds():
    g3, g4 = fo.GridWorld(size=3, p_success=0.7, gamma=0.9), fo.GridWorld(size=4, p_success=0.8, gamma=0.9)
    mdps = [g3, g4, g3]
    rng = np.random.default_rng(0)
    Phis = [rng.random((9, 3)), rng.random((16 * 4, 3)), rng.random((9, 3))]
    demos = [fo.sample_demonstrations(m, rng.normal(size=(1, m.n_states, 4)), 2, 5, rng=i)[0] for i, m in enumerate(mdps)]
    return mdps, Phis, demos


def _setups(kind, shared, worlds, objective):
    """(objective, features, p) of the shared or the per-task environments."""
    if kind == "shared":
        mdp, F, demos = shared
        return make_objective(mdp, demos, 2.0, objective), reward_features(mdp, F), 4
    mdps, Phis, demos = worlds
    envs = task_set(mdps, demos, Phis)
    obj = task_objective(envs, 2.0, objective)
    return obj, envs.basis, 3


@pytest.mark.parametrize("kind", ["shared", "environments"])
@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_gradients_match_central_differences(shared, worlds, rng, kind, objective):
    obj, F, p = _setups(kind, shared, worlds, objective)
    n, k = obj.n_tasks, 2
    D, H, Delta = 0.5 * rng.normal(size=(p, k)), rng.normal(size=(n, k)), 0.3 * rng.normal(size=(n, p))
    wp = residual_weights_problem(obj, F, D, LAM)
    X, rows = np.concatenate([H, Delta], axis=1), np.arange(n)[::-1]
    loss, g = wp.loss_and_grad(X, rows)
    assert g.shape == (n, k + p)
    num = central_difference(lambda x: wp.loss_and_grad(x, rows)[0].sum(), X)
    assert rel_err(g, num) < 1e-6
    # the loss is the model's: the flat loss of w_i = D h_i + delta_i plus the penalty
    wl, _ = weights_problem(obj, F).loss_and_grad(H @ D.T + Delta, rows)
    np.testing.assert_allclose(loss, wl + LAM * np.sum(Delta ** 2, axis=1), rtol=1e-12)
    for unit_norm in (False, True):
        dp = residual_dictionary_problem(obj, F, H, Delta, unit_norm)
        _, gD = dp.loss_and_grad(D.reshape(1, -1), None)
        num = central_difference(lambda x: dp.loss_and_grad(x, None)[0][0], D.reshape(1, -1))
        assert rel_err(gD, num) < 1e-6


@pytest.mark.parametrize("kind", ["shared", "environments"])
def test_least_squares_pieces_match_central_differences(shared, worlds, rng, kind):
    obj, F, p = _setups(kind, shared, worlds, "policy-matching")
    n, k = obj.n_tasks, 2
    D = 0.5 * rng.normal(size=(p, k))
    wp = residual_weights_problem(obj, F, D, LAM)
    X, V, rows = rng.normal(size=(n, k + p)), rng.normal(size=(n, k + p)), np.arange(n)
    loss, r, J = wp.residual_jacobian(X, rows)
    np.testing.assert_allclose(loss, np.sum(r * r, axis=1), rtol=1e-12)
    eps = 1e-6
    num = (wp.residual_jacobian(X + eps * V, rows)[1] - wp.residual_jacobian(X - eps * V, rows)[1]) / (2 * eps)
    assert rel_err(np.einsum("rmq,rq->rm", J, V), num) < 1e-6
    lin = wp.linearize(X, rows)
    np.testing.assert_allclose(lin.jvp(V), np.einsum("rmq,rq->rm", J, V), rtol=0, atol=1e-10)
    U = rng.normal(size=r.shape)
    np.testing.assert_allclose(lin.vjp(U), np.einsum("rmq,rm->rq", J, U), rtol=0, atol=1e-10)
    H, Delta = rng.normal(size=(n, k)), rng.normal(size=(n, p))
    dp = residual_dictionary_problem(obj, F, H, Delta)
    dlin = dp.linearize(D.reshape(1, -1), None)
    Vd = rng.normal(size=(1, p * k))
    num = (dp.linearize(D.reshape(1, -1) + eps * Vd, None).residual - dp.linearize(D.reshape(1, -1) - eps * Vd, None).residual) / (2 * eps)
    assert rel_err(dlin.jvp(Vd), num) < 1e-6
    Ud = rng.normal(size=dlin.residual.shape)
    assert abs(np.sum(dlin.jvp(Vd) * Ud) - np.sum(Vd * dlin.vjp(Ud))) < 1e-9 * np.abs(np.sum(Vd * dlin.vjp(Ud)))


def _fit(**kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        return fo.FactIRL(n_primitives=2, rng=0, **kw)


def test_infinite_penalty_is_the_factorial_learner(shared):
    mdp, F, demos = shared
    a = _fit(features=F, max_iter=8).fit(mdp, demos)
    b = _fit(features=F, max_iter=8, residual_penalty=np.inf).fit(mdp, demos)
    np.testing.assert_allclose(b.rewards_, a.rewards_, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b.dictionary_, a.dictionary_, rtol=0, atol=1e-12)
    assert b.residual_penalty_ == np.inf and not np.any(b.residuals_) and b.residuals_.shape == (5, 4)
    ha, hb = a.transfer(mdp, demos[:2]), b.transfer(mdp, demos[:2])
    np.testing.assert_allclose(hb, ha, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b.transfer_rewards_, a.transfer_rewards_, rtol=0, atol=1e-12)


def test_fit_and_transfer_record_the_residuals(shared):
    mdp, F, demos = shared
    model = _fit(features=F, max_iter=6, residual_penalty=LAM).fit(mdp, demos)
    W = model.coefficients_ @ model.dictionary_.T + model.residuals_
    Phi = reward_features(mdp, F)
    np.testing.assert_allclose(model.rewards_.reshape(5, -1), W @ Phi.T, rtol=1e-12, atol=1e-12)
    assert model.residual_penalty_ == LAM and np.any(model.residuals_ != 0)
    mu, pi = fo.empirical_statistics(mdp, demos)
    loss = fo.policy_matching_loss(mdp, model.rewards_, mu, pi, 5.0)[0]
    np.testing.assert_allclose(model.loss_, loss, rtol=1e-10)  # the loss without the penalty
    assert model.loss_history_[-1] >= loss.sum() + LAM * np.sum(model.residuals_ ** 2) - 1e-10  # the best seen, with it
    h = model.transfer(mdp, demos[:3])
    assert h.shape == (3, 2) and model.transfer_residuals_.shape == (3, 4)
    Wn = h @ model.dictionary_.T + model.transfer_residuals_
    np.testing.assert_allclose(model.transfer_rewards_.reshape(3, -1), Wn @ Phi.T, rtol=1e-12, atol=1e-12)


def test_transfer_of_each_task_alone_with_residuals(shared):
    mdp, F, demos = shared
    model = _fit(features=F, max_iter=4, residual_penalty=LAM, solver="lbfgs").fit(mdp, demos)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        together = model.transfer(mdp, demos, max_iter=50)
        for i in (0, 4):
            np.testing.assert_allclose(together[i], model.transfer(mdp, demos[i:i + 1], max_iter=50)[0], rtol=0, atol=1e-10)


def test_small_penalty_approaches_the_flat_learner(shared):
    """lambda -> 0: the transfer's fit of the demonstrations approaches the flat learner's (the
    residuals take what the dictionary cannot); a large lambda stays at the dictionary's."""
    mdp, F, demos = shared
    flat = fo.GradIRL(features=F, max_iter=500, tol=1e-10, solver="lbfgs").fit(mdp, demos)
    losses = {}
    for lam in (1e-6, 1e-2, 1e2):
        model = _fit(features=F, max_iter=6, residual_penalty=lam, solver="lbfgs").fit(mdp, demos)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            model.transfer(mdp, demos, max_iter=500)
        losses[lam] = model.transfer_loss_.sum()
    assert losses[1e-6] <= losses[1e-2] <= losses[1e2]
    assert losses[1e-6] - flat.loss_.sum() <= 1e-3 * flat.loss_.sum() + 1e-8
    assert losses[1e2] > 1.01 * flat.loss_.sum()  # the test can fail: the dictionary alone fits worse


@pytest.mark.parametrize("kind", ["tabular", "environments"])
def test_fit_over_every_layout(shared, worlds, kind):
    if kind == "tabular":
        mdp, _, demos = shared
        model = _fit(max_iter=3, residual_penalty=1.0, solver="gn-qp-clarabel").fit(mdp, demos)
        assert model.residuals_.shape == (5, 36) and model.rewards_.shape == (5, 9, 4)
        model.transfer(mdp, demos[:1])
        assert model.transfer_rewards_.shape == (1, 9, 4)
    else:
        mdps, Phis, demos = worlds
        model = _fit(features=Phis, max_iter=3, residual_penalty=1.0, objective="mce").fit(mdps, demos)
        assert [r.shape for r in model.rewards_] == [(9, 4), (16, 4), (9, 4)] and model.residuals_.shape == (3, 3)
        model.transfer(mdps[1:], demos[1:], features=Phis[1:])
        assert [r.shape for r in model.transfer_rewards_] == [(16, 4), (9, 4)]


def test_fit_in_two_shards_equals_one(shared):
    mdp, F, demos = shared
    a = _fit(features=F, max_iter=3, residual_penalty=LAM).fit(mdp, demos)
    b = _fit(features=F, max_iter=3, residual_penalty=LAM, n_jobs=2).fit(mdp, demos)
    np.testing.assert_allclose(b.rewards_, a.rewards_, rtol=0, atol=1e-10)


@pytest.mark.parametrize("value, message", [
    (-1.0, r"residual_penalty must be >= 0 \(np.inf: no residuals\); got -1.0"),
    (np.nan, r"residual_penalty must be >= 0 \(np.inf: no residuals\); got nan"),
    ("big", r"residual_penalty must be a number >= 0, np.inf or 'auto'; got 'big'"),
    (True, r"residual_penalty must be a number >= 0, np.inf or 'auto'; got True \(bool\)"),
])
def test_bad_penalties_are_refused(shared, value, message):
    with pytest.raises(ValidationError, match=message):
        check_residual_penalty(value)
    mdp, F, demos = shared
    with pytest.raises(ValidationError, match=message.replace(" or 'auto'", ".*")):
        _fit(features=F, max_iter=1, residual_penalty=value).fit(mdp, demos)


def test_a_constrained_h_solver_is_refused_with_residuals(shared):
    mdp, F, demos = shared
    with pytest.raises(ValidationError, match=r"residual_penalty=0.3 needs an unconstrained h_solver .* 'armijo-nonneg' has "
                                              r"constraint 'nonneg'"):
        _fit(features=F, max_iter=1, residual_penalty=LAM, solver="armijo-nonneg").fit(mdp, demos)


def test_every_planner_fits_the_residual_model(shared):
    """The planners agree to rounding on one evaluation; alternating fits amplify that (with or
    without residuals: 0.1 on these rewards after 3 outer iterations), so the fits are compared by
    their loss, and transfer, a separable run from zero, by its coefficients."""
    mdp, F, demos = shared
    dense = _fit(features=F, max_iter=3, residual_penalty=LAM, planner="dense").fit(mdp, demos)
    sparse = _fit(features=F, max_iter=3, residual_penalty=LAM, planner="sparse-lu").fit(mdp, demos)
    for model in (dense, sparse):
        assert model.loss_history_[-1] < model.loss_history_[0]
    assert abs(sparse.loss_history_[-1] - dense.loss_history_[-1]) < 1e-2 * dense.loss_history_[-1]
    sparse.dictionary_, sparse.coefficients_ = dense.dictionary_, dense.coefficients_
    np.testing.assert_allclose(sparse.transfer(mdp, demos[:2]), dense.transfer(mdp, demos[:2]), rtol=0, atol=1e-6)
    np.testing.assert_allclose(sparse.transfer_residuals_, dense.transfer_residuals_, rtol=0, atol=1e-6)


def test_residual_h_step_solves_each_task_alone_without_a_block_qp(shared, monkeypatch):
    """The H-step of the residual model is separable over tasks given D: an unconstrained Gauss-Newton
    subproblem of k + p variables per task is solved exactly, never compiled into one QP over every task
    (which ran out of memory at Objectworld's sizes)."""
    import solvers.gauss_newton as gn

    def no_block_qp(self, *args, **kwargs):
        raise AssertionError("the residual H-step built a block QP over the tasks")

    mdp, F, demos = shared
    fitted = fo.FactIRL(n_primitives=2, features=F, residual_penalty=LAM, solver="gn-qp-osqp", max_iter=3, rng=0)
    monkeypatch.setattr(gn.GaussNewtonSolver, "solve_subproblems", no_block_qp)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fo.exceptions.ConvergenceWarning)
        fitted.fit(mdp, demos)
    assert np.all(np.isfinite(fitted.residuals_)) and np.any(fitted.residuals_ != 0)
    with pytest.raises(AssertionError, match="block QP"):  # the fixed-k model's H-step does use it (unchanged)
        fo.FactIRL(n_primitives=2, features=F, solver="gn-qp-osqp", max_iter=1, rng=0, scheme="alternating").fit(mdp, demos)


@pytest.mark.parametrize("flat_solver", ["armijo", "lbfgs"])
def test_flat_model_transfers_as_the_flat_learner(shared, flat_solver):
    """lambda = 0: the dictionary plays no part, and transfer fits each new task as GradIRL does (the same
    solver, budget, tolerance and saturation rule, the transfer's ``transfer_stol``): the same rewards to the
    last bit, h = 0, delta = the flat weights."""
    mdp, F, demos = shared
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fo.exceptions.ConvergenceWarning)
        model = fo.FactIRL(n_primitives=2, features=F, residual_penalty=0.0, max_iter=2, flat_max_iter=15,
                           flat_solver=flat_solver, rng=0).fit(mdp, demos[:3])
        new = [d[:1] for d in demos[3:]]
        H = model.transfer(mdp, new)
        flat = fo.GradIRL(features=F, max_iter=15, solver=flat_solver, stol=model.transfer_stol).fit(mdp, new)
    assert model.transfer_stol == TRANSFER_STOL
    assert np.array_equal(H, np.zeros((2, 2)))
    assert np.array_equal(model.transfer_residuals_, flat.weights_)
    assert np.array_equal(np.asarray(model.transfer_rewards_), flat.rewards_)
    np.testing.assert_allclose(model.transfer_loss_, flat.loss_, rtol=1e-12)


def test_flat_solver_is_validated(shared):
    mdp, F, demos = shared
    with pytest.raises(fo.exceptions.UnknownSolverError, match="unknown solver 'no-such-solver'"):
        fo.FactIRL(n_primitives=2, features=F, flat_solver="no-such-solver", rng=0).fit(mdp, demos)


def test_transfer_eliminating_the_residuals_is_the_stacked_transfer(shared):
    """The Gauss-Newton transfer with each task's residual eliminated in closed form (the default) gives
    the rewards of the stacked (k + p)-unknown steps, and each task's are those of its transfer alone."""
    mdp, F, demos = shared
    model = _fit(features=F, max_iter=4, residual_penalty=LAM, solver="gn-qp-clarabel").fit(mdp, demos)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        eliminated = model.set_params(solver_options={"ridge": "eliminate"}).transfer(mdp, demos, max_iter=50)
        R, delta = model.transfer_rewards_.copy(), model.transfer_residuals_.copy()
        stacked = model.set_params(solver_options={"ridge": "stack"}).transfer(mdp, demos, max_iter=50)
        assert np.max(np.abs(R - model.transfer_rewards_)) <= 1e-6 * np.max(np.abs(model.transfer_rewards_))
        np.testing.assert_allclose(eliminated, stacked, rtol=0, atol=1e-6 * np.max(np.abs(stacked)))
        assert np.max(np.abs(delta - model.transfer_residuals_)) <= 1e-6 * np.max(np.abs(delta))
        assert np.any(delta != 0)
        model.set_params(solver_options={"ridge": "eliminate"})
        for i in (0, 4):
            np.testing.assert_allclose(eliminated[i], model.transfer(mdp, demos[i:i + 1], max_iter=50)[0], rtol=0, atol=1e-10)


@pytest.mark.parametrize("given", [True, False])
def test_no_penalty_starts_at_the_flat_start(shared, given):
    """residual_penalty=0 is the flat model: with the PCA start, the fit begins at the flat start's own
    rewards (delta_i = w_i - D h_i), given as flat_rewards or fitted by the model, and never ends above it."""
    mdp, F, demos = shared
    flat = fo.GradIRL(features=F, gtol=0.0, max_iter=200, solver=FLAT_SOLVER).fit(mdp, demos)  # the start's rules
    model = fo.FactIRL(n_primitives=2, features=F, residual_penalty=0.0, max_iter=5, flat_max_iter=200, rng=0)
    model.fit(mdp, demos, flat_rewards=flat.rewards_ if given else None)
    start = model.loss_history_[0]
    np.testing.assert_allclose(start, flat.loss_.sum(), rtol=1e-6)
    assert model.loss_.sum() <= start * (1 + 1e-12)


def test_weights_from_rewards_inverts_the_basis(shared):
    """The least-squares weights of rewards built from known weights are those weights; a wrong count is refused."""
    mdp, F, demos = shared
    tasks = task_set(mdp, demos, F, "state-action")
    W = np.random.default_rng(1).standard_normal((len(demos), tasks.basis.n_params))
    R = tasks.basis.rewards(W)
    np.testing.assert_allclose(tasks.basis.weights_from_rewards(R, len(demos)), W, atol=1e-10)
    with pytest.raises(ValidationError, match="one \\(S_i, A\\) array per task"):
        tasks.basis.weights_from_rewards(R[:2], len(demos))

"""The joint scheme of the factorial fit: quasi-Newton steps on (D, H) together."""

import numpy as np
import pytest

import solvers

import factirl_opt as fo
from helpers import five_dictionary_tasks
from factirl_opt.exceptions import ValidationError
from factirl_opt.learners.factorial import _joint_problem, _pack, _unpack, check_scheme
from factirl_opt.learners.gradirl import make_objective
from factirl_opt.objectives.problems import as_problem_basis, dictionary_problem, weights_problem

K = 2


@pytest.fixture
def data(rng, grid3):
    return five_dictionary_tasks(rng, grid3, K)


def _pca_start(mdp, demos):
    flat = fo.GradIRL(max_iter=10).fit(mdp, demos)
    return fo.pca_dictionary(flat.rewards_.reshape(len(demos), -1), K)


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_joint_problem_gradient_matches_the_blocks_and_finite_differences(data, objective):
    """The joint gradient is (dJ/dD, dJ/dH) of eqs. 11-12, as the two block problems give them,
    and matches central differences of the total loss."""
    mdp, _, demos = data
    D, H = _pca_start(mdp, demos)
    obj = make_objective(mdp, demos, 5.0, objective)
    basis = as_problem_basis(obj, None)
    problem = _joint_problem(obj, basis, 36, K, 5)
    x = _pack(D, 0.3 * H)
    loss, grad = problem.loss_and_grad(x, np.arange(1))
    Dx, Hx = _unpack(x, 36, K, 5)
    gH = weights_problem(obj, Dx).loss_and_grad(Hx, np.arange(5))[1]
    gD = dictionary_problem(obj, Hx).loss_and_grad(Dx.reshape(1, -1), np.arange(1))[1]
    np.testing.assert_allclose(grad[0], np.concatenate([gD.ravel(), gH.ravel()]), rtol=1e-10, atol=1e-14)
    rng = np.random.default_rng(3)
    for _ in range(3):
        v = rng.standard_normal(x.shape)
        eps = 1e-5
        fd = (problem.loss_and_grad(x + eps * v, np.arange(1))[0][0] - problem.loss_and_grad(x - eps * v, np.arange(1))[0][0]) / (2 * eps)
        assert fd == pytest.approx(float(grad[0] @ v[0]), rel=1e-6)


def test_joint_fit_decreases_the_loss_and_keeps_the_memory(data, monkeypatch):
    """Each outer iteration runs inner_steps steps of the D-solver itself (not its alternating
    form) on one row of (p + n) k parameters, warm-started by its whole previous state; the best
    point is returned with its primitives back in the band."""
    mdp, _, demos = data
    D0, H0 = _pca_start(mdp, demos)
    seen = []
    original = solvers.StepSolver.run

    def spy(self, problem, x0, max_iter, state=None, **kw):
        seen.append((self.name, problem.n_rows, problem.n_params, max_iter, state))
        return original(self, problem, x0, max_iter, state=state, **kw)

    monkeypatch.setattr(solvers.StepSolver, "run", spy)
    fit = fo.fit_factorial(mdp, demos, D0, H0, d_solver="lbfgs", max_iter=6, inner_steps=3, tol=0.0, gtol=0.0,
                           scheme="joint")
    assert [s[:4] for s in seen] == [("lbfgs", 1, (36 + 5) * K, 3)] * 6  # no H-step runs
    assert seen[0][4] is None and all(int(s[4].count[0]) > 0 for s in seen[1:])  # the memory carried over
    assert fit.n_iter == 6 and fit.status == "max_iter" and len(fit.loss_history) == 7
    assert np.all(np.diff(fit.loss_history) <= 0) and fit.loss.sum() < fit.loss_history[0]
    assert min(fit.loss_history) == pytest.approx(fit.loss.sum(), rel=1e-12)
    ev = fit.evaluation_history
    assert ev[-1] == fit.n_evaluations and all(b > a for a, b in zip(ev, ev[1:]))
    norms = np.linalg.norm(fit.dictionary, axis=0)
    assert np.all((norms >= 0.5 - 1e-9) & (norms <= 2.0 + 1e-9))
    R = fo.task_rewards(fit.dictionary, fit.coefficients, 9, 4)
    obj = make_objective(mdp, demos, 5.0)
    np.testing.assert_allclose(obj.loss_and_grad(R)[0], fit.loss, rtol=1e-10)


def test_factirl_scheme(data):
    mdp, _, demos = data
    kw = dict(n_primitives=K, max_iter=4, inner_steps=2, flat_max_iter=5, d_solver="lbfgs", rng=0)
    joint = fo.FactIRL(scheme="joint", **kw).fit(mdp, demos)
    alt = fo.FactIRL(scheme="alternating", **kw).fit(mdp, demos)
    assert fo.FactIRL().scheme == "auto" and joint.get_params()["scheme"] == "joint"
    assert (joint.scheme_, alt.scheme_) == ("joint", "alternating")
    assert joint.loss_history_[0] == alt.loss_history_[0]  # the same start
    assert joint.loss_history_[-1] < joint.loss_history_[0] and joint.n_iter_ == 4
    # the residual model alternates whatever the scheme
    res_joint = fo.FactIRL(scheme="joint", residual_penalty=1.0, **kw).fit(mdp, demos)
    res_alt = fo.FactIRL(scheme="alternating", residual_penalty=1.0, **kw).fit(mdp, demos)
    np.testing.assert_array_equal(res_joint.rewards_, res_alt.rewards_)
    assert res_joint.scheme_ == "alternating"


def test_auto_scheme_is_joint_on_features_and_alternating_on_tables(data):
    """The default ``scheme="auto"`` runs the fit of ``"joint"`` on features and of ``"alternating"`` on
    tables (tabular or state rewards), and alternates wherever the joint scheme does not apply."""
    mdp, _, demos = data
    F = np.random.default_rng(3).standard_normal((mdp.n_states, 6))
    kw = dict(n_primitives=K, max_iter=3, flat_max_iter=5, rng=0)
    for fit_kw, scheme in ((dict(), "alternating"), (dict(reward="state"), "alternating"), (dict(features=F), "joint"),
                           (dict(features=F, solver="gn-qp-clarabel-nonneg"), "alternating"),
                           (dict(features=F, dictionary_constraint="nonneg"), "alternating"),
                           (dict(features=F, residual_penalty=1.0), "alternating")):
        auto = fo.FactIRL(**kw, **fit_kw).fit(mdp, demos)
        same = fo.FactIRL(scheme=scheme, **kw, **fit_kw).fit(mdp, demos)
        assert auto.scheme == "auto" and auto.scheme_ == scheme, fit_kw
        np.testing.assert_array_equal(auto.rewards_, same.rewards_)


@pytest.mark.parametrize("kwargs, match", [
    (dict(scheme="joined"), r"scheme must be one of 'auto', 'alternating', 'joint'; got 'joined'"),
    (dict(scheme=None), r"scheme must be one of .*; got None"),
    (dict(scheme="joint", solver="gn-qp-clarabel-nonneg"), r"H-solver 'gn-qp-clarabel-nonneg' with constraint 'nonneg'"),
    (dict(scheme="joint", d_solver="gn-cg"), r"D-solver 'gn-cg', which needs residuals or a Hessian"),
    (dict(scheme="joint", d_solver="newton"), r"D-solver 'newton', which needs residuals or a Hessian"),
    (dict(scheme="joint", dictionary_constraint="nonneg"), r"a constrained dictionary"),
])
def test_factirl_refuses_a_scheme_that_does_not_apply_before_any_work(data, kwargs, match):
    mdp, _, demos = data
    model = fo.FactIRL(n_primitives=K, max_iter=2, flat_max_iter=2, **kwargs)
    with pytest.raises(ValidationError, match=match):
        model.fit(mdp, demos)
    assert not hasattr(model, "dictionary_")


def test_check_scheme_and_fit_factorial_refuse_the_residual_model(data):
    mdp, _, demos = data
    lbfgs, armijo = solvers.get_solver("lbfgs"), solvers.get_solver("armijo")
    assert check_scheme("alternating", armijo, armijo, 1.0) == "alternating"
    assert check_scheme("joint", armijo, lbfgs) == "joint"
    with pytest.raises(ValidationError, match=r"residual_penalty=1.0 \(the residual model"):
        check_scheme("joint", armijo, lbfgs, 1.0)
    D0, H0 = _pca_start(mdp, demos)
    with pytest.raises(ValidationError, match="scheme must be one of"):
        fo.fit_factorial(mdp, demos, D0, H0, scheme="both")
    with pytest.raises(ValidationError, match="H-solver 'armijo-nonneg'"):
        fo.fit_factorial(mdp, demos, D0, H0, h_solver="armijo-nonneg", scheme="joint")


def test_an_interrupted_joint_fit_keeps_its_best_point_in_the_band(data):
    """Ctrl-C after the second outer iteration: the model keeps the best point seen (the last,
    the loss never rises), its primitives rescaled into the band as at the end of a fit."""
    from factirl_opt.exceptions import InterruptedFitWarning

    mdp, _, demos = data
    D0, H0 = _pca_start(mdp, demos)

    def stop(iteration, total):
        if iteration == 2:
            raise KeyboardInterrupt

    model = fo.FactIRL(n_primitives=K, init=(D0, H0), d_solver="lbfgs", max_iter=10, inner_steps=2, tol=0.0, gtol=0.0,
                       scheme="joint", callback=stop)
    with pytest.warns(InterruptedFitWarning), pytest.raises(KeyboardInterrupt):
        model.fit(mdp, demos)
    assert model.status_ == "interrupted" and model.n_iter_ == 2 and len(model.loss_history_) == 3
    assert model.loss_.sum() == pytest.approx(min(model.loss_history_), rel=1e-12)
    norms = np.linalg.norm(model.dictionary_, axis=0)
    assert np.all((norms >= 0.5 - 1e-9) & (norms <= 2.0 + 1e-9))
    R = fo.task_rewards(model.dictionary_, model.coefficients_, 9, 4)
    np.testing.assert_allclose(make_objective(mdp, demos, 5.0).loss_and_grad(R)[0], model.loss_, rtol=1e-10)


def test_flat_tol_stops_the_pca_start_earlier_and_is_checked(data):
    """flat_tol is the start's per-task relative-decrease rule: a loose one ends the flat fit
    sooner (fewer evaluations, another start); the default is the flat learner's 1e-5."""
    mdp, _, demos = data
    kw = dict(n_primitives=K, max_iter=0, solver=fo.SolverSettings(flat_solver="lbfgs"), rng=0)
    start = dict(flat_max_iter=50, pca_shrink=False)
    tight = fo.FactIRL(start=fo.Start(**start), **kw).fit(mdp, demos)
    loose = fo.FactIRL(start=fo.Start(flat_tol=0.5, **start), **kw).fit(mdp, demos)
    assert fo.Start().flat_tol == 1e-5 and loose.get_params()["start__flat_tol"] == 0.5
    assert loose.n_evaluations_ < tight.n_evaluations_
    assert loose.loss_history_[0] != tight.loss_history_[0]
    for bad in (-1.0, np.nan):
        with pytest.raises(ValidationError, match="flat_tol"):
            fo.FactIRL(start=fo.Start(flat_tol=bad, **start), **kw).fit(mdp, demos)


def test_flat_stol_stops_the_pca_start_by_saturation_as_gradirl_does_and_is_checked(data):
    """flat_stol is the start's saturation rule, GradIRL's default 1e-5: with it, the start's weights
    are those of GradIRL with the same tolerances and rules (gradient rule off), and the fit
    takes no more evaluations than without it."""
    mdp, _, demos = data
    kw = dict(n_primitives=K, max_iter=0, solver=fo.SolverSettings(flat_solver="lbfgs"), rng=0)
    start = dict(flat_max_iter=60, pca_shrink=False)
    plain = fo.FactIRL(start=fo.Start(flat_stol=0.0, **start), **kw).fit(mdp, demos)
    saturating = fo.FactIRL(start=fo.Start(flat_stol=1e-2, **start), **kw).fit(mdp, demos)
    assert fo.Start().flat_stol == 1e-5 and saturating.get_params()["start__flat_stol"] == 1e-2
    assert saturating.n_evaluations_ < plain.n_evaluations_
    flat = fo.GradIRL(max_iter=60, tol=1e-5, gtol=0.0, stol=1e-2, solver="lbfgs").fit(mdp, demos)
    given = fo.FactIRL(start=fo.Start(flat_stol=1e-2, **start), **kw).fit(mdp, demos, flat_rewards=flat.rewards_)
    np.testing.assert_allclose(given.dictionary_, saturating.dictionary_, rtol=1e-10, atol=1e-12)
    for bad in (-1.0, np.inf, "x"):
        with pytest.raises((ValidationError, TypeError), match="flat_stol"):
            fo.FactIRL(start=fo.Start(flat_stol=bad, **start), **kw).fit(mdp, demos)

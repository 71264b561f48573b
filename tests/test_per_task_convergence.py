"""Per-task convergence of the flat learner and of transfer: a task's answer does not depend on
which other tasks share the fit (each stops by its own rule and leaves the batch)."""

import warnings

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ConvergenceWarning, ValidationError
import solvers
from factirl_opt.learners.gradirl import fit_weights
from factirl_opt.learners.transfer import TRANSFER_STOL
from factirl_opt.learners.fitting import make_objective
from factirl_opt.tasks.task_set import reward_features
from helpers import five_tasks_on_a_small_grid, quiet_fit, three_tasks_on_two_grids

FLAT_SOLVERS = [name for name in ("armijo", "armijo-nonneg", "lbfgs", "gn-cg", "gn-qp-osqp", "gn-qp-clarabel")
                if name in solvers.available_solvers()]


@pytest.fixture(scope="module")
def tasks():
    return five_tasks_on_a_small_grid()


@pytest.fixture(scope="module")
def worlds():
    return three_tasks_on_two_grids()


def _assert_alone(together, alone, i):
    np.testing.assert_allclose(together.weights_[i], alone.weights_[0], rtol=0, atol=1e-10)
    assert abs(together.loss_[i] - alone.loss_[0]) <= 1e-10


@pytest.mark.parametrize("solver", FLAT_SOLVERS)
@pytest.mark.parametrize("features", [False, True], ids=["tabular", "features"])
def test_flat_fit_equals_each_task_fitted_alone(tasks, solver, features):
    """The default tol stops the tasks at different iterations; each one's weights are its own fit's."""
    mdp, F, demos = tasks
    kw = dict(max_iter=60, solver=solver, features=F if features else None)
    together = quiet_fit(fo.GradIRL(**kw), mdp, demos)
    for i in range(len(demos)):
        _assert_alone(together, quiet_fit(fo.GradIRL(**kw), mdp, demos[i:i + 1]), i)


def test_tasks_stop_at_different_iterations_and_leave_the_batch(tasks):
    """The rows record their own stops; the evaluations of rows that stopped are saved."""
    mdp, F, demos = tasks
    objective = make_objective(mdp, demos, 5.0)
    res = fit_weights(objective, reward_features(mdp, F), solvers.get_solver("lbfgs"), 200, 1e-5)
    assert res.status == "converged" and set(res.row_status) == {"converged"}
    assert len(set(res.row_iterations.tolist())) > 1 and res.iterations == res.row_iterations.max()
    # every row is evaluated at its start and at least once per step; no row after it stopped
    assert np.all(res.row_evaluations >= res.row_iterations + 1)
    assert res.row_evaluations.sum() < len(demos) * res.row_evaluations.max()
    assert res.reason == f"per row, of {len(demos)}: {len(demos)} by relative decrease <= tol=1e-05"


@pytest.mark.parametrize("solver", ["armijo", "lbfgs", "gn-qp-osqp", "gn-cg"])
def test_flat_fit_over_environments_equals_each_task_alone(worlds, solver):
    """Each task alone in its own environment (the same representation: one MDP and one feature
    matrix in a list)."""
    mdps, Phis, demos = worlds
    kw = dict(max_iter=40, solver=solver)
    together = quiet_fit(fo.GradIRL(features=Phis, **kw), mdps, demos)
    for i in range(3):
        _assert_alone(together, quiet_fit(fo.GradIRL(features=[Phis[i]], **kw), [mdps[i]], [demos[i]]), i)


def test_flat_fit_in_two_shards_equals_each_task_alone(tasks):
    mdp, F, demos = tasks
    together = quiet_fit(fo.GradIRL(features=F, max_iter=40, solver="lbfgs", n_jobs=2), mdp, demos)
    for i in (0, 3):
        _assert_alone(together, quiet_fit(fo.GradIRL(features=F, max_iter=40, solver="lbfgs"), mdp, demos[i:i + 1]), i)


def test_max_iter_warning_names_the_tasks_that_did_not_converge(tasks):
    mdp, F, demos = tasks
    full = quiet_fit(fo.GradIRL(features=F, max_iter=300, solver="lbfgs"), mdp, demos)
    steps = np.array([quiet_fit(fo.GradIRL(features=F, max_iter=300, solver="lbfgs"), mdp, demos[i:i + 1]).n_iter_
                      for i in range(len(demos))])
    cut = int(np.median(steps))
    late = np.flatnonzero(steps > cut)
    assert full.status_ == "converged" and 0 < late.size < len(demos)
    with pytest.warns(ConvergenceWarning, match=rf"max_iter={cut} before its tolerance for {late.size} of "
                                                   rf"{len(demos)} task\(s\): \[{', '.join(map(str, late))}\]"):
        model = fo.GradIRL(features=F, max_iter=cut, solver="lbfgs").fit(mdp, demos)
    assert model.status_ == "max_iter" and model.n_iter_ == cut


def test_no_warning_when_every_task_converges(tasks):
    mdp, F, demos = tasks
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConvergenceWarning)
        model = fo.GradIRL(features=F, max_iter=300, solver="lbfgs").fit(mdp, demos)
    assert model.status_ == "converged"


# ----------------------------------------------------------------------------- transfer


@pytest.fixture(scope="module")
def dictionary_tasks():
    mdp = fo.GridWorld(size=4, p_success=0.7, gamma=0.9)
    rng = np.random.default_rng(3)
    D = fo.random_dictionary(mdp.n_params, 3, rng)
    H = 3.0 * fo.random_coefficients(6, 3, kind="nonneg", rng=rng)
    demos = fo.sample_demonstrations(mdp, fo.task_rewards(D, H, mdp.n_states, mdp.n_actions), 2, 8, rng)
    return mdp, D, demos


@pytest.mark.parametrize("solver", FLAT_SOLVERS)
def test_transfer_equals_each_task_transferred_alone(dictionary_tasks, solver):
    mdp, D, demos = dictionary_tasks
    model = fo.FactIRL(n_primitives=3, solver=solver)
    model.dictionary_ = D
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        together = model.transfer(mdp, demos, max_iter=60)
        for i in range(len(demos)):
            alone = model.transfer(mdp, demos[i:i + 1], max_iter=60)
            np.testing.assert_allclose(together[i], alone[0], rtol=0, atol=1e-10)


def test_transfer_warns_naming_the_tasks_at_max_iter(dictionary_tasks):
    mdp, D, demos = dictionary_tasks
    model = fo.FactIRL(n_primitives=3, solver="armijo")
    model.dictionary_ = D
    with pytest.warns(ConvergenceWarning, match=r"transfer stopped at max_iter=2 before its tolerance for \d of 6 task"):
        model.transfer(mdp, demos, max_iter=2)
    assert model.transfer_status_ == "max_iter"
    assert "at max_iter=2: rows [" in model.transfer_stop_reason_


@pytest.mark.parametrize("solver", ["armijo", "gn-qp-clarabel"])
def test_transfer_to_new_environments_equals_each_task_alone(worlds, solver):
    mdps, Phis, demos = worlds
    model = fo.FactIRL(n_primitives=2, solver=solver)
    model.features, model.dictionary_ = Phis, np.random.default_rng(2).normal(size=(3, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        together = model.transfer(mdps, demos, features=Phis, max_iter=60)
        for i in range(3):
            alone = model.transfer([mdps[i]], [demos[i]], features=[Phis[i]], max_iter=60)
            np.testing.assert_allclose(together[i], alone[0], rtol=0, atol=1e-10)


# ----------------------------------------------------------------------------- saturation


@pytest.fixture(scope="module")
def matched():
    """One demonstration per task on a 3x3 grid: tabular rewards match each one exactly, as do the
    coefficients of a transfer with the dictionary that made the tasks; the loss then falls
    toward 0 as the rewards grow without bound (the Boltzmann policy saturates)."""
    mdp = fo.GridWorld(size=3, p_success=0.7, gamma=0.9)
    rng = np.random.default_rng(7)
    demos = fo.sample_demonstrations(mdp, 2.0 * rng.standard_normal((5, 9, 4)), 1, 6, rng=rng)
    D = fo.random_dictionary(mdp.n_params, 3, rng=1)
    new = fo.sample_demonstrations(mdp, fo.task_rewards(D, fo.random_coefficients(6, 3, rng=2), 9, 4), 1, 8, rng=3)
    return mdp, demos, D, new


@pytest.mark.parametrize("solver", ["armijo", "lbfgs", "gn-qp-clarabel"])
def test_flat_tasks_that_match_their_demonstrations_converge(matched, solver):
    """The relative decrease of a loss that tends to 0 stays large; the gradient rule, per task,
    stops each task (the saturation rule off), with no MaxIterWarning; without both rules
    (gtol=stol=0) every task runs to max_iter."""
    mdp, demos, _, _ = matched
    start = fo.GradIRL(max_iter=0).fit(mdp, demos).loss_
    with warnings.catch_warnings():
        warnings.simplefilter("error", fo.exceptions.ConvergenceWarning)
        model = fo.GradIRL(solver=solver, stol=0.0).fit(mdp, demos)
    assert model.status_ == "converged" and model.n_iter_ < 100
    assert model.stop_reason_ == f"per row, of {len(demos)}: {len(demos)} by gradient norm <= gtol=0.0001 x initial"
    assert np.all(model.loss_ <= 1e-3 * start)
    with pytest.warns(fo.exceptions.MaxIterWarning, match=rf"max_iter=100 before its tolerance for {len(demos)} of"):
        fixed = fo.GradIRL(solver=solver, gtol=0.0, stol=0.0).fit(mdp, demos)
    assert fixed.status_ == "max_iter" and fixed.n_evaluations_ > model.n_evaluations_
    for i in (0, 3):  # each task stops where it stops alone
        _assert_alone(model, fo.GradIRL(solver=solver, stol=0.0).fit(mdp, demos[i:i + 1]), i)


@pytest.mark.parametrize("solver", ["lbfgs", "gn-qp-clarabel", "gn-cg"])
def test_flat_tasks_that_match_their_demonstrations_stop_when_their_loss_saturates(matched, solver):
    """Without the gradient rule (gtol=0, the harness's presets), the saturation rule stops each
    task once an iteration decreases its loss by at most stol of its decrease since the start:
    every task by that rule, at the iteration it stops alone, its loss a small fraction of its
    start; a larger stol stops every task no later."""
    mdp, demos, _, _ = matched
    start = fo.GradIRL(max_iter=0).fit(mdp, demos).loss_
    with warnings.catch_warnings():
        warnings.simplefilter("error", fo.exceptions.ConvergenceWarning)
        model = fo.GradIRL(solver=solver, gtol=0.0).fit(mdp, demos)
    assert model.status_ == "converged" and model.n_iter_ < 100
    assert model.stop_reason_ == (f"per row, of {len(demos)}: {len(demos)} by saturation (decrease <= stol=1e-05 x "
                                  f"decrease since the start)")
    assert np.all(model.loss_ <= 1e-3 * start) and np.all(model.loss_ > 0)
    for i in range(len(demos)):
        alone = fo.GradIRL(solver=solver, gtol=0.0).fit(mdp, demos[i:i + 1])
        assert alone.stop_reason_.startswith("per row, of 1: 1 by saturation")
        _assert_alone(model, alone, i)
    loose = fo.GradIRL(solver=solver, gtol=0.0, stol=1e-3).fit(mdp, demos)
    assert loose.status_ == "converged" and loose.n_evaluations_ < model.n_evaluations_
    assert np.all(loose.loss_ >= model.loss_)


@pytest.mark.parametrize("solver", ["gn-qp-clarabel", "gn-qp-osqp", "gn-cg"])
def test_transfer_from_one_demonstration_converges(matched, solver):
    """The maximum-likelihood transfer (``transfer_stol=0``) stops every task by the gradient rule."""
    mdp, _, D, new = matched
    model = fo.FactIRL(n_primitives=3, solver=solver, transfer_stol=0.0)
    model.dictionary_ = D
    with warnings.catch_warnings():
        warnings.simplefilter("error", fo.exceptions.ConvergenceWarning)
        together = model.transfer(mdp, new)
    assert model.transfer_status_ == "converged"
    assert model.transfer_stop_reason_.endswith(f"{len(new)} by gradient norm <= gtol=0.0001 x initial")
    with pytest.warns(fo.exceptions.MaxIterWarning):
        fixed = fo.transfer_coefficients(mdp, new, D, h_solver=solver, gtol=0.0)
    assert fixed.status == "max_iter" and model.transfer_n_evaluations_ < fixed.n_evaluations / 4
    for i in (0, 5):
        np.testing.assert_allclose(together[i], model.transfer(mdp, new[i:i + 1])[0], rtol=0, atol=1e-10)
    model.gtol = 0.0  # FactIRL's gtol is its transfer's
    with pytest.warns(fo.exceptions.MaxIterWarning):
        model.transfer(mdp, new)


@pytest.mark.parametrize("solver", ["armijo", "lbfgs", "gn-qp-clarabel"])
def test_default_transfer_from_one_demonstration_stops_by_its_own_rules(matched, solver):
    """FactIRL's default transfer (the saturation rule ``transfer_stol=TRANSFER_STOL`` beside the gradient
    rule) stops every task before ``max_iter``, even without the gradient rule, where the
    maximum-likelihood transfer of the same tasks runs to ``max_iter``."""
    mdp, _, D, new = matched
    model = fo.FactIRL(n_primitives=3, solver=solver, gtol=0.0)
    model.dictionary_ = D
    assert model.transfer_stol == TRANSFER_STOL
    with warnings.catch_warnings():
        warnings.simplefilter("error", fo.exceptions.ConvergenceWarning)
        model.transfer(mdp, new)
    assert model.transfer_status_ == "converged" and "max_iter" not in model.transfer_stop_reason_
    assert "by saturation (decrease <= stol=0.001 x decrease since the start)" in model.transfer_stop_reason_
    with pytest.warns(fo.exceptions.MaxIterWarning):
        model.set_params(transfer_stol=0.0).transfer(mdp, new)


@pytest.mark.parametrize("bad", [-1e-4, float("nan"), "1e-4"])
def test_gtol_is_checked(matched, bad):
    mdp, demos, D, new = matched
    with pytest.raises(ValidationError, match="gtol"):
        fo.GradIRL(gtol=bad).fit(mdp, demos)
    with pytest.raises(ValidationError, match="stol"):
        fo.GradIRL(stol=bad).fit(mdp, demos)
    with pytest.raises(ValidationError, match="gtol"):
        fo.transfer_coefficients(mdp, new, D, gtol=bad)

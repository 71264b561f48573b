"""GradIRL, the flat learner."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import UnknownSolverError, ValidationError


@pytest.fixture
def data(rng, grid3):
    R = rng.standard_normal((4, 9, 4))
    return grid3, R, fo.sample_demonstrations(grid3, R, 4, 6, rng)


def assert_non_increasing(history):
    h = np.asarray(history)
    assert np.all(np.diff(h) <= 1e-12 * np.abs(h[:-1])), h


def test_fit_tabular(data):
    mdp, R, demos = data
    model = fo.GradIRL(max_iter=30)
    assert model.fit(mdp, demos) is model
    assert model.rewards_.shape == (4, 9, 4) and model.weights_.shape == (4, 36)
    np.testing.assert_array_equal(model.rewards_.reshape(4, -1), model.weights_)
    assert model.loss_.shape == (4,)
    assert len(model.loss_history_) == model.n_iter_ + 1
    assert_non_increasing(model.loss_history_)
    assert model.loss_history_[-1] < 0.5 * model.loss_history_[0]
    assert isinstance(model.n_evaluations_, int) and model.n_evaluations_ >= model.n_iter_
    assert model.status_ in ("converged", "max_iter", "stalled")
    # the recorded loss is the loss of the learnt rewards
    mu, pi = fo.empirical_statistics(mdp, demos)
    np.testing.assert_allclose(model.loss_, fo.policy_matching_loss(mdp, model.rewards_, mu, pi, 5.0)[0], rtol=1e-12)
    np.testing.assert_allclose(model.loss_history_[-1], model.loss_.sum(), rtol=1e-12)


def test_fit_learns_better_than_zero_reward(data):
    mdp, R, demos = data
    model = fo.GradIRL(max_iter=50).fit(mdp, demos)
    assert fo.deviation(mdp, R, model.rewards_).mean() < fo.deviation(mdp, R, np.zeros_like(R)).mean()


def test_batched_fit_equals_per_task_fits(data):
    """Tasks are independent rows: fitting them together or one by one gives the same rewards."""
    mdp, _, demos = data
    together = fo.GradIRL(max_iter=10, tol=0).fit(mdp, demos)
    for i in range(2):
        alone = fo.GradIRL(max_iter=10, tol=0).fit(mdp, demos[i : i + 1])
        np.testing.assert_allclose(alone.rewards_[0], together.rewards_[i], rtol=1e-9, atol=1e-12)


def test_features_path(rng, data):
    mdp, R, demos = data
    F = rng.standard_normal((36, 3))
    model = fo.GradIRL(features=F, max_iter=20).fit(mdp, demos)
    assert model.weights_.shape == (4, 3)
    np.testing.assert_allclose(model.rewards_.reshape(4, -1), model.weights_ @ F.T)
    assert_non_increasing(model.loss_history_)
    assert model.loss_history_[-1] < model.loss_history_[0]


def test_same_data_same_result(data):
    mdp, _, demos = data
    a = fo.GradIRL(max_iter=10).fit(mdp, demos)
    b = fo.GradIRL(max_iter=10).fit(mdp, demos)
    np.testing.assert_array_equal(a.rewards_, b.rewards_)
    assert a.loss_history_ == b.loss_history_


def test_max_iter_zero_keeps_zero_rewards(data):
    mdp, _, demos = data
    model = fo.GradIRL(max_iter=0).fit(mdp, demos)
    np.testing.assert_array_equal(model.rewards_, 0.0)
    assert len(model.loss_history_) == 1


def test_solver_given_as_object_and_options(data):
    mdp, _, demos = data
    a = fo.GradIRL(max_iter=5, solver="armijo", solver_options={"initial_step": 0.5}).fit(mdp, demos)
    import solvers

    b = fo.GradIRL(max_iter=5, solver=solvers.ArmijoSolver(initial_step=0.5)).fit(mdp, demos)
    np.testing.assert_array_equal(a.rewards_, b.rewards_)


@pytest.mark.parametrize(
    "kwargs, error, fragment",
    [
        (dict(beta=0.0), ValidationError, r"beta must be a finite number > 0; got 0\.0"),
        (dict(beta=-2), ValidationError, r"beta must be a finite number > 0; got -2"),
        (dict(max_iter=-1), ValidationError, r"max_iter must be an integer >= 0; got -1"),
        (dict(max_iter=2.5), ValidationError, r"max_iter must be an integer >= \d; got 2\.5"),
        (dict(tol=-1e-3), ValidationError, r"tol must be a finite number >= 0; got -0\.001"),
        (dict(tol="small"), ValidationError, r"tol must be a finite number >= 0; got 'small'"),
        (dict(features=np.ones((35, 2))), ValidationError, r"features must have shape \(S\*A = 36 or S = 9, p\) with p >= 1; got \(35, 2\)"),
        (dict(features=np.ones(36)), ValidationError, r"\(36,\)"),
        (dict(features=np.ones((36, 0))), ValidationError, r"got \(36, 0\)"),
        (dict(features=np.full((36, 2), np.nan)), ValidationError, r"features must be finite"),
        (dict(solver="newton-raphson"), UnknownSolverError, r"unknown solver 'newton-raphson'; available: .*armijo"),
        (dict(solver=3), ValidationError, r"h_solver must be a registered solver name or a solvers.StepSolver; got 3"),
    ],
)
def test_validation(data, kwargs, error, fragment):
    mdp, _, demos = data
    with pytest.raises(error, match=fragment):
        fo.GradIRL(**kwargs).fit(mdp, demos)


def test_fit_needs_an_mdp(data):
    _, _, demos = data
    with pytest.raises(ValidationError, match="mdp must be a TabularMDP"):
        fo.GradIRL().fit("grid", demos)


def test_first_step_stall_allows_a_few_ulps_of_rounding_only():
    from factirl_opt.learners.fitting import first_step_stall

    h0 = 2.7725887222397803
    assert first_step_stall([h0, np.nextafter(h0, 0)], 1) is not None  # one ulp: nothing moved
    assert first_step_stall([h0, h0 - 2 * np.spacing(h0)], 1) is not None
    assert first_step_stall([h0, h0 - 1e-12], 1) is None  # a real (tiny) decrease
    assert first_step_stall([h0, np.nextafter(h0, 0)], 2) is None  # only the first iteration counts
    assert first_step_stall([h0, np.nextafter(h0, 0)], 1, held=True) is None
    assert first_step_stall([0.0, 0.0], 1) is not None

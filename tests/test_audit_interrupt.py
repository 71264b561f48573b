"""Audit: interrupted fits at points the other tests do not reach, and what can be done with them.

A partial fit is usable: it can be saved, loaded and transferred from, also when the interrupt
came before some tasks were ever evaluated (their loss is NaN). An interrupt between the end
of the flat start and the shrinking (in the PCA itself) must not lose the flat fit.
"""

import warnings

import numpy as np
import pytest

import factirl_opt as fo
import factirl_opt.learners.start as start_module
import factirl_opt.tasks.basis as basis_module
from factirl_opt.learners.dictionary import feature_weights
from factirl_opt.learners.start import FLAT_SOLVER
from factirl_opt.exceptions import FitInterrupted, InterruptedFitWarning
from factirl_opt.objectives import Objective


@pytest.fixture
def data(rng, grid3):
    D = fo.random_dictionary(36, 2, rng)
    H = fo.random_coefficients(4, 2, rng=rng)
    return grid3, fo.sample_demonstrations(grid3, fo.task_rewards(D, H, 9, 4), 3, 5, rng)


def interrupt_call(monkeypatch, owner, name, at):
    original = getattr(owner, name)
    calls = [0]

    def wrapped(*args, **kwargs):
        calls[0] += 1
        if calls[0] == at:
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(owner, name, wrapped)


def fit_interrupted(fit, *args):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InterruptedFitWarning)
        with pytest.raises(FitInterrupted):
            fit(*args)


@pytest.mark.parametrize("learner, at", [("gradirl", 1), ("factirl", 1), ("factirl", 3), ("factirl-random", 1)])
def test_a_fit_interrupted_before_every_task_was_evaluated_saves_and_loads(monkeypatch, data, tmp_path, learner, at):
    mdp, demos = data
    model = {"gradirl": fo.GradIRL(max_iter=5), "factirl": fo.FactIRL(n_primitives=2, max_iter=3, rng=0),
             "factirl-random": fo.FactIRL(n_primitives=2, max_iter=3, init="random", rng=0)}[learner]
    interrupt_call(monkeypatch, Objective, "loss_and_grad", at)
    fit_interrupted(model.fit, mdp, demos)
    monkeypatch.undo()
    assert model.stop_reason_ == "interrupted" and np.all(np.isfinite(model.rewards_))
    path = fo.save_model(model, tmp_path / "partial.npz")
    loaded = fo.load_model(path)
    assert loaded.stop_reason_ == "interrupted"
    np.testing.assert_array_equal(loaded.rewards_, model.rewards_)
    np.testing.assert_array_equal(np.isnan(loaded.loss_), np.isnan(model.loss_))
    if learner != "gradirl":
        np.testing.assert_array_equal(loaded.transfer(mdp, demos[:1]), model.transfer(mdp, demos[:1]))


def test_an_interrupted_transfer_saves_and_loads(monkeypatch, data, tmp_path):
    mdp, demos = data
    model = fo.FactIRL(n_primitives=2, max_iter=2, rng=0).fit(mdp, demos)
    interrupt_call(monkeypatch, Objective, "loss_and_grad", 1)
    fit_interrupted(model.transfer, mdp, demos[:2])
    monkeypatch.undo()
    assert model.transfer_stop_reason_ == "interrupted"
    loaded = fo.load_model(fo.save_model(model, tmp_path / "m.npz"))
    np.testing.assert_array_equal(loaded.transfer_coefficients_, model.transfer_coefficients_)


def test_nan_losses_are_still_refused_for_a_finished_fit(data, tmp_path):
    mdp, demos = data
    model = fo.GradIRL(max_iter=2).fit(mdp, demos)
    model.loss_ = np.full_like(model.loss_, np.nan)
    with pytest.raises(fo.exceptions.PersistenceError, match="loss_ must be finite"):
        fo.save_model(model, tmp_path / "m.npz")


def test_infinite_losses_are_refused_for_an_interrupted_fit(data, tmp_path):
    mdp, demos = data
    model = fo.GradIRL(max_iter=2).fit(mdp, demos)
    model.stop_reason_ = "interrupted"
    model.loss_ = np.full_like(model.loss_, np.inf)
    with pytest.raises(fo.exceptions.PersistenceError, match="loss_ must be finite"):
        fo.save_model(model, tmp_path / "m.npz")


@pytest.mark.parametrize("where", ["pca_dictionary", "least_squares_weights"])
def test_an_interrupt_in_the_pca_keeps_the_pca_start(monkeypatch, data, where):
    mdp, demos = data
    features = None if where == "pca_dictionary" else np.eye(36)[:, :30]
    model = fo.FactIRL(n_primitives=2, max_iter=3, flat_max_iter=5, features=features, rng=0)
    interrupt_call(monkeypatch, start_module if where == "pca_dictionary" else basis_module, where, 1)
    try:
        fit_interrupted(model.fit, mdp, demos)
    except KeyboardInterrupt:  # not FitInterrupted: nothing kept (caught, or pytest itself would stop)
        pytest.fail("a plain KeyboardInterrupt escaped FactIRL.fit: the flat fit is lost")
    assert model.stop_reason_ == "interrupted" and model.dictionary_.shape[1] == 2
    assert model.n_iter_ == 0 and np.all(np.isnan(model.loss_)) and model.loss_history_ == []
    monkeypatch.undo()  # the kept state is the PCA start of the whole flat fit (GradIRL's), before the shrinking
    start = fo.Start()  # the start's flat fit: FLAT_SOLVER, its tolerance and saturation rule, no gradient rule
    flat = fo.GradIRL(max_iter=5, features=features, solver=FLAT_SOLVER, tol=start.flat_tol, stol=start.flat_stol,
                      gtol=0.0).fit(mdp, demos).rewards_.reshape(len(demos), -1)
    D, H = fo.pca_dictionary(flat, 2, np.random.default_rng(0))
    np.testing.assert_allclose(model.dictionary_, D if features is None else feature_weights(features, D),
                               rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(model.coefficients_, H, rtol=1e-12, atol=1e-12)

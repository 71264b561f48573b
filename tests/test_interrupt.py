"""Ctrl-C during a fit keeps the best point seen, warns, and still propagates."""

import signal

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import FitInterrupted, InterruptedFitWarning
from factirl_opt.objectives import Objective
from factirl_opt.learners.start import FLAT_SOLVER

K = 2


@pytest.fixture
def data(rng, grid3):
    D = fo.random_dictionary(36, K, rng)
    H = fo.random_coefficients(5, K, rng=rng)
    return grid3, fo.sample_demonstrations(grid3, fo.task_rewards(D, H, 9, 4), 4, 6, rng)


class Recorder:
    """Wraps ``Objective.loss_and_grad``: records every task's (loss, rewards), raises at call ``stop_at``."""

    def __init__(self, monkeypatch, stop_at=None):
        self.calls, self.stop_at, self.seen = 0, stop_at, {}
        original = Objective.loss_and_grad
        recorder = self

        def loss_and_grad(obj, rewards, rows=None):
            recorder.calls += 1
            if recorder.calls == recorder.stop_at:
                raise KeyboardInterrupt
            loss, grad = original(obj, rewards, rows)
            for j, i in enumerate(np.arange(obj.n_tasks) if rows is None else np.asarray(rows)):
                recorder.seen.setdefault(int(i), []).append((float(loss[j]), np.array(rewards[j])))
            return loss, grad

        monkeypatch.setattr(Objective, "loss_and_grad", loss_and_grad)

    def best(self, task):
        losses = [loss for loss, _ in self.seen[task]]
        return self.seen[task][int(np.argmin(losses))]


def interrupted(fit, *args, **kwargs):
    """Run ``fit``; check it raised a KeyboardInterrupt and warned that it was interrupted."""
    with pytest.warns(InterruptedFitWarning, match="interrupted"), pytest.raises(KeyboardInterrupt) as info:
        fit(*args, **kwargs)
    assert isinstance(info.value, FitInterrupted)
    return info.value


def count_evaluations(monkeypatch, fit):
    rec = Recorder(monkeypatch)
    fit()
    monkeypatch.undo()
    return rec.calls


@pytest.mark.parametrize("seed", range(5))
def test_gradirl_keeps_every_tasks_best_point_at_a_random_interrupt(monkeypatch, data, seed):
    mdp, demos = data
    total = count_evaluations(monkeypatch, lambda: fo.GradIRL(max_iter=30).fit(mdp, demos))
    stop = int(np.random.default_rng(seed).integers(2, total))
    rec = Recorder(monkeypatch, stop)
    model = fo.GradIRL(max_iter=30)
    interrupted(model.fit, mdp, demos)
    assert model.status_ == model.stop_reason_ == "interrupted"
    assert model.loss_history_ and model.n_iter_ == len(model.loss_history_) - 1
    for i in range(len(demos)):
        loss, rewards = rec.best(i)
        assert model.loss_[i] == loss
        np.testing.assert_array_equal(model.rewards_[i], rewards)
    np.testing.assert_array_equal(model.rewards_, model.weights_.reshape(-1, 9, 4))
    assert np.sum(model.loss_) <= min(model.loss_history_)


@pytest.mark.parametrize("seed", range(5))
def test_factirl_keeps_the_best_outer_point_at_a_random_interrupt(monkeypatch, data, seed):
    mdp, demos = data
    make = lambda: fo.FactIRL(n_primitives=K, init="random", max_iter=6, rng=0)  # noqa: E731
    total = count_evaluations(monkeypatch, lambda: make().fit(mdp, demos))
    stop = int(np.random.default_rng(seed).integers(2, total))
    Recorder(monkeypatch, stop)
    model = make()
    interrupted(model.fit, mdp, demos)
    monkeypatch.undo()
    assert model.status_ == model.stop_reason_ == "interrupted"
    assert model.n_iter_ == len(model.loss_history_) - 1
    assert np.sum(model.loss_) == min(model.loss_history_)
    np.testing.assert_allclose(model.rewards_, fo.task_rewards(model.dictionary_, model.coefficients_, 9, 4), rtol=1e-15)
    mu, pi = fo.empirical_statistics(mdp, demos)
    np.testing.assert_allclose(model.loss_, fo.policy_matching_loss(mdp, model.rewards_, mu, pi, 5.0)[0], rtol=1e-9)


def test_factirl_interrupted_at_its_start_keeps_the_start(monkeypatch, data):
    mdp, demos = data
    D0, H0 = np.linalg.qr(np.random.default_rng(0).standard_normal((36, K)))[0], np.full((5, K), 0.1)
    Recorder(monkeypatch, 1)
    model = fo.FactIRL(n_primitives=K, init=(D0, H0))
    interrupted(model.fit, mdp, demos)
    assert model.loss_history_ == [] and model.n_iter_ == 0 and np.all(np.isnan(model.loss_))
    np.testing.assert_array_equal(model.coefficients_ @ model.dictionary_.T, H0 @ D0.T)


def test_factirl_interrupted_in_its_flat_start_keeps_the_pca_of_the_flat_fit(monkeypatch, data):
    mdp, demos = data
    Recorder(monkeypatch, 6)
    start = fo.Start()  # the flat fit of FactIRL's start: its solver, tolerance and saturation rule, no gradient rule
    flat = fo.GradIRL(max_iter=10, solver=FLAT_SOLVER, tol=start.flat_tol, stol=start.flat_stol, gtol=0.0)
    interrupted(flat.fit, mdp, demos)
    monkeypatch.undo()
    Recorder(monkeypatch, 6)
    model = fo.FactIRL(n_primitives=K, flat_max_iter=10)
    exc = interrupted(model.fit, mdp, demos)
    D, H = fo.pca_dictionary(flat.rewards_.reshape(5, -1), K)
    np.testing.assert_array_equal(model.dictionary_, D)
    np.testing.assert_array_equal(model.coefficients_, H)
    np.testing.assert_array_equal(model.rewards_, fo.task_rewards(D, H, 9, 4))
    assert model.status_ == "interrupted" and model.n_iter_ == 0 and np.all(np.isnan(model.loss_))
    assert exc.result.dictionary is model.dictionary_


def test_factirl_interrupted_while_shrinking_keeps_the_best_scale(monkeypatch, data):
    mdp, demos = data
    flat = fo.GradIRL(max_iter=10).fit(mdp, demos)
    Recorder(monkeypatch, 2)  # the unscaled start is evaluated, the halved trial is interrupted
    model = fo.FactIRL(n_primitives=K, pca_shrink=True)
    interrupted(model.fit, mdp, demos, flat_rewards=flat.rewards_)
    monkeypatch.undo()
    D, H = fo.pca_dictionary(flat.rewards_.reshape(5, -1), K)
    np.testing.assert_array_equal(model.coefficients_, H)
    mu, pi = fo.empirical_statistics(mdp, demos)
    np.testing.assert_array_equal(model.loss_, fo.policy_matching_loss(mdp, fo.task_rewards(D, H, 9, 4), mu, pi, 5.0)[0])
    assert model.loss_history_ == [float(np.sum(model.loss_))]


@pytest.mark.parametrize("seed", range(3))
def test_transfer_keeps_every_new_tasks_best_coefficients(monkeypatch, data, seed):
    mdp, demos = data
    model = fo.FactIRL(n_primitives=K, init="random", max_iter=3, rng=0).fit(mdp, demos)
    fitted = model.dictionary_.copy()
    total = count_evaluations(monkeypatch, lambda: model.transfer(mdp, demos[:3], max_iter=20))
    rec = Recorder(monkeypatch, int(np.random.default_rng(seed).integers(2, total)))
    interrupted(model.transfer, mdp, demos[:3], max_iter=20)
    assert model.transfer_status_ == model.transfer_stop_reason_ == "interrupted"
    for i in range(3):
        loss, rewards = rec.best(i)
        assert model.transfer_loss_[i] == loss
        np.testing.assert_allclose(model.transfer_rewards_[i], rewards, rtol=1e-14, atol=1e-15)  # batch vs row product
    np.testing.assert_array_equal(model.dictionary_, fitted)  # the fitted state is untouched
    assert model.status_ != "interrupted"


@pytest.mark.parametrize("learner", ["gradirl", "factirl"])
def test_a_callback_raising_keyboardinterrupt_keeps_the_fit(data, learner):
    mdp, demos = data

    def stop_at_3(iteration, loss):
        if iteration == 3:
            raise KeyboardInterrupt

    model = (fo.GradIRL(max_iter=20, callback=stop_at_3) if learner == "gradirl"
             else fo.FactIRL(n_primitives=K, max_iter=20, flat_max_iter=5, callback=stop_at_3))
    interrupted(model.fit, mdp, demos)
    assert model.n_iter_ == 3 and len(model.loss_history_) == 4
    assert model.status_ == "interrupted" and model.rewards_.shape == (5, 9, 4)


def test_a_real_sigint_keeps_the_fit(data):
    mdp, demos = data

    def sigint_at_2(iteration, loss):
        if iteration == 2:
            signal.raise_signal(signal.SIGINT)  # the default handler raises KeyboardInterrupt here

    model = fo.GradIRL(max_iter=20, callback=sigint_at_2)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # ignored in a shell's background job
    try:
        interrupted(model.fit, mdp, demos)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert model.status_ == "interrupted" and model.n_iter_ == 2
    assert np.all(np.isfinite(model.rewards_)) and np.sum(model.loss_) <= min(model.loss_history_)


def test_fit_factorial_raises_fitinterrupted_with_its_result(monkeypatch, data):
    mdp, demos = data
    D0 = np.linalg.qr(np.random.default_rng(1).standard_normal((36, K)))[0]
    Recorder(monkeypatch, 12)
    with pytest.raises(FitInterrupted) as info:
        fo.fit_factorial(mdp, demos, D0, np.full((5, K), 0.1), max_iter=10)
    fit = info.value.result
    assert isinstance(fit, fo.learners.factirl.FactorialFit) and fit.status == "interrupted"
    assert np.sum(fit.loss) == min(fit.loss_history)


@pytest.mark.parametrize("n_jobs", [1, 2])
def test_an_unevaluated_start_kept_at_an_interrupt_says_so(monkeypatch, data, n_jobs):
    mdp, demos = data
    Recorder(monkeypatch, 3)  # in the flat start (in the driver's own shard with n_jobs=2)
    model = fo.FactIRL(n_primitives=K, flat_max_iter=10, n_jobs=n_jobs)
    with pytest.warns(InterruptedFitWarning, match=r"kept the start \(its loss was not evaluated before the interrupt: "
                                                   r"loss_ is NaN\)") as record, pytest.raises(FitInterrupted):
        model.fit(mdp, demos)
    assert not any("nan" in str(w.message) for w in record)
    assert model.n_iter_ == 0 and np.all(np.isnan(model.loss_)) and np.all(np.isfinite(model.dictionary_))


def test_the_kept_loss_is_described_plainly():
    from factirl_opt.interruption import loss_phrase

    assert loss_phrase(np.array([1.0, 2.0])) == "total loss 3"
    assert loss_phrase(np.array([1.0, np.nan, 2.0])) == ("total loss 3 over the 2 tasks evaluated; loss_ is NaN for the "
                                                         "1 tasks never evaluated")
    assert loss_phrase(np.full(3, np.nan)) == "its loss was not evaluated before the interrupt: loss_ is NaN"


@pytest.mark.parametrize("make", [lambda: fo.GradIRL(max_iter=3), lambda: fo.FactIRL(n_primitives=K, max_iter=2)])
def test_a_finished_fit_leaves_no_reference_cycle(data, make):
    """The Ctrl-C tracker wraps the problem's functions without a cycle back to them: a fitted model's
    objective, environment and planner caches go when its last reference does, not at the next full
    garbage collection."""
    import gc
    import weakref

    _, demos = data
    mdp = fo.GridWorld(size=3, p_success=0.7, gamma=0.9)  # the fit's own environment, referenced by nothing else
    gc.collect()
    gc.disable()
    try:
        model = make().fit(mdp, demos)
        if isinstance(model, fo.FactIRL):
            model.transfer(mdp, demos[:1])
        alive = weakref.ref(mdp)
        del model, mdp
        assert alive() is None
        gc.set_debug(gc.DEBUG_SAVEALL)  # what the collector would have had to free (other threads' cycles aside)
        gc.collect()
        # the fit's objective, problem, tracker and solver (a sparse planner left by an earlier test in the
        # same process can still turn up here: its own cycle is not this test's)
        left = [type(o).__name__ for o in gc.garbage
                if type(o).__module__.startswith(("factirl_opt.objectives", "factirl_opt.interruption", "solvers"))
                or isinstance(o, fo.TabularMDP)]
        assert left == []
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
        gc.enable()

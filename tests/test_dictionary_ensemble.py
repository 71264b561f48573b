"""The dictionary ensemble and the misfit noise level of the transfer posterior (factirl_opt.learners.dictionary_ensemble)."""

import copy
import dataclasses

import numpy as np
import pytest

import factirl_opt as fo
from helpers import transfer_tasks_on_a_grid
from factirl_opt.exceptions import ValidationError
from factirl_opt.learners.dictionary_ensemble import dictionary_ensemble, resampled_tasks
from factirl_opt.learners import posterior as posterior_module
from factirl_opt.learners.noise_levels import noise_reference
from factirl_opt.learners.posterior import member_posteriors
from factirl_opt.learners.transfer_likelihood import repeated_problem, transfer_problem

pytestmark = pytest.mark.filterwarnings("ignore::factirl_opt.exceptions.MaxIterWarning")  # short fits


@pytest.fixture(scope="module")
def tasks():
    return transfer_tasks_on_a_grid(4, 10, 3, 8, rng=5)


def _fit(tasks, **params):
    mdp, train, test = tasks
    params = {"rng": 0, **params}
    model = fo.FactIRL(n_primitives=2, max_iter=4, transfer_max_iter=20, **params).fit(mdp, train.demos)
    model.transfer(mdp, test.demos)
    return model


def test_resampled_tasks_bootstrap_and_folds():
    boots = resampled_tasks(10, 4, "bootstrap", 0)
    assert len(boots) == 4 and all(b.shape == (10,) and b.min() >= 0 and b.max() < 10 for b in boots)
    assert any(np.unique(b).size < 10 for b in boots)  # with replacement
    folds = resampled_tasks(10, 3, "folds", 0)
    left_out = np.concatenate([np.setdiff1d(np.arange(10), f) for f in folds])
    np.testing.assert_array_equal(np.sort(left_out), np.arange(10))  # every task held out exactly once
    for a, b in zip(resampled_tasks(10, 3, "folds", 1), resampled_tasks(10, 3, "folds", 1)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("args, match", [((1, 2, "bootstrap"), "n_tasks"), ((5, 0, "bootstrap"), "n_dictionaries"),
                                         ((5, 1, "folds"), "at least 2"), ((5, 2, "jackknife"), "resampling must be")])
def test_resampled_tasks_refuses(args, match):
    with pytest.raises(ValidationError, match=match):
        resampled_tasks(*args, rng=0)


@pytest.mark.parametrize("params, match", [({"posterior": fo.PosteriorSettings(n_dictionaries=-1)}, "n_dictionaries"),
                                           ({"posterior": fo.PosteriorSettings(resampling="jackknife")}, "resampling"),
                                           ({"posterior": fo.PosteriorSettings(noise="gaussian")}, "noise"),
                                           ({"posterior": fo.PosteriorSettings(n_dictionaries=1, resampling="folds")},
                                            "folds"),
                                           ({"posterior": "bootstrap"}, "PosteriorSettings"),
                                           ({"posterior": fo.PosteriorSettings(noise="misfit"), "objective": "mce"},
                                            "noise_levels_")])
def test_fit_refuses_bad_posterior_settings(tasks, params, match):
    mdp, train, test = tasks
    model = fo.FactIRL(n_primitives=2, max_iter=2, rng=0, **params)
    if params.get("objective") == "mce":  # fits (MCE has no misfit level), and says so when the posterior is built
        model.fit(mdp, train.demos)
        assert not hasattr(model, "noise_levels_")
        model.transfer(mdp, test.demos)
        with pytest.raises(ValidationError, match=match):
            model.transfer_posterior_
        return
    with pytest.raises(ValidationError, match=match):
        model.fit(mdp, train.demos)


def test_fit_stores_the_ensemble_and_the_noise_levels(tasks):
    model = _fit(tasks, posterior=fo.PosteriorSettings(n_dictionaries=3))
    p, k = model.dictionary_.shape
    assert model.dictionary_ensemble_.shape == (3, p, k)
    assert model.ensemble_prior_means_.shape == (3, k) and model.ensemble_prior_precisions_.shape == (3, k, k)
    assert model.noise_levels_.shape == (10,) and np.all(model.noise_levels_ >= 0)
    posts = model.transfer_posterior_
    assert all(q.n_dictionaries == 4 and len(q.members) == 3 for q in posts)
    assert all(m.mean.shape == (k,) and m.dictionary is not q.dictionary for q in posts for m in q.members)
    model.set_params(posterior=fo.PosteriorSettings(n_dictionaries=0)).fit(tasks[0], tasks[1].demos)  # a refit without: no stale ensemble
    assert not hasattr(model, "dictionary_ensemble_")
    model.set_params(objective="mce", max_iter=1).fit(tasks[0], tasks[1].demos)  # nor stale noise levels
    assert not hasattr(model, "noise_levels_")


def test_marginal_sampling_mixes_the_dictionaries_and_is_reproducible(tasks):
    a, b = _fit(tasks, posterior=fo.PosteriorSettings(n_dictionaries=2)), _fit(tasks, posterior=fo.PosteriorSettings(n_dictionaries=2))
    np.testing.assert_array_equal(a.dictionary_ensemble_, b.dictionary_ensemble_)  # same rng, same ensemble
    pa, pb = a.transfer_posterior_[0], b.transfer_posterior_[0]
    np.testing.assert_array_equal(pa.sample_regrets(9, 3), pb.sample_regrets(9, 3))
    R = pa.sample_rewards(9, 3)
    assert pa.member_counts(9) == [3, 3, 3] and pa.member_counts(10) == [4, 3, 3]
    gen = np.random.default_rng(3)
    parts = [q.rewards(q.sample(3, gen)) for q in (pa, *pa.members)]
    np.testing.assert_array_equal(R, np.concatenate(parts))
    np.testing.assert_array_equal(pa.sample_rewards(9, 3, marginal=False), pa.sample_rewards(9, 3, marginal=False))
    assert not np.array_equal(pa.sample_rewards(9, 3, marginal=False), R)
    c = _fit(tasks, posterior=fo.PosteriorSettings(n_dictionaries=2), rng=1)
    assert not np.array_equal(a.dictionary_ensemble_, c.dictionary_ensemble_)


def test_folds_ensemble_fits_on_all_but_one_fold(tasks):
    mdp, train, _ = tasks
    model = _fit(tasks)
    Ds, means, precisions = dictionary_ensemble(model, mdp, train.demos, 2, "folds", rng=0)
    idx = resampled_tasks(10, 2, "folds", 0)
    refit = fo.FactIRL(n_primitives=2, max_iter=4, transfer_max_iter=20, rng=0).fit(mdp, [train.demos[i] for i in idx[0]])
    np.testing.assert_allclose(Ds[0], refit.dictionary_, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(means[0], refit.coefficients_.mean(axis=0), rtol=1e-10, atol=1e-12)


def test_misfit_noise_widens_a_badly_explained_task(tasks):
    model = _fit(tasks)
    base = model.transfer_posterior_
    ref = noise_reference(model.set_params(posterior__noise="misfit"))
    assert ref == pytest.approx(float(np.median(model.noise_levels_)))
    model.transfer(tasks[0], tasks[2].demos)
    noisy = model.transfer_posterior_
    for q0, q1 in zip(base, noisy):
        np.testing.assert_array_equal(q0.mean, q1.mean)  # the mean stays the MAP
        assert q1.scaling != q0.scaling
        # the covariance is the precision's inverse at the new scale: wider where the ratio is above 1
        wider = q1.scaling < q0.scaling
        assert (np.trace(q1.covariance) > np.trace(q0.covariance)) == wider


def test_noise_reference_needs_noise_levels(tasks):
    model = _fit(tasks, posterior=fo.PosteriorSettings(noise="misfit"))
    del model.noise_levels_
    with pytest.raises(ValidationError, match="noise_levels_"):
        noise_reference(model)
    assert noise_reference(model.set_params(posterior__noise="multinomial")) is None


def test_auto_model_refits_its_chosen_pair(tasks):
    mdp, train, test = tasks
    model = fo.FactIRL(n_primitives="auto", max_iter=2, rng=0, posterior=fo.PosteriorSettings(n_dictionaries=2)).fit(mdp, train.demos)
    assert model.posterior == fo.PosteriorSettings(n_dictionaries=2)  # restored after the search
    assert model.dictionary_ensemble_.shape == (2, *model.dictionary_.shape)


def test_ensemble_and_noise_levels_persist(tasks, tmp_path):
    model = _fit(tasks, posterior=fo.PosteriorSettings(n_dictionaries=2, noise="misfit"))
    loaded = fo.load_model(fo.save_model(model, tmp_path / "m.npz"))
    for name in ("dictionary_ensemble_", "ensemble_prior_means_", "ensemble_prior_precisions_", "noise_levels_"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(model, name))
    assert loaded.posterior == fo.PosteriorSettings(n_dictionaries=2, noise="misfit")
    loaded.transfer(tasks[0], tasks[2].demos)
    np.testing.assert_array_equal(loaded.transfer_posterior_[0].sample_regrets(6, 2),
                                  model.transfer_posterior_[0].sample_regrets(6, 2))


def test_saved_posterior_keeps_its_members(tasks, tmp_path):
    from factirl_opt.persistence.posterior import posterior_arrays, posteriors_from_arrays

    model = _fit(tasks, posterior=fo.PosteriorSettings(n_dictionaries=2))
    posts = model.transfer_posterior_
    loaded = fo.load_model(fo.save_model(model, tmp_path / "m.npz"))
    for a, b in zip(loaded.transfer_posterior_, posts):  # the posterior as saved, before any new transfer
        assert len(a.members) == 2
        np.testing.assert_array_equal(a.sample_regrets(8, 4), b.sample_regrets(8, 4))
    spec, arrays = posterior_arrays(posts)
    with pytest.raises(ValidationError, match="members"):
        posteriors_from_arrays(spec, {**arrays, "members/mean": arrays["members/mean"][:, :1]})
    with pytest.raises(ValidationError, match="incomplete"):
        posteriors_from_arrays(spec, {k: v for k, v in arrays.items() if k != "members/scaling"})


def test_a_given_start_is_resampled_with_its_tasks(tasks):
    mdp, train, _ = tasks
    start = fo.FactIRL(n_primitives=2, max_iter=3, rng=0).fit(mdp, train.demos)
    model = fo.FactIRL(n_primitives=2, max_iter=3, rng=0, posterior=fo.PosteriorSettings(n_dictionaries=2),
                       start=fo.Start(init=(start.dictionary_, start.coefficients_))).fit(mdp, train.demos)
    assert model.dictionary_ensemble_.shape == (2, *model.dictionary_.shape)


@pytest.mark.parametrize("params", [{}, {"posterior__noise": "misfit"}, {"residual_penalty": 0.5},
                                    {"objective": "mce"}])
@pytest.mark.parametrize("batch_rows", [64, 8, 16])
def test_batched_members_are_the_members_one_at_a_time(tasks, params, batch_rows, monkeypatch):
    # every (member, task) pair iterated in one problem, or whole members per batch, gives each
    # member's posterior as its own laplace_posteriors call does
    params = dict(params)
    posterior = fo.PosteriorSettings(n_dictionaries=3, noise=params.pop("posterior__noise", "multinomial"))
    model = _fit(tasks, posterior=posterior, **params)
    monkeypatch.setattr(posterior_module, "MEMBER_BATCH_ROWS", batch_rows)
    mdp, _, test = tasks
    problem = transfer_problem(model, mdp, test.demos)
    conditional = [copy.copy(q) for q in model.transfer_posterior_]
    one, each = ([copy.copy(q) for q in conditional] for _ in range(2))
    reference = noise_reference(model)
    member_posteriors(model, problem, one, reference, batched=True)
    member_posteriors(model, problem, each, reference, batched=False)
    for q1, q2 in zip(one, each):
        assert len(q1.members) == len(q2.members) == 3
        for b, (m1, m2) in enumerate(zip(q1.members, q2.members)):
            assert m1.dictionary is model.dictionary_ensemble_[b] or np.array_equal(m1.dictionary, model.dictionary_ensemble_[b])
            np.testing.assert_allclose(m1.mean, m2.mean, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(m1.covariance, m2.covariance, rtol=1e-9, atol=1e-14)
            assert m1.scaling == pytest.approx(m2.scaling, rel=1e-12)
    # not vacuous: the members differ from one another and from the conditional posterior
    means = np.array([[m.mean for m in q.members] for q in one])
    assert not np.allclose(means[:, 0], means[:, 1]) and not np.allclose(means[:, 0], np.array([q.mean for q in conditional]))


def test_batched_members_need_the_task_set(tasks):
    model = _fit(tasks, posterior=fo.PosteriorSettings(n_dictionaries=2))
    mdp, _, test = tasks
    problem = transfer_problem(model, mdp, test.demos)
    with pytest.raises(ValidationError, match="task set"):
        repeated_problem(model, dataclasses.replace(problem, tasks=None), model.dictionary_ensemble_)
    # a problem without it: the members one at a time
    posts = member_posteriors(model, dataclasses.replace(problem, tasks=None), [copy.copy(q) for q in model.transfer_posterior_])
    np.testing.assert_allclose(posts[0].members[1].mean, model.transfer_posterior_[0].members[1].mean, rtol=1e-9, atol=1e-12)

"""Audit: threads sharing sparse models give exactly the sequential results.

Variants beyond concurrent fits: sampling, scoring and estimating on one shared sparse model
(built from successor lists), a fitted model transferring from several threads, and saving
the same model to several files at once.
"""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import factirl_opt as fo


def shared_model():
    grid = fo.GridWorld(size=5)
    return fo.mdp.from_successors(*fo.mdp.to_successors(grid), gamma=0.9)


def work(mdp, R, seed):
    demos = fo.sample_demonstrations(mdp, R, 2, 5, rng=seed)
    learnt = R + 0.2 * np.random.default_rng(seed).standard_normal(R.shape)
    return (demos, fo.deviation(mdp, R, learnt, planner="sparse-lu"),
            fo.soft_deviation(mdp, R, learnt, beta=5.0, planner="sparse-lu"),
            fo.optimal_q(mdp, learnt, planner="sparse-lu")[1])


def test_sampling_and_scoring_a_shared_sparse_model_in_threads(rng):
    mdp = shared_model()
    R = rng.normal(size=(3, mdp.n_states, mdp.n_actions))
    sequential = [work(mdp, R, seed) for seed in range(8)]
    with ThreadPoolExecutor(4) as pool:
        threaded = list(pool.map(lambda seed: work(mdp, R, seed), range(8)))
    for seq, thr in zip(sequential, threaded):
        for a, b in zip(seq[0], thr[0]):
            np.testing.assert_array_equal(a, b)
        for a, b in zip(seq[1:], thr[1:]):
            np.testing.assert_array_equal(a, b)


@pytest.fixture
def fitted(rng):
    mdp = shared_model()
    R = rng.normal(size=(3, mdp.n_states, mdp.n_actions))
    demos = fo.sample_demonstrations(mdp, R, 2, 5, rng=1)
    return mdp, demos, fo.FactIRL(n_primitives=2, max_iter=2, flat_max_iter=5, planner="sparse-lu", rng=0).fit(mdp, demos)


def test_save_one_fitted_model_from_threads(fitted, tmp_path):
    mdp, demos, model = fitted
    with ThreadPoolExecutor(4) as pool:
        paths = list(pool.map(lambda i: fo.save_model(model, tmp_path / f"m{i}.npz"), range(6)))
    for path in paths:
        np.testing.assert_array_equal(fo.load_model(path).dictionary_, model.dictionary_)
    assert not [f for f in (p.name for p in tmp_path.iterdir()) if f.startswith(".tmp")]


def test_transfer_does_not_depend_on_what_the_thread_planned_before(fitted):
    mdp, demos, model = fitted
    warm = model.transfer(mdp, demos[:1])  # in the thread whose cache holds the fit's factorisations
    with ThreadPoolExecutor(2) as pool:
        fresh = list(pool.map(lambda _: model.transfer(mdp, demos[:1]), range(2)))
    for h in fresh:
        np.testing.assert_array_equal(h, warm)

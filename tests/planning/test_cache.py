"""The caches: factorisations (bounded, exact hits, per thread), planners per MDP (weak, not on the
MDP), and thread safety (concurrent calls and fits equal to sequential ones)."""

import gc
import sys
import weakref
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt import planning
from factirl_opt._threads import limit_blas_threads
from factirl_opt.planning import cache


def test_factorisation_cache_hits_are_exact_and_bounded(monkeypatch, make_statistics, assert_rel):
    grid = fo.GridWorld(12)
    pl = planning.get_planner(grid, "sparse-lu")
    pl.clear_cache()
    rng = np.random.default_rng(9)
    R = rng.standard_normal((6, grid.n_states, 4))
    mu, pi_hat = make_statistics(rng, grid, 6)
    first = fo.policy_matching_loss(grid, R, mu, pi_hat, planner="sparse-lu")
    _, pol = fo.optimal_q(grid, R, planner="sparse-lu")
    n_cached = len(pl.factor_cache)
    again = fo.policy_matching_loss(grid, R, mu, pi_hat, policy=pol, planner="sparse-lu")
    assert len(pl.factor_cache) == n_cached  # all hits: nothing new factorised
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    # a budget of one group: evictions keep the accounting exact and the results unchanged
    monkeypatch.setattr(cache, "FACTOR_CACHE_BYTES", 1)
    pl.clear_cache()
    bounded = fo.policy_matching_loss(grid, R, mu, pi_hat, planner="sparse-lu")
    assert len(pl.factor_cache.groups) == 1
    base, keys, update = next(iter(pl.factor_cache.groups.values()))
    assert set(pl.factor_cache.entries) == set(keys) | ({update} - {None})
    assert pl.factor_cache.nbytes == base.nbytes + (0 if update is None else pl.factor_cache.entries[update].nbytes)
    for a, b in zip(first, bounded):
        assert_rel(b, a, 1e-12)
    planning.clear_caches(grid)
    assert not pl.factor_cache.entries and pl.factor_cache.nbytes == 0


def test_planners_live_beside_the_mdp_and_go_with_it():
    grid = fo.GridWorld(13)
    fo.optimal_q(grid, np.zeros((grid.n_states, 4)), planner="sparse-lu")
    pl = planning.get_planner(grid, "sparse-lu")
    assert not any(isinstance(v, (dict, planning.Planner)) for v in vars(grid).values())  # nothing hidden on the model
    assert pl.mdp is grid and planning.get_planner(grid, "sparse-lu") is pl
    dead_mdp, dead_planner = weakref.ref(grid), weakref.ref(pl)
    del grid, pl
    gc.collect()
    assert dead_mdp() is None and dead_planner() is None  # the planner does not keep its MDP alive


@pytest.fixture
def racy():
    """Thread switches every microsecond: data races in a cache show up within a few hundred calls."""
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    yield
    sys.setswitchinterval(interval)


def test_concurrent_optimal_q_calls_equal_sequential_ones(racy):
    grid = fo.GridWorld(8)
    rewards = np.random.default_rng(0).standard_normal((40, grid.n_states, 4))[np.arange(1200) % 40]
    sequential = [fo.optimal_q(grid, R, planner="sparse-lu")[0] for R in rewards]
    planning.clear_caches(grid)
    with limit_blas_threads(1), ThreadPoolExecutor(8) as pool:
        concurrent = list(pool.map(lambda R: fo.optimal_q(grid, R, planner="sparse-lu")[0], rewards))
    for got, expected in zip(concurrent, sequential):
        np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("planner", ["sparse-lu", "dense"])
def test_four_concurrent_fits_equal_the_sequential_fits(racy, planner):
    grid = fo.GridWorld(13)
    rng = np.random.default_rng(7)
    R = fo.task_rewards(fo.random_dictionary(grid.n_params, 2, rng), fo.random_coefficients(4, 2, rng=rng), grid.n_states, 4)
    demos = fo.sample_demonstrations(grid, R, 4, 10, rng)

    def fit(seed):
        model = fo.FactIRL(n_primitives=2, max_iter=5, flat_max_iter=8, planner=planner, rng=seed).fit(grid, demos)
        return model.rewards_, model.loss_history_

    sequential = [fit(seed) for seed in range(4)]
    planning.clear_caches(grid)
    with limit_blas_threads(1), ThreadPoolExecutor(4) as pool:
        concurrent = list(pool.map(fit, range(4)))
    for (rewards, history), (rewards_seq, history_seq) in zip(concurrent, sequential):
        np.testing.assert_array_equal(rewards, rewards_seq)
        assert history == history_seq


def test_a_fit_plans_with_caches_of_its_own_whatever_the_thread_planned_before():
    grid = fo.GridWorld(8)
    rng = np.random.default_rng(4)
    demos = fo.sample_demonstrations(grid, rng.standard_normal((3, grid.n_states, 4)), 3, 8, rng)
    pl = planning.get_planner(grid, "sparse-lu")
    pl.clear_cache()
    kw = dict(n_primitives=2, max_iter=4, planner="sparse-lu", rng=0)
    first = fo.FactIRL(**kw).fit(grid, demos)
    assert len(pl.factor_cache) == 0  # the fit's factorisations went with it
    # the thread now caches policies near the fit's: a fit that reused them would differ by round-off
    fo.optimal_q(grid, first.rewards_ + 1e-3 * rng.standard_normal(first.rewards_.shape), planner="sparse-lu")
    assert len(pl.factor_cache) > 0
    again = fo.FactIRL(**kw).fit(grid, demos)
    np.testing.assert_array_equal(again.rewards_, first.rewards_)
    h = [first.transfer(grid, demos[:1]) for _ in range(2)]
    np.testing.assert_array_equal(h[0], h[1])


def test_isolated_blocks_nest_and_leave_the_thread_cache_alone():
    grid = fo.GridWorld(6)
    pl = planning.get_planner(grid, "sparse-lu")
    pl.clear_cache()
    R = np.random.default_rng(1).standard_normal((2, grid.n_states, 4))
    assert cache.scoped_cache(pl) is None  # outside a block: the thread's own cache
    with cache.isolated_caches():
        outer = cache.scoped_cache(pl)
        fo.optimal_q(grid, R, planner="sparse-lu")
        assert pl.factor_cache is outer and len(outer) > 0
        with cache.isolated_caches():
            assert cache.scoped_cache(pl) is outer  # nested: the outermost block's
        pl.clear_thread_cache()
        assert len(outer) == 0
    assert cache.scoped_cache(pl) is None and len(pl.factor_cache) == 0

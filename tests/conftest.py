"""Shared fixtures: a seeded ``rng`` and the ``--runslow`` option for ``@pytest.mark.slow``."""

import os
import sys

import numpy as np
import pytest



def _register_shared_test_modules():
    """Make ``from helpers import ...`` and ``from solver_problems import ...`` work in every test.

    Test modules live in sub-folders mirroring the package and are imported with
    ``--import-mode=importlib``; tests/ is not put on ``sys.path`` (its folder ``solvers/``
    would shadow the ``solvers`` package), so the two shared modules are registered by path.
    """
    import importlib.util

    here = os.path.dirname(os.path.abspath(__file__))
    for name in ("helpers", "solver_problems"):
        if name not in sys.modules:
            spec = importlib.util.spec_from_file_location(name, os.path.join(here, f"{name}.py"))
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            spec.loader.exec_module(module)


_register_shared_test_modules()

import factirl_opt as fo
from helpers import greedy_gap, random_statistics


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", default=False, help="also run tests marked slow")


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: long-running checks, opt-in with --runslow")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--runslow"):
        return
    skip = pytest.mark.skip(reason="slow: pass --runslow to run")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(scope="session", autouse=True)
def _single_threaded_blas():
    """Run the tests with one OpenBLAS thread.

    The library's batched solves are of small matrices; on a loaded 2-core machine a
    multi-threaded OpenBLAS makes them 10-200x slower (spin-wait contention), which only
    adds noise to the test runtime. Restored at the end of the session.
    """
    from factirl_opt._threads import limit_blas_threads

    with limit_blas_threads(1):
        yield


@pytest.fixture
def rng():
    """A seeded Generator: every test sees the same stream, independent of test order."""
    return np.random.default_rng(20140601)


@pytest.fixture
def grid3():
    return fo.GridWorld(size=3, p_success=0.7, gamma=0.9)


@pytest.fixture
def grid4():
    return fo.GridWorld(size=4, p_success=0.7, gamma=0.9)


@pytest.fixture
def random_mdp(rng):
    """A random dense TabularMDP (6 states, 3 actions; rows drawn from a Dirichlet)."""
    P = rng.dirichlet(np.ones(6), size=(6, 3))
    return fo.TabularMDP(P, 0.85)


@pytest.fixture
def make_statistics():
    """Factory ``(rng, mdp, n) -> (mu_hat, pi_hat)`` of random empirical statistics.

    ``mu_hat`` rows on the simplex with state 0 unvisited; ``pi_hat`` rows on the simplex,
    zero in the unvisited state (as :func:`empirical_statistics` produces).
    """
    return random_statistics


@pytest.fixture
def tie_free_rewards():
    """Factory ``(rng, mdp, shape) -> R`` of random rewards whose greedy policy has no
    near-ties (gap > 1e-3, i.e. 1000x the finite-difference step), so Q* is differentiable
    there and a central difference with step 1e-6 never crosses a policy switch."""

    def make(rng, mdp, shape):
        for _ in range(200):
            R = rng.standard_normal(shape)
            if greedy_gap(mdp, R.reshape(-1, mdp.n_states, mdp.n_actions)) > 1e-3:
                return R
        raise RuntimeError("no tie-free reward found")

    return make

"""Memory over repeated fits in one process: nothing a fit or an evaluation leaves holds memory until
the next full garbage collection (a reference cycle), and the resident size stays flat.

Reference: the garbage collector itself. With collection disabled during the run and
``gc.DEBUG_SAVEALL`` set after it, ``gc.collect()`` lists in ``gc.garbage`` every object that only
a collection could have freed; none may be a planner, a factorisation or a sharded objective.
"""

import gc
import os
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.objectives import PolicyMatchingObjective

WATCHED = ("factirl_opt.planning", "factirl_opt.objectives", "factirl_opt.parallel", "factirl_opt.interruption")


def cyclic_garbage(run):
    """The library's objects that ``run()`` left in reference cycles, by type name."""
    gc.collect()
    gc.disable()
    try:
        run()
        gc.set_debug(gc.DEBUG_SAVEALL)
        gc.collect()
        return sorted({type(o).__name__ for o in gc.garbage if type(o).__module__.startswith(WATCHED)
                       or isinstance(o, fo.TabularMDP)})
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
        gc.enable()


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(0)
    mdp = fo.GridWorld(size=8, p_success=0.7, gamma=0.9)
    demos = fo.sample_demonstrations(mdp, rng.standard_normal((4, mdp.n_states, mdp.n_actions)), 4, 6, rng)
    return demos, rng.standard_normal((4, mdp.n_states, mdp.n_actions))


def test_evaluations_with_low_rank_updates_leave_no_planner_in_a_cycle(data):
    # outside a fit the planner's own per-thread cache keeps the factorisations, among them low-rank
    # updates of earlier ones; an update referring back to its planner made a cycle of both
    demos, R = data

    def run():
        mdp = fo.GridWorld(size=8, p_success=0.7, gamma=0.9)
        mu, pi = fo.empirical_statistics(mdp, demos)
        obj = PolicyMatchingObjective(mdp, mu, pi, 5.0, planner="sparse-lu")
        step = np.random.default_rng(1).standard_normal(R.shape)
        for i in range(8):
            obj.loss_and_grad(R + 0.05 * i * step)

    assert cyclic_garbage(run) == []


@pytest.mark.parametrize("n_jobs", [1, 2])
def test_a_fit_leaves_no_planner_or_shards_in_a_cycle(data, n_jobs):
    demos, _ = data

    def run():
        mdp = fo.GridWorld(size=8, p_success=0.7, gamma=0.9)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = fo.FactIRL(n_primitives=2, max_iter=2, planner="sparse-lu", solver="gn-qp-clarabel",
                               n_jobs=n_jobs).fit(mdp, demos)
            model.transfer(mdp, demos[:2])

    assert cyclic_garbage(run) == []

"""Tasks in several environments over shards of whole environments: the n_jobs=1 results."""

import multiprocessing

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.objectives.sharding import sharded
from factirl_opt.objectives.environments import multi_environment_objective
from factirl_opt.objectives.sharded_environments import ShardedEnvironments, deal_groups

TOL = dict(rtol=1e-10, atol=1e-12)


@pytest.fixture(scope="module")
def worlds():
    """Five tasks on grids of 9, 16, 9, 16 and 25 states (equal sizes: the same object); p = 3."""
    g3, g4, g5 = (fo.GridWorld(size=s, p_success=0.7, gamma=0.9) for s in (3, 4, 5))
    mdps = [g3, g4, g3, g4, g5]
    rng = np.random.default_rng(0)
    Phis = [rng.random((m.n_states, 3)) for m in mdps]
    demos = [fo.sample_demonstrations(m, rng.normal(size=(1, m.n_states, 4)), 2, 5, rng=i)[0] for i, m in enumerate(mdps)]
    return mdps, Phis, demos


def test_deal_groups_keeps_environments_whole():
    parts = deal_groups(np.array([0, 1, 0, 1, 2, 0]), 2)
    assert [p.tolist() for p in parts] == [[0, 2, 5], [1, 3, 4]]  # group 0 (3 tasks); groups 1 and 2 (2 + 1)
    assert [p.tolist() for p in deal_groups(np.array([0, 0]), 3)] == [[0, 1]]


def test_sharded_environments_equal_the_objective(worlds):
    mdps, Phis, demos = worlds
    ref = multi_environment_objective(mdps, demos, 5.0)
    rng = np.random.default_rng(1)
    R = [rng.normal(size=(m.n_states, 4)) for m in mdps]
    with sharded(multi_environment_objective(mdps, demos, 5.0), 2) as obj:
        assert isinstance(obj, ShardedEnvironments) and obj.n_shards == 2
        (la, ya), (lb, yb) = ref.loss_and_grad(R), obj.loss_and_grad(R)
        np.testing.assert_allclose(lb, la, **TOL)
        for u, v in zip(ya, yb):
            np.testing.assert_allclose(v, u, **TOL)
        rows = np.array([4, 1, 0])
        lin_a, lin_b = ref.linearize([R[i] for i in rows], rows), obj.linearize([R[i] for i in rows], rows)
        np.testing.assert_allclose(lin_b.residual, lin_a.residual, **TOL)
        dR = [np.ones_like(R[i]) for i in rows]
        np.testing.assert_allclose(lin_b.jvp(dR), lin_a.jvp(dR), **TOL)
        for u, v in zip(lin_a.vjp(lin_a.residual), lin_b.vjp(lin_a.residual)):
            np.testing.assert_allclose(v, u, **TOL)
        assert obj.n_evaluations == ref.n_evaluations


@pytest.mark.parametrize("h_solver", ["gn-qp-clarabel", "gn-cg", "armijo"])
def test_factirl_over_environments_n_jobs_equals_serial(worlds, h_solver):
    mdps, Phis, demos = worlds
    kw = dict(n_primitives=2, max_iter=2, init="random", rng=0, features=Phis, solver=h_solver, d_solver="lbfgs")
    a = fo.FactIRL(**kw).fit(mdps, demos)
    b = fo.FactIRL(n_jobs=2, **kw).fit(mdps, demos)
    for name in ("dictionary_", "coefficients_", "loss_"):
        np.testing.assert_allclose(getattr(b, name), getattr(a, name), **TOL, err_msg=name)
    assert a.n_evaluations_ == b.n_evaluations_
    assert not multiprocessing.active_children()


def test_gradirl_over_environments_n_jobs_equals_serial(worlds):
    mdps, Phis, demos = worlds
    a = fo.GradIRL(features=Phis, max_iter=4, solver="gn-qp-clarabel").fit(mdps, demos)
    b = fo.GradIRL(features=Phis, max_iter=4, solver="gn-qp-clarabel", n_jobs=3).fit(mdps, demos)
    np.testing.assert_allclose(b.weights_, a.weights_, **TOL)
    assert a.n_evaluations_ == b.n_evaluations_


def test_killed_environment_shard_is_rebuilt(worlds):
    import os
    import signal

    mdps, _, demos = worlds
    ref = multi_environment_objective(mdps, demos, 5.0)
    R = [np.full((m.n_states, 4), 0.1 * i) for i, m in enumerate(mdps)]
    obj = ShardedEnvironments(multi_environment_objective(mdps, demos, 5.0), 2)
    try:
        lin = obj.linearize(R)
        proc = obj.shards.handles[1].proc
        os.kill(proc.pid, signal.SIGKILL)
        proc.join()
        for u, v in zip(ref.loss_and_grad(R)[1], obj.loss_and_grad(R)[1]):
            np.testing.assert_allclose(v, u, **TOL)
        dR = [np.ones_like(r) for r in R]
        np.testing.assert_allclose(lin.jvp(dR), ref.linearize(R).jvp(dR), **TOL)
        assert obj.shards.n_restarts == 1
    finally:
        obj.close()

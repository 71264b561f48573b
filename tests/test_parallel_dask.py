"""Task shards on a Dask LocalCluster: a fit equals the local one, and a killed worker is recovered.

Reference: the same objective or fit without Dask (``n_jobs=1``). A rebuilt shard plans from
scratch (no warm start), so after a worker is killed the results agree to rounding.
"""

import os
import time

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError, WorkersLost
from factirl_opt.objectives import PolicyMatchingObjective
from factirl_opt.objectives.distributed import ShardedObjective

distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(2)
    mdp = fo.GridWorld(size=5, p_success=0.7, gamma=0.9)
    demos = fo.sample_demonstrations(mdp, rng.standard_normal((6, mdp.n_states, mdp.n_actions)), 4, 6, rng)
    return mdp, demos, rng.random((25, 4))


@pytest.mark.parametrize("h_solver", ["gn-qp-clarabel", "gn-cg"])
def test_factirl_on_local_cluster_equals_local_fit(client, data, h_solver):
    mdp, demos, F = data
    kw = dict(n_primitives=2, max_iter=3, init="random", rng=0, planner="sparse-lu", features=F, solver=h_solver,
              d_solver="lbfgs")
    a = fo.FactIRL(**kw).fit(mdp, demos)
    client.wait_for_workers(2)
    b = fo.FactIRL(backend="dask", client=client, **kw).fit(mdp, demos)
    for name in ("dictionary_", "coefficients_", "loss_"):
        np.testing.assert_allclose(getattr(b, name), getattr(a, name), rtol=1e-10, atol=1e-12, err_msg=name)
    assert a.n_evaluations_ == b.n_evaluations_


def test_gradirl_on_local_cluster_equals_local_fit(client, data):
    mdp, demos, _ = data
    a = fo.GradIRL(max_iter=4).fit(mdp, demos)
    b = fo.GradIRL(max_iter=4, backend="dask", client=client, n_jobs=3).fit(mdp, demos)
    np.testing.assert_allclose(b.weights_, a.weights_, rtol=1e-10, atol=1e-12)
    assert a.n_evaluations_ == b.n_evaluations_


def test_killed_worker_is_recovered(client, data):
    mdp, demos, _ = data
    mu, pi = fo.empirical_statistics(mdp, demos)
    R = np.random.default_rng(4).standard_normal((6, mdp.n_states, mdp.n_actions))
    ref = PolicyMatchingObjective(mdp, mu, pi, 5.0, planner="sparse-lu")
    client.wait_for_workers(2)  # a worker killed by another test is back
    obj = ShardedObjective(ref, 2, "dask", client)
    try:
        for x, y in zip(ref.loss_and_grad(R), obj.loss_and_grad(R)):
            np.testing.assert_allclose(y, x, rtol=1e-12, atol=1e-14)
        # rewards and local rows in, losses and gradients out
        assert obj.shards.bytes_sent == 2 * R.nbytes + 6 * 8 + 6 * 8
        lin_b = obj.linearize(R)
        victim = sorted(client.scheduler_info()["workers"])[0]
        with pytest.raises(Exception):  # the worker dies while answering
            client.run(os._exit, 1, workers=[victim])
        time.sleep(0.5)
        R2 = R + 0.01
        for x, y in zip(ref.loss_and_grad(R2), obj.loss_and_grad(R2)):
            np.testing.assert_allclose(y, x, rtol=1e-11, atol=1e-13)
        lin_a = ref.linearize(R)
        np.testing.assert_allclose(lin_b.jvp(R2), lin_a.jvp(R2), rtol=1e-11, atol=1e-13)
        np.testing.assert_allclose(lin_b.vjp(lin_a.residual), lin_a.vjp(lin_a.residual), rtol=1e-11, atol=1e-13)
        assert obj.shards.n_restarts >= 1 and ref.n_evaluations == obj.n_evaluations == 3
    finally:
        obj.close()


def test_dask_workers_run_fits_with_one_job(client):
    from factirl_opt.parallel.shards import effective_n_jobs

    assert client.submit(effective_n_jobs, -1, pure=False).result() == 1


def test_worker_killed_mid_fit_does_not_change_the_result(client, data, monkeypatch):
    mdp, demos, F = data
    restarts = []
    close = ShardedObjective.close
    monkeypatch.setattr(ShardedObjective, "close", lambda self: (restarts.append(self.shards.n_restarts), close(self)))
    kw = dict(n_primitives=2, max_iter=3, init="random", rng=0, planner="sparse-lu", features=F,
              solver="gn-qp-clarabel", d_solver="lbfgs")
    a = fo.FactIRL(**kw).fit(mdp, demos)

    def kill(iteration, total):
        if iteration == 1:
            victim = sorted(client.scheduler_info()["workers"])[-1]
            try:
                client.run(os._exit, 1, workers=[victim])
            except Exception:  # noqa: BLE001 - the worker dies while answering
                pass
            time.sleep(0.5)

    client.wait_for_workers(2)  # a worker killed by another test is back
    b = fo.FactIRL(backend="dask", client=client, n_jobs=2, callback=kill, **kw).fit(mdp, demos)
    assert restarts == [1]  # the lost shard was rebuilt once
    for name in ("dictionary_", "coefficients_", "loss_"):
        np.testing.assert_allclose(getattr(b, name), getattr(a, name), rtol=1e-10, atol=1e-12, err_msg=name)


def test_errors_of_the_computation_are_raised_not_retried(client):
    from factirl_opt.parallel.shards import Shards

    shards = Shards([(dict, ()), (dict, ())], "dask", client)
    try:
        with pytest.raises(KeyError, match="missing"):
            shards.call([(0, "pop", ("missing",)), (1, "pop", ("missing", 7))])
        assert shards.call([(1, "pop", ("missing", 7))]) == [7] and shards.n_restarts == 0
    finally:
        shards.close()


def test_warnings_of_dask_shards_are_raised_in_the_driver(client):
    import importlib

    from factirl_opt.parallel.shards import Shards

    client.wait_for_workers(2)
    shards = Shards([(importlib.import_module, ("warnings",))], "dask", client)
    try:
        with pytest.warns(RuntimeWarning, match="from a Dask worker"):
            assert shards.call([(0, "warn", ("from a Dask worker", RuntimeWarning))]) == [None]
    finally:
        shards.close()


@pytest.fixture
def threads_cluster():
    """A cluster of two workers in this process (fast to start; closed by the tests that need it)."""
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0")
    c = distributed.Client(cluster)
    yield cluster, c
    c.close()
    cluster.close()


KW = dict(n_primitives=2, max_iter=4, init="random", rng=0)


def test_a_closed_client_is_refused_before_the_fit(threads_cluster, data):
    mdp, demos, F = data
    cluster, c = threads_cluster
    c.close()
    with pytest.raises(ValidationError, match="Dask client .* cannot be used: its status is 'closed'"):
        fo.FactIRL(backend="dask", client=c, features=F, **KW).fit(mdp, demos)
    with pytest.raises(ValidationError, match=r"needs client= a dask.distributed.Client; got LocalCluster \(a cluster: "
                                                 r"pass dask.distributed.Client\(cluster\)\)"):
        fo.GradIRL(backend="dask", client=cluster).fit(mdp, demos)


def test_a_cluster_closed_during_a_fit_interrupts_it_keeping_the_best_point(threads_cluster, data):
    mdp, demos, F = data
    cluster, c = threads_cluster

    def close(iteration, total):
        if iteration == 2:
            cluster.close()

    model = fo.FactIRL(backend="dask", client=c, n_jobs=2, callback=close, features=F, **KW)
    # (the InterruptedFitWarning is not asserted: closing a cluster from this thread resets the warnings
    # machinery pytest.warns relies on; test_parallel checks it for lost shard processes)
    with pytest.raises(WorkersLost, match="status is 'closed'"):
        model.fit(mdp, demos)
    assert model.status_ == "interrupted" and model.n_iter_ == 2 and np.all(np.isfinite(model.loss_))


def test_every_worker_lost_interrupts_the_fit_after_a_bounded_wait(threads_cluster, data, monkeypatch):
    from factirl_opt.parallel import shards

    mdp, demos, F = data
    cluster, c = threads_cluster
    monkeypatch.setattr(shards, "DASK_WAIT_SECONDS", 1.0)

    def drop(iteration, total):
        if iteration == 1:
            cluster.scale(0)
            deadline = time.monotonic() + 10
            while c.scheduler_info()["workers"] and time.monotonic() < deadline:
                time.sleep(0.05)

    model = fo.GradIRL(max_iter=4, backend="dask", client=c, n_jobs=2, callback=drop, features=F)
    with pytest.raises(WorkersLost, match="no worker left and none joined within 1 s"):
        model.fit(mdp, demos)
    assert model.status_ == "interrupted" and model.weights_.shape == (6, 4)


def test_a_cluster_without_workers_warns_and_fits_in_this_process(data):
    mdp, demos, F = data
    cluster = distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=":0")
    c = distributed.Client(cluster)
    try:
        a = fo.FactIRL(features=F, **KW).fit(mdp, demos)
        for n_jobs in (None, 2):
            with pytest.warns(RuntimeWarning, match="has no worker: this fit runs unsharded in this process"):
                b = fo.FactIRL(backend="dask", client=c, n_jobs=n_jobs, features=F, **KW).fit(mdp, demos)
            np.testing.assert_allclose(b.dictionary_, a.dictionary_, rtol=1e-10, atol=1e-12)
    finally:
        c.close()
        cluster.close()


def within(seconds, fn, *args):
    """``fn(*args)`` in a daemon thread: its result or its exception, or a failure if it hangs."""
    import threading

    out = []

    def run():
        try:
            out.append(("ok", fn(*args)))
        except BaseException as exc:  # noqa: BLE001 - handed to the test's thread
            out.append(("error", exc))

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"still waiting after {seconds} s (a hang)"
    if out[0][0] == "error":
        raise out[0][1]
    return out[0][1]


def test_a_shard_no_worker_starts_ends_in_workers_lost_after_the_bounded_wait(client, monkeypatch):
    # as a shard's creation stranded by workers dying around it: here a task bound to a worker that does not exist
    from factirl_opt.parallel import shards

    monkeypatch.setattr(shards, "DASK_WAIT_SECONDS", 1.0)
    submit = client.submit
    monkeypatch.setattr(client, "submit", lambda *a, **kw: submit(*a, **{**kw, "workers": ["tcp://127.0.0.1:9"],
                                                                       "allow_other_workers": False}))
    client.wait_for_workers(2)
    with pytest.raises(fo.exceptions.WorkersLost, match=r"shard 0 was not started on any worker .* within 1 s"):
        within(30, shards.Shards, [(dict, ())], "dask", client)


@pytest.mark.slow
def test_every_worker_killed_mid_fit_recovers_or_stops_within_the_bound(client, data):
    # the nannies restart the killed workers: the fit goes on with rebuilt shards, or stops with WorkersLost
    # (within DASK_WAIT_SECONDS of waiting for a worker per shard); it used to wait forever now and then
    mdp, demos, F = data

    def kill_all(iteration, total):
        if iteration == 1:
            try:
                client.run(os._exit, 1)
            except Exception:  # noqa: BLE001 - the workers die while answering
                pass

    client.wait_for_workers(2)
    model = fo.FactIRL(backend="dask", client=client, n_jobs=2, callback=kill_all, n_primitives=2, max_iter=3,
                       init="random", rng=0, features=F, solver="gn-qp-clarabel", d_solver="lbfgs")
    try:
        within(120, model.fit, mdp, demos)
        assert model.status_ != "interrupted"
    except fo.exceptions.WorkersLost:
        assert model.status_ == "interrupted" and np.all(np.isfinite(model.loss_))
    finally:
        client.wait_for_workers(2, timeout=60)

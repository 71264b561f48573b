"""Task shards on worker processes (n_jobs): the same results as n_jobs=1, and the backend's rules.

Reference: the unsharded objective and the ``n_jobs=1`` fit (today's code path). A shard's
sub-objective plans the same tasks with the same planner, so results agree to rounding and the
evaluation counts are equal.
"""

import multiprocessing
import os
import signal
import threading
import time

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.parallel import shards as parallel
from factirl_opt.exceptions import FactIRLError, ValidationError, WorkersLost
from factirl_opt.objectives import MCEObjective, PolicyMatchingObjective
from factirl_opt.objectives.distributed import ShardedObjective, reduced_least_squares
from factirl_opt.objectives.sharding import sharded
from factirl_opt.parallel.shards import Shards, check_backend, contiguous_shards, effective_n_jobs

TOL = dict(rtol=1e-10, atol=1e-12)


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(2)
    mdp = fo.GridWorld(size=5, p_success=0.7, gamma=0.9)
    demos = fo.sample_demonstrations(mdp, rng.standard_normal((5, mdp.n_states, mdp.n_actions)), 4, 6, rng)
    R = rng.standard_normal((5, mdp.n_states, mdp.n_actions))
    return mdp, demos, rng.random((mdp.n_states, 4)), R


def objective(data, cls=PolicyMatchingObjective, planner="sparse-lu"):
    mdp, demos, _, _ = data
    mu, pi = fo.empirical_statistics(mdp, demos)
    return cls(mdp, mu, pi, 5.0, planner=planner)


def test_effective_n_jobs(monkeypatch):
    monkeypatch.delenv(parallel.WORKER_ENV, raising=False)
    assert effective_n_jobs(None) == 1 and effective_n_jobs(3) == 3
    assert effective_n_jobs(-1) == (os.cpu_count() or 1)
    for bad in (0, 1.5, "2", True):
        with pytest.raises(ValidationError, match="n_jobs"):
            effective_n_jobs(bad)
    with pytest.raises(ValidationError, match="leaves no core"):
        effective_n_jobs(-(os.cpu_count() or 1) - 1)
    monkeypatch.setenv(parallel.WORKER_ENV, "1")  # inside a worker: never nested
    assert parallel.in_worker() and effective_n_jobs(-1) == 1 and effective_n_jobs(4) == 1


def test_check_backend_and_shards():
    assert check_backend("processes", None) == "processes"
    with pytest.raises(ValidationError, match="backend"):
        check_backend("threads", None)
    with pytest.raises(ValidationError, match="only used with backend='dask'"):
        check_backend("processes", object())
    with pytest.raises(ValidationError, match="backend=.dask. needs"):  # a Client (or the dask extra)
        check_backend("dask", "tcp://127.0.0.1:8786")
    parts = contiguous_shards(7, 3)
    assert [p.tolist() for p in parts] == [[0, 1, 2], [3, 4], [5, 6]]
    assert len(contiguous_shards(2, 5)) == 2


def test_n_jobs_one_is_the_objective_itself(data):
    obj = objective(data)
    with sharded(obj, None) as a, sharded(obj, 1) as b:
        assert a is obj and b is obj


@pytest.mark.parametrize("cls", [PolicyMatchingObjective, MCEObjective])
def test_sharded_objective_equals_objective(data, cls):
    R = data[3]
    ref = objective(data, cls)
    with sharded(objective(data, cls), 2) as obj:
        assert isinstance(obj, ShardedObjective) and obj.n_shards == 2
        for x, y in zip(ref.loss_and_grad(R), obj.loss_and_grad(R)):
            np.testing.assert_allclose(y, x, **TOL)
        rows = np.array([4, 0, 3])  # rows of both shards, out of order
        for x, y in zip(ref.loss_and_grad(R[rows] + 0.1, rows), obj.loss_and_grad(R[rows] + 0.1, rows)):
            np.testing.assert_allclose(y, x, **TOL)
        obj.loss_and_grad(R[rows] + 0.1, rows)  # the last point: served from the cache, not counted
        ref.loss_and_grad(R[rows] + 0.1, rows)
        assert obj.n_evaluations == ref.n_evaluations == 2
        obj.reset()
        ref.reset()
        for x, y in zip(ref.loss_and_grad(R), obj.loss_and_grad(R)):
            np.testing.assert_allclose(y, x, **TOL)
        assert obj.shards.bytes_sent > 0 and obj.n_evaluations == 3


def test_sharded_least_squares_products(data):
    mdp, _, F, R = data
    ref = objective(data)
    with sharded(objective(data), 3) as obj:
        (la, ra, Ja), (lb, rb, Jb) = ref.residual_jacobian(R, None, F), obj.residual_jacobian(R, None, F)
        np.testing.assert_allclose(lb, la, **TOL)
        for x, y in zip(reduced_least_squares(ra, Ja), (rb, Jb)):  # the reduced form travels
            np.testing.assert_allclose(y, x, **TOL)
        la, lb = ref.linearize(R), obj.linearize(R)
        np.testing.assert_allclose(lb.residual, la.residual, **TOL)
        dR = np.random.default_rng(0).standard_normal(R.shape)
        np.testing.assert_allclose(lb.jvp(dR), la.jvp(dR), **TOL)
        np.testing.assert_allclose(lb.vjp(la.residual), la.vjp(la.residual), **TOL)
        assert obj.n_evaluations == ref.n_evaluations == 2


@pytest.mark.parametrize("h_solver, features", [("gn-qp-clarabel", True), ("gn-cg", True), ("armijo", False)])
def test_factirl_n_jobs_equals_serial_fit(data, h_solver, features):
    mdp, demos, F, _ = data
    kw = dict(n_primitives=2, max_iter=3, init="random", rng=0, solver=h_solver, d_solver="lbfgs",
              features=F if features else None)
    a = fo.FactIRL(**kw).fit(mdp, demos)
    b = fo.FactIRL(n_jobs=2, **kw).fit(mdp, demos)
    for name in ("dictionary_", "coefficients_", "loss_", "rewards_"):
        np.testing.assert_allclose(getattr(b, name), getattr(a, name), **TOL, err_msg=name)
    assert a.n_evaluations_ == b.n_evaluations_ and a.n_iter_ == b.n_iter_
    assert not multiprocessing.active_children()  # the shards' processes stop with the fit


def test_factirl_pca_start_and_gradirl_n_jobs(data):
    mdp, demos, F, _ = data
    a = fo.FactIRL(n_primitives=2, max_iter=2, flat_max_iter=3, rng=0).fit(mdp, demos)
    b = fo.FactIRL(n_primitives=2, max_iter=2, flat_max_iter=3, rng=0, n_jobs=-1).fit(mdp, demos)
    np.testing.assert_allclose(b.dictionary_, a.dictionary_, **TOL)
    assert a.n_evaluations_ == b.n_evaluations_
    a = fo.GradIRL(max_iter=4, features=F, solver="gn-qp-clarabel").fit(mdp, demos)
    b = fo.GradIRL(max_iter=4, features=F, solver="gn-qp-clarabel", n_jobs=5).fit(mdp, demos)
    np.testing.assert_allclose(b.weights_, a.weights_, **TOL)
    assert a.n_evaluations_ == b.n_evaluations_


def test_fit_refuses_bad_parallel_parameters(data):
    mdp, demos, _, _ = data
    with pytest.raises(ValidationError, match="n_jobs"):
        fo.GradIRL(max_iter=1, n_jobs=0).fit(mdp, demos)
    with pytest.raises(ValidationError, match="backend"):
        fo.FactIRL(n_primitives=2, max_iter=1, init="random", backend="mpi").fit(mdp, demos)


def test_killed_shard_process_is_rebuilt(data):
    R = data[3]
    ref = objective(data)
    obj = ShardedObjective(objective(data), 2)
    try:
        obj.loss_and_grad(R)
        lin = obj.linearize(R)
        proc = obj.shards.handles[1].proc
        os.kill(proc.pid, signal.SIGKILL)
        proc.join()
        for x, y in zip(ref.loss_and_grad(R + 0.01), obj.loss_and_grad(R + 0.01)):
            np.testing.assert_allclose(y, x, **TOL)
        dR = np.ones_like(R)
        np.testing.assert_allclose(lin.jvp(dR), ref.linearize(R).jvp(dR), **TOL)  # linearisation replayed
        assert obj.shards.n_restarts == 1
    finally:
        obj.close()
    with pytest.raises(FactIRLError, match="closed"):
        obj.loss_and_grad(R)


class Failing:
    """A shard state whose ``boom`` raises (in a worker process for shard 1)."""

    def ok(self, x):
        return np.asarray(x) * 2

    def boom(self, x):
        raise ValidationError(f"bad value {x}")


def test_worker_error_is_raised_and_the_shards_stay_usable():
    shards = Shards([(Failing, ()), (Failing, ())])
    try:
        with pytest.raises(ValidationError, match="bad value 3"):
            shards.call([(0, "ok", (np.ones(2),)), (1, "boom", (3,))])
        out = shards.call([(0, "ok", (np.ones(2),)), (1, "ok", (np.arange(2.0),))])
        np.testing.assert_array_equal(out[1], [0.0, 2.0])
        assert shards.bytes_sent == 2 * 16  # shard 1 only (the failed call sent no array): 16 B in, 16 B out
    finally:
        shards.close()


def test_reduced_least_squares_keeps_the_normal_equations():
    rng = np.random.default_rng(1)
    r, J = rng.standard_normal((3, 20)), rng.standard_normal((3, 20, 4))
    r2, J2 = reduced_least_squares(r, J)
    assert r2.shape == (3, 5) and J2.shape == (3, 5, 4)
    np.testing.assert_allclose(np.einsum("nmk,nml->nkl", J2, J2), np.einsum("nmk,nml->nkl", J, J), rtol=1e-12)
    np.testing.assert_allclose(np.einsum("nmk,nm->nk", J2, r2), np.einsum("nmk,nm->nk", J, r), rtol=1e-12)
    np.testing.assert_allclose(np.sum(r2**2, axis=1), np.sum(r**2, axis=1), rtol=1e-12)
    r3, J3 = reduced_least_squares(r[:, :2], J[:, :2])  # fewer residuals than k+1: zero rows
    assert J3.shape == (3, 5, 4) and np.all(J3[:, 2:] == 0)
    np.testing.assert_allclose(np.einsum("nmk,nm->nk", J3, r3), np.einsum("nmk,nm->nk", J[:, :2], r[:, :2]), rtol=1e-12)


def test_interrupted_fit_stops_its_shards_and_keeps_the_best_point(data):
    mdp, demos, F, _ = data

    def stop(iteration, total):
        if iteration == 2:
            raise KeyboardInterrupt

    fits = []
    for n_jobs in (1, 2):
        model = fo.FactIRL(n_primitives=2, max_iter=5, init="random", rng=0, features=F, callback=stop, n_jobs=n_jobs)
        with pytest.warns(fo.exceptions.InterruptedFitWarning), pytest.raises(KeyboardInterrupt):
            model.fit(mdp, demos)
        assert not multiprocessing.active_children()
        fits.append(model)
    np.testing.assert_allclose(fits[1].dictionary_, fits[0].dictionary_, **TOL)
    assert fits[0].status_ == fits[1].status_ == "interrupted" and fits[0].n_iter_ == fits[1].n_iter_


def test_sweep_workers_run_fits_with_one_job():
    from factirl_opt.lab.experiments.workers import imap_unordered

    assert sorted(imap_unordered(effective_n_jobs, [(-1,), (2,)], 2)) == [1, 1]


def test_transfer_n_jobs_equals_serial_transfer(data):
    mdp, demos, F, _ = data
    model = fo.FactIRL(n_primitives=2, max_iter=2, init="random", rng=0, features=F, solver="gn-qp-clarabel")
    model.fit(mdp, demos[:3])
    a = model.transfer(mdp, demos[3:], max_iter=4)
    evaluations = model.transfer_n_evaluations_
    model.n_jobs = 2
    b = model.transfer(mdp, demos[3:], max_iter=4)
    np.testing.assert_allclose(b, a, **TOL)
    assert model.transfer_n_evaluations_ == evaluations
    assert not multiprocessing.active_children()


def test_recording_warnings_keeps_distinct_warnings_in_order_and_picklable_categories():
    import warnings

    class ScriptWarning(RuntimeWarning):  # as if defined in a user's script: the driver could not unpickle it
        pass

    ScriptWarning.__module__ = "__main__"

    def noisy():
        for _ in range(3):
            warnings.warn("again", UserWarning)
        warnings.warn("script", ScriptWarning)
        return 7

    result, caught = parallel.recording_warnings(noisy)
    assert result == 7 and caught == [(UserWarning, "again"), (RuntimeWarning, "script")]


def test_warnings_of_shard_processes_are_raised_in_the_driver():
    import importlib
    import warnings

    shards = Shards([(importlib.import_module, ("warnings",)), (importlib.import_module, ("warnings",))])
    try:
        with warnings.catch_warnings(record=True) as record:
            warnings.simplefilter("always")
            shards.call([(0, "warn", ("from shard 0",)), (1, "warn", ("from shard 1", RuntimeWarning))])
        # shard 0 runs in this process; shard 1's warning crossed the pipe
        assert sorted((str(w.message), w.category) for w in record) == [("from shard 0", UserWarning),
                                                                        ("from shard 1", RuntimeWarning)]
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # the driver's filters decide, as in a run with one job
            with pytest.raises(UserWarning, match="from shard 1 again"):
                shards.call([(1, "warn", ("from shard 1 again",))])
    finally:
        shards.close()


def within(seconds, fn, *args):
    """``fn(*args)`` in a daemon thread: its result or its exception, or a failure if it hangs."""
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


def call_and_close(shards, calls):
    try:
        return shards.call(calls)
    finally:
        shards.close()


def test_shards_forked_while_another_thread_holds_the_blas_lock_answer():
    from factirl_opt import _threads

    out = []
    start = threading.Thread(target=lambda: out.append(call_and_close(Shards([(dict, ()), (dict, ())]),
                                                                      [(1, "get", ("a", 5))])), daemon=True)
    # as when the main thread sets BLAS threads at the moment another thread's fit forks a shard: the
    # fork waits for the lock (it used to fork with the lock held, and the shard waited for it forever)
    with _threads._lock:
        start.start()
        time.sleep(0.5)
    start.join(30)
    assert not start.is_alive() and out == [[5]]


def test_a_stopped_shard_process_is_killed_and_rebuilt(monkeypatch):
    monkeypatch.setattr(parallel, "SILENCE_SECONDS", 1.0)
    shards = Shards([(dict, ()), (dict, ())])
    try:
        shards.call([(1, "setdefault", ("a", 1))])
        proc = shards.handles[1].proc
        os.kill(proc.pid, signal.SIGSTOP)  # alive, silent: neither EOF nor an answer would ever come
        assert within(30, shards.call, [(1, "get", ("a", 7))]) == [7]  # a rebuilt dict: the default
        assert shards.n_restarts == 1 and not proc.is_alive()
    finally:
        shards.close()


class Stuck:
    """A shard state whose ``wait`` never returns and uses no CPU time (a deadlock)."""

    def wait(self):
        threading.Event().wait()


def test_a_deadlocked_shard_ends_in_a_clear_error(monkeypatch):
    monkeypatch.setattr(parallel, "SILENCE_SECONDS", 1.0)
    monkeypatch.setattr(parallel, "MAX_RESTARTS", 1)
    shards = Shards([(Stuck, ()), (Stuck, ())])
    try:
        with pytest.raises(WorkersLost, match=r"lost 2 times in one call.*used no CPU time for 1 s \(stopped, or deadlocked\)"):
            within(30, shards.call, [(1, "wait", ())])
        assert shards.n_restarts == 1
    finally:
        shards.close()
    assert not multiprocessing.active_children()


def test_a_fit_whose_shards_keep_dying_keeps_its_best_point(data, monkeypatch):
    mdp, demos, F, _ = data
    monkeypatch.setattr(parallel, "MAX_RESTARTS", 0)
    parallel.start_shard_server(wait=True)  # the shards are processes from the start (not served here meanwhile)

    def kill(iteration, total):
        if iteration == 2:
            for child in multiprocessing.active_children():
                os.kill(child.pid, signal.SIGKILL)

    model = fo.FactIRL(n_primitives=2, max_iter=5, init="random", rng=0, features=F, callback=kill, n_jobs=2)
    caught = None
    with pytest.warns(fo.exceptions.InterruptedFitWarning, match="stopped by an error"):
        try:
            model.fit(mdp, demos)
        except Exception as exc:  # noqa: BLE001 - an ordinary error: a script's `except Exception` catches it
            caught = exc
    assert isinstance(caught, fo.exceptions.WorkersLost) and not isinstance(caught, KeyboardInterrupt)
    assert "shard 1's worker was lost 1 times" in str(caught)
    assert model.status_ == "interrupted" and model.n_iter_ == 2 and np.all(np.isfinite(model.loss_))
    assert not multiprocessing.active_children()


def test_workers_lost_is_an_ordinary_error_and_the_fit_keeps_its_best_point(data, monkeypatch):
    # lost in a solver's run (interruption.run_keeping_best: the per-task best point)
    mdp, demos, F, _ = data
    monkeypatch.setattr(parallel, "MAX_RESTARTS", 0)
    parallel.start_shard_server(wait=True)  # the shards are processes from the start (not served here meanwhile)

    def kill(iteration, total):
        if iteration == 3:
            for child in multiprocessing.active_children():
                os.kill(child.pid, signal.SIGKILL)

    model = fo.GradIRL(max_iter=6, features=F, callback=kill, n_jobs=2)
    with pytest.warns(fo.exceptions.InterruptedFitWarning, match="stopped by an error"), \
            pytest.raises(fo.exceptions.WorkersLost) as info:
        model.fit(mdp, demos)
    assert isinstance(info.value, Exception) and not isinstance(info.value, KeyboardInterrupt)  # `except Exception` catches it
    assert model.status_ == "interrupted" and np.all(np.isfinite(model.rewards_))


def _fit_once(mdp, demos, F):
    fo.FactIRL(n_primitives=2, max_iter=3, init="random", rng=0, features=F, solver="gn-qp-clarabel", d_solver="lbfgs",
               n_jobs=2).fit(mdp, demos)


def _threads_in_a_forked_child(data, rounds, factor):
    """In a child forked from this process (as a test runner's or notebook server's worker), ``rounds`` times
    two threads each doing an n_jobs=2 fit; each round is given ``factor`` times one fit's time (the median
    of three, measured in the child). Returns ``(one fit's seconds, [seconds of each round, None if a fit
    was still running at the deadline])``."""
    import json
    import warnings

    mdp, demos, F, _ = data
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        try:
            os.close(read)
            warnings.simplefilter("ignore")
            _fit_once(mdp, demos, F)  # starts this child's fork server
            times = []
            for _ in range(3):
                t0 = time.perf_counter()
                _fit_once(mdp, demos, F)
                times.append(time.perf_counter() - t0)
            one = sorted(times)[1]
            out = []
            for _ in range(rounds):
                t0 = time.perf_counter()
                threads = [threading.Thread(target=_fit_once, args=(mdp, demos, F), daemon=True) for _ in range(2)]
                for t in threads:
                    t.start()
                for t in threads:
                    t.join(max(0.0, t0 + factor * one - time.perf_counter()))
                out.append(None if any(t.is_alive() for t in threads) else time.perf_counter() - t0)
                if out[-1] is None:
                    break
            os.write(write, json.dumps([one, out]).encode())
        finally:
            os._exit(0)
    os.close(write)
    chunks = []
    while chunk := os.read(read, 65536):
        chunks.append(chunk)
    os.close(read)
    os.waitpid(pid, 0)
    assert chunks, "the forked child wrote nothing (it failed before its report)"
    return json.loads(b"".join(chunks))


@pytest.mark.parametrize("rounds", [pytest.param(20, marks=pytest.mark.slow), 4])
def test_two_threads_fitting_in_a_forked_child_never_stall(data, rounds):
    # a shard process forked from a multithreaded process could deadlock on a lock another thread held at
    # the fork (the library's, glibc's or BLAS's); shard processes now start from a fork server
    one, out = _threads_in_a_forked_child(data, rounds, 10.0)
    assert None not in out, f"round {out.index(None) + 1}: a fit still ran after 10 x {one:.2f} s (one fit)"
    assert len(out) == rounds


_HELD = threading.Lock()


class NeedsTheLock:
    """A shard state whose ``value`` takes a lock of its module (as the library's, glibc's or BLAS's)."""

    def value(self):
        with _HELD:
            return os.getpid()


def test_a_shard_process_never_inherits_a_lock_another_thread_holds(monkeypatch):
    # a process forked while another thread holds a lock inherits it held, by a thread it does not have:
    # it waits forever (here: until the silence rule kills and rebuilds it). A shard process started by a
    # fork server has this module's lock free, whatever this process's threads hold.
    monkeypatch.setattr(parallel, "SILENCE_SECONDS", 2.0)
    held, release = threading.Event(), threading.Event()

    def hold():
        with _HELD:
            held.set()
            release.wait(30)

    holder = threading.Thread(target=hold, daemon=True)
    holder.start()
    held.wait(10)
    try:
        shards = Shards([(NeedsTheLock, ()), (NeedsTheLock, ())])
    finally:
        release.set()
        holder.join(10)
    try:
        assert within(60, shards.call, [(1, "value", ())]) != [os.getpid()]
        assert shards.n_restarts == 0  # answered at once, not rebuilt after a deadlock
    finally:
        shards.close()


def test_a_script_without_a_main_guard_fits_with_n_jobs(tmp_path):
    # shard processes come from a fork server; they import the script's __main__ only when a shard's
    # state refers to it, so a script without `if __name__ == "__main__":` runs once, as with fork
    import subprocess
    import sys

    script = tmp_path / "fit.py"
    script.write_text("import numpy as np\nimport factirl_opt as fo\nprint('start')\n"
                      "rng = np.random.default_rng(0)\nmdp = fo.GridWorld(size=3, p_success=0.7, gamma=0.9)\n"
                      "demos = fo.sample_demonstrations(mdp, rng.standard_normal((4, 9, 4)), 2, 5, rng)\n"
                      "fo.FactIRL(n_primitives=2, max_iter=2, init='random', rng=0, n_jobs=2).fit(mdp, demos)\n"
                      "print('done')\n")
    out = subprocess.run([sys.executable, "-W", "ignore", str(script)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["start", "done"]


def _fit_in_pool_worker(data):
    """In a multiprocessing.Pool worker (a daemonic process): a FactIRL fit with n_jobs=2, its warnings."""
    import warnings

    mdp, demos = data
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = fo.FactIRL(n_primitives=2, max_iter=2, rng=0, n_jobs=2).fit(mdp, demos)
        fo.FactIRL(n_primitives=2, max_iter=1, rng=0, n_jobs=2).fit(mdp, demos)  # a second fit: no second warning
    return model.coefficients_, [(w.category.__name__, str(w.message)) for w in caught
                                 if not issubclass(w.category, fo.exceptions.ConvergenceWarning)]


def test_a_fit_with_n_jobs_in_a_daemonic_process_runs_its_shards_here_with_one_warning(data):
    """A Pool worker cannot have children ("daemonic processes are not allowed to have children" used to
    end the fit): its shards run in the worker itself, with one warning naming daemonic processes, and the
    result is that of n_jobs=1."""
    import warnings

    mdp, demos = data[0], data[1]
    with multiprocessing.get_context("fork").Pool(1) as pool:
        coefficients, caught = pool.apply(_fit_in_pool_worker, ((mdp, demos),))
    assert len(caught) == 1, caught
    assert caught[0][0] == "RuntimeWarning" and "daemonic process" in caught[0][1] and "n_jobs=2" in caught[0][1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fo.exceptions.ConvergenceWarning)
        serial = fo.FactIRL(n_primitives=2, max_iter=2, rng=0, n_jobs=1).fit(mdp, demos)
    np.testing.assert_allclose(coefficients, serial.coefficients_, rtol=1e-10, atol=1e-12)


_WHERE = """
import os


class Where:  # a shard's state: which process serves it, and what it was given
    def __init__(self):
        self.given = []

    def pid(self):
        return os.getpid()

    def give(self, x):
        self.given.append(x)
        return list(self.given)
"""

_FIRST_SHARDS = """
import json, os, time
from factirl_opt.parallel import shards as parallel
from where_state import Where

restored = []
shards = parallel.Shards([(Where, ()), (Where, ())], serve_while_starting=True)
kind = type(shards.handles[1]).__name__
first = shards.call([(1, "pid", ())], on_restart=restored.append)[0]
shards.call([(1, "give", (1,))], on_restart=restored.append)
deadline = time.monotonic() + 60
while not shards.handles[1].done() and time.monotonic() < deadline:
    time.sleep(0.05)
restore = lambda k: (restored.append(k), shards.handles[k].submit("give", (1,)), shards.handles[k].result())
after = shards.call([(1, "pid", ())], on_restart=restore)[0]
given = shards.call([(1, "give", (2,))], on_restart=restore)[0]
later = parallel.Shards([(Where, ()), (Where, ())], serve_while_starting=True)
print(json.dumps({"kind": kind, "first_here": first == os.getpid(), "after_here": after == os.getpid(),
                  "restored": restored, "given": given, "n_restarts": shards.n_restarts,
                  "later_kind": type(later.handles[1]).__name__}))
shards.close()
later.close()
"""


def test_the_first_shards_of_a_process_do_not_wait_for_the_fork_server(tmp_path):
    """A fresh process's first shard processes start in the background (the fork server imports the
    library meanwhile, about a second): their calls are served in the calling process until the process
    is built, then handed over to it as a rebuilt shard is (``on_restart`` restores what the calls
    need); later shards start as processes at once."""
    import json
    import subprocess
    import sys

    script = tmp_path / "first_shards.py"
    script.write_text(_FIRST_SHARDS)
    (tmp_path / "where_state.py").write_text(_WHERE)  # importable by the shard process (not the script itself)
    res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300,
                         cwd=os.path.dirname(os.path.dirname(fo.__file__)))
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["kind"] == "StartingShard" and out["first_here"], out  # served here while the process starts
    assert not out["after_here"] and out["restored"] == [1] and out["n_restarts"] == 0, out  # handed over once
    assert out["given"] == [1, 2], out  # the state restored in the process, then the new call
    assert out["later_kind"] == "ProcessShard", out

"""Worker processes: results, errors, and nothing left behind after SIGTERM, Ctrl-C or kill -9 of the parent.

The signal tests run ``factirl-opt reproduce --preset tiny --seeds 6 --jobs 2`` (18 runs) in a
subprocess, wait for the first finished run, take a census of the sweep's descendant processes
(2 workers and multiprocessing's resource tracker), send the signal to the parent only, and
check that every one of them is gone, that nothing holds the caller's stdout, and that no
``/dev/shm`` entry of theirs remains.
"""

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from factirl_opt.lab.experiments import run_sweep
from factirl_opt.lab.experiments.workers import POLL_SECONDS, WorkerError, imap_unordered

ROOT = Path(__file__).resolve().parents[2]
N_SEEDS = 6
TABLES = ("results.csv", "summary.csv", "figure3.json")


def _square(x):
    return x * x


def _fail(x):
    raise ValueError(f"bad task {x}")


def _die(x):
    os._exit(7)


def test_imap_unordered_returns_every_result():
    assert sorted(imap_unordered(_square, [(i,) for i in range(7)], jobs=2)) == [i * i for i in range(7)]
    assert list(imap_unordered(_square, [], jobs=2)) == []


def test_worker_exceptions_are_reraised():
    with pytest.raises(ValueError, match="bad task 3") as exc:
        list(imap_unordered(_fail, [(3,)], jobs=1))
    assert "Traceback" in str(exc.value.__cause__)  # the worker's traceback


def test_a_dying_worker_is_an_error():
    with pytest.raises(WorkerError, match="died"):
        list(imap_unordered(_die, [(1,)], jobs=1))


# --- signals -----------------------------------------------------------------------------


def _children():
    """{pid: ppid} of every process, and their states."""
    table, states = {}, {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as fh:
                    fields = fh.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            table[int(d)], states[int(d)] = int(fields[1]), fields[0]
    return table, states


def _descendants(pid):
    table, _ = _children()
    found, frontier = set(), {pid}
    while frontier:
        frontier = {p for p, pp in table.items() if pp in frontier} - found
        found |= frontier
    return found


def _alive(pids):
    _, states = _children()
    return {p for p in pids if p in states and states[p] not in ("Z", "X")}


def _shm_entries(pids):
    try:
        names = os.listdir("/dev/shm")
    except FileNotFoundError:
        return set()
    return {n for n in names if any(str(p) in n for p in pids)}


def _start_sweep(out):
    cmd = [sys.executable, "-m", "factirl_opt.lab.cli", "reproduce", "--preset", "tiny", "--seeds", str(N_SEEDS),
           "--jobs", "2", "--out", str(out), "--no-plot", "--quiet"]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
    # a shell's background job starts with SIGINT ignored, and a child inherits that: give the
    # sweep the default disposition, as a foreground command has
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while not (out / "runs").is_dir() or not _finished_runs(out):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no run finished in 120 s"
        time.sleep(0.05)
    family = _descendants(proc.pid)
    assert len(family) >= 2, "expected 2 worker processes"
    return proc, family


#: how long the sweep's processes may outlive a SIGTERM or Ctrl-C of the parent (seconds)
BOUND_SECONDS = 1.0


def _signal_sweep(tmp_path, signum, bound=None):
    """Signal the parent; with ``bound``, also return the processes still alive ``bound`` seconds later."""
    out = tmp_path / "out"
    proc, family = _start_sweep(out)
    os.kill(proc.pid, signum)
    late = set()
    if bound is not None:
        deadline = time.monotonic() + bound
        while _alive(family) and time.monotonic() < deadline:
            time.sleep(0.02)
        late = _alive(family)
    stdout, stderr = proc.communicate(timeout=60)  # returns only once nothing holds our pipes
    return out, proc, family, stderr, late


def _finished_runs(out):
    """The run records written in full: an atomic write's temporary file (``.tmp-...json``) is not one."""
    return sorted(f for f in os.listdir(out / "runs") if f.endswith(".json") and not f.startswith("."))


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_terminating_the_parent_leaves_nothing(tmp_path, signum):
    out, proc, family, stderr, late = _signal_sweep(tmp_path, signum, bound=BOUND_SECONDS)
    assert proc.returncode == 128 + signum, stderr
    assert "interrupted; rerun the same command to resume" in stderr and "Traceback" not in stderr
    # the workers and the resource tracker are stopped with the sweep, not at the parent's exit
    assert not late, f"alive {BOUND_SECONDS} s after the signal: {late}"
    assert not _alive(family), f"left alive: {_alive(family)}"
    assert not _shm_entries(family | {proc.pid})
    assert not (out / ".lock").exists()
    assert 1 <= len(_finished_runs(out)) < 3 * N_SEEDS


def test_workers_exit_by_themselves_after_kill_9_of_the_parent(tmp_path):
    out, proc, family, _, _ = _signal_sweep(tmp_path, signal.SIGKILL)
    assert proc.returncode == -signal.SIGKILL
    deadline = time.monotonic() + 30  # bound; they poll their parent every POLL_SECONDS
    while _alive(family) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(family), f"alive 30 s after the parent died: {_alive(family)}"
    assert POLL_SECONDS <= 1


@pytest.mark.slow
def test_resume_after_kill_9_gives_identical_tables(tmp_path):
    out, proc, family, _, _ = _signal_sweep(tmp_path, signal.SIGKILL)
    deadline = time.monotonic() + 30
    while _alive(family) and time.monotonic() < deadline:
        time.sleep(0.1)
    done = _finished_runs(out)
    assert (out / ".lock").exists()  # left by the killed parent: stale, replaced below
    res = run_sweep("tiny", out, seeds=N_SEEDS, jobs=2, progress=False)
    assert res["n_computed"] == 3 * N_SEEDS - len(done) and not res["rejected"]  # no finished run lost
    ref = tmp_path / "ref"
    run_sweep("tiny", ref, seeds=N_SEEDS, jobs=1, progress=False)
    for t in TABLES:
        assert (out / t).read_bytes() == (ref / t).read_bytes()


def _sleep_then_square(x):
    time.sleep(0.2)
    return x * x


def test_a_sigterm_while_workers_start_stops_them_all():
    """A SIGTERM during the workers' start is held, then every worker is stopped and the signal delivered."""
    from factirl_opt.lab.experiments.workers import Terminated, sigterm_raises

    import factirl_opt.lab.experiments.workers as workers_mod

    started = []
    original = workers_mod._stop

    def spy(workers):
        started.extend(p for p, _ in workers)
        return original(workers)

    timer = threading.Timer(0.01, os.kill, (os.getpid(), signal.SIGTERM))
    workers_mod._stop = spy
    try:
        with pytest.raises(Terminated), sigterm_raises():
            timer.start()
            list(imap_unordered(_sleep_then_square, [(i,) for i in range(4)], jobs=2))
    finally:
        workers_mod._stop = original
        timer.join()
    assert started and all(p.exitcode is not None for p in started)


def test_an_ignored_sigterm_while_workers_start_changes_nothing():
    previous = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    timer = threading.Timer(0.01, os.kill, (os.getpid(), signal.SIGTERM))
    try:
        timer.start()
        assert sorted(imap_unordered(_sleep_then_square, [(i,) for i in range(4)], jobs=2)) == [0, 1, 4, 9]
    finally:
        timer.join()
        signal.signal(signal.SIGTERM, previous)


def test_warnings_of_sweep_workers_are_raised_in_the_parent():
    import warnings

    with pytest.warns(UserWarning, match="from a sweep worker"):
        assert list(imap_unordered(warnings.warn, [("from a sweep worker",)], 1)) == [None]

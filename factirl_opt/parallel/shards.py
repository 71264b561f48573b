"""Stateful shards: objects built once on worker processes (or Dask workers) and called by method name.

A fit evaluated over task shards (:mod:`factirl_opt.objectives.distributed`) keeps each
shard's state (its MDP, statistics, warm starts and planner caches) where the shard runs, so
that only rewards go in and losses and gradients come out. This module is the small backend
under it; it knows nothing of objectives:

- a *spec* ``(factory, args)`` says how to build a shard's state; the driver keeps it, so a
  shard whose worker was lost is built again from the driver's copy;
- :class:`Shards` holds one handle per shard and calls ``state.method(*args)`` on several
  shards at once (all sent first, then collected), counting the array bytes sent and
  received (:attr:`Shards.bytes_sent`); a shard whose worker went away is rebuilt and the
  call retried (at most :data:`MAX_RESTARTS` times per call), after an ``on_restart(k)``
  hook lets the caller restore what the call needs (e.g. a linearisation); when the
  rebuilds run out, or a Dask client or cluster is gone, :class:`WorkersLost` (an ordinary
  library error, which a fit ends like an interruption: the estimator keeps its best point) is raised;
- handles: :class:`InProcessShard` (the driver's own shard: no copy, no process),
  :class:`ProcessShard` (one ``multiprocessing`` process and pipe per shard, started once
  per fit by a fork server (:func:`_context`: never forked from the caller's process, which
  may be multithreaded), SIGINT ignored, exits when its parent is gone;
  a shard process that dies, or that sends nothing and uses no CPU time for
  :data:`SILENCE_SECONDS` while a call waits (stopped, or deadlocked), is noticed within
  :data:`POLL_SECONDS`, killed and rebuilt)
  and :class:`DaskShard` (a Dask actor holding the state on a worker of a
  ``dask.distributed.Client``; :func:`dask_workers` is the one check of a client and its
  cluster).

Warnings a worker raises (a stalled fit in a sweep worker, an overflow while a shard plans)
are recorded there (:func:`recording_warnings`), sent back with the reply and raised again in
the driver (:func:`replay_warnings`), where the user's warning filters apply: ``-W error``
or ``warnings.catch_warnings`` see them as in a run with one job.

``n_jobs`` follows scikit-learn: None means 1, -1 every core (``os.cpu_count()``), -2 all
but one, and so on (:func:`effective_n_jobs`). Inside a worker process (a shard's, a sweep
worker of ``reproduce --jobs``, or a Dask worker, see :func:`in_worker`) it is 1: pools are
never nested by accident.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import signal
import sys
import threading
import time
import traceback
import warnings
from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..exceptions import FactIRLError, ValidationError, WorkersLost

__all__ = ["Client", "WorkersLost", "dask_workers", "SILENCE_SECONDS", "DASK_WAIT_SECONDS", "become_worker", "serve_calls", "recording_warnings", "replay_warnings", "BACKENDS", "WORKER_ENV", "MAX_RESTARTS", "ShardLost", "in_worker", "mark_worker", "effective_n_jobs", "daemonic", "start_shard_server",
           "check_backend", "contiguous_shards", "array_bytes", "ShardHost", "InProcessShard", "ProcessShard", "StartingShard",
           "DaskShard", "Shards"]

#: where shards run: worker processes of this machine, or a Dask cluster
BACKENDS = ("processes", "dask")
#: environment variable set in every worker process (shards and sweep workers): n_jobs is 1 there
WORKER_ENV = "FACTIRL_OPT_WORKER"
#: rebuilds of one shard within one call before its error is raised
MAX_RESTARTS = 2
#: how often a shard process checks that its parent is alive, and the driver that a shard it
#: waits for is alive and working (seconds)
POLL_SECONDS = 0.5
#: a shard process that sends nothing and whose serving thread uses no CPU time for this long
#: while the driver waits for its reply is stuck (stopped, or deadlocked on a lock another
#: thread held when it was forked): it is killed and rebuilt like a dead one (seconds)
SILENCE_SECONDS = 60.0
#: how long a fit whose Dask cluster has lost every worker waits for one to come back before
#: it stops with :class:`WorkersLost` (seconds)
DASK_WAIT_SECONDS = 30.0
#: held while a shard process is started: a process forked by another thread meanwhile (the
#: caller's own, or a fallback start method's) would inherit the new shard's end of the pipe, and
#: its death would then go unnoticed
_START_LOCK = threading.Lock()


if TYPE_CHECKING:
    from distributed import Client
else:
    class _ClientType(type):
        """``isinstance``/``issubclass`` against ``distributed.Client`` once ``distributed`` is imported
        (False before: no object can be a Client then); importing it here would cost a second."""

        def __instancecheck__(cls, obj: Any) -> bool:
            module = sys.modules.get("distributed")
            return module is not None and isinstance(obj, module.Client)

        def __subclasscheck__(cls, sub: type) -> bool:
            module = sys.modules.get("distributed")
            return module is not None and issubclass(sub, module.Client)

    class Client(metaclass=_ClientType):
        """``dask.distributed.Client`` as an annotation that resolves at run time without importing
        ``distributed`` (:func:`typing.get_type_hints` on the estimators' ``__init__``); type checkers
        see the real class. ``isinstance(c, Client)`` is ``isinstance(c, distributed.Client)``."""

    Client.__module__, Client.__qualname__ = "distributed", "Client"


class ShardLost(FactIRLError):
    """A shard's worker went away (its process died, or its Dask worker was lost)."""


def mark_worker() -> None:
    """Mark this process as a worker: :func:`effective_n_jobs` is 1 in it (and its children)."""
    os.environ[WORKER_ENV] = "1"


def in_worker() -> bool:
    """Whether this process is a worker: a shard or sweep worker (:func:`mark_worker`), or a Dask worker."""
    if os.environ.get(WORKER_ENV):
        return True
    if "distributed" not in sys.modules:  # a Dask worker has imported it; importing it here would cost a second
        return False
    from distributed import get_worker

    try:
        get_worker()
    except ValueError:
        return False
    return True


def daemonic() -> bool:
    """Whether this process is daemonic (a ``multiprocessing.Pool`` worker, a daemon ``Process``): it
    cannot start processes of its own, so shards of the ``"processes"`` backend cannot run in it."""
    return bool(multiprocessing.current_process().daemon)


def effective_n_jobs(n_jobs: int | None) -> int:
    """The number of shards ``n_jobs`` asks for: None is 1, -1 every core, -k all but k-1 cores.

    Always 1 inside a worker process (:func:`in_worker`).

    Raises
    ------
    ValidationError
        For 0, a non-integer, or a negative value beyond the number of cores.
    """
    if n_jobs is None:
        return 1
    if isinstance(n_jobs, bool) or not isinstance(n_jobs, (int, np.integer)) or n_jobs == 0:
        raise ValidationError(f"n_jobs must be None, a positive integer, or -1 (every core), -2, ...; got {n_jobs!r}")
    cores = os.cpu_count() or 1
    n = int(n_jobs) if n_jobs > 0 else cores + 1 + int(n_jobs)
    if n < 1:
        raise ValidationError(f"n_jobs={n_jobs} leaves no core: this machine has {cores}")
    return 1 if in_worker() else n


def check_backend(backend: str, client: Any) -> str:
    """Validate ``backend`` (one of :data:`BACKENDS`) and its ``client`` (a ``dask.distributed.Client``
    for ``"dask"``, None otherwise)."""
    if not isinstance(backend, str) or backend not in BACKENDS:
        raise ValidationError(f"backend must be one of {', '.join(map(repr, BACKENDS))}; got {backend!r}")
    if backend == "processes":
        if client is not None:
            raise ValidationError("client is only used with backend='dask'")
        return backend
    try:
        from distributed import Client
    except ImportError:
        raise ValidationError("backend='dask' needs dask[distributed]: pip install 'factirl-opt[dask]'") from None
    if not isinstance(client, Client):
        hint = " (a cluster: pass dask.distributed.Client(cluster))" if hasattr(client, "scheduler_address") else ""
        raise ValidationError(f"backend='dask' needs client= a dask.distributed.Client; got {type(client).__name__}{hint}")
    dask_workers(client)
    return backend


def dask_workers(client: Any, during_fit: bool = False) -> list[str]:
    """The addresses of the workers of ``client``'s cluster, sorted: the one check of a Dask
    client and its cluster, made when a fit starts and whenever a shard is (re)built.

    Parameters
    ----------
    client : dask.distributed.Client
    during_fit : bool
        Whether a fit is under way: a client that cannot be used then stops the fit as an
        interruption (:class:`WorkersLost`); before it, it is a :class:`ValidationError`.

    Returns
    -------
    list of str
        Possibly empty (a cluster that has no worker yet, or lost them all).

    Raises
    ------
    ValidationError or WorkersLost
        The client was closed, or its scheduler (cluster) is gone or cannot be reached.
    """
    error = WorkersLost if during_fit else ValidationError
    status = str(getattr(client, "status", "unknown"))
    if status != "running":
        raise error(f"the Dask client {client!r} cannot be used: its status is {status!r} (it was closed, or its "
                    "cluster was closed or cannot be reached); connect a new dask.distributed.Client")
    try:
        info = client.scheduler_info()
    except Exception as exc:  # noqa: BLE001 - any failure to reach the scheduler
        raise error(f"the Dask scheduler of {client!r} cannot be reached ({type(exc).__name__}: {exc})") from exc
    workers = info.get("workers") if isinstance(info, dict) else None
    if workers is None:
        raise error(f"the Dask client {client!r} has no information from its scheduler (its cluster was closed or "
                    "cannot be reached); connect a new dask.distributed.Client")
    return sorted(workers)


def _wait_for_dask_worker(client: Any) -> list[str]:
    """The workers of ``client``, waiting up to :data:`DASK_WAIT_SECONDS` for one to join when there is
    none (during a fit: a cluster that lost every worker); :class:`WorkersLost` if none does."""
    workers = dask_workers(client, during_fit=True)
    deadline = time.monotonic() + DASK_WAIT_SECONDS
    while not workers:
        if time.monotonic() > deadline:
            raise WorkersLost(f"the Dask cluster of {client!r} has no worker left and none joined within "
                              f"{DASK_WAIT_SECONDS:g} s (parallel.DASK_WAIT_SECONDS); restart workers, or refit with n_jobs=1")
        time.sleep(min(POLL_SECONDS, DASK_WAIT_SECONDS))
        workers = dask_workers(client, during_fit=True)
    return workers


def contiguous_shards(n: int, n_shards: int) -> list[np.ndarray]:
    """Rows 0..n-1 cut into ``min(n_shards, n)`` contiguous runs of sizes differing by at most one."""
    return [rows for rows in np.array_split(np.arange(n), max(1, min(int(n_shards), n))) if rows.size]


def array_bytes(value: Any) -> int:
    """Bytes of the numpy arrays in ``value`` (nested tuples and lists)."""
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, (tuple, list)):
        return sum(array_bytes(v) for v in value)
    return 0


def recording_warnings(fn: Callable[..., Any], *args: Any) -> tuple[Any, list[tuple[type[Warning], str]]]:
    """``fn(*args)`` and the warnings it raised, as distinct ``(category, message)`` pairs in order.

    Every warning is recorded (filter ``"always"``, whatever this process's filters say), to be
    raised again in the driver by :func:`replay_warnings`; one raised many times is sent once.
    A category the driver could not unpickle is sent as its nearest base class that it can.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = fn(*args)
    return result, list(dict.fromkeys((_picklable(w.category), str(w.message)) for w in caught))


def _picklable(category: type[Warning]) -> type[Warning]:
    """``category`` or its nearest base that the driver can unpickle (not one of a script's ``__main__``)."""
    for cls in category.__mro__:
        if cls.__module__ in ("__main__", "__mp_main__"):
            continue
        try:
            pickle.loads(pickle.dumps(cls))
        except Exception:
            continue
        return cls
    return UserWarning


def replay_warnings(records: Sequence[tuple[type[Warning], str]]) -> None:
    """Raise again, in this process and under its filters, warnings recorded by :func:`recording_warnings`."""
    for category, message in records:
        warnings.warn(message, category, stacklevel=2)


class ShardHost:
    """A shard's state built from its spec, called by method name (also the Dask actor class)."""

    def __init__(self, factory: Callable[..., Any], args: tuple) -> None:
        self.state = factory(*args)

    def call(self, method: str, args: tuple) -> Any:
        return getattr(self.state, method)(*args)

    def call_recording(self, method: str, args: tuple) -> tuple[Any, list[tuple[type[Warning], str]]]:
        """:meth:`call` and the warnings it raised (:func:`recording_warnings`)."""
        return recording_warnings(self.call, method, args)


class InProcessShard:
    """A shard kept in the driver's process: evaluated when its result is asked for."""

    def __init__(self, spec: tuple) -> None:
        self.host = ShardHost(*spec)
        self.pending: tuple | None = None

    def submit(self, method: str, args: tuple) -> None:
        self.pending = (method, args)

    def result(self) -> Any:
        if self.pending is None:
            raise FactIRLError("internal: a shard's result was asked for before its call was sent")
        (method, args), self.pending = self.pending, None
        return self.host.call(method, args)

    def close(self) -> None:
        self.host = None  # type: ignore[assignment]


def _parent_alive(parent_pid: int) -> bool:
    """Whether the process ``parent_pid`` that started this one is alive: its ``multiprocessing`` sentinel
    (a fork server's child is not the driver's child), else the parent's pid."""
    parent = multiprocessing.parent_process()
    if parent is not None and parent.pid == parent_pid:
        return parent.is_alive()
    return os.getppid() == parent_pid


def _watch_parent(parent_pid: int) -> None:
    while True:
        time.sleep(POLL_SECONDS)
        if not _parent_alive(parent_pid):
            os._exit(3)


def become_worker(parent_pid: int) -> None:
    """Make this child process a worker: Ctrl-C ignored (it reaches the whole process group; the
    parent decides), marked as a worker (fits inside run with one job), and exited when its
    parent ``parent_pid`` dies (a thread polls every :data:`POLL_SECONDS`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    mark_worker()
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True).start()


def serve_calls(conn: Any, handle: Callable[[Any], Any], error: type[Exception] = FactIRLError) -> None:
    """Answer each message of ``conn`` with ``("ok", handle(message), warnings)`` or ``("error", exc, tb)``
    until ``None`` arrives or the pipe closes; ``warnings`` are those the call raised
    (:func:`recording_warnings`; the receiver raises them again with :func:`replay_warnings`). A reply that cannot
    be pickled is answered with an ``error`` saying so."""
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        reply: tuple
        try:
            reply = ("ok", *recording_warnings(handle, task))
        except Exception as exc:
            reply = ("error", exc, traceback.format_exc())
        try:
            conn.send(reply)
        except (OSError, ValueError):
            return
        except Exception as exc:  # an unpicklable result or exception
            conn.send(("error", error(f"cannot send the result back: {exc}"), traceback.format_exc()))


def _cpu_clock() -> Callable[[], float]:
    """CPU seconds used by the calling thread, readable from another thread (the process's CPU
    time where threads have no clock of their own)."""
    try:
        clock = time.pthread_getcpuclockid(threading.get_ident())
        time.clock_gettime(clock)
    except (AttributeError, OSError):
        return time.process_time
    return lambda: time.clock_gettime(clock)


def _beat(progress: Any, clock: Callable[[], float]) -> None:
    """Publish the serving thread's CPU time in ``progress`` (shared memory) until the process exits:
    the driver sees a shard that is working from one that is stopped or deadlocked."""
    while True:
        progress.value = clock()
        time.sleep(POLL_SECONDS / 2)


def _serve(conn: Any, spec: tuple | bytes, parent_pid: int, progress: Any = None) -> None:
    """A shard process: build the state from ``spec`` (pickled, or not), then answer ``(method, args)``
    with ``("ok", result)`` or ``("error", exc, tb)``."""
    from .._threads import blas_thread_limit, limit_blas_threads

    if progress is not None:
        threading.Thread(target=_beat, args=(progress, _cpu_clock()), daemon=True).start()
    become_worker(parent_pid)
    with limit_blas_threads(blas_thread_limit()):
        try:
            if isinstance(spec, bytes):
                spec = pickle.loads(spec)
            host, caught = recording_warnings(ShardHost, *spec)
        except Exception as exc:
            conn.send(("error", exc, traceback.format_exc()))
            return
        conn.send(("ok", None, caught))
        serve_calls(conn, lambda task: host.call(*task))


#: the modules the fork server imports once (:func:`_context`): its shard processes start with the
#: library loaded and marked as workers, before they import anything of the caller's
FORKSERVER_PRELOAD = ["factirl_opt.parallel._preload"]
#: the name of a shard process; one whose spec does not refer to the caller's ``__main__`` (a class
#: defined in a script) does not import it (:func:`_skip_main_for_shards`): a script without the
#: ``if __name__ == "__main__":`` guard is not run again in each shard process
SHARD_PROCESS_NAME = "factirl-opt shard"


def _context() -> Any:
    """The start method of shard processes: ``forkserver`` where available, else ``spawn``; never ``fork``.

    A process forked from a multithreaded one (a notebook server, a test runner's worker, a
    program whose other thread runs a fit) can deadlock on any lock another thread held at the
    fork: the library's own, glibc's or BLAS's. A fork server is a fresh single-threaded process
    (started once per process, on the first sharded fit) that imports the library once
    (:data:`FORKSERVER_PRELOAD`) and forks every shard process; a shard's spec is pickled and
    sent there. The caller's ``__main__`` is imported there, as with ``spawn``, only when the spec
    refers to it (:data:`SHARD_PROCESS_NAME`): then a script needs the usual
    ``if __name__ == "__main__":`` guard.
    """
    _skip_main_for_shards()
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(FORKSERVER_PRELOAD)  # no effect once the server runs
    return ctx


def start_shard_server(wait: bool = False) -> bool:
    """Start the fork server of shard processes now, so that the first fit with ``n_jobs`` does not wait for it.

    The server is a fresh process that imports the library once (:data:`FORKSERVER_PRELOAD`),
    then forks every shard process of this process's fits (:func:`_context`). It starts on the
    first sharded fit otherwise, and that fit waits for the import (about a second of the
    server's CPU time, on another core). This call returns at once: the server imports in its own
    process while the caller goes on (loads data, builds its problem). Call it early in a program
    that will fit with ``n_jobs`` (the experiment runner and the benchmarks do, when given jobs).
    Safe from any thread, and a no-op when already running, where ``forkserver`` is not
    available (shards are spawned), in a worker process (fits there run with one job) or in a
    daemonic process (it cannot have children).

    Parameters
    ----------
    wait : bool, default=False
        Return only once the server has imported the library and started a first process
        (then the next fit's shards start as processes at once).

    Returns
    -------
    bool
        Whether a fork server runs (or is starting) for this process.
    """
    if in_worker() or daemonic():
        return False
    ctx = _context()
    if ctx.get_start_method() != "forkserver":
        return False
    from multiprocessing import forkserver

    with _START_LOCK:  # no shard process starts meanwhile (its pipe end would leak into the server)
        forkserver.ensure_running()
    if not _SERVER_READY[0]:  # a first process from it, in the background: ready once the server has imported
        first = threading.Thread(target=_first_child, args=(ctx,), daemon=True, name="factirl-opt shard server start")
        first.start()
        if wait:
            first.join()
    return True


def _no_work() -> None:
    """What the first process of a fork server started by :func:`start_shard_server` does."""


def _first_child(ctx: Any) -> None:
    """Start and join one process from the fork server: when it returns, the server has imported the
    library, and the next shards start as processes at once (not :class:`StartingShard`)."""
    try:
        with _START_LOCK:
            proc = ctx.Process(target=_no_work, daemon=True, name=SHARD_PROCESS_NAME)
            proc.start()
        proc.join()
        _SERVER_READY[0] = True
    except Exception:  # noqa: BLE001 - a fit starts its shards as it would have without it
        pass


_MAIN_KEYS = ("init_main_from_path", "init_main_from_name")
_WRAP_LOCK = threading.Lock()


def _skip_main_for_shards() -> None:
    """Once per process, on the first sharded fit: ``multiprocessing``'s preparation data of a process
    named exactly :data:`SHARD_PROCESS_NAME` omits the caller's ``__main__`` (that of every other
    process is unchanged). A shard whose spec refers to ``__main__`` is named otherwise and imports it."""
    from multiprocessing import spawn

    with _WRAP_LOCK:
        original = spawn.get_preparation_data
        if getattr(original, "skips_main_for_shards", False):
            return

        def get_preparation_data(name: str) -> dict[str, Any]:
            data = original(name)
            if name == SHARD_PROCESS_NAME:
                data = {key: value for key, value in data.items() if key not in _MAIN_KEYS}
            return data

        get_preparation_data.skips_main_for_shards = True  # type: ignore[attr-defined]
        spawn.get_preparation_data = get_preparation_data


def _forget_fork_server() -> None:
    """In a child forked from a process that runs a fork server: start a server of its own when one is
    needed. The inherited one is not the child's child (``multiprocessing`` would fail with
    ``ChildProcessError`` checking it), and its lock may have been held by another thread at the fork."""
    from multiprocessing import forkserver

    _SERVER_READY[0] = False  # this child's first shards start its own server
    server = getattr(forkserver, "_forkserver", None)
    if server is None or getattr(server, "_forkserver_pid", None) is None:
        return
    try:
        os.close(server._forkserver_alive_fd)
    except (OSError, TypeError):
        pass
    server._forkserver_address = server._forkserver_alive_fd = server._forkserver_pid = None
    server._lock = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_fork_server)


class ProcessShard:
    """A shard in its own process, talking through a pipe; started at once, stopped by :meth:`close`."""

    def __init__(self, spec: tuple) -> None:
        ctx = _context()
        self.progress = ctx.RawValue("d", -1.0)  # the shard's serving thread's CPU seconds (:func:`_beat`)
        # the spec travels pickled: a fork server's child imports the caller's __main__ only when the spec
        # refers to it (:data:`SHARD_PROCESS_NAME`), and a spec that does not unpickle there is an error reply
        data = pickle.dumps(spec, protocol=pickle.HIGHEST_PROTOCOL)
        name = SHARD_PROCESS_NAME + (" (__main__)" if b"__main__" in data else "")
        with _START_LOCK:
            self.conn, child = ctx.Pipe()
            self.proc = ctx.Process(target=_serve, args=(child, data, os.getpid(), self.progress), daemon=True, name=name)
            self.proc.start()
            child.close()
        self._ready = False

    def _wait(self) -> None:
        """Until a reply is readable. :class:`ShardLost` once the process is dead (even if another process
        still holds its end of the pipe), or silent for :data:`SILENCE_SECONDS`: nothing sent and no CPU
        time used (stopped, or deadlocked); a silent process is killed."""
        last, since = self.progress.value, time.monotonic()
        while not self.conn.poll(POLL_SECONDS):
            if not self.proc.is_alive():
                raise ShardLost(f"shard process {self.proc.pid} died (exit code {self.proc.exitcode})")
            now, value = time.monotonic(), self.progress.value
            if value != last:
                last, since = value, now
            elif now - since >= SILENCE_SECONDS:
                self.proc.kill()
                raise ShardLost(f"shard process {self.proc.pid} sent nothing and used no CPU time for "
                                f"{SILENCE_SECONDS:g} s (stopped, or deadlocked); it was killed")

    def _receive(self) -> Any:
        try:
            self._wait()
            reply = self.conn.recv()
        except (EOFError, OSError) as exc:
            raise ShardLost(f"shard process {self.proc.pid} died (exit code {self.proc.exitcode})") from exc
        if reply[0] == "error":
            raise reply[1]
        replay_warnings(reply[2])
        return reply[1]

    def submit(self, method: str, args: tuple) -> None:
        try:
            self.conn.send((method, args))
        except (OSError, ValueError) as exc:
            raise ShardLost(f"shard process {self.proc.pid} cannot be reached") from exc

    def wait_built(self) -> None:
        """Until the shard's state is built in its process (its first reply)."""
        if not self._ready:
            self._receive()  # the state was built
            self._ready = True
            _SERVER_READY[0] = True

    def result(self) -> Any:
        self.wait_built()
        return self._receive()

    def close(self) -> None:
        try:
            self.conn.send(None)
        except (OSError, ValueError):
            pass
        self.proc.join(timeout=1.0)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()
        self.conn.close()


#: true once a shard process of this process was built: its fork server runs and has imported the library
#: (a plain flag, not an Event: a child forked from this process clears it, see :func:`_forget_fork_server`)
_SERVER_READY = [False]


class StartingShard:
    """A shard whose process starts in the background, served in this process until it is built.

    Used for the shard processes of a process's first sharded fit (:class:`Shards`), which would
    otherwise wait, idle, for the fork server to start and import the library (about a second of
    its CPU time): a thread starts the process while the caller's calls to this shard run here, on
    a copy of its state built from the same spec (:class:`InProcessShard`, built on the first
    call). :meth:`Shards.call` hands the shard over to its process (:attr:`started`) at the start
    of a call, as it does a rebuilt shard: ``on_restart(k)`` gives it what the calls need.
    """

    def __init__(self, spec: tuple) -> None:
        self.spec = spec
        self.local: InProcessShard | None = None
        self.started: ProcessShard | None = None  # the process, once started and its state built
        self.error: BaseException | None = None  # why the process could not be started or built
        self._lock = threading.Lock()
        self._closed = False
        self._done = threading.Event()
        threading.Thread(target=self._start, daemon=True, name="factirl-opt shard start").start()

    def _start(self) -> None:
        shard = None
        try:
            shard = ProcessShard(self.spec)
            shard.wait_built()
        except BaseException as exc:  # noqa: BLE001 - reported when the shard is handed over
            self.error = exc
        with self._lock:
            keep = not self._closed and self.error is None
            if keep:
                self.started = shard
        if shard is not None and not keep:
            shard.close()
        self._done.set()

    def done(self) -> bool:
        """Whether the background start has ended (:attr:`started` or :attr:`error` is set)."""
        return self._done.is_set()

    @property
    def proc(self) -> Any:
        """The shard's process, once started (waits for it)."""
        self._done.wait()
        if self.started is None:
            raise ShardLost(f"the shard process could not be started: {self.error}")
        return self.started.proc

    def submit(self, method: str, args: tuple) -> None:
        if self.local is None:
            self.local = InProcessShard(self.spec)
        self.local.submit(method, args)

    def result(self) -> Any:
        if self.local is None:
            raise FactIRLError("internal: a shard's result was asked for before its call was sent")
        return self.local.result()

    def close(self) -> None:
        """Stop the shard: its process too, once its start has ended (waited for, so that no process of a
        fit outlives it)."""
        with self._lock:
            self._closed = True
        if self.local is not None:
            self.local.close()
        self._done.wait(SILENCE_SECONDS + POLL_SECONDS)
        with self._lock:
            started, self.started = self.started, None
        if started is not None:
            started.close()


def _lost_dask_worker(exc: BaseException) -> bool:
    """Whether ``exc`` says an actor's worker went away (not an error of the computation)."""
    from distributed.comm.core import CommClosedError

    if isinstance(exc, FactIRLError):  # the library's own errors come from the computation
        return False
    text = str(exc).lower()
    return isinstance(exc, (CommClosedError, OSError)) or any(w in text for w in ("lost", "closed", "not found", "no longer"))


@contextlib.contextmanager
def _lost_as_shard_lost() -> Iterator[None]:
    try:
        yield
    except Exception as exc:
        if _lost_dask_worker(exc):
            raise ShardLost(f"a Dask worker holding a shard was lost ({exc})") from exc
        raise


class DaskShard:
    """A shard held by a Dask actor (:class:`ShardHost`) on worker ``k mod n_workers`` of ``client``.

    Every wait is bounded: the actor's creation waits at most :data:`DASK_WAIT_SECONDS` while no
    worker runs it (every worker gone, or a task stranded by workers dying around it), then
    :class:`WorkersLost`; a call's reply is awaited while the actor's worker is in the cluster, and
    :class:`ShardLost` (the shard is rebuilt) as soon as it is not (a call to a dead worker's actor can
    otherwise wait on Dask's own connection timeouts and re-creation of the actor).
    """

    def __init__(self, spec: tuple, client: Any, k: int) -> None:
        self.client, self.k = client, k
        workers = _wait_for_dask_worker(client)
        with _lost_as_shard_lost():
            future = client.submit(ShardHost, *spec, actor=True, workers=[workers[k % len(workers)]],
                                   allow_other_workers=True, pure=False)
            self.actor = self._created(future)
        self.worker = getattr(self.actor, "_address", None)  # where the actor lives
        self.future: Any = None

    def _created(self, future: Any) -> Any:
        since = time.monotonic()  # the last moment a worker was running the creation
        while True:
            try:
                return future.result(timeout=POLL_SECONDS)
            except TimeoutError:
                pass
            workers = dask_workers(self.client, during_fit=True)
            try:
                running = any(future.key in keys for keys in self.client.processing(workers=workers).values()) if workers else False
            except Exception:  # noqa: BLE001 - the scheduler went away meanwhile: judged at the next check
                running = False
            now = time.monotonic()
            if running:
                since = now
            elif now - since > DASK_WAIT_SECONDS:
                future.cancel()
                raise WorkersLost(f"shard {self.k} was not started on any worker of the Dask cluster of {self.client!r} "
                                  f"within {DASK_WAIT_SECONDS:g} s (parallel.DASK_WAIT_SECONDS; its workers were lost); "
                                  "restart workers, or refit with n_jobs=1")

    def submit(self, method: str, args: tuple) -> None:
        with _lost_as_shard_lost():
            self.future = self.actor.call_recording(method, args)

    def result(self) -> Any:
        with _lost_as_shard_lost():
            while True:
                try:
                    result, caught = self.future.result(timeout=POLL_SECONDS)
                    break
                except TimeoutError:
                    if self.worker is not None and self.worker not in dask_workers(self.client, during_fit=True):
                        raise ShardLost(f"the Dask worker {self.worker} holding shard {self.k} left the cluster") from None
        replay_warnings(caught)
        return result

    def close(self) -> None:
        self.actor = self.future = None


def _given_up(k: int, exc: ShardLost) -> WorkersLost:
    return WorkersLost(f"shard {k}'s worker was lost {MAX_RESTARTS + 1} times in one call (parallel.MAX_RESTARTS "
                       f"rebuilds); the last time: {exc}")


class Shards:
    """One handle per shard spec, called together; rebuilt from the spec when a worker is lost.

    Parameters
    ----------
    specs : sequence of (factory, args)
        How to build each shard's state (``factory(*args)``), kept by the driver.
    backend : {"processes", "dask"}
        ``"processes"``: shard 0 in this process, the others in processes of this machine;
        ``"dask"``: every shard in an actor on ``client``'s workers.
    client : dask.distributed.Client, optional
    serve_while_starting : bool, default=False
        Whether a process's first shard processes may be served in this process while they start
        (:class:`StartingShard`): for callers whose every call passes ``on_restart`` (the sharded
        objectives), which gives a shard handed over to its process what its calls need. Otherwise
        the start waits for the fork server.

    Attributes
    ----------
    bytes_sent : int
        Array bytes sent to the shards and received from them by the calls so far (the
        driver's own shard sends nothing).
    bytes_setup : int
        Array bytes of the specs sent when shards were (re)built outside this process.
    n_restarts : int
        Shards rebuilt after their worker was lost.
    """

    def __init__(self, specs: Sequence[tuple], backend: str = "processes", client: Any = None,
                 serve_while_starting: bool = False) -> None:
        self.specs, self.backend, self.client = list(specs), check_backend(backend, client), client
        self.serve_while_starting = serve_while_starting
        self.bytes_sent = self.bytes_setup = self.n_restarts = 0
        self.handles: list[Any] = [None] * len(self.specs)
        try:  # the driver's own shard last: it is built while the other shards' processes start
            for k in sorted(range(len(self.specs)), key=lambda k: backend == "processes" and k == 0):
                self.handles[k] = self._start(k, first=True)
        except BaseException:
            self.close()
            raise

    def _start(self, k: int, first: bool = False) -> Any:
        if self.backend == "processes" and k == 0:
            return InProcessShard(self.specs[k])
        self.bytes_setup += array_bytes(list(self.specs[k][1]))
        if self.backend == "dask":
            return DaskShard(self.specs[k], self.client, k)
        if first and self.serve_while_starting and not _SERVER_READY[0]:  # not waiting for the fork server
            return StartingShard(self.specs[k])
        return ProcessShard(self.specs[k])

    def _hand_over(self, k: int, on_restart: Callable[[int], None] | None) -> None:
        """Shard k served here while its process started (:class:`StartingShard`) goes to its process once
        that is built, as a rebuilt shard (``on_restart(k)``; without one the shard stays here until a
        call that has one). A start that failed is retried as a lost shard is."""
        h = self.handles[k]
        if not isinstance(h, StartingShard) or on_restart is None or not h.done():
            return
        if h.started is None:
            if h.error is not None and not isinstance(h.error, (ShardLost, OSError, EOFError)):
                raise h.error  # the spec does not build: the error it gives, as from a shard process
            raise ShardLost(f"shard {k}'s process was lost while it started ({h.error})")  # rebuilt as a lost one
        with h._lock:
            self.handles[k], h.started = h.started, None
        h.close()
        on_restart(k)

    def _restart(self, k: int, on_restart: Callable[[int], None] | None) -> None:
        try:
            self.handles[k].close()
        except Exception:  # noqa: BLE001 - the lost worker's handle may not close cleanly
            pass
        self.handles[k] = self._start(k)
        self.n_restarts += 1
        if on_restart is not None:
            on_restart(k)

    def call(self, calls: Sequence[tuple[int, str, tuple]], on_restart: Callable[[int], None] | None = None) -> list[Any]:
        """``state.method(*args)`` for each ``(k, method, args)`` (distinct shards), all sent before any is
        collected; results in the order of ``calls``. A lost shard is rebuilt, ``on_restart(k)`` run,
        and its call sent again."""
        if not self.handles:
            raise FactIRLError("these shards are closed (their fit ended or was interrupted)")
        order = sorted(range(len(calls)), key=lambda j: not isinstance(self.handles[calls[j][0]], InProcessShard))
        results: list[Any] = [None] * len(calls)
        error: Exception | None = None
        try:
            for k, method, args in calls:
                self._send(k, method, args, on_restart)
            for j in order:  # the driver's own shard first: it runs while the others do
                try:
                    results[j] = self._collect(*calls[j], on_restart)
                except Exception as exc:  # noqa: BLE001 - every reply is read before raising the first error
                    error = error or exc
        except BaseException:
            self.close()  # interrupted mid-call: the pipes hold unread replies
            raise
        if error is not None:
            raise error
        return results

    def _send(self, k: int, method: str, args: tuple, on_restart: Callable[[int], None] | None) -> None:
        for attempt in range(MAX_RESTARTS + 1):
            try:
                self._hand_over(k, on_restart)
                self.handles[k].submit(method, args)
                break
            except ShardLost as exc:
                if attempt == MAX_RESTARTS:
                    raise _given_up(k, exc) from exc
                self._restart(k, on_restart)
        if not isinstance(self.handles[k], InProcessShard):
            self.bytes_sent += array_bytes(list(args))

    def _collect(self, k: int, method: str, args: tuple, on_restart: Callable[[int], None] | None) -> Any:
        for attempt in range(MAX_RESTARTS + 1):
            try:
                out = self.handles[k].result()
                break
            except ShardLost as exc:
                if attempt == MAX_RESTARTS:
                    raise _given_up(k, exc) from exc
                self._restart(k, on_restart)
                self._send(k, method, args, on_restart)
        if not isinstance(self.handles[k], InProcessShard):
            self.bytes_sent += array_bytes(out)
        return out

    def close(self) -> None:
        """Stop every shard (processes joined, actors dropped)."""
        handles, self.handles = self.handles, []
        for h in handles:
            try:
                if h is not None:
                    h.close()
            except Exception:  # noqa: BLE001 - closing the others matters more
                pass

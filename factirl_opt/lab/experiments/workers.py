"""Worker processes of the runner: spawned, fed one task at a time, and never outliving their parent.

Why not joblib's loky: its workers are kept for reuse after the work is done (300 s idle
timeout), do not notice that their parent died (after a ``kill -9`` of the parent they finish
their run, then wait), keep a resource tracker and joblib memmapping folders in ``/dev/shm``.
Here:

- each worker is a ``multiprocessing`` *spawn* process talking to the parent through its own
  pipe (no shared memory, no semaphores, nothing in ``/dev/shm``);
- a worker ignores SIGINT (a Ctrl-C reaches the whole process group: the parent decides) and
  runs a watchdog thread that polls ``os.getppid()`` every :data:`POLL_SECONDS` and exits at
  once when the parent is gone (SIGKILL of the parent: the workers exit within about a
  second); a worker whose pipe closes exits too;
- a SIGTERM that arrives while the workers start is held until every worker is known, then
  delivered (so no worker is ever started without being stopped);
- the parent, on any exit from :func:`imap_unordered` (done, an error, KeyboardInterrupt, or
  :class:`Terminated` raised by SIGTERM inside :func:`sigterm_raises`), terminates and reaps
  every worker (SIGTERM, then SIGKILL after :data:`GRACE_SECONDS`), so none outlives the
  signal by more than a second.

Python's spawn start method also starts multiprocessing's resource tracker (it holds no
resources here). When :func:`imap_unordered` started it, it is stopped with the workers;
otherwise it exits by itself once the parent and the workers are gone.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import multiprocessing.resource_tracker
import os
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from multiprocessing.connection import wait
from typing import Any

from ...exceptions import FactIRLError
from ...parallel.shards import POLL_SECONDS, become_worker, replay_warnings, serve_calls

__all__ = ["imap_unordered", "sigterm_raises", "Terminated", "WorkerError", "POLL_SECONDS"]

#: how often a worker checks that its parent is alive (seconds)
#: how long a terminated worker gets before SIGKILL (seconds): workers hold nothing to clean up
GRACE_SECONDS = 0.5


class WorkerError(FactIRLError):
    """A worker process died without returning its task's result."""


class Terminated(KeyboardInterrupt):
    """Raised in the main thread by SIGTERM inside :func:`sigterm_raises` (``signum`` attribute)."""

    def __init__(self, signum):
        super().__init__(f"terminated by signal {signum}")
        self.signum = signum


class _RemoteTraceback(Exception):
    def __init__(self, tb):
        super().__init__(tb)
        self.tb = tb

    def __str__(self):
        return self.tb


@contextlib.contextmanager
def sigterm_raises() -> Iterator[None]:
    """Turn SIGTERM into a :class:`Terminated` exception in the main thread for the block.

    So ``finally`` clauses run (workers reaped, lock released) when a sweep is terminated. Does
    nothing outside the main thread (where signal handlers cannot be set).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise Terminated(signum)

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _worker_main(conn, parent_pid):
    """A worker's loop: receive ``(fn, args)``, send back ``("ok", result, warnings)`` or ``("error", exc, tb)``."""
    become_worker(parent_pid)  # a fit in a sweep worker runs with n_jobs=1: pools never nest
    serve_calls(conn, lambda task: task[0](*task[1]), WorkerError)


def _start(ctx, n):
    """Start ``n`` workers, with SIGINT ignored from their first instruction (spawned children inherit it).

    A SIGTERM received meanwhile is held (an exception raised inside ``Process.start`` could
    lose a started child); once every worker is known, they are stopped and the signal is
    delivered to the previous handler (the workers are stopped if it raises or ends the process).
    """
    main = threading.current_thread() is threading.main_thread()
    held = []
    if main:
        previous_int = signal.signal(signal.SIGINT, signal.SIG_IGN)
        previous_term = signal.signal(signal.SIGTERM, lambda signum, frame: held.append(signum))
    workers = []
    try:
        for _ in range(n):
            parent_end, child_end = ctx.Pipe()
            proc = ctx.Process(target=_worker_main, args=(child_end, os.getpid()), daemon=True)
            workers.append((proc, parent_end))
            proc.start()
            child_end.close()
    except BaseException:
        _stop([(p, c) for p, c in workers if p.pid is not None])
        raise
    finally:
        if main:
            signal.signal(signal.SIGINT, previous_int)
            signal.signal(signal.SIGTERM, previous_term)
    if held and previous_term is not signal.SIG_IGN:
        if previous_term in (signal.SIG_DFL, None):
            _stop(workers)  # the signal ends this process: stop the workers first
        try:
            signal.raise_signal(held[0])  # the previous handler: Terminated inside sigterm_raises
        except BaseException:
            _stop(workers)
            raise
    return workers


def _stop(workers):
    """Terminate and reap every worker (SIGTERM, then SIGKILL after the grace period)."""
    for proc, conn in workers:
        conn.close()
        if proc.is_alive():
            proc.terminate()
    deadline = time.monotonic() + GRACE_SECONDS
    for proc, _ in workers:
        proc.join(max(0.0, deadline - time.monotonic()))
        if proc.is_alive():
            proc.kill()
            proc.join()


def _tracker_running():
    """Whether multiprocessing's resource tracker runs (started by an earlier spawn)."""
    return getattr(multiprocessing.resource_tracker._resource_tracker, "_fd", None) is not None


def _stop_tracker():
    """Stop the resource tracker the workers' spawn started (best effort: a private stdlib method)."""
    stop = getattr(multiprocessing.resource_tracker._resource_tracker, "_stop", None)
    if stop is not None:
        with contextlib.suppress(Exception):
            stop()


def imap_unordered(fn: Callable[..., Any], tasks: Iterable[tuple], jobs: int) -> Iterator[Any]:
    """Yield ``fn(*args)`` for every ``args`` of ``tasks``, computed by ``jobs`` worker processes.

    Results come as they finish. An exception raised by ``fn`` in a worker is re-raised here
    (with the worker's traceback as its cause); a worker that dies raises :class:`WorkerError`.
    ``fn`` and the arguments must be picklable (module-level functions, plain data).
    """
    tasks = list(tasks)
    if not tasks:
        return
    ours = not _tracker_running()
    try:
        workers = _start(multiprocessing.get_context("spawn"), min(int(jobs), len(tasks)))
    except BaseException:
        if ours:
            _stop_tracker()
        raise
    try:
        pending = iter(tasks)
        busy: dict[Any, Any] = {}
        for proc, conn in workers:
            _submit(pending, proc, conn, busy, fn)
        while busy:
            for conn in wait(list(busy)):
                proc, args = busy.pop(conn)
                yield _receive(conn, proc, args)
                _submit(pending, proc, conn, busy, fn)
    finally:
        _stop(workers)
        if ours:
            _stop_tracker()


def _submit(pending, proc, conn, busy, fn):
    args = next(pending, None)
    if args is not None:
        conn.send((fn, args))
        busy[conn] = (proc, args)


def _receive(conn, proc, args):
    try:
        reply = conn.recv()
    except (EOFError, OSError):
        proc.join(1.0)
        raise WorkerError(f"worker process {proc.pid} died (exit code {proc.exitcode}) while running {args!r}") from None
    if reply[0] == "error":
        raise reply[1] from _RemoteTraceback(reply[2])
    replay_warnings(reply[2])
    return reply[1]

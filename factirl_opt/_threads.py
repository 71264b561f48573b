"""BLAS thread limits for the library's batched small dense solves (internal).

The planning and gradient kernels solve many small (S x S) systems at once. Multi-threaded
BLAS gains nothing on them and, on a loaded or shared machine (or under ``--jobs`` process
parallelism), thread oversubscription slows them by one to two orders of magnitude. The public
entry points therefore run with BLAS limited to ``FACTIRL_BLAS_THREADS`` threads (default 1);
set that environment variable to another positive integer, or to ``0`` to leave the BLAS
configuration untouched.

BLAS thread counts are process-wide, and OpenBLAS does not reliably take a new count from a
thread other than the main one (measured with OpenBLAS 0.3.30/0.3.31: after the main thread
lowered the count, a worker thread's request to raise it back is ignored, so a limit opened in a
worker could never be undone). Limits are therefore changed by the main thread only: calls made
from other threads (a thread pool) run under the limits in force, e.g. those of a
:func:`limit_blas_threads` block the main thread opened around the pool, and never change them.
The main thread's open limits form a stack under a lock: the innermost one is in effect, and the
counts the process had before the first one opened are restored when the last one closes.
"""

from __future__ import annotations

import contextlib
import functools
import os
import threading
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

from .exceptions import ValidationError

__all__ = ["blas_limited", "blas_thread_limit", "limit_blas_threads"]

F = TypeVar("F", bound=Callable[..., Any])

_controller = None
_lock = threading.Lock()
_open: list[int] = []  # the limits of the open blocks of every thread, in the order they opened
_saved: list[int] = []  # per BLAS library, its thread count before the first block opened


def _before_fork() -> None:
    """Hold the lock across a fork: no thread is then inside a BLAS library's thread setter, whose
    own lock (OpenBLAS's ``server_lock``) a forked child would otherwise inherit held."""
    _lock.acquire()


def _after_fork_in_parent() -> None:
    _lock.release()


def _after_fork_in_child() -> None:
    """A forked child starts with a free lock and no open block: the thread that held the lock
    (or opened the blocks) at the fork does not exist in the child, which would wait forever."""
    global _lock
    _lock = threading.Lock()
    _open.clear()
    _saved.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(before=_before_fork, after_in_parent=_after_fork_in_parent, after_in_child=_after_fork_in_child)


def blas_thread_limit() -> int | None:
    """The configured limit (int >= 1), or None to leave BLAS alone."""
    raw = os.environ.get("FACTIRL_BLAS_THREADS", "1").strip()
    try:
        value = int(raw)
    except ValueError:
        raise ValidationError(f"FACTIRL_BLAS_THREADS must be a nonnegative integer; got {raw!r}") from None
    if value < 0:
        raise ValidationError(f"FACTIRL_BLAS_THREADS must be a nonnegative integer; got {raw!r}")
    return value or None


def _blas_libraries() -> list[Any]:
    global _controller
    if _controller is None:
        from threadpoolctl import ThreadpoolController

        _controller = ThreadpoolController()  # built once: inspecting the loaded libraries is slow
    return _controller.select(user_api="blas").lib_controllers


def _set(libs: list[Any], counts: list[int]) -> None:
    for lib, n in zip(libs, counts):
        if lib.num_threads != n:  # a setter call only when it changes something (it takes the library's lock)
            lib.set_num_threads(n)


@contextlib.contextmanager
def _limited(n_threads: int) -> Iterator[list[int]]:
    """BLAS limited to ``n_threads`` while the block is open, from the main thread only (see the
    module docstring); yields the counts in effect."""
    if threading.current_thread() is not threading.main_thread():
        yield [lib.num_threads for lib in _blas_libraries()]
        return
    with _lock:
        libs = _blas_libraries()
        if not _open:
            _saved[:] = [lib.num_threads for lib in libs]
        _open.append(n_threads)
        _set(libs, [n_threads] * len(libs))
        counts = [lib.num_threads for lib in libs]
    try:
        yield counts
    finally:
        with _lock:
            _open.pop()  # only the main thread opens limits: they close in the reverse order
            _set(libs, [_open[-1]] * len(libs) if _open else _saved)


@contextlib.contextmanager
def limit_blas_threads(n_threads: int | None = 1) -> Iterator[list[int]]:
    """Context manager: BLAS limited to ``n_threads`` threads, restored on exit.

    Used by the experiment runner and the benchmarks around whole runs. ``n_threads`` None or
    0 leaves BLAS as it is. Yields the thread counts now in effect, one per BLAS library
    loaded (empty when none is found). Called from a thread other than the main one, it changes
    nothing (see the module docstring), so threaded use never leaves the limits changed.
    """
    if not n_threads:
        yield [lib.num_threads for lib in _blas_libraries()]
        return
    with _limited(int(n_threads)) as counts:
        yield counts


def blas_limited(func: F) -> F:
    """Decorator: run ``func`` with BLAS limited to ``FACTIRL_BLAS_THREADS`` threads."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        limit = blas_thread_limit()
        if limit is None:
            return func(*args, **kwargs)
        with _limited(limit):
            return func(*args, **kwargs)

    return wrapper  # type: ignore[return-value]

"""BLAS thread limits for the library's batched small dense solves (internal).

The planning and gradient kernels solve many small (S x S) systems at once. Multi-threaded
BLAS gains nothing on them and, on a loaded or shared machine (or under ``--jobs`` process
parallelism), thread oversubscription slows them by one to two orders of magnitude (measured
on the 2-core development machine: ``deviation`` on 100 tasks 43.7 s with 2 OpenBLAS threads
vs 0.20 s with 1). The public entry points therefore run with BLAS limited to
``FACTIRL_BLAS_THREADS`` threads (default 1); set that environment variable to another
positive integer, or to ``0`` to leave the BLAS configuration untouched.
"""

import contextlib
import functools
import os

from .exceptions import ValidationError

__all__ = ["blas_limited", "blas_thread_limit", "limit_blas_threads"]

_controller = None


def blas_thread_limit():
    """The configured limit (int >= 1), or None to leave BLAS alone."""
    raw = os.environ.get("FACTIRL_BLAS_THREADS", "1").strip()
    try:
        value = int(raw)
    except ValueError:
        raise ValidationError(f"FACTIRL_BLAS_THREADS must be a nonnegative integer; got {raw!r}") from None
    if value < 0:
        raise ValidationError(f"FACTIRL_BLAS_THREADS must be a nonnegative integer; got {raw!r}")
    return value or None


def _get_controller():
    global _controller
    if _controller is None:
        from threadpoolctl import ThreadpoolController

        _controller = ThreadpoolController()  # built once: inspecting the loaded libraries is slow
    return _controller


def _limit():
    limit = blas_thread_limit()
    return None if limit is None else _get_controller().limit(limits=limit, user_api="blas")


@contextlib.contextmanager
def limit_blas_threads(n_threads=1):
    """Context manager: BLAS limited to ``n_threads`` threads, restored on exit.

    Used by the experiment runner and the benchmarks around whole runs. ``n_threads`` None or
    0 leaves BLAS as it is. Yields the thread counts now in effect, one per BLAS library
    loaded (empty when none is found).
    """
    controller = _get_controller()
    libs = controller.select(user_api="blas").lib_controllers
    if not n_threads:
        yield [lib.num_threads for lib in libs]
        return
    with controller.limit(limits=int(n_threads), user_api="blas"):
        yield [lib.num_threads for lib in libs]


def blas_limited(func):
    """Decorator: run ``func`` with BLAS limited to ``FACTIRL_BLAS_THREADS`` threads."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        ctx = _limit()
        if ctx is None:
            return func(*args, **kwargs)
        with ctx:
            return func(*args, **kwargs)

    return wrapper

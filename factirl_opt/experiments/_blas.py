"""Limit the BLAS thread count of the running process (OpenBLAS, through ctypes).

Each experiment run is made of batched solves of small matrices; multi-threaded OpenBLAS only
adds overhead there and, when runs execute side by side (``--jobs``), oversubscribes the cores:
measured on a loaded 2-core machine, one GradIRL fit ran 13x slower with OpenBLAS's default
threads than with one thread. Runs are therefore single-threaded and parallel across runs;
fixing the thread count also keeps results bit-identical whatever ``--jobs`` is.
"""

import contextlib
import ctypes

__all__ = ["limit_blas_threads"]

_SET_NAMES = (
    "scipy_openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads",
    "openblas_set_num_threads64_",
    "openblas_set_num_threads",
)
_GET_NAMES = tuple(n.replace("set_", "get_") for n in _SET_NAMES)


def _blas_functions():
    """(setter, getter) pairs of every OpenBLAS loaded in this process (numpy's, scipy's)."""
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({ln.split()[-1] for ln in fh if "openblas" in ln.lower() and ln.split()[-1].startswith("/")})
    except OSError:  # not Linux: leave the BLAS alone
        return []
    pairs = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        setter = next((getattr(lib, n) for n in _SET_NAMES if hasattr(lib, n)), None)
        getter = next((getattr(lib, n) for n in _GET_NAMES if hasattr(lib, n)), None)
        if setter is not None and getter is not None:
            setter.argtypes, setter.restype = [ctypes.c_int], None
            getter.argtypes, getter.restype = [], ctypes.c_int
            pairs.append((setter, getter))
    return pairs


@contextlib.contextmanager
def limit_blas_threads(n_threads=1):
    """Context manager: every loaded OpenBLAS uses ``n_threads`` threads; restored on exit.

    Yields the thread counts in effect (empty when no OpenBLAS is loaded, e.g. another BLAS,
    which is then left as it is).
    """
    pairs = _blas_functions()
    previous = [get() for _, get in pairs]
    for set_, _ in pairs:
        set_(int(n_threads))
    try:
        yield [get() for _, get in pairs]
    finally:
        for (set_, _), n in zip(pairs, previous):
            set_(n)

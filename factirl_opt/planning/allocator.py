"""glibc allocator tuning for the sparse planner's factorisations (docs/maths.md §4).

Why. SuperLU sizes each factorisation's storage from an estimate, 20 nnz(M): four blocks of
3.4 MB at S = 1024 and 34 MB at S = 10,000, about ten times what it fills. A block is resident
only where it is written, unless glibc carves it from heap memory written before (glibc serves
any request from the heap's free chunks when it has some, whatever its mmap threshold). So the
sparse planner (1) has SuperLU's blocks memory-mapped when the heap has no room for them
(:func:`mapped_allocations`; mapped blocks return to the OS when freed) and (2) after building
factorisations returns the heap's free pages to the OS (:func:`release_free_memory`), so that a
block carved from them stays unresident where SuperLU never writes.

Process-wide effect. Both calls act on the C allocator of the whole process, not on the
library's memory alone: inside :func:`mapped_allocations` every thread's ``malloc`` of 64 KiB or
more is memory-mapped, and on exit glibc's mmap threshold is left at 32 MiB and its trim
threshold at 64 MiB (the ceilings its own dynamic thresholds reach, where numpy's temporaries
raise them anyway); ``malloc_trim`` returns every free heap page of the process. Neither changes
a computed value. Without glibc (macOS, Windows, musl) both do nothing.

The trim threshold. Setting the mmap threshold turns glibc's dynamic thresholds off, and the
trim threshold stays where it was (128 KiB in a fresh process): every ``free`` that leaves more
than that free at the heap's top returns it to the OS, and the next temporaries of a batch
(numpy's arrays of 1.2 MB for 30 tasks at S = 1024, A = 5) fault their pages in again, one
fault per 4 KiB. At 64 MiB, freed memory stays resident until the sparse planner's next
:func:`release_free_memory` (``TRIM_BYTES`` of factorisations later). On ``bench mce``'s
draw the two together took the default MCE fit from 1.8 to 1.0 million page faults and from
3.9 to 2.0-2.3 s of system time; neither alone did (1.8 million each; ``results/defaults/README.md``
§11).
"""

from __future__ import annotations

import contextlib
import ctypes
import platform
import threading
from collections.abc import Iterator
from typing import Any

__all__ = ["mapped_allocations", "release_free_memory"]

_M_TRIM_THRESHOLD = -1  # glibc's mallopt parameter numbers
_M_MMAP_THRESHOLD = -3
#: what :func:`mapped_allocations` leaves glibc's mmap and trim thresholds at (glibc's dynamic ceilings)
_MMAP_THRESHOLD_BYTES = 32 * 2**20
_TRIM_THRESHOLD_BYTES = 64 * 2**20
_GLIBC: list[Any] = []  # [the C library if it is glibc, else None], looked up once
_LOOKUP_LOCK = threading.Lock()


def _glibc() -> Any:
    """The C library when it is glibc (for ``mallopt`` and ``malloc_trim``), else None."""
    with _LOOKUP_LOCK:
        if not _GLIBC:
            lib = None
            if platform.libc_ver()[0] == "glibc":
                lib = ctypes.CDLL(None)
                lib.mallopt.argtypes, lib.mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
                lib.malloc_trim.argtypes, lib.malloc_trim.restype = (ctypes.c_size_t,), ctypes.c_int
            _GLIBC.append(lib)
        return _GLIBC[0]


@contextlib.contextmanager
def mapped_allocations() -> Iterator[None]:
    """glibc only: inside the ``with`` block, new allocations of 64 KiB or more are memory-mapped
    (process-wide, see the module docstring); on exit the mmap threshold is 32 MiB and the trim
    threshold 64 MiB."""
    lib = _glibc()
    if lib is None:
        yield
        return
    lib.mallopt(_M_MMAP_THRESHOLD, 64 * 2**10)
    try:
        yield
    finally:
        lib.mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_BYTES)
        lib.mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD_BYTES)


def release_free_memory() -> None:
    """glibc only: return the process heap's free pages to the OS (``malloc_trim(0)``)."""
    lib = _glibc()
    if lib is not None:
        lib.malloc_trim(0)

"""Observing step-solver runs: a callback after every :meth:`StepSolver.run`, for profiling.

>>> import solvers
>>> seen = []
>>> with solvers.observe_runs(lambda solver, problem, result, **info: seen.append(info["cpu_seconds"])):
...     ...  # every StepSolver.run finished here calls the callback

Observers are process-wide (a run in any thread calls them), kept in a list guarded by a lock;
with none registered a run pays one truthiness test.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from .exceptions import SolverOptionError

__all__ = ["observe_runs", "RunObserver"]

#: ``callback(solver, problem, result, *, separable, cpu_seconds)``
RunObserver = Callable[..., Any]

_OBSERVERS: list[RunObserver] = []
_LOCK = threading.Lock()


@contextmanager
def observe_runs(callback: RunObserver) -> Iterator[RunObserver]:
    """Call ``callback`` after every step-solver run finished inside the ``with`` block.

    Parameters
    ----------
    callback : callable
        Called as ``callback(solver, problem, result, separable=..., cpu_seconds=...)`` when a
        :meth:`~solvers.StepSolver.run` returns: the solver, its :class:`~solvers.StepProblem`,
        the :class:`~solvers.SolverResult`, whether the run was separable (``run(...,
        separable=True)``) and the CPU time of the calling thread spent in the run
        (``time.thread_time``, seconds). Runs that raise are not reported. Calls are serialised
        by a lock; the callback must not start a run itself.

    Yields
    ------
    callable
        ``callback``, registered until the block exits (also on an exception); blocks may nest,
        every registered callback is called, in the order registered.

    Raises
    ------
    SolverOptionError
        When ``callback`` is not callable.
    """
    if not callable(callback):
        raise SolverOptionError(f"observe_runs: callback must be callable; got {type(callback).__name__}")
    with _LOCK:
        _OBSERVERS.append(callback)
    try:
        yield callback
    finally:
        with _LOCK:
            for i in range(len(_OBSERVERS) - 1, -1, -1):
                if _OBSERVERS[i] is callback:
                    del _OBSERVERS[i]
                    break


def observing() -> bool:
    """Whether any observer is registered (a run then measures its CPU time)."""
    return bool(_OBSERVERS)


def notify(solver: Any, problem: Any, result: Any, separable: bool, cpu_seconds: float) -> None:
    """Call every registered observer with one finished run (see :func:`observe_runs`)."""
    with _LOCK:
        for callback in list(_OBSERVERS):
            callback(solver, problem, result, separable=separable, cpu_seconds=cpu_seconds)

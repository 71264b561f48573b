"""Argument types of the command line and the benchmarks: every option is checked by its parser.

Each function here returns an ``argparse`` type: it parses an option's text and raises
``argparse.ArgumentTypeError`` saying what the option accepts, so a bad value ends in the
parser's ``PROG: error: argument --flag: ...`` and exit code 2 before any work starts. The
types are marked (:data:`CHECKED`), and the tests require every option that takes a value
to have one of them, ``choices``, or to be a free text listed there (paths, addresses...).
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable
from typing import Any

__all__ = ["mark_checked", "integer", "count", "real", "solver_name", "scheduler_address", "text", "is_checked"]

#: attribute set on the types of this module (what the parser tests look for)
CHECKED = "_factirl_checked"
#: a Dask scheduler address: ``[protocol://]host:port`` (tcp, tls, ucx, ws, wss, inproc)
_ADDRESS = re.compile(r"^(?:(?:tcp|tls|ucx|ws|wss|inproc)://)?(?:\[[0-9a-fA-F:.]+\]|[A-Za-z0-9_.-]+):\d{1,5}$")


def mark_checked(fn: Callable[[str], Any], rule: str) -> Callable[[str], Any]:
    """Mark ``fn`` as a checked argparse type (:func:`is_checked`) named ``rule``; returns it."""
    setattr(fn, CHECKED, True)
    fn.__name__ = rule  # argparse names the type in "invalid <name> value" messages
    return fn


def is_checked(kind: Any) -> bool:
    """Whether ``kind`` (an action's ``type``) is one of this module's checked types."""
    return bool(getattr(kind, CHECKED, False))


def integer(minimum: int = 0, also: tuple[int, ...] = (), note: str = "") -> Callable[[str], int]:
    """An integer >= ``minimum`` (or one of ``also``, e.g. -1 for every core)."""
    rule = f"an integer >= {minimum}{note}"

    def parse(value: str) -> int:
        try:
            number = int(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {rule}; got {value!r}") from None
        if number < minimum and number not in also:
            raise argparse.ArgumentTypeError(f"must be {rule}; got {value!r}")
        return number

    return mark_checked(parse, rule)


def count(minimum: int = 0) -> Callable[[str], int]:
    """A whole number >= ``minimum``, also in float notation (``1e5``)."""
    rule = f"a whole number >= {minimum} (1e5 accepted)"

    def parse(value: str) -> int:
        try:
            number = float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {rule}; got {value!r}") from None
        if not number.is_integer() or number < minimum:
            raise argparse.ArgumentTypeError(f"must be {rule}; got {value!r}")
        return int(number)

    return mark_checked(parse, rule)


def real(low: float | None = None, high: float | None = None, low_open: bool = False,
         high_open: bool = False) -> Callable[[str], float]:
    """A finite number in the interval given (``low_open``/``high_open``: the bound excluded)."""
    bounds = []
    if low is not None:
        bounds.append(f"{'>' if low_open else '>='} {low:g}")
    if high is not None:
        bounds.append(f"{'<' if high_open else '<='} {high:g}")
    rule = "a finite number" + (" " + " and ".join(bounds) if bounds else "")

    def parse(value: str) -> float:
        try:
            number = float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {rule}; got {value!r}") from None
        ok = math.isfinite(number)
        if ok and low is not None:
            ok = number > low if low_open else number >= low
        if ok and high is not None:
            ok = number < high if high_open else number <= high
        if not ok:
            raise argparse.ArgumentTypeError(f"must be {rule}; got {value!r}")
        return number

    return mark_checked(parse, rule)


def _solver_name(value: str) -> str:
    import solvers

    names = solvers.available_solvers()
    if value not in names:
        raise argparse.ArgumentTypeError(f"unknown solver {value!r}; available: {', '.join(names)}")
    return value


#: a step solver's name (``solvers.available_solvers()``)
solver_name = mark_checked(_solver_name, "solver name")


def _scheduler_address(value: str) -> str:
    if not _ADDRESS.match(value.strip()):
        raise argparse.ArgumentTypeError(f"must be a Dask scheduler address such as tcp://host:8786 "
                                         f"([protocol://]host:port); got {value!r}")
    return value.strip()


#: a Dask scheduler address, ``[protocol://]host:port``
scheduler_address = mark_checked(_scheduler_address, "scheduler address")


def text(what: str) -> Callable[[str], str]:
    """A non-empty free text (a path, a name), stripped."""

    def parse(value: str) -> str:
        if not value.strip():
            raise argparse.ArgumentTypeError(f"is empty; give {what}")
        return value

    return mark_checked(parse, what)

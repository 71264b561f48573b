"""The step-solver registry's own exceptions.

Every error the registry and its solvers raise on purpose derives from :class:`SolversError`,
so a caller can catch them without catching unrelated ones. Each also derives from the
matching built-in exception (``RuntimeError``, ``KeyError``, ``ValueError``, ``ImportError``)
so code written against plain Python conventions keeps working.

``solvers`` is a leaf package: it imports nothing from ``factirl_opt``. The library on top
(``factirl_opt.exceptions``) subclasses these classes, and its ``translate_solver_errors``
re-raises them as the library's own family.
"""

from __future__ import annotations

__all__ = ["SolversError", "SolverError", "UnknownSolverError", "SolverOptionError", "MissingDependencyError",
           "DeprecatedNameWarning"]


class SolversError(Exception):
    """Base class of every exception raised by the step-solver registry and its solvers."""


class SolverError(SolversError, RuntimeError):
    """A solver, a library it calls (a QP solver) or the problem it was given failed during a run (e.g. a
    non-finite objective at the starting point); the message says where."""


class UnknownSolverError(SolversError, KeyError):
    """A solver name is not in the registry; the message lists the available ones."""

    def __str__(self) -> str:  # KeyError quotes its argument; keep the message readable
        return str(self.args[0]) if self.args else ""


class SolverOptionError(SolversError, ValueError):
    """An option or argument of a solver has the wrong type or value; the message names it
    and the value given."""


class MissingDependencyError(SolversError, ImportError):
    """A registered solver needs a module that is not installed (e.g. the QP solver of a Gauss-Newton name); the message
    names the module and the ``pip install`` command that provides it."""


class DeprecatedNameWarning(FutureWarning):
    """An option (or one of its values) was renamed; the old name still works for now and
    warns. A ``FutureWarning``, so that users see it by default;
    ``factirl_opt.exceptions.DeprecatedNameWarning`` derives from it."""


def __getattr__(name: str) -> type:
    """The former name ``MissingBackendError`` of :class:`MissingDependencyError` (deprecated)."""
    if name == "MissingBackendError":
        import warnings

        warnings.warn("solvers.MissingBackendError was renamed MissingDependencyError; the old name will be removed in "
                      "the next release", DeprecatedNameWarning, stacklevel=2)
        return MissingDependencyError
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

"""The library's own exceptions.

Every error raised on bad user input derives from :class:`FactIRLError`, so a caller can catch
the library's errors without catching unrelated ones. Validation errors also derive from
``ValueError`` (and type errors from ``TypeError``) so code written against plain Python
conventions keeps working.
"""

__all__ = [
    "FactIRLError",
    "ValidationError",
    "NotFittedError",
    "SolverError",
    "UnknownSolverError",
    "PersistenceError",
    "MissingDependencyError",
    "ConvergenceWarning",
]


class FactIRLError(Exception):
    """Base class of every exception raised by factirl-opt."""


class ValidationError(FactIRLError, ValueError):
    """An argument has the wrong shape, type or value; the message names it."""


class NotFittedError(FactIRLError, AttributeError):
    """A learnt attribute was used before ``fit`` was called."""


class SolverError(FactIRLError, RuntimeError):
    """A step solver or its backend failed in a way the caller must know about."""


class UnknownSolverError(FactIRLError, KeyError):
    """A solver name is not in the registry; the message lists the available ones."""

    def __str__(self):  # KeyError quotes its argument; keep the message readable
        return str(self.args[0]) if self.args else ""


class PersistenceError(FactIRLError, ValueError):
    """A saved file is corrupt, of the wrong kind, incomplete or from a newer format version,
    or an object cannot be saved; the message says which."""


class MissingDependencyError(FactIRLError, ImportError):
    """An optional dependency (an extra such as ``gymnasium``) is needed but not installed."""


class ConvergenceWarning(UserWarning):
    """A fit stopped without making progress (stalled at its start, or only on worse points);
    the message says what to check (scaling of features or initialisation, beta)."""


def translate_solver_errors():
    """Context manager re-raising a ``solvers`` registry error as this library's (interim).

    Until the registry owns its exceptions, its errors already are this library's; this keeps
    the learners' call sites in their final form.
    """
    import contextlib

    return contextlib.nullcontext()

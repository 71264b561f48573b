"""The library's own exceptions.

Every error raised on bad user input derives from :class:`FactIRLError`, so a caller can catch
the library's errors without catching unrelated ones. Validation errors also derive from
``ValueError`` (and type errors from ``TypeError``) so code written against plain Python
conventions keeps working.
"""

__all__ = ["FactIRLError", "ValidationError", "NotFittedError", "SolverError", "UnknownSolverError"]


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

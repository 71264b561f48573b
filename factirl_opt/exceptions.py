"""The library's own exceptions.

Every error raised on bad user input derives from :class:`FactIRLError`, so a caller can catch
the library's errors without catching unrelated ones. Validation errors also derive from
``ValueError`` (and type errors from ``TypeError``) so code written against plain Python
conventions keeps working.

The step-solver registry (the leaf package ``solvers``) has its own family, rooted at
:class:`solvers.SolversError`. The solver exceptions below derive from both families, and
:func:`translate_solver_errors` re-raises any ``solvers`` exception as the matching one of
this module, so code that calls the registry inside it gives users one family to catch
(``except factirl_opt.FactIRLError``) while ``except solvers.SolversError`` keeps working.
"""

import contextlib
import warnings
from typing import Any

from solvers import exceptions as _solvers

__all__ = [
    "FactIRLError",
    "ValidationError",
    "NotFittedError",
    "SolverError",
    "UnknownSolverError",
    "SolverOptionError",
    "PersistenceError",
    "MissingDependencyError",
    "MissingSolverDependencyError",
    "ConvergenceWarning",
    "FitInterrupted",
    "InterruptedFitWarning",
    "DeprecatedNameWarning",
    "WorkersLost",
    "MaxIterWarning",
    "translate_solver_errors",
]


class FactIRLError(Exception):
    """Base class of every exception raised by factirl-opt."""


class ValidationError(FactIRLError, ValueError):
    """An argument has the wrong shape, type or value; the message names it."""


class NotFittedError(FactIRLError, AttributeError):
    """A learnt attribute was used before ``fit`` was called."""


class SolverError(FactIRLError, _solvers.SolverError):
    """A step solver (or a QP solver it calls) failed in a way the caller must know about."""


class UnknownSolverError(FactIRLError, _solvers.UnknownSolverError):
    """A solver name is not in the registry; the message lists the available ones."""


class SolverOptionError(ValidationError, _solvers.SolverOptionError):
    """A solver option or argument has the wrong type or value (a :class:`ValidationError`)."""


class PersistenceError(FactIRLError, ValueError):
    """A saved file is corrupt, of the wrong kind, incomplete or from a newer format version,
    or an object cannot be saved; the message says which."""


class MissingDependencyError(FactIRLError, ImportError):
    """An optional dependency (an extra such as ``gymnasium``) is needed but not installed."""


class WorkersLost(FactIRLError):
    """The workers of a parallel fit were lost and could not be replaced: a Dask client or
    cluster closed, every Dask worker gone and none back in time, or a shard process that kept
    dying or stopped answering; the message says which.

    An ordinary library error (``except Exception`` and ``except FactIRLError`` catch it), which
    a fit nevertheless ends like an interruption (:mod:`factirl_opt.interruption`): the estimator
    keeps the best point seen (``status_ == "interrupted"``, an ``InterruptedFitWarning``) and
    this error is raised again.
    """


class ConvergenceWarning(UserWarning):
    """A fit stopped without making progress (stalled at its start, or only on worse points);
    the message says what to check (scaling of features or initialisation, beta)."""


class DeprecatedNameWarning(_solvers.DeprecatedNameWarning):
    """A name (an estimator parameter) was renamed; the old one still works for now and warns
    once per process. A ``FutureWarning``, so that users see it by default; it derives from
    ``solvers.DeprecatedNameWarning``, the warning of a renamed solver option, so one filter
    on that class covers both."""


class MaxIterWarning(ConvergenceWarning):
    """Tasks of a fit or transfer reached ``max_iter`` before their own stopping rule held; the
    message names them. The experiments, which run the paper's fixed budgets, ignore it."""


class MissingSolverDependencyError(MissingDependencyError, _solvers.MissingDependencyError):
    """A module a registered solver needs (e.g. its QP solver) is not installed (a
    :class:`MissingDependencyError`)."""


#: solvers exception -> the library's exception it becomes (most specific first)
_TRANSLATION = (
    (_solvers.MissingDependencyError, MissingSolverDependencyError),
    (_solvers.SolverOptionError, SolverOptionError),
    (_solvers.UnknownSolverError, UnknownSolverError),
    (_solvers.SolversError, SolverError),
)


@contextlib.contextmanager
def translate_solver_errors():
    """Re-raise any ``solvers.SolversError`` as the matching exception of this module.

    Usable as a context manager or as a decorator (``@translate_solver_errors()``). The new
    exception has the same message and is raised ``from`` the original; it derives from both
    families, so ``except solvers.SolverOptionError`` still catches a translated option
    error. Exceptions already in this module's family, and every other exception, pass
    through unchanged.

    ============================== ==================================
    ``solvers``                    ``factirl_opt.exceptions``
    ============================== ==================================
    ``MissingDependencyError``     :class:`MissingSolverDependencyError`
    ``SolverOptionError``          :class:`SolverOptionError`
    ``UnknownSolverError``         :class:`UnknownSolverError`
    ``SolverError`` (and the base) :class:`SolverError`
    ============================== ==================================

    Examples
    --------
    >>> with translate_solver_errors():
    ...     solver = solvers.resolve_solver(name, options)
    """
    try:
        yield
    except _solvers.SolversError as exc:
        if isinstance(exc, FactIRLError):
            raise
        cls = next(ours for theirs, ours in _TRANSLATION if isinstance(exc, theirs))
        raise cls(*exc.args) from exc


class FitInterrupted(KeyboardInterrupt):
    """A KeyboardInterrupt during a fit, carrying the best result seen so far.

    Attributes
    ----------
    result : object
        What the interrupted function returns normally (``SolverResult``, ``FactorialFit``,
        ``TransferFit``, ...), at the best point seen, with ``status == "interrupted"``.
    """

    def __init__(self, result: Any, what: str) -> None:
        super().__init__(f"{what} was interrupted; the best point seen so far is kept")
        self.result = result


class InterruptedFitWarning(ConvergenceWarning):
    """A fit was interrupted (Ctrl-C): the estimator holds the best point seen, not a finished fit."""


def __getattr__(name: str) -> type:
    """The former name ``MissingSolverBackendError`` of :class:`MissingSolverDependencyError` (deprecated)."""
    if name == "MissingSolverBackendError":
        warnings.warn("factirl_opt.exceptions.MissingSolverBackendError was renamed MissingSolverDependencyError; the "
                      "old name will be removed in the next release", DeprecatedNameWarning, stacklevel=2)
        return MissingSolverDependencyError
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

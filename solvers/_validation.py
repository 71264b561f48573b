"""Small validators shared by every solver of the registry (internal).

Solver options are dataclass fields declared with :func:`option`, which attaches a check;
:func:`validate_fields` runs the checks of every field, so no option can be left
unvalidated. Every check raises :class:`~solvers.exceptions.SolverOptionError` with a message
that names the solver, the option and the value given (and its type when the type is wrong).
The checks of what a problem's callables return (:func:`check_evaluation`) raise
:class:`~solvers.exceptions.SolverError`.
"""

import functools
import warnings
from collections.abc import Mapping
from dataclasses import field, fields

import numpy as np

from .exceptions import DeprecatedNameWarning, SolverError, SolverOptionError

__all__ = [
    "option",
    "number",
    "integer",
    "choice",
    "boolean",
    "optional",
    "validate_fields",
    "check_number",
    "check_options",
    "check_evaluation",
    "renamed_options",
    "rename_options",
    "deprecated",
]

_REALS = (int, float, np.integer, np.floating)


def _got(value):
    """``'0.5' (str)``: the value, and its type when it is not a plain number."""
    if isinstance(value, _REALS) and not isinstance(value, (bool, np.bool_)):
        return repr(value)
    return f"{value!r} ({type(value).__name__})"


def _bounds(low, high, low_open, high_open):
    if low is not None and high is not None:
        return f" in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
    if low is not None:
        return f" {'>' if low_open else '>='} {low:g}"
    if high is not None:
        return f" {'<' if high_open else '<='} {high:g}"
    return ""


def check_number(value, name, owner="", *, low=None, high=None, low_open=False, high_open=False, integer=False):
    """``value`` if it is a finite real number (an integer if asked) within the bounds.

    ``bool``, strings, NaN and infinities are rejected; so are floats when ``integer``
    (``2.0`` included: an integer option takes an ``int``).

    Raises
    ------
    SolverOptionError
        Naming ``owner``, ``name``, the expected kind and bounds, and the value given.
    """
    kinds = (int, np.integer) if integer else _REALS
    ok = isinstance(value, kinds) and not isinstance(value, (bool, np.bool_))
    ok = ok and bool(np.isfinite(value))
    if ok and low is not None:
        ok = value > low if low_open else value >= low
    if ok and high is not None:
        ok = value < high if high_open else value <= high
    if not ok:
        kind = "an integer" if integer else "a finite number"
        prefix = f"{owner}: " if owner else ""
        raise SolverOptionError(f"{prefix}{name} must be {kind}{_bounds(low, high, low_open, high_open)}; got {_got(value)}")
    return value


def number(low=None, high=None, *, low_open=False, high_open=False):
    """The check of a real-valued option (see :func:`check_number`)."""

    def check(value, name, owner):
        return check_number(value, name, owner, low=low, high=high, low_open=low_open, high_open=high_open)

    return check


def integer(low=None, high=None):
    """The check of an integer option, ``low <= value <= high``."""

    def check(value, name, owner):
        return check_number(value, name, owner, low=low, high=high, integer=True)

    return check


def choice(*choices):
    """The check of an option that takes one of a few strings."""

    def check(value, name, owner):
        if not isinstance(value, str) or value not in choices:
            raise SolverOptionError(f"{owner}: {name} must be one of {choices}; got {_got(value)}")
        return value

    return check


def boolean():
    """The check of a ``True``/``False`` option (numbers and strings are rejected)."""

    def check(value, name, owner):
        if not isinstance(value, (bool, np.bool_)):
            raise SolverOptionError(f"{owner}: {name} must be True or False; got {value!r} ({type(value).__name__})")
        return bool(value)

    return check


def optional(inner):
    """The check of an option that is ``None`` or passes ``inner``."""

    def check(value, name, owner):
        return None if value is None else inner(value, name, owner)

    return check


def option(default, check):
    """A dataclass field with a default and the check :func:`validate_fields` runs on it."""
    return field(default=default, metadata={"check": check})


def validate_fields(obj, owner):
    """Run the check of every init field of the dataclass ``obj`` (in declaration order).

    Raises
    ------
    TypeError
        When a field was declared without a check (a programming error of the solver).
    SolverOptionError
        From the first check that fails.
    """
    for f in fields(obj):
        if not f.init:
            continue
        check = f.metadata.get("check")
        if check is None:
            raise TypeError(f"{type(obj).__name__}.{f.name} is declared without a check; use solvers._validation.option")
        setattr(obj, f.name, check(getattr(obj, f.name), f.name, owner))


def deprecated(message, stacklevel=3):
    """Warn that a name or value of an option is deprecated (a :class:`DeprecatedNameWarning`)."""
    warnings.warn(message, DeprecatedNameWarning, stacklevel=stacklevel)


def rename_options(owner, renames, options, stacklevel=4):
    """``options`` (a dict) with the deprecated names in ``renames`` (old -> new) replaced, each
    with a :class:`DeprecatedNameWarning`.

    Raises
    ------
    SolverOptionError
        When an option is given under both its old and its new name.
    """
    out = dict(options)
    for old, new in renames.items():
        if old in out:
            if new in out:
                raise SolverOptionError(f"{owner}: {old!r} is the deprecated name of {new!r}; give only {new!r}")
            deprecated(f"{owner}: the option {old!r} was renamed {new!r}; the old name will be removed in the "
                       "next release", stacklevel=stacklevel)
            out[new] = out.pop(old)
    return out


def renamed_options(**renames):
    """Class decorator: the solver's ``__init__`` also takes the deprecated option names
    ``old=new`` (with a :class:`DeprecatedNameWarning`); its signature shows the new names only.

    The mapping is kept as the class attribute ``renamed_options``, which
    :func:`solvers.get_solver` reads, so the registry accepts the old names too.
    """

    def decorate(cls):
        init = cls.__init__

        @functools.wraps(init)
        def __init__(self, *args, **kwargs):
            init(self, *args, **rename_options(cls.__name__, renames, kwargs))

        cls.__init__ = __init__
        cls.renamed_options = {**getattr(cls, "renamed_options", {}), **renames}
        return cls

    return decorate


def check_options(options, where):
    """Solver options as a new dict: a mapping from option names (strings) to values.

    Raises
    ------
    SolverOptionError
        When ``options`` is not a mapping (e.g. a list), or a key is not a string.
    """
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise SolverOptionError(
            f"{where}: options must be a mapping from option names to values, e.g. {{'shrink': 0.5}}; got {_got(options)}"
        )
    bad = [key for key in options if not isinstance(key, str)]
    if bad:
        raise SolverOptionError(f"{where}: option names must be strings; got {bad[0]!r} ({type(bad[0]).__name__})")
    return dict(options)


def check_evaluation(owner, what, rows, loss, *arrays, shapes=(), start=False):
    """Check what a problem callable returned for ``rows``; the finite rows as a mask.

    Parameters
    ----------
    owner : str
        Solver name, for the message.
    what : str
        The callable, e.g. ``"loss_and_grad"``.
    rows : ndarray of int, shape (r,)
    loss : array_like, shape (r,)
    *arrays : array_like, shape (r, ...)
        Gradient, residual, Jacobian, ...
    shapes : sequence of tuple
        Expected shape of each array after the row axis; ``None`` entries match any size.
    start : bool
        At the starting point a non-finite row is an error; elsewhere (a trial point) it is
        a rejected step, reported through the mask.

    Returns
    -------
    loss : ndarray of float64, shape (r,)
    arrays : list of ndarray of float64
    finite : ndarray of bool, shape (r,)
        Rows whose loss and arrays are all finite.

    Raises
    ------
    SolverError
        When a shape is wrong, or (``start=True``) when a row is not finite.
    """
    r = len(rows)
    loss = np.asarray(loss, dtype=np.float64)
    if loss.shape != (r,):
        raise SolverError(f"{owner}: problem.{what} returned a loss of shape {loss.shape} for {r} rows; expected ({r},)")
    out = [np.asarray(a, dtype=np.float64) for a in arrays]
    for i, (a, tail) in enumerate(zip(out, shapes)):
        expected = (r, *tail)
        if a.ndim != len(expected) or any(e is not None and e != s for e, s in zip(expected, a.shape)):
            shown = tuple("*" if e is None else e for e in expected)
            raise SolverError(f"{owner}: problem.{what} returned output {i + 2} of shape {a.shape}; expected {shown}")
    finite = np.isfinite(loss)
    for a in out:
        finite &= np.all(np.isfinite(a), axis=tuple(range(1, a.ndim)))
    if start and not finite.all():
        bad = np.asarray(rows)[~finite]
        kind = "loss" if not np.all(np.isfinite(loss)) else "derivative"
        raise SolverError(
            f"{owner}: the objective returned a non-finite {kind} at the starting point, rows {bad[:10].tolist()}"
            f"{' ...' if bad.size > 10 else ''}; check the problem's data and the initial parameters"
        )
    return loss, out, finite

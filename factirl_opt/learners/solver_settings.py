"""The estimators' solver settings as one value, their one home.

:class:`SolverSettings` holds every setting that chooses a fit's step solvers: the H-step
solver (per-task coefficients; GradIRL's weights), the D-step solver (the shared dictionary),
the flat learner's (FactIRL's PCA start and the flat model's transfer) and the transfer's, each
with its options (docs/maths.md §8). It is validated once, at construction, and then travels
as one value through the estimators (``solver=SolverSettings(...)``, or a solver name for the
H-step alone), the experiment presets, the planned runs, the learner line-ups, the command line
and the benchmarks; :func:`estimator_solvers` reads it back from an estimator.

Options are stored as canonical JSON (sorted keys, no spaces; ``""``: none), so settings are
hashable, ordered, and compare equal exactly when they configure the same solvers.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping
from typing import Any

import solvers

from .._params import ParameterGroup
from ..exceptions import FactIRLError, ValidationError, translate_solver_errors

__all__ = ["SolverSettings", "decode_options", "estimator_solvers", "step_solver"]


def decode_options(text: str) -> dict[str, Any]:
    """Solver options stored as canonical JSON (``""``: none), as a dict."""
    return json.loads(text) if text else {}


def _canonical_options(options: Mapping[str, Any] | str | None, field: str) -> str:
    """``options`` (a dict, its JSON, or None) as canonical JSON; ``""`` for none."""
    if options is None or options == "":
        return ""
    original = options
    if isinstance(options, str):
        try:
            options = json.loads(options)
        except ValueError:
            raise ValidationError(f"{field} must be a dict or its JSON; got {options!r}") from None
    if not isinstance(options, Mapping) or not all(isinstance(k, str) and k for k in options):
        raise ValidationError(f"{field} must be a dict of option names to values; got {options!r}")
    try:
        canonical = json.dumps(dict(options), sort_keys=True, separators=(",", ":")) if options else ""
    except (TypeError, ValueError):
        raise ValidationError(f"{field} must hold plain values (numbers, strings, booleans, lists); "
                              f"got {original!r}") from None
    # canonical JSON given is kept as the very object given: SolverSettings(**s.get_params()) stores
    # each value unchanged, as sklearn.base.clone checks
    return original if canonical == original else canonical


#: the fields added after the first four, shown by :meth:`SolverSettings.fields` only when set
LATER_FIELDS = ("flat_solver", "flat_solver_options", "transfer_solver", "transfer_solver_options")


@dataclasses.dataclass(frozen=True, order=True, repr=False)
class SolverSettings(ParameterGroup):
    """The step solvers of a fit, with their options: H-step, D-step, flat learner and transfer.

    Each solver is a name in ``solvers.available_solvers()`` (or a ``solvers.StepSolver``
    object, which cannot be saved); ``""`` or None leaves the estimator's default for that step.

    Parameters
    ----------
    h_solver : str or solvers.StepSolver
        H-step solver (default ``"armijo"``): the coefficients of FactIRL and MultiIntentIRL,
        GradIRL's weights.
    h_solver_options : dict, str or None
        Its options: a dict, or its JSON (None or ``""``: none).
    d_solver : str, solvers.StepSolver or None
        D-step solver; None or ``""``: the estimator's default D-step (FactIRL's ``"lbfgs"``, or
        ``"armijo"`` with a ``dictionary_constraint``; MultiIntentIRL's H-step solver). GradIRL
        has no D-step.
    d_solver_options : dict, str or None
        Its options; only with a named ``d_solver``.
    flat_solver : str, solvers.StepSolver or None
        FactIRL's flat learner (the ``"pca"`` start's flat fit and the flat model's transfer,
        ``residual_penalty=0``); None or ``""``: ``"armijo"``
        (:data:`~factirl_opt.learners.start.FLAT_SOLVER`).
    flat_solver_options : dict, str or None
        Its options; only with a named ``flat_solver``.
    transfer_solver : str, solvers.StepSolver or None
        FactIRL's ``transfer`` (the coefficients of new tasks); None or ``""``: the H-step
        solver with its options.
    transfer_solver_options : dict, str or None
        Its options; only with a named ``transfer_solver``.

    Raises
    ------
    ValidationError
        Naming the bad field: a name that is not a non-empty string, options that are not a
        dict of plain values, options of the default D-step.
    UnknownSolverError, SolverOptionError, MissingSolverDependencyError
        A name that is not registered, options the solver does not accept, a module the solver
        needs that is not installed (e.g. its QP solver).

    Examples
    --------
    >>> s = SolverSettings("gn-qp-osqp-sparse", {"alpha": 0.03}, d_solver="lbfgs")
    >>> s.label()
    'gn-qp-osqp-sparse {"alpha":0.03} | d: lbfgs'
    >>> FactIRL(n_primitives=5, solver=s)  # doctest: +SKIP
    >>> FactIRL(n_primitives=5, **s.learner_kwargs())  # the same, per name  # doctest: +SKIP
    """

    h_solver: Any = "armijo"
    h_solver_options: Any = ""  # canonical JSON once constructed, as are the others
    d_solver: Any = ""
    d_solver_options: Any = ""
    flat_solver: Any = ""
    flat_solver_options: Any = ""
    transfer_solver: Any = ""
    transfer_solver_options: Any = ""

    def __post_init__(self) -> None:
        for step in ("h", "d", "flat", "transfer"):
            field = f"{step}_solver"
            name = "" if getattr(self, field) is None else getattr(self, field)
            if not (isinstance(name, solvers.StepSolver) or isinstance(name, str) and (name or step != "h")):
                raise ValidationError(f"{field} must be a registered solver name or a solvers.StepSolver; got {name!r}")
            object.__setattr__(self, field, name)
            object.__setattr__(self, field + "_options", _canonical_options(getattr(self, field + "_options"), field + "_options"))
            if not name and getattr(self, field + "_options"):
                raise ValidationError(f"{field}_options given without {field}")
            if isinstance(name, str) and name:
                try:
                    with translate_solver_errors():  # the library's exceptions: unknown names list the available ones
                        solvers.get_solver(name, **decode_options(getattr(self, field + "_options")))
                except FactIRLError as exc:
                    if step == "h":  # the estimators' solver=: the message names no field, as it always did
                        raise
                    head, sep, tail = str(exc).partition(";")  # the same error, naming the field
                    raise type(exc)(f"{head} for SolverSettings.{field}{sep}{tail}") from exc

    @classmethod
    def of(cls, value: Any) -> SolverSettings:
        """An estimator's ``solver`` parameter as settings: a name or StepSolver is the H-step solver."""
        return value if isinstance(value, SolverSettings) else cls(h_solver=value)

    @property
    def h_options(self) -> dict[str, Any]:
        """The H-step solver's options, a dict."""
        return decode_options(self.h_solver_options)

    @property
    def d_options(self) -> dict[str, Any]:
        """The D-step solver's options, a dict."""
        return decode_options(self.d_solver_options)

    def former(self, field: str) -> Any:
        """The field as the deprecated flat parameter held it: options a dict, a step not named None."""
        value = getattr(self, field)
        return (decode_options(value) if field.endswith("_options") else value) or None

    def learner_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of an estimator for these settings: ``{"solver": self}``, or the
        H-step solver's name alone when nothing else is set (``FactIRL(solver="armijo")``)."""
        return {"solver": self if any(self.fields()[f] for f in self.fields() if f != "h_solver") else self.h_solver}

    def with_overrides(self, h_solver: str | None = None, h_solver_options: Mapping[str, Any] | str | None = None,
                       d_solver: str | None = None,
                       d_solver_options: Mapping[str, Any] | str | None = None) -> SolverSettings:
        """These settings with some replaced (the command line over a preset's).

        A solver not named (None) stays, with the given options or else its own; a named
        solver takes only the options given with it.
        """
        if h_solver is None:
            h_solver = self.h_solver
            h_solver_options = self.h_solver_options if h_solver_options is None else h_solver_options
        if d_solver is None and self.d_solver:
            d_solver = self.d_solver
            d_solver_options = self.d_solver_options if d_solver_options is None else d_solver_options
        return dataclasses.replace(self, h_solver=h_solver, h_solver_options=h_solver_options, d_solver=d_solver or "",
                                   d_solver_options=d_solver_options or "")

    def label(self) -> str:
        """A readable label: the H-step solver, then its options and the D-step solver when they
        are not the defaults (e.g. ``gn-qp-osqp-sparse {"alpha":0.03} | d: lbfgs``)."""
        label = " ".join(str(x) for x in (self.h_solver, self.h_solver_options) if x)
        for step in ("d", "flat", "transfer"):
            name, options = getattr(self, f"{step}_solver"), getattr(self, f"{step}_solver_options")
            if name:
                label += f" | {step}: " + " ".join(str(x) for x in (name, options) if x)
        return label

    def key_part(self) -> str:
        """A stable file-name part: the H-step solver's name, and a short hash of the rest when
        it is not the default (e.g. ``armijo`` or ``gn-qp-clarabel-1a2b3c4d``)."""
        extra = (self.h_solver_options, self.d_solver, self.d_solver_options, *(getattr(self, f) for f in LATER_FIELDS))
        extra = tuple(x for i, x in enumerate(extra) if i < 3 or x)  # the keys of the first four's settings unchanged
        if not any(extra):
            return self.h_solver
        return f"{self.h_solver}-{hashlib.sha256(repr(extra).encode()).hexdigest()[:8]}"

    def fields(self) -> dict[str, str]:
        """The settings as stored (names, options as canonical JSON): the first four always, the
        flat and transfer steps' when set (the run records of the settings before them unchanged)."""
        return {k: v for k, v in self.get_params().items() if v or k not in LATER_FIELDS}

    def to_dict(self) -> dict[str, Any]:
        """The four settings as plain values: options as dicts, ``d_solver`` None for the default."""
        return dict(h_solver=self.h_solver, h_solver_options=self.h_options, d_solver=self.d_solver or None,
                    d_solver_options=self.d_options, **{f: v for f, v in self.fields().items() if f in LATER_FIELDS})


def estimator_solvers(estimator: Any, d_step: bool = True) -> tuple[Any, dict | None, Any, dict | None]:
    """An estimator's H- and D-step solvers as ``(solver, solver_options, d_solver, d_solver_options)``.

    From its ``solver`` parameter (:meth:`SolverSettings.of`); a D-step solver not named is the
    estimator's default (its ``default_d_solver``: ``"lbfgs"`` for FactIRL, ``"armijo"`` with a
    dictionary constraint; None for MultiIntentIRL, whose None means the H-step solver).

    Parameters
    ----------
    estimator : GradIRL, FactIRL or MultiIntentIRL
    d_step : bool
        Whether the estimator has a D-step (GradIRL has none).

    Raises
    ------
    ValidationError
        Without a D-step, the settings name a D-step solver.
    """
    settings = SolverSettings.of(estimator.solver)
    if not d_step and settings.d_solver:
        raise ValidationError(f"{type(estimator).__name__} has no D-step: its solver settings cannot name a d_solver; "
                              f"got {settings.label()!r}")
    h = (settings.h_solver, settings.h_options or None)
    if not settings.d_solver:
        return (*h, getattr(estimator, "default_d_solver", None) if d_step else None, None)
    return (*h, settings.d_solver, settings.d_options or None)


def step_solver(settings: SolverSettings, step: str, default: Any) -> tuple[Any, dict | None]:
    """The ``(solver, options)`` of the ``"flat"`` or ``"transfer"`` step; ``default`` when not named."""
    name = getattr(settings, f"{step}_solver")
    return (name, decode_options(getattr(settings, f"{step}_solver_options")) or None) if name else default

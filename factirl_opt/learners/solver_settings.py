"""The factorial learner's solver settings as one value.

:class:`SolverSettings` holds the four settings of a :class:`~factirl_opt.FactIRL` fit that
choose its step solvers: the H-step solver (per-task coefficients) and the D-step solver (the
shared dictionary), each with its options (docs/maths.md §8). It is validated once, at
construction, and then travels as one value through the experiment presets, the planned runs,
the learner line-ups, the command line and the benchmarks. The estimators take it as one value,
``solver=SolverSettings(...)``, or per name: :meth:`SolverSettings.learner_kwargs` gives their
keyword arguments ``solver`` (the H-step's), ``solver_options``, ``d_solver`` and
``d_solver_options``; :func:`estimator_solvers` reads either form back from an estimator.

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

from ..exceptions import ValidationError, translate_solver_errors

__all__ = ["SolverSettings", "decode_options", "estimator_solvers"]


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


@dataclasses.dataclass(frozen=True, order=True)
class SolverSettings:
    """The H-step and D-step solvers of a factorial fit, with their options.

    Parameters
    ----------
    h_solver : str
        H-step solver: a name in ``solvers.available_solvers()`` (default ``"armijo"``).
    h_solver_options : dict, str or None
        Its options: a dict, or its JSON (None or ``""``: none).
    d_solver : str or None
        D-step solver, a registered name; None or ``""``: FactIRL's default D-step (then no
        ``d_solver`` keyword is passed to the learner at all).
    d_solver_options : dict, str or None
        Its options; only with a named ``d_solver``.

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

    h_solver: str = "armijo"
    h_solver_options: Any = ""  # canonical JSON once constructed, as are the others
    d_solver: Any = ""
    d_solver_options: Any = ""

    def __post_init__(self) -> None:
        d_solver = "" if self.d_solver is None else self.d_solver
        for field, name in (("h_solver", self.h_solver), ("d_solver", d_solver)):
            if not isinstance(name, str) or (field == "h_solver" and not name):
                raise ValidationError(f"{field} must be a registered solver name; got {name!r}")
        for field in ("h_solver_options", "d_solver_options"):
            object.__setattr__(self, field, _canonical_options(getattr(self, field), field))
        object.__setattr__(self, "d_solver", d_solver)
        if not d_solver and self.d_solver_options:
            raise ValidationError("d_solver_options given without d_solver")
        for name, options in ((self.h_solver, self.h_options), (d_solver, self.d_options)):
            if name:
                with translate_solver_errors():  # the library's exceptions: unknown names list the available ones
                    solvers.get_solver(name, **options)

    @property
    def h_options(self) -> dict[str, Any]:
        """The H-step solver's options, a dict."""
        return decode_options(self.h_solver_options)

    @property
    def d_options(self) -> dict[str, Any]:
        """The D-step solver's options, a dict."""
        return decode_options(self.d_solver_options)

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """The four settings as stored (names, options as canonical JSON), by field name.

        With :meth:`set_params`, the settings follow scikit-learn's parameter protocol, so an
        estimator whose ``solver`` is a SolverSettings shows them in its
        ``get_params(deep=True)`` as ``solver__h_solver``, ``solver__h_solver_options``,
        ``solver__d_solver`` and ``solver__d_solver_options``, and ``SolverSettings(**s.get_params())``
        equals ``s``.

        Parameters
        ----------
        deep : bool, default=True
            Accepted for scikit-learn's protocol; the settings hold no nested parameters.
        """
        return self.fields()

    def set_params(self, **params: Any) -> SolverSettings:
        """New settings with some fields replaced (the settings are frozen: ``self`` is unchanged).

        An estimator's ``set_params(solver__h_solver="lbfgs")`` calls this and keeps the new
        settings as its ``solver``.

        Parameters
        ----------
        **params
            Fields (``h_solver``, ``h_solver_options``, ``d_solver``, ``d_solver_options``) and
            their new values, validated as by the constructor.

        Returns
        -------
        SolverSettings

        Raises
        ------
        ValidationError
            Naming a key that is not a field, with the fields there are; the constructor's
            errors for a bad value.
        """
        names = [f.name for f in dataclasses.fields(self)]
        unknown = [key for key in params if key not in names]
        if unknown:
            raise ValidationError(f"{unknown[0]!r} is not a parameter of SolverSettings; its parameters are "
                                  f"{', '.join(names)}")
        return dataclasses.replace(self, **params)

    def learner_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :class:`~factirl_opt.FactIRL` for these settings, per name.

        ``solver`` (the H-step solver) always; ``solver_options`` when there are options;
        ``d_solver`` (and ``d_solver_options``, when there are options) only when a D-step
        solver is named, so the default settings build exactly ``FactIRL(solver="armijo")``.
        """
        kw: dict[str, Any] = {"solver": self.h_solver}
        if self.h_solver_options:
            kw["solver_options"] = self.h_options
        if self.d_solver:
            kw["d_solver"] = self.d_solver
            if self.d_solver_options:
                kw["d_solver_options"] = self.d_options
        return kw

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
        return SolverSettings(h_solver, h_solver_options, d_solver, d_solver_options)

    def label(self) -> str:
        """A readable label: the H-step solver, then its options and the D-step solver when they
        are not the defaults (e.g. ``gn-qp-osqp-sparse {"alpha":0.03} | d: lbfgs``)."""
        label = " ".join(x for x in (self.h_solver, self.h_solver_options) if x)
        if self.d_solver:
            label += " | d: " + " ".join(x for x in (self.d_solver, self.d_solver_options) if x)
        return label

    def key_part(self) -> str:
        """A stable file-name part: the H-step solver's name, and a short hash of the rest when
        it is not the default (e.g. ``armijo`` or ``gn-qp-clarabel-1a2b3c4d``)."""
        extra = (self.h_solver_options, self.d_solver, self.d_solver_options)
        if not any(extra):
            return self.h_solver
        return f"{self.h_solver}-{hashlib.sha256(repr(extra).encode()).hexdigest()[:8]}"

    def fields(self) -> dict[str, str]:
        """The four settings as stored (names, options as canonical JSON)."""
        return dataclasses.asdict(self)

    def to_dict(self) -> dict[str, Any]:
        """The four settings as plain values: options as dicts, ``d_solver`` None for the default."""
        return dict(h_solver=self.h_solver, h_solver_options=self.h_options, d_solver=self.d_solver or None,
                    d_solver_options=self.d_options)


def estimator_solvers(estimator: Any, d_step: bool = True) -> tuple[Any, dict | None, Any, dict | None]:
    """An estimator's solvers as ``(solver, solver_options, d_solver, d_solver_options)``.

    The estimator gives them as one :class:`SolverSettings` in its ``solver`` parameter, or per
    name (``solver``, ``solver_options`` and, with a D-step, ``d_solver``, ``d_solver_options``).
    A :class:`SolverSettings` whose D-step solver is not named leaves the estimator's default
    D-step (``d_solver``'s default: ``"armijo"`` for FactIRL, None for MultiIntentIRL, whose
    None means the H-step solver).

    Parameters
    ----------
    estimator : GradIRL, FactIRL or MultiIntentIRL
    d_step : bool
        Whether the estimator has a D-step (GradIRL has none: its ``d_solver`` is None).

    Raises
    ------
    ValidationError
        ``solver`` is a SolverSettings and another solver parameter is given too (not its
        default), or, without a D-step, the settings name a D-step solver.
    """
    solver = estimator.solver
    d_solver = getattr(estimator, "d_solver", None) if d_step else None
    d_options = getattr(estimator, "d_solver_options", None) if d_step else None
    if not isinstance(solver, SolverSettings):
        return solver, estimator.solver_options, d_solver, d_options
    defaults = type(estimator).param_defaults()
    name = type(estimator).__name__
    given = [key for key, value in (("solver_options", estimator.solver_options), ("d_solver", d_solver),
                                    ("d_solver_options", d_options))
             if key in defaults and value is not defaults[key] and value != defaults[key]]
    if given:
        raise ValidationError(f"{name}: give the solvers either as one SolverSettings in solver or per name, not both; "
                              f"got solver={solver.label()!r} and {given[0]}={getattr(estimator, given[0])!r}")
    if not d_step and solver.d_solver:
        raise ValidationError(f"{name} has no D-step: its solver settings cannot name a d_solver; "
                              f"got {solver.label()!r}")
    if not solver.d_solver:
        return solver.h_solver, solver.h_options or None, d_solver, d_options
    return solver.h_solver, solver.h_options or None, solver.d_solver, solver.d_options or None

"""Settings as one value: the estimators' grouped parameters (solvers, execution, start).

A group is a small frozen dataclass of settings, in the manner of jaxopt's solvers, that
follows scikit-learn's parameter protocol: :meth:`ParameterGroup.get_params` gives its fields,
:meth:`ParameterGroup.set_params` a new value with some replaced (the value itself cannot
change). An estimator holding a group shows its fields in ``get_params(deep=True)`` as
``<parameter>__<field>`` and sets them by the same keys (:mod:`factirl_opt.learners.estimator`).
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

from .exceptions import ValidationError

__all__ = ["ParameterGroup"]

G = TypeVar("G", bound="ParameterGroup")


class ParameterGroup:
    """Base of the parameter groups (frozen dataclasses): scikit-learn's ``get_params``/``set_params``."""

    def __repr__(self) -> str:
        """The class and the fields that differ from their defaults (``Execution(n_jobs=2)``)."""
        shown = []
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            try:
                same = value is f.default or bool(value == f.default)
            except (TypeError, ValueError):  # arrays
                same = False
            if not same:
                shown.append(f"{f.name}={value!r}")
        return f"{type(self).__name__}({', '.join(shown)})"

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """The fields as stored, by name (``type(g)(**g.get_params())`` equals ``g``).

        Parameters
        ----------
        deep : bool, default=True
            Accepted for scikit-learn's protocol; a group holds no nested parameters.
        """
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}  # type: ignore[arg-type]

    def former(self, field: str) -> Any:
        """The field as the deprecated flat parameter of its name held it (the field itself here)."""
        return getattr(self, field)

    def set_params(self: G, **params: Any) -> G:
        """A new value with some fields replaced (``self`` is unchanged: the value is frozen).

        Raises
        ------
        ValidationError
            Naming a key that is not a field, with the fields there are; the constructor's
            errors for a bad value.
        """
        names = [f.name for f in dataclasses.fields(self)]  # type: ignore[arg-type]
        unknown = [key for key in params if key not in names]
        if unknown:
            raise ValidationError(f"{unknown[0]!r} is not a parameter of {type(self).__name__}; its parameters are "
                                  f"{', '.join(names)}")
        return dataclasses.replace(self, **params)  # type: ignore[type-var]

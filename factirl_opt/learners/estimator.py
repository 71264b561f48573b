"""What the three estimators share, in the manner of scikit-learn: parameters, cloning, repr.

:class:`Estimator` is the base of :class:`~factirl_opt.GradIRL`, :class:`~factirl_opt.FactIRL`
and :class:`~factirl_opt.MultiIntentIRL`. Its parameters are the arguments of the subclass's
``__init__``, read from its signature: ``__init__`` only stores each argument under its own
name (no validation, no conversion: that happens in ``fit``), so that

- :meth:`Estimator.get_params` returns them, :meth:`Estimator.set_params` changes them (by
  name, unknown names refused), and ``type(est)(**est.get_params())`` rebuilds the estimator;
- :func:`clone` makes an unfitted estimator of the same class with the same parameters;
- ``repr`` shows the class and the parameters that differ from their defaults;
- persistence (:mod:`factirl_opt.persistence`) stores exactly these parameters, each as the
  class declares its kind in ``param_kinds``, and the fitted attributes the class declares in
  ``learnt_attributes``.

Parameter groups. Settings that belong together are one parameter whose value is a small
frozen dataclass (:class:`factirl_opt._params.ParameterGroup`): ``solver`` a
:class:`~factirl_opt.SolverSettings`, ``execution`` an :class:`~factirl_opt.Execution`,
``start`` a :class:`~factirl_opt.Start`. A class lists them in ``param_groups`` (name -> class);
None (the default, as scikit-learn's defaults are plain values) is the class's default value,
and the ``solver`` may be a solver name, the H-step solver (:meth:`SolverSettings.of`).

Nested parameters. A parameter whose value has parameters of its own (a group, another
estimator: any object with ``get_params``) shows them in ``get_params(deep=True)`` under
``<parameter>__<name>`` (``execution__n_jobs``; a group left at None has none to show, so
``type(est)(**est.get_params())`` rebuilds a default estimator), and :meth:`Estimator.set_params`
sets them by the same keys, a group at None from its default value, as scikit-learn does.

Renamed parameters. A class lists its old parameter names in ``deprecated_params`` (old name
-> name now, or ``<group>__<field>`` for a parameter moved into a group); ``__init__``
(decorated with :func:`renamed_params`), :meth:`set_params`, the attribute of the old name and
unpickling accept it, and issue one :class:`~factirl_opt.exceptions.DeprecatedNameWarning` (once
per class and name in a process).

scikit-learn itself is not a dependency: its ``BaseEstimator`` would bring scikit-learn (and
its own checks of fitted state and tags) for the 100 lines here. The protocol is scikit-learn's
all the same, and the test suite runs scikit-learn's own checks on the three estimators
(default-constructible parameters, ``get_params`` invariance, ``set_params``, no attribute set
in ``__init__``, ``sklearn.base.clone``): ``sklearn.base.clone`` works on them, as it needs
only ``get_params(deep=False)`` and a constructor storing those parameters unchanged.
"""

from __future__ import annotations

import copy
import functools
import inspect
from typing import Any, Callable, ClassVar, TypeVar

import numpy as np

from .._deprecation import warn_once
from .._params import ParameterGroup
from ..exceptions import ValidationError

__all__ = ["Estimator", "clone", "renamed_params", "renamed_attribute", "EXECUTION_PARAM_KINDS", "EXECUTION_RENAMED"]

E = TypeVar("E", bound="Estimator")

#: The kinds (:mod:`factirl_opt.persistence.params`) of the execution settings every estimator
#: takes: how a fit is watched and where its evaluations run, none of them part of the model.
EXECUTION_PARAM_KINDS: dict[str, str] = {"execution": "group", "execution__n_jobs": "runtime",
                                         "execution__backend": "runtime", "execution__client": "runtime",
                                         "execution__planner": "planner", "execution__planner_options": "runtime",
                                         "execution__callback": "runtime"}
#: The deprecated flat names of the execution settings, now fields of ``execution`` (:class:`~factirl_opt.Execution`).
EXECUTION_RENAMED: dict[str, str] = {name: f"execution__{name}" for name in
                                     ("n_jobs", "backend", "client", "planner", "planner_options", "verbose", "callback")}

def _warn_renamed(cls: type[Estimator], old: str, new: str, stacklevel: int = 4) -> None:
    """One :class:`DeprecatedNameWarning` per class and old name in a process (:func:`factirl_opt._deprecation.warn_once`)."""
    top, _, sub = new.partition("__")
    now = (f"is now the field {sub!r} of {top}={cls.param_groups[top].__name__}(...) (set_params({new}=...))" if sub
           else f"is now called {new!r}")
    warn_once(f"param:{cls.__name__}.{old}", f"{cls.__name__}: the parameter {old!r} {now}; {old!r} is "
                                              "deprecated and will be removed in a future release", stacklevel=stacklevel + 1)


def _renamed(cls: type[Estimator], params: dict[str, Any], what: str, groups: bool = True) -> dict[str, Any]:
    """``params`` with the class's deprecated names replaced by the names now (warned once); with
    ``groups``, a name moved into a group sets that field of the group's value (given, or the default)."""
    renamed: dict[str, str] = {old: new for old, new in getattr(cls, "deprecated_params", {}).items()
                               if groups or "__" not in new}
    if not renamed or not renamed.keys() & params.keys():
        return params
    out = dict(params)
    fields: dict[str, dict[str, Any]] = {}
    for old, new in renamed.items():
        if old in out:
            top, _, sub = new.partition("__")
            if new in out or sub in fields.get(top, {}):
                raise TypeError(f"{what} got both {old!r} and {new!r} ({old!r} is the deprecated name of {new!r})")
            _warn_renamed(cls, old, new)
            if sub and isinstance(out.get(top), cls.param_groups[top]):
                raise ValidationError(f"{what}: give the settings either as one {cls.param_groups[top].__name__} in "
                                      f"{top} or per name (deprecated), not both; got {top}={out[top]!r:.80} and "
                                      f"{old}={out[old]!r:.80}")
            if sub:
                fields.setdefault(top, {})[sub] = out.pop(old)
            else:
                out[new] = out.pop(old)
    for top, sub_params in fields.items():
        out[top] = _as_group(cls, top, out.get(top, cls.param_defaults()[top])).set_params(**sub_params)
    return out


def _as_group(cls: type[Estimator], name: str, value: Any) -> Any:
    """The value of group parameter ``name``: None is the group's default, a solver name the H-step's settings."""
    group = cls.param_groups[name]
    if value is None:
        return group()
    if isinstance(value, group):
        return value
    if hasattr(group, "of"):
        return group.of(value)
    raise ValidationError(f"{cls.__name__}: {name} must be a {group.__name__} or None; got {_short(value):.80}")


def renamed_params(method: Callable[..., Any]) -> Callable[..., Any]:
    """Decorator of an estimator's ``__init__`` (or a method taking the same names, such as
    ``FactIRL.transfer``): the deprecated keyword names of ``deprecated_params`` accepted.

    The signature seen by :func:`inspect.signature` stays the decorated method's (the names
    now), so :meth:`Estimator.get_params` does not list the old names.
    """

    @functools.wraps(method)
    def wrapper(self: Any, *args: Any, **kwargs: Any) -> Any:
        return method(self, *args, **_renamed(type(self), kwargs, f"{type(self).__name__}.{method.__name__}()",
                                              groups=method.__name__ == "__init__"))

    return wrapper


def renamed_attribute(old: str, new: str) -> property:
    """A property reading and writing the attribute ``new`` (or the group field ``<group>__<field>``)
    under its deprecated name ``old`` (warned once)."""
    top, _, sub = new.partition("__")

    def get(self: Any) -> Any:
        _warn_renamed(type(self), old, new, stacklevel=3)
        return self._group(top).former(sub) if sub else getattr(self, new)

    def set_(self: Any, value: Any) -> None:
        _warn_renamed(type(self), old, new, stacklevel=3)
        if sub:
            setattr(self, top, self._group(top).set_params(**{sub: value}))
        else:
            setattr(self, new, value)

    return property(get, set_, doc=f"Deprecated name of ``{new}``.")


def _copied(value: Any) -> Any:
    """A parameter value for a clone: data (arrays, containers, random generators) copied, other objects shared.

    Callbacks, clients, solver and objective objects are shared as they are: a clone's
    callback is the same function, its client the same cluster.
    """
    if isinstance(value, (np.ndarray, list, tuple, dict, np.random.Generator, np.random.SeedSequence)):
        return copy.deepcopy(value)
    return value


def _has_params(value: Any) -> bool:
    """Whether a parameter value has parameters of its own (``get_params``, as scikit-learn tells; a class has none)."""
    return callable(getattr(value, "get_params", None)) and not isinstance(value, type)


def _differs(value: Any, default: Any) -> bool:
    """Whether a parameter value differs from its default (arrays and objects: unless the same object)."""
    if value is default:
        return False
    if default is inspect.Parameter.empty or type(value) is not type(default) and not (
            isinstance(value, (int, float)) and isinstance(default, (int, float))):
        return True
    if isinstance(value, np.ndarray):
        return True
    try:
        return not bool(value == default)
    except (TypeError, ValueError):
        return True


def _short(value: Any) -> str:
    """A parameter value as ``repr`` shows it: arrays by shape, lists of arrays by count."""
    if isinstance(value, np.ndarray):
        return f"<array {value.shape}>"
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, np.ndarray) for v in value):
        return f"<{type(value).__name__} of {len(value)} arrays>"
    if isinstance(value, np.random.Generator):
        return f"Generator({type(value.bit_generator).__name__})"
    if isinstance(value, type):
        return value.__name__
    if callable(value) and hasattr(value, "__qualname__"):
        return value.__qualname__
    return repr(value)


class Estimator:
    """Base of the estimators: parameters from ``__init__``'s signature, ``get_params``/``set_params``, repr.

    Subclasses declare

    - ``deprecated_params``: old parameter name -> name now (see :func:`renamed_params`);
    - ``param_kinds``: how :func:`~factirl_opt.persistence.save_model` stores each parameter
      that is not a plain JSON value (a registry name, the features, the ``rng``, a start, or
      ``"runtime"``: not saved); the others are stored as JSON;
    - ``learnt_attributes``: the fitted attributes and their kinds (:mod:`factirl_opt.persistence.learnt`).
    """

    deprecated_params: ClassVar[dict[str, str]] = {}
    param_groups: ClassVar[dict[str, type]] = {}
    param_kinds: ClassVar[dict[str, str]] = {}
    learnt_attributes: ClassVar[dict[str, tuple[str, ...] | str]] = {}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """The attribute of each deprecated parameter name (:func:`renamed_attribute`)."""
        super().__init_subclass__(**kwargs)
        for old, new in cls.deprecated_params.items():
            if old not in cls.__dict__:
                setattr(cls, old, renamed_attribute(old, new))

    def _group(self, name: str) -> Any:
        """The value of the group parameter ``name`` (its default for None; :data:`param_groups`)."""
        return _as_group(type(self), name, getattr(self, name))

    @classmethod
    def _signature(cls) -> list[inspect.Parameter]:
        init = cls.__init__
        if init is object.__init__:
            return []
        params = [p for p in inspect.signature(init).parameters.values() if p.name != "self"]
        for p in params:
            if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
                raise TypeError(f"{cls.__name__}.__init__ must name its parameters (no *{p.name}): they are read "
                                f"from its signature")
        return params

    @classmethod
    def param_names(cls) -> list[str]:
        """The parameters, in the order of ``__init__``'s signature."""
        return [p.name for p in cls._signature()]

    @classmethod
    def param_defaults(cls) -> dict[str, Any]:
        """The parameters' defaults (``inspect.Parameter.empty`` for one without a default)."""
        return {p.name: p.default for p in cls._signature()}

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """The estimator's parameters, by name (the values as given, not copies).

        Parameters
        ----------
        deep : bool, default=True
            Also the parameters of each parameter that has parameters of its own (an object
            with ``get_params``: another estimator, a :class:`~factirl_opt.SolverSettings`),
            under ``<parameter>__<name>``, as scikit-learn does.

        Returns
        -------
        dict
            Every argument of ``__init__``, and with ``deep`` the nested parameters:
            ``type(self)(**self.get_params(deep=False))`` rebuilds the estimator.
        """
        out: dict[str, Any] = {}
        for name in self.param_names():
            value = getattr(self, name)
            if deep and _has_params(value):
                out.update((f"{name}__{key}", sub) for key, sub in value.get_params(deep=True).items())
            out[name] = value
        return out

    def set_params(self: E, **params: Any) -> E:
        """Set parameters by name; the fitted attributes are left as they are (fit again to use them).

        A key ``<parameter>__<name>`` sets the parameter ``name`` of the parameter's value (an
        object with ``set_params``, e.g. ``solver__h_solver="lbfgs"`` on a
        :class:`~factirl_opt.SolverSettings`, which gives a new settings value: the parameter
        then holds that). With both ``solver=...`` and ``solver__...``, the nested keys apply to
        the new value. A deprecated name (``deprecated_params``) sets the parameter it was
        renamed to, with a :class:`~factirl_opt.exceptions.DeprecatedNameWarning` (once per
        class and name).

        Returns
        -------
        self

        Raises
        ------
        ValidationError
            Naming the first name that is not a parameter, or a nested key whose parameter
            has no parameters of its own (nothing is set then), with the parameters there
            are; a nested value's own refusal (e.g. a SolverSettings field) is raised as it is.
        """
        names = self.param_names()
        cls = type(self)
        plain: dict[str, Any] = {}
        nested: dict[str, dict[str, Any]] = {}
        for key, value in params.items():
            top, delim, sub = key.partition("__")
            if top in self.deprecated_params:
                _warn_renamed(cls, top, self.deprecated_params[top], stacklevel=3)
                key = self.deprecated_params[top] + delim + sub
                top, delim, sub = key.partition("__")
            if top not in names:
                raise ValidationError(f"{key!r} is not a parameter of {cls.__name__}; its parameters are "
                                      f"{', '.join(names)}")
            if key in plain or sub in nested.get(top, {}):
                raise TypeError(f"{cls.__name__}.set_params() got {key!r} twice (under its name and a deprecated one)")
            if delim:
                nested.setdefault(top, {})[sub] = value
            else:
                plain[key] = value
        for top in nested:
            base = plain.get(top, getattr(self, top))
            if top in self.param_groups:
                base = _as_group(cls, top, base)
            if not (_has_params(base) and callable(getattr(base, "set_params", None))):
                raise ValidationError(f"{top + '__' + next(iter(nested[top]))!r} is not a parameter of "
                                      f"{cls.__name__}: its parameter {top}={_short(base)} has no parameters "
                                      "of its own")
            inner = list(base.get_params(deep=False))
            unknown = [sub for sub in nested[top] if sub.partition("__")[0] not in inner]
            if unknown:
                raise ValidationError(f"{top + '__' + unknown[0]!r} is not a parameter of {cls.__name__}: its "
                                      f"parameter {top} ({type(base).__name__}) has the parameters {', '.join(inner)}")
        for top, sub_params in nested.items():
            base = plain.get(top, getattr(self, top))
            base = _as_group(cls, top, base) if top in self.param_groups else base
            changed = base.set_params(**sub_params)  # an estimator changes in place; a settings value gives a new one
            plain[top] = base if changed is None else changed
        for key, value in plain.items():
            setattr(self, key, value)
        return self

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Unpickling: a parameter saved under a deprecated name gets the name now; one added since gets its default."""
        state = dict(state)
        fields: dict[str, dict[str, Any]] = {}
        for old, new in self.deprecated_params.items():
            top, _, sub = new.partition("__")
            if old in state and sub:
                fields.setdefault(top, {})[sub] = state.pop(old)
            elif old in state and new not in state:
                state[new] = state.pop(old)
        for top, sub_params in fields.items():  # a pickle of before the groups: its values, grouped
            state[top] = _as_group(type(self), top, state.get(top)).set_params(**sub_params)
        for name, default in self.param_defaults().items():
            if name not in state and default is not inspect.Parameter.empty:
                state[name] = default
        self.__dict__.update(state)

    def __repr__(self) -> str:
        try:
            defaults = self.param_defaults()
        except TypeError:  # a subclass whose __init__ takes **kwargs: no parameters to show
            return object.__repr__(self)
        shown = [f"{name}={_short(value)}" for name, value in self.get_params(deep=False).items()
                 if _differs(value, defaults[name])]
        return f"{type(self).__name__}({', '.join(shown)})"


def clone(estimator: E) -> E:
    """A new unfitted estimator of the same class with the same parameters.

    Array, list, dict and random-generator parameters are copied (a clone's ``rng`` Generator
    starts in the state of the original's), and a parameter that is itself an estimator is
    cloned; other objects (a callback, a Dask client, a solver object, a
    :class:`~factirl_opt.SolverSettings`, which cannot change) are shared. No fitted attribute
    is carried over. As ``sklearn.base.clone`` does, the clone's constructor must store each
    parameter unchanged: the very object it was given.

    Parameters
    ----------
    estimator : GradIRL, FactIRL or MultiIntentIRL
        Any :class:`Estimator`.

    Returns
    -------
    Estimator

    Raises
    ------
    ValidationError
        ``estimator`` is not an :class:`Estimator`.
    RuntimeError
        The class's ``__init__`` does not store a parameter, or stores another object than the
        one given (scikit-learn's check and exception): the message names the parameter.
    """
    if not isinstance(estimator, Estimator):
        raise ValidationError(f"clone takes an estimator (GradIRL, FactIRL, MultiIntentIRL); got {type(estimator).__name__}")
    params = {name: clone(value) if isinstance(value, Estimator) else _copied(value)
              for name, value in estimator.get_params(deep=False).items()}
    params = {name: type(value)(**{k: _copied(v) for k, v in value.get_params().items()})
              if isinstance(value, ParameterGroup) else value for name, value in params.items()}
    new = type(estimator)(**params)
    stored = new.get_params(deep=False)
    for name, value in params.items():
        if stored[name] is not value:
            raise RuntimeError(f"cannot clone {type(estimator).__name__}: its __init__ does not store the parameter "
                               f"{name!r} as given ({_short(value):.80} became {_short(stored[name]):.80}); "
                               "__init__ must only store each argument under its own name")
    return new

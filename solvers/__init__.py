"""Step-solver registry: a plain mapping from a name to a step-solver factory.

>>> import solvers
>>> solvers.available_solvers()          # names whose backend is installed
>>> solver = solvers.get_solver("armijo", initial_step=0.5)

Register your own solver (a :class:`StepSolver` subclass or any factory returning one)::

    @solvers.register_solver("my-solver")
    class MySolver(solvers.StepSolver):
        ...

An unknown name raises :class:`factirl_opt.exceptions.UnknownSolverError` listing what is
available.

Built-in solvers
----------------
``armijo``, ``armijo-nonneg``
    The paper's Armijo gradient descent (projected onto ``x >= 0`` for the second).
``gn-qp-{osqp,clarabel}``
    Gauss-Newton / Levenberg-Marquardt steps, each a QP solved through cvxpy with the named
    backend (:class:`GaussNewtonSolver`; needs ``residual_jacobian``).
``gn-qp-{osqp,clarabel}-nonneg``
    The same with ``h >= 0`` (``constraint="nonneg"``).
``gn-qp-{osqp,clarabel}-sparse``
    The same with an L1 penalty ``alpha ||h||_1`` (``constraint="sparse"``, option ``alpha``,
    default 0.01).

Every Gauss-Newton name also takes the options of :class:`GaussNewtonSolver`, e.g.
``get_solver("gn-qp-osqp", interface="direct")`` calls OSQP without cvxpy. A name is only
*available* when its backend (and cvxpy) is installed.
"""

import importlib.util
import inspect

from factirl_opt.exceptions import UnknownSolverError, ValidationError

from ._base import SolverResult, StepProblem, StepSolver
from .armijo import ArmijoSolver
from .gauss_newton import GaussNewtonSolver, QPFallbackWarning

__all__ = [
    "StepProblem",
    "StepSolver",
    "SolverResult",
    "ArmijoSolver",
    "GaussNewtonSolver",
    "QPFallbackWarning",
    "register_solver",
    "unregister_solver",
    "available_solvers",
    "registered_solvers",
    "get_solver",
    "resolve_solver",
]

#: name -> (factory, default options, required importable modules)
_REGISTRY = {}


def register_solver(name, factory=None, *, requires=(), overwrite=False, **defaults):
    """Register a step-solver factory under ``name``; usable as a decorator.

    Parameters
    ----------
    name : str
        Registry name, e.g. ``"gn-qp-osqp"``.
    factory : callable, optional
        Called as ``factory(**defaults, **options)``; must return a :class:`StepSolver`.
        Omit it to use ``register_solver(name)`` as a class decorator.
    requires : tuple of str
        Modules that must be importable for the solver to be available (its backend).
    overwrite : bool
        Allow replacing an existing name.
    **defaults
        Default options passed to the factory.
    """
    if not isinstance(name, str) or not name:
        raise ValidationError(f"solver name must be a non-empty string; got {name!r}")

    def decorate(f):
        if not callable(f):
            raise ValidationError(f"solver factory for {name!r} must be callable; got {type(f).__name__}")
        if name in _REGISTRY and not overwrite:
            raise ValidationError(f"a solver named {name!r} is already registered (pass overwrite=True to replace it)")
        _REGISTRY[name] = (f, dict(defaults), tuple(requires))
        return f

    return decorate if factory is None else decorate(factory)


def unregister_solver(name):
    """Remove ``name`` from the registry."""
    if name not in _REGISTRY:
        raise UnknownSolverError(f"unknown solver {name!r}; registered: {', '.join(sorted(_REGISTRY))}")
    del _REGISTRY[name]


def _installed(requires):
    return all(importlib.util.find_spec(m) is not None for m in requires)


def registered_solvers():
    """All registered names, whether or not their backend is installed (sorted)."""
    return sorted(_REGISTRY)


def available_solvers():
    """Registered names whose backend is installed (sorted)."""
    return sorted(n for n, (_, _, req) in _REGISTRY.items() if _installed(req))


def get_solver(name, **options):
    """A new solver instance for a registered ``name``, with ``options`` over its defaults."""
    if name not in _REGISTRY:
        raise UnknownSolverError(f"unknown solver {name!r}; available: {', '.join(available_solvers())}")
    factory, defaults, requires = _REGISTRY[name]
    if not _installed(requires):
        raise UnknownSolverError(
            f"solver {name!r} needs {', '.join(requires)}, which is not installed; available: {', '.join(available_solvers())}"
        )
    kwargs = {**defaults, **options}
    try:
        signature = inspect.signature(factory)
    except (TypeError, ValueError):  # a builtin without a signature: let the call decide
        signature = None
    if signature is not None:
        try:
            signature.bind(**kwargs)
        except TypeError:
            accepted = [p for p in signature.parameters if not p.startswith("_")]
            bad = sorted(set(options) - set(accepted)) or sorted(options)
            raise ValidationError(f"solver {name!r} does not accept option(s) {', '.join(bad)}; its options are: {', '.join(accepted)}") from None
    return factory(**kwargs)


def resolve_solver(solver, **options):
    """A solver from a registered name or a :class:`StepSolver` instance (returned as is)."""
    if isinstance(solver, StepSolver):
        if options:
            raise ValidationError("options can only be given with a solver name, not a solver object")
        return solver
    if isinstance(solver, str):
        return get_solver(solver, **options)
    raise ValidationError(f"solver must be a registered name or a StepSolver; got {type(solver).__name__}")


register_solver("armijo", ArmijoSolver)
register_solver("armijo-nonneg", ArmijoSolver, nonneg=True)
for _backend in ("osqp", "clarabel"):
    for _constraint in ("none", "nonneg", "sparse"):
        register_solver(
            f"gn-qp-{_backend}" + ("" if _constraint == "none" else f"-{_constraint}"),
            GaussNewtonSolver,
            requires=("cvxpy", _backend),
            backend=_backend,
            constraint=_constraint,
        )
del _backend, _constraint

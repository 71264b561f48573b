"""Step-solver registry: a plain mapping from a name to a step-solver factory.

>>> import solvers
>>> solvers.available_solvers()          # names whose required modules are installed
>>> solver = solvers.get_solver("armijo", initial_step=0.5)

Register your own solver (a :class:`StepSolver` subclass or any factory returning one)::

    @solvers.register_solver("my-solver")
    class MySolver(solvers.StepSolver):
        ...

Errors derive from :class:`SolversError` (module :mod:`solvers.exceptions`): an unknown name
raises :class:`UnknownSolverError` listing what is available; a registered name whose required
module is not installed raises :class:`MissingDependencyError` with the ``pip install`` command;
a bad option (wrong name, type or value; options given as anything but a mapping) raises
:class:`SolverOptionError` naming the option and the value; a run that fails raises
:class:`SolverError`. ``solvers`` imports nothing from ``factirl_opt`` (a leaf package);
``factirl_opt.exceptions.translate_solver_errors`` maps these to the library's family.

Built-in solvers
----------------
``armijo``, ``armijo-nonneg``
    The paper's Armijo gradient descent (projected onto ``x >= 0`` for the second).
``gn-qp-{osqp,clarabel}``
    Gauss-Newton / Levenberg-Marquardt steps, each a QP solved through cvxpy with the named
    QP solver (:class:`GaussNewtonSolver`, option ``qp_solver``, one of :data:`QP_SOLVERS`;
    needs ``residual_jacobian``).
``gn-qp-{osqp,clarabel}-nonneg``
    The same with ``h >= 0`` (``constraint="nonneg"``).
``gn-qp-{osqp,clarabel}-sparse``
    The same with an L1 penalty ``alpha ||h||_1`` (``constraint="sparse"``, option ``alpha``,
    default 0.01).
``lbfgs``
    Limited-memory BFGS with an Armijo line search, one memory per row
    (:class:`LBFGSSolver`; options ``memory``, ``initial_step``, ...). Its memory is kept
    across runs given the previous ``state`` and reset with ``state=None``; between the runs
    of an alternating scheme only the step scale is carried over (:meth:`StepSolver.carry_over`).
    Unconstrained.
``gn-cg``
    Matrix-free Gauss-Newton / Levenberg-Marquardt steps, ``(J^T J + lam I) delta = -J^T r``
    solved by truncated conjugate gradients, each iteration one batched Jacobian-vector
    product and one vector-Jacobian product (:class:`GaussNewtonCGSolver`; needs
    ``StepProblem.linearize``; options ``cg_max_iter``, ``cg_tol``, ...). Unconstrained. Its
    alternating form (FactIRL's D-step) takes proximal, inexact steps.

``newton``
    Damped Newton steps with a trust-region ratio test, one damping per row
    (:class:`NewtonSolver`): the exact Hessian where the problem gives one
    (``StepProblem.hessian``: the MCE likelihood), else the Gauss-Newton matrix of the residuals
    (``residual_jacobian``: policy matching); options ``damping``, ``eta``, ... Unconstrained;
    a dense (p, p) curvature per row (feature weights, not large tabular rewards).

To watch the runs (profiling), :func:`observe_runs` (module :mod:`solvers.observe`) calls a
callback after every :meth:`StepSolver.run` inside a ``with`` block.

Not registered (it needs callables, not only a name): :class:`ProximalArmijoSolver`, the
Armijo descent with a proximal map ``prox(v, t)`` and its penalty (:mod:`solvers.proximal`;
``constraint="proximal"``), and :func:`unit_columns_prox`, the map of unit-norm columns,
optionally nonnegative and/or L1-penalised (FactIRL's constrained dictionary).

Every solver's run stops early by the rules of :mod:`solvers.stopping`: the relative decrease
of the total objective (:func:`has_converged`, ``tol``), its decrease over a step relative to
its decrease since the start (:func:`has_saturated`, ``stol``; off by default) and
the norm of its gradient relative to the start (:func:`gradient_converged`, ``gtol``; projected
or minimum-norm subgradient for the constrained and penalised solvers,
:meth:`StepSolver.optimality`); the result says why it
stopped (``SolverResult.reason``). A separable run (``run(..., separable=True)``,
:mod:`solvers.separable`) applies the rules to every row on its own and drops the rows that
stopped, so each row's result is the one of a run on that row alone (the steps are
:meth:`StepSolver.step_rows`; ``SolverResult.row_status``, ``row_iterations`` and
``row_evaluations`` record the rows). Solvers bound their steps relative to ``max(1, ||x_i||)``
(``max_step_norm``) where they take Newton-like steps. In an alternating scheme a learner
uses each solver's :meth:`StepSolver.for_alternating` form and warm-starts it with
:meth:`StepSolver.carry_over` of its previous run.

Every Gauss-Newton name also takes the options of :class:`GaussNewtonSolver`, e.g.
``get_solver("gn-qp-osqp", interface="direct")`` calls OSQP without cvxpy. A name is only
*available* when the modules it needs (for a Gauss-Newton name: cvxpy and its QP solver) are
installed.
"""

from __future__ import annotations

import importlib.util
import inspect
from collections.abc import Callable, Mapping
from typing import Any

from ._base import Linearization, SolverResult, StepProblem, StepSolver
from ._blockqp import CONSTRAINTS, QP_SOLVERS
from ._validation import check_options, deprecated, rename_options
from .armijo import ArmijoSolver
from .exceptions import (
    DeprecatedNameWarning,
    MissingDependencyError,
    SolverError,
    SolverOptionError,
    SolversError,
    UnknownSolverError,
)
from .gauss_newton import GaussNewtonSolver, QPFallbackWarning, qp_solver_name
from .gn_cg import GaussNewtonCGSolver
from .lbfgs import LBFGSSolver
from .newton import NewtonSolver
from .observe import observe_runs
from .proximal import ProximalArmijoSolver, unit_columns_prox
from .stopping import gradient_converged, has_converged, has_saturated, relative_decrease

__all__ = [
    "StepProblem",
    "Linearization",
    "StepSolver",
    "SolverResult",
    "ArmijoSolver",
    "GaussNewtonSolver",
    "LBFGSSolver",
    "GaussNewtonCGSolver",
    "NewtonSolver",
    "ProximalArmijoSolver",
    "unit_columns_prox",
    "QPFallbackWarning",
    "qp_solver_name",
    "observe_runs",
    "relative_decrease",
    "has_converged",
    "gradient_converged",
    "has_saturated",
    "SolversError",
    "SolverError",
    "UnknownSolverError",
    "SolverOptionError",
    "MissingDependencyError",
    "DeprecatedNameWarning",
    "QP_SOLVERS",
    "register_solver",
    "unregister_solver",
    "available_solvers",
    "registered_solvers",
    "get_solver",
    "resolve_solver",
]

#: name -> (factory, default options, required importable modules)
_REGISTRY: dict[str, tuple[Callable[..., StepSolver], dict[str, Any], tuple[str, ...]]] = {}


def register_solver(
    name: str,
    factory: Callable[..., StepSolver] | None = None,
    *,
    requires: tuple[str, ...] = (),
    overwrite: bool = False,
    **defaults: Any,
) -> Any:
    """Register a step-solver factory under ``name``; usable as a decorator.

    Parameters
    ----------
    name : str
        Registry name, e.g. ``"gn-qp-osqp"``.
    factory : callable, optional
        Called as ``factory(**defaults, **options)``; must return a :class:`StepSolver`.
        Omit it to use ``register_solver(name)`` as a class decorator.
    requires : tuple of str
        Modules that must be importable for the solver to be available (e.g. its QP solver); each
        is also the name of the package ``pip`` installs it from.
    overwrite : bool
        Allow replacing an existing name.
    **defaults
        Default options passed to the factory.

    Raises
    ------
    SolverOptionError
        When the name is not a non-empty string, the factory is not callable, ``requires``
        is not a tuple of strings, or the name is taken (and ``overwrite`` is False).
    """
    if not isinstance(name, str) or not name:
        raise SolverOptionError(f"solver name must be a non-empty string; got {name!r}")
    if isinstance(requires, str) or not all(isinstance(m, str) and m for m in requires):
        raise SolverOptionError(f"requires of solver {name!r} must be a tuple of module names; got {requires!r}")

    def decorate(f: Any) -> Any:
        if not callable(f):
            raise SolverOptionError(f"solver factory for {name!r} must be callable; got {type(f).__name__}")
        if name in _REGISTRY and not overwrite:
            raise SolverOptionError(f"a solver named {name!r} is already registered (pass overwrite=True to replace it)")
        _REGISTRY[name] = (f, dict(defaults), tuple(requires))
        return f

    return decorate if factory is None else decorate(factory)


def unregister_solver(name: str) -> None:
    """Remove ``name`` from the registry."""
    if not isinstance(name, str) or name not in _REGISTRY:
        raise UnknownSolverError(f"unknown solver {name!r}; registered: {', '.join(sorted(_REGISTRY))}")
    del _REGISTRY[name]


def _missing(requires: tuple[str, ...]) -> list[str]:
    return [m for m in requires if importlib.util.find_spec(m) is None]


def registered_solvers() -> list[str]:
    """All registered names, whether or not the modules they need are installed (sorted)."""
    return sorted(_REGISTRY)


def available_solvers() -> list[str]:
    """Registered names whose required modules are installed (sorted)."""
    return sorted(n for n, (_, _, req) in _REGISTRY.items() if not _missing(req))


def _factory_name(factory: Any) -> str:
    return f"{getattr(factory, '__module__', '?')}.{getattr(factory, '__qualname__', repr(factory))}"


def _check_accepted(name: str, factory: Any, kwargs: dict[str, Any], options: dict[str, Any]) -> None:
    """Raise SolverOptionError when ``factory`` cannot take the options ``kwargs``."""
    try:
        signature = inspect.signature(factory)
    except (TypeError, ValueError):  # a builtin without a signature: let the call decide
        return
    try:
        signature.bind(**kwargs)
    except TypeError:
        accepted = [p for p in signature.parameters if not p.startswith("_")]
        bad = sorted(set(options) - set(accepted)) or sorted(options)
        raise SolverOptionError(f"solver {name!r} does not accept option(s) {', '.join(bad)}; its options are: {', '.join(accepted)}") from None


def get_solver(name: str, **options: Any) -> StepSolver:
    """A new solver instance for a registered ``name``, with ``options`` over its defaults.

    Raises
    ------
    UnknownSolverError
        ``name`` is not registered (the message lists the available names).
    MissingDependencyError
        ``name`` is registered but a module it needs is not installed.
    SolverOptionError
        An option is unknown to the solver or has a bad type or value.
    SolverError
        The factory failed otherwise, or returned something that is not a :class:`StepSolver`.
    """
    if not isinstance(name, str):
        raise SolverOptionError(f"solver name must be a string; got {name!r} ({type(name).__name__})")
    if name not in _REGISTRY:
        raise UnknownSolverError(f"unknown solver {name!r}; available: {', '.join(available_solvers())}")
    factory, defaults, requires = _REGISTRY[name]
    missing = _missing(requires)
    if missing:
        raise MissingDependencyError(
            f"solver {name!r} needs the module(s) {', '.join(missing)}, which are not installed; "
            f"install them with: pip install {' '.join(missing)}",
            name=missing[0],
        )
    options = rename_options(f"solver {name!r}", getattr(factory, "renamed_options", {}), options)
    kwargs = {**defaults, **options}
    _check_accepted(name, factory, kwargs, options)
    try:
        solver = factory(**kwargs)
    except SolversError:
        raise
    except (TypeError, ValueError) as exc:
        raise SolverOptionError(f"solver {name!r}: invalid options {options!r}: {type(exc).__name__}: {exc}") from exc
    except Exception as exc:
        raise SolverError(f"solver {name!r}: its factory {_factory_name(factory)} failed: {type(exc).__name__}: {exc}") from exc
    if not isinstance(solver, StepSolver):
        raise SolverError(
            f"solver {name!r}: its factory {_factory_name(factory)} returned {type(solver).__name__} "
            f"{solver!r:.80}, not a solvers.StepSolver"
        )
    return solver


def resolve_solver(solver: str | StepSolver, options: Mapping[str, Any] | None = None, /, **kwargs: Any) -> StepSolver:
    """A solver from a registered name or a :class:`StepSolver` instance (returned as is).

    Parameters
    ----------
    solver : str or StepSolver
    options : mapping, optional
        Options of a named solver, e.g. ``{"shrink": 0.3}`` (a dict; a list or any other
        non-mapping is an error). Keyword arguments are merged in (they may not repeat a key).
    **kwargs
        More options.

    Raises
    ------
    SolverOptionError
        When ``options`` is not a mapping, a key is repeated, options are given with a solver
        object, or ``solver`` is neither a name nor a :class:`StepSolver`.
    UnknownSolverError, MissingDependencyError, SolverError
        As :func:`get_solver`.
    """
    opts = check_options(options, "resolve_solver")
    repeated = sorted(set(opts) & set(kwargs))
    if repeated:
        raise SolverOptionError(f"resolve_solver: option(s) {', '.join(repeated)} given both in options and as keywords")
    opts.update(kwargs)
    if isinstance(solver, StepSolver):
        if opts:
            raise SolverOptionError("options can only be given with a solver name, not a solver object")
        return solver
    if isinstance(solver, str):
        return get_solver(solver, **opts)
    raise SolverOptionError(f"solver must be a registered name or a StepSolver; got {type(solver).__name__}")


register_solver("armijo", ArmijoSolver)
register_solver("armijo-nonneg", ArmijoSolver, nonneg=True)
register_solver("lbfgs", LBFGSSolver)
register_solver("gn-cg", GaussNewtonCGSolver)
register_solver("newton", NewtonSolver)
for _qp_solver in QP_SOLVERS:
    for _constraint in CONSTRAINTS:
        register_solver(
            qp_solver_name(_qp_solver, _constraint),
            GaussNewtonSolver,
            requires=("cvxpy", _qp_solver),
            qp_solver=_qp_solver,
            constraint=_constraint,
        )
del _qp_solver, _constraint


def __getattr__(name: str) -> Any:
    """The former names ``BACKENDS`` of :data:`QP_SOLVERS` and ``MissingBackendError`` of
    :class:`MissingDependencyError`, with a :class:`DeprecatedNameWarning`."""
    if name == "BACKENDS":
        deprecated("solvers.BACKENDS was renamed solvers.QP_SOLVERS; the old name will be removed in the next release")
        return QP_SOLVERS
    if name == "MissingBackendError":
        deprecated("solvers.MissingBackendError was renamed solvers.MissingDependencyError; the old name will be "
                   "removed in the next release")
        return MissingDependencyError
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

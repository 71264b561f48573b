"""Every option of every registered solver is validated: a clear SolverOptionError naming the
option and the value, never a raw TypeError or a silently accepted value."""

import dataclasses

import numpy as np
import pytest

import solvers
from solvers import SolverError, SolverOptionError, UnknownSolverError

CLASSES = [solvers.ArmijoSolver, solvers.GaussNewtonSolver, solvers.LBFGSSolver, solvers.GaussNewtonCGSolver]


def _fields(cls):
    return [f for f in dataclasses.fields(cls) if f.init]


def _accepts_none(field):
    try:
        return field.metadata["check"](None, field.name, "x") is None
    except SolverOptionError:
        return False


def _numeric_fields():
    for cls in CLASSES:
        for f in _fields(cls):
            if isinstance(f.default, (int, float)) and not isinstance(f.default, bool):
                yield pytest.param(cls, f.name, isinstance(f.default, int), id=f"{cls.__name__}.{f.name}")


def _bad_values():
    for param in _numeric_fields():
        cls, name, _ = param.values
        field = next(f for f in _fields(cls) if f.name == name)
        for value in [np.nan, np.inf, -np.inf, "1", True, [1.0]] + ([] if _accepts_none(field) else [None]):
            yield pytest.param(cls, name, value, id=f"{cls.__name__}.{name}={value!r}")


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_every_option_has_a_check(cls):
    assert _fields(cls), cls
    for f in _fields(cls):
        assert callable(f.metadata.get("check")), f"{cls.__name__}.{f.name} has no check"


@pytest.mark.parametrize("cls, name, value", list(_bad_values()))
def test_numeric_option_rejects_non_numbers(cls, name, value):
    with pytest.raises(SolverOptionError, match=rf"{name} must be (a finite number|an integer).*got {__import__('re').escape(repr(value))}"):
        cls(**{name: value})


@pytest.mark.parametrize("cls, name", [(c, n) for c, n, i in [p.values for p in _numeric_fields()] if i])
def test_integer_option_rejects_fractions(cls, name):
    with pytest.raises(SolverOptionError, match=rf"{name} must be an integer.*got 2\.7"):
        cls(**{name: 2.7})


@pytest.mark.parametrize(
    "name, options, fragment",
    [
        ("armijo", {"max_step": -1}, r"max_step must be a finite number > 0; got -1"),
        ("armijo", {"grow": np.inf}, r"grow must be a finite number >= 1; got inf"),
        ("armijo", {"max_backtracks": 2.7}, r"max_backtracks must be an integer >= 1; got 2\.7"),
        ("armijo", {"shrink": "0.5"}, r"shrink must be a finite number in \(0, 1\); got '0\.5' \(str\)"),
        ("armijo", {"c": np.nan}, r"c must be a finite number in \(0, 1\); got nan"),
        ("armijo", {"nonneg": 1}, r"nonneg must be True or False; got 1 \(int\)"),
        ("gn-qp-osqp", {"max_step_norm": 0.0}, r"max_step_norm must be a finite number > 0; got 0\.0"),
        ("gn-qp-osqp", {"lam_min": 1.0, "lam_max": 0.5}, r"lam_max must be > lam_min = 1\.0; got 0\.5"),
        ("gn-qp-osqp", {"qp_solver": ["osqp"]}, r"qp_solver must be one of \('osqp', 'clarabel'\); got \['osqp'\] \(list\)"),
        ("gn-qp-osqp", {"tolerance": {"osqp": "1e-6"}}, r"tolerance\['osqp'\] must be a finite number"),
        ("gn-qp-osqp", {"alternating_damping": -1.0}, r"alternating_damping must be a finite number > 0; got -1\.0"),
    ],
)
def test_named_bad_options(name, options, fragment):
    with pytest.raises(SolverOptionError, match=fragment):
        solvers.get_solver(name, **options)
    with pytest.raises(SolverOptionError, match=fragment):
        solvers.resolve_solver(name, options)


@pytest.mark.parametrize("options", [["shrink"], [("shrink", 0.3)], "shrink=0.3", 0.5, {1: 0.3}])
def test_options_must_be_a_mapping_with_string_keys(options):
    with pytest.raises(SolverOptionError, match="resolve_solver: (options must be a mapping|option names must be strings)"):
        solvers.resolve_solver("armijo", options)


def test_resolve_solver_mapping_and_keywords():
    s = solvers.resolve_solver("armijo", {"shrink": 0.3}, grow=1.5)
    assert (s.shrink, s.grow) == (0.3, 1.5)
    assert solvers.resolve_solver("armijo", None).shrink == 0.5
    with pytest.raises(SolverOptionError, match="shrink given both"):
        solvers.resolve_solver("armijo", {"shrink": 0.3}, shrink=0.2)
    with pytest.raises(SolverOptionError, match="options can only be given with a solver name"):
        solvers.resolve_solver(solvers.ArmijoSolver(), {"shrink": 0.3})


@pytest.mark.parametrize("name", [3, ["armijo"], None])
def test_solver_name_must_be_a_string(name):
    with pytest.raises(SolverOptionError, match="solver name must be a string"):
        solvers.get_solver(name)


def test_unknown_option_lists_the_options():
    with pytest.raises(SolverOptionError, match=r"solver 'armijo' does not accept option\(s\) shrnk; its options are: initial_step, shrink"):
        solvers.get_solver("armijo", shrnk=0.3)


def _register(name, factory):
    solvers.register_solver(name, factory, overwrite=True)


@pytest.mark.parametrize(
    "factory, error, fragment",
    [
        (lambda: 3, SolverError, r"factory .*<lambda> returned int 3, not a solvers.StepSolver"),
        (lambda: solvers.ArmijoSolver, SolverError, r"returned type .*ArmijoSolver.*not a solvers.StepSolver"),
        (lambda: None, SolverError, r"returned NoneType None"),
        (lambda: (_ for _ in ()).throw(ValueError("bad value")), SolverOptionError, r"invalid options \{\}: ValueError: bad value"),
        (lambda: (_ for _ in ()).throw(RuntimeError("boom")), SolverError, r"factory .* failed: RuntimeError: boom"),
    ],
)
def test_factory_must_return_a_step_solver(factory, error, fragment):
    _register("test-bad-factory", factory)
    try:
        with pytest.raises(error, match=fragment):
            solvers.get_solver("test-bad-factory")
    finally:
        solvers.unregister_solver("test-bad-factory")
    assert "test-bad-factory" not in solvers.registered_solvers()


def test_register_validates_requires():
    with pytest.raises(SolverOptionError, match="requires of solver 'x' must be a tuple of module names"):
        solvers.register_solver("x", solvers.ArmijoSolver, requires="osqp")
    with pytest.raises(UnknownSolverError, match="unknown solver 3"):
        solvers.unregister_solver(3)


def _problem(**kw):
    base = dict(loss_and_grad=lambda x, rows: (np.sum(x * x, axis=1), 2 * x), n_evaluations=lambda: 0, n_rows=2, n_params=3)
    return solvers.StepProblem(**{**base, **kw})


@pytest.mark.parametrize(
    "kw, fragment",
    [
        (dict(loss_and_grad=None), r"loss_and_grad must be callable; got None"),
        (dict(n_evaluations=3), r"n_evaluations must be callable; got 3"),
        (dict(residual_jacobian="f"), r"residual_jacobian must be callable"),
        (dict(linearize=1.0), r"linearize must be callable"),
        (dict(n_rows=0), r"n_rows must be an integer >= 1; got 0"),
        (dict(n_params=2.0), r"n_params must be an integer >= 1; got 2\.0"),
    ],
)
def test_step_problem_validation(kw, fragment):
    with pytest.raises(SolverOptionError, match=fragment):
        _problem(**kw)


@pytest.mark.parametrize(
    "args, fragment",
    [
        (dict(x0=np.full((2, 3), np.nan)), r"armijo: x0 must be finite; rows \[0, 1\] hold NaN or inf"),
        (dict(x0=[["a"] * 3] * 2), r"x0 must be a numeric array"),
        (dict(tol=np.nan), r"tol must be a finite number >= 0; got nan"),
        (dict(tol=-1.0), r"tol must be a finite number >= 0; got -1\.0"),
        (dict(max_iter=True), r"max_iter must be an integer >= 0; got True \(bool\)"),
        (dict(callback="print"), r"callback must be callable; got str"),
        (dict(problem="p"), r"problem must be a StepProblem; got str"),
    ],
)
def test_run_validation(args, fragment):
    kwargs = {"problem": _problem(), "x0": np.ones((2, 3)), "max_iter": 2, **args}
    with pytest.raises(SolverOptionError, match=fragment):
        solvers.ArmijoSolver().run(**kwargs)

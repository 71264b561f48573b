"""The registry as a leaf package: its own exceptions, their translation into the library's
family (``factirl_opt.exceptions.translate_solver_errors``), and no import of ``factirl_opt``."""

import os
import subprocess
import sys

import pytest

import factirl_opt.exceptions as fe
import solvers
from solvers import exceptions as se


def test_import_solvers_does_not_import_factirl_opt():
    code = "import sys, solvers; solvers.get_solver('armijo'); print(sorted(m for m in sys.modules if m.startswith('factirl_opt')))"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (os.getcwd(), os.environ.get("PYTHONPATH")) if p)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_solvers_sources_do_not_mention_factirl_opt_imports():
    root = os.path.dirname(solvers.__file__)
    for name in sorted(os.listdir(root)):
        if name.endswith(".py"):
            with open(os.path.join(root, name)) as f:
                text = f.read()
            assert "from factirl_opt" not in text and "import factirl_opt" not in text, name


@pytest.mark.parametrize(
    "cls, builtin",
    [
        (se.SolverError, RuntimeError),
        (se.UnknownSolverError, KeyError),
        (se.SolverOptionError, ValueError),
        (se.MissingDependencyError, ImportError),
    ],
)
def test_hierarchy(cls, builtin):
    assert issubclass(cls, se.SolversError) and issubclass(cls, builtin)
    assert getattr(solvers, cls.__name__) is cls
    assert not issubclass(cls, fe.FactIRLError)


def test_unknown_solver_error_message_is_not_quoted():
    err = se.UnknownSolverError("unknown solver 'x'; available: armijo")
    assert str(err) == "unknown solver 'x'; available: armijo"
    assert str(se.UnknownSolverError()) == ""


def test_library_classes_derive_from_both_families():
    assert issubclass(fe.SolverError, fe.FactIRLError) and issubclass(fe.SolverError, se.SolverError)
    assert issubclass(fe.UnknownSolverError, fe.FactIRLError) and issubclass(fe.UnknownSolverError, se.UnknownSolverError)
    assert issubclass(fe.SolverOptionError, fe.ValidationError) and issubclass(fe.SolverOptionError, se.SolverOptionError)
    assert issubclass(fe.MissingSolverDependencyError, fe.MissingDependencyError)
    assert issubclass(fe.MissingSolverDependencyError, se.MissingDependencyError)
    assert fe.ValidationError.__bases__ == (fe.FactIRLError, ValueError)
    assert not issubclass(fe.MissingDependencyError, se.SolversError)  # e.g. a missing gymnasium


def _raise(exc):
    raise exc


@pytest.mark.parametrize(
    "original, expected",
    [
        (se.SolverError("run failed"), fe.SolverError),
        (se.SolversError("base"), fe.SolverError),
        (se.UnknownSolverError("unknown solver 'x'"), fe.UnknownSolverError),
        (se.SolverOptionError("armijo: shrink must be ..."), fe.SolverOptionError),
        (se.MissingDependencyError("pip install osqp"), fe.MissingSolverDependencyError),
    ],
)
def test_translate_as_context_manager_and_decorator(original, expected):
    with pytest.raises(expected) as info:
        with fe.translate_solver_errors():
            _raise(original)
    assert type(info.value) is expected
    assert str(info.value) == str(original) and info.value.__cause__ is original
    assert isinstance(info.value, fe.FactIRLError) and isinstance(info.value, type(original))

    @fe.translate_solver_errors()
    def call():
        _raise(original)

    with pytest.raises(expected):
        call()
    with pytest.raises(expected):
        call()  # the decorator is reusable


def test_translate_passes_other_exceptions_through():
    ours = fe.SolverError("already ours")
    for exc in (ValueError("plain"), fe.ValidationError("ours"), ours):
        with pytest.raises(type(exc)) as info:
            with fe.translate_solver_errors():
                _raise(exc)
        assert info.value is exc
    with fe.translate_solver_errors():
        value = 1
    assert value == 1


def test_translate_real_registry_errors():
    with pytest.raises(fe.UnknownSolverError, match="unknown solver 'nope'; available: .*armijo"):
        with fe.translate_solver_errors():
            solvers.get_solver("nope")
    with pytest.raises(fe.ValidationError, match=r"armijo: shrink must be a finite number in \(0, 1\); got '0.5' \(str\)"):
        with fe.translate_solver_errors():
            solvers.resolve_solver("armijo", {"shrink": "0.5"})
    solvers.register_solver("test-needs-missing", solvers.ArmijoSolver, requires=("no_such_module_abc",))
    try:
        with pytest.raises(fe.MissingDependencyError, match="pip install no_such_module_abc"):
            with fe.translate_solver_errors():
                solvers.get_solver("test-needs-missing")
    finally:
        solvers.unregister_solver("test-needs-missing")

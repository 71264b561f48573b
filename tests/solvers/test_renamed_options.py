"""The Gauss-Newton solvers' former option names (``backend``, ``fallback="backend"``) still work
and warn; the new names do not warn."""

import dataclasses
import inspect
import warnings

import numpy as np
import pytest

import solvers
from solvers import DeprecatedNameWarning, GaussNewtonSolver, SolverOptionError

from solver_problems import K, N, linear_problem


def test_backend_option_is_the_deprecated_name_of_qp_solver():
    with pytest.warns(DeprecatedNameWarning, match="'backend' was renamed 'qp_solver'"):
        old = GaussNewtonSolver(backend="clarabel")
    assert old.qp_solver == "clarabel" and old.name == "gn-qp-clarabel"
    assert old == GaussNewtonSolver(qp_solver="clarabel")
    with pytest.warns(DeprecatedNameWarning, match="'backend' was renamed 'qp_solver'"):
        via_registry = solvers.get_solver("gn-qp-osqp-nonneg", backend="clarabel")  # the option wins over the name's default
    assert via_registry == solvers.get_solver("gn-qp-clarabel-nonneg")


def test_the_deprecated_warning_points_at_the_caller():
    with pytest.warns(DeprecatedNameWarning) as record:
        GaussNewtonSolver(backend="clarabel")
        solvers.get_solver("gn-qp-osqp", backend="clarabel")
        GaussNewtonSolver(fallback="backend")
    assert [w.filename for w in record] == [__file__] * 3


def test_both_names_at_once_is_an_error():
    with pytest.raises(SolverOptionError, match="'backend' is the deprecated name of 'qp_solver'"):
        GaussNewtonSolver(backend="clarabel", qp_solver="osqp")
    with pytest.raises(SolverOptionError, match="'backend' is the deprecated name of 'qp_solver'"):
        solvers.get_solver("gn-qp-osqp", backend="clarabel", qp_solver="osqp")


def test_a_bad_value_under_the_old_name_names_the_new_option():
    with pytest.warns(DeprecatedNameWarning), pytest.raises(SolverOptionError, match="qp_solver must be one of"):
        GaussNewtonSolver(backend="mosek")


def test_fallback_backend_is_the_deprecated_value_of_qp_solver():
    with pytest.warns(DeprecatedNameWarning, match='fallback="qp-solver"'):
        old = GaussNewtonSolver(fallback="backend")
    assert old.fallback == "qp-solver" and old == GaussNewtonSolver()


def test_backend_attribute_reads_qp_solver_and_warns():
    with pytest.warns(DeprecatedNameWarning, match="renamed qp_solver"):
        assert GaussNewtonSolver(qp_solver="clarabel").backend == "clarabel"


def test_module_constants_keep_their_former_names():
    with pytest.warns(DeprecatedNameWarning, match="QP_SOLVERS"):
        assert solvers.BACKENDS == solvers.QP_SOLVERS == ("osqp", "clarabel")
    from solvers import qp_cvxpy

    with pytest.warns(DeprecatedNameWarning, match="qp_solver_options"):
        assert qp_cvxpy.backend_options is qp_cvxpy.qp_solver_options
    with pytest.raises(AttributeError):
        solvers.NO_SUCH_NAME  # noqa: B018


def test_new_names_do_not_warn_and_the_signature_shows_only_them(rng):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        solver = solvers.get_solver("gn-qp-clarabel", fallback="qp-solver")
        problem, _, _ = linear_problem(rng)
        result = solver.run(problem, np.zeros((N, K)), 3)
    assert np.all(np.isfinite(result.coefficients))
    params = inspect.signature(GaussNewtonSolver).parameters
    assert "qp_solver" in params and "backend" not in params
    assert "backend" not in {f.name for f in dataclasses.fields(GaussNewtonSolver)}
    assert dataclasses.replace(solver, damping=1.0).qp_solver == "clarabel"


def test_a_deprecated_solver_name_warning_is_a_future_warning_and_the_librarys_derives_from_it():
    import factirl_opt.exceptions as fe

    assert issubclass(DeprecatedNameWarning, FutureWarning)
    assert issubclass(fe.DeprecatedNameWarning, DeprecatedNameWarning)


def test_missing_backend_error_is_the_former_name_of_missing_dependency_error():
    import factirl_opt as fo
    import factirl_opt.exceptions as fe
    from solvers import exceptions as se

    with pytest.warns(DeprecatedNameWarning, match="MissingDependencyError"):
        assert solvers.MissingBackendError is solvers.MissingDependencyError
    with pytest.warns(DeprecatedNameWarning, match="MissingDependencyError"):
        assert se.MissingBackendError is se.MissingDependencyError
    with pytest.warns(DeprecatedNameWarning, match="MissingSolverDependencyError"):
        assert fe.MissingSolverBackendError is fe.MissingSolverDependencyError
    with pytest.warns(DeprecatedNameWarning):
        assert fo.MissingSolverBackendError is fe.MissingSolverDependencyError  # the former top-level name
    with pytest.raises(AttributeError):
        fe.NO_SUCH_NAME  # noqa: B018

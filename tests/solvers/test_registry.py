"""Registry, option validation and QP-solver-failure handling of the step solvers."""

import warnings

import numpy as np
import pytest

import solvers
from solvers import MissingDependencyError, SolverError, SolverOptionError, UnknownSolverError
from solvers._blockqp import BlockQPResult
from solvers.gauss_newton import reduce_least_squares, safe_step
from solvers.qp_cvxpy import CvxpyBlockQP
from solvers.qp_direct import DirectBlockQP

from solver_problems import K, N, exact_step, linear_problem

EXPECTED = {
    "armijo",
    "armijo-nonneg",
    "gn-qp-osqp",
    "gn-qp-clarabel",
    "gn-qp-osqp-nonneg",
    "gn-qp-clarabel-nonneg",
    "gn-qp-osqp-sparse",
    "gn-qp-clarabel-sparse",
    "lbfgs",
    "gn-cg",
}


def test_builtin_names_available():
    assert EXPECTED <= set(solvers.available_solvers())
    for name in {n for n in EXPECTED if n.startswith("gn-qp-")}:
        solver = solvers.get_solver(name)
        assert isinstance(solver, solvers.GaussNewtonSolver) and solver.name == name
        assert solver.needs_jacobian
    assert isinstance(solvers.get_solver("lbfgs"), solvers.LBFGSSolver)
    assert isinstance(solvers.get_solver("gn-cg"), solvers.GaussNewtonCGSolver)
    for name in EXPECTED:
        assert solvers.get_solver(name).name == name


def test_gauss_newton_names_come_from_one_builder():
    gn = {n for n in solvers.registered_solvers() if n.startswith("gn-qp-")}
    assert gn == {solvers.qp_solver_name(b, c) for b in ("osqp", "clarabel") for c in ("none", "nonneg", "sparse")}
    assert solvers.qp_solver_name("osqp", "sparse", "direct") == solvers.get_solver("gn-qp-osqp-sparse", interface="direct").name
    with pytest.raises(SolverOptionError, match="qp_solver must be one of"):
        solvers.qp_solver_name("mosek")
    with pytest.raises(SolverOptionError, match="constraint must be one of"):
        solvers.qp_solver_name("osqp", "l2")


def test_unknown_name_lists_available():
    with pytest.raises(UnknownSolverError) as err:
        solvers.get_solver("gn-qp-gurobi")
    msg = str(err.value)
    assert "gn-qp-gurobi" in msg and "gn-qp-osqp" in msg and "armijo" in msg


@pytest.mark.parametrize(
    "options, word",
    [
        ({"qp_solver": "gurobi"}, "qp_solver"),
        ({"constraint": "l2"}, "constraint"),
        ({"interface": "ctypes"}, "interface"),
        ({"fallback": "pray"}, "fallback"),
        ({"alpha": -1.0}, "alpha"),
        ({"lam_up": 0.5}, "lam_up"),
        ({"lam_down": 1.0}, "lam_down"),
        ({"damping": 0.0}, "damping"),
        ({"max_retries": 1.5}, "max_retries"),
        ({"tolerance": {"osqp": 1e-3}}, "tolerance"),
        ({"tolerance": {"mosek": 1e-8}}, "QP solvers"),
        ({"tolerance": 1e-6}, "tolerance"),
        ({"no_such_option": 1}, "no_such_option"),
    ],
)
def test_bad_options_raise_validation_error(options, word):
    with pytest.raises(SolverOptionError, match=word):
        solvers.get_solver("gn-qp-osqp", **options)


def test_options_only_with_names():
    with pytest.raises(SolverOptionError):
        solvers.resolve_solver(solvers.get_solver("gn-qp-osqp"), alpha=1.0)
    with pytest.raises(SolverOptionError):
        solvers.resolve_solver(3)


def test_missing_dependency_not_available():
    solvers.register_solver("needs-missing", solvers.ArmijoSolver, requires=("no_such_module_xyz_123",))
    try:
        assert "needs-missing" in solvers.registered_solvers()
        assert "needs-missing" not in solvers.available_solvers()
        with pytest.raises(MissingDependencyError, match="no_such_module_xyz_123.*pip install no_such_module_xyz_123") as info:
            solvers.get_solver("needs-missing")
        assert isinstance(info.value, ImportError) and "unknown" not in str(info.value)
    finally:
        solvers.unregister_solver("needs-missing")


def test_user_solver_by_decorator(rng):
    @solvers.register_solver("test-halving")
    class Halving(solvers.StepSolver):
        """Moves every row half-way to zero (a toy solver)."""

        def init_state(self, problem, x, previous=None):
            loss, _ = problem.loss_and_grad(x, np.arange(problem.n_rows))
            return _S(loss)

        def update(self, problem, x, state):
            x = 0.5 * x
            state.loss = problem.loss_and_grad(x, np.arange(problem.n_rows))[0]
            return x, state, True

    class _S:
        def __init__(self, loss):
            self.loss = loss

    try:
        assert "test-halving" in solvers.available_solvers()
        with pytest.raises(SolverOptionError, match="already registered"):
            solvers.register_solver("test-halving", Halving)
        problem = solvers.StepProblem(
            loss_and_grad=lambda x, rows: (np.sum(x * x, axis=1), 2 * x),
            n_evaluations=lambda: 0,
            n_rows=N,
            n_params=K,
        )
        res = solvers.get_solver("test-halving").run(problem, np.ones((N, K)), 3)
        np.testing.assert_allclose(res.coefficients, 0.125)
        assert res.status == "max_iter" and np.allclose(res.loss_history, np.array([4.0, 1.0, 0.25, 0.0625]) * N)
    finally:
        solvers.unregister_solver("test-halving")
    assert "test-halving" not in solvers.registered_solvers()


def test_gn_needs_least_squares_problem(rng):
    problem, _, _ = linear_problem(rng)
    bare = solvers.StepProblem(problem.loss_and_grad, problem.n_evaluations, problem.n_rows, problem.n_params)
    with pytest.raises(SolverOptionError, match="residual_jacobian"):
        solvers.get_solver("gn-qp-osqp").run(bare, np.zeros((N, K)), 2)


def _inaccurate(real_solve, failing):
    """A CvxpyBlockQP.solve that reports optimal_inaccurate for the QP solvers in ``failing``."""

    def solve(self, R, b, qp_solver="osqp", **kw):
        res = real_solve(self, R, b, qp_solver, **kw)
        if qp_solver in failing:
            return BlockQPResult(z=res.z + 0.1, status="optimal_inaccurate", ok=False, solve_time=res.solve_time, qp_solver=qp_solver)
        return res

    return solve


def _setup(rng, **options):
    problem, A, y = linear_problem(rng)
    solver = solvers.get_solver("gn-qp-osqp-nonneg", damping=0.05, **options)
    x0 = solver.project(rng.standard_normal((N, K)))
    state = solver.init_state(problem, x0)
    ref = exact_step(A, y, x0, state.lam, "nonneg", 0.0)
    return problem, solver, x0, state, ref


def test_inaccurate_status_falls_back_to_other_qp_solver(rng, monkeypatch):
    monkeypatch.setattr(CvxpyBlockQP, "solve", _inaccurate(CvxpyBlockQP.solve, {"osqp"}))
    problem, solver, x0, state, ref = _setup(rng)
    with pytest.warns(solvers.QPFallbackWarning, match="optimal_inaccurate.*clarabel"):
        x1, state, ok = solver.update(problem, x0, state)
    assert ok and state.qp_failures == 1
    np.testing.assert_allclose(x1, ref, atol=1e-6)  # the clarabel solution, not the perturbed one


def test_all_qp_solvers_inaccurate_takes_safe_step(rng, monkeypatch):
    monkeypatch.setattr(CvxpyBlockQP, "solve", _inaccurate(CvxpyBlockQP.solve, {"osqp", "clarabel"}))
    problem, solver, x0, state, ref = _setup(rng)
    loss0 = state.loss.copy()
    R, b = reduce_least_squares(state.jacobian, state.residual, x0, state.lam)
    expected = safe_step(R, b, x0, "nonneg")
    with pytest.warns(solvers.QPFallbackWarning, match="safe proximal-gradient step"):
        x1, state, ok = solver.update(problem, x0, state)
    assert ok and np.min(x1) >= 0
    assert np.all(state.loss <= loss0)
    np.testing.assert_allclose(x1, expected, atol=1e-12)  # the safe step, never the inaccurate point


def test_fallback_none_rejects_inaccurate_step(rng, monkeypatch):
    monkeypatch.setattr(CvxpyBlockQP, "solve", _inaccurate(CvxpyBlockQP.solve, {"osqp"}))
    problem, solver, x0, state, ref = _setup(rng, fallback="none")
    lam0 = state.lam.copy()
    evals = problem.n_evaluations()
    with pytest.warns(solvers.QPFallbackWarning, match="rejected"):
        x1, state, ok = solver.update(problem, x0, state)
    np.testing.assert_array_equal(x1, x0)
    np.testing.assert_allclose(state.lam, lam0 * solver.lam_up)
    assert problem.n_evaluations() == evals  # nothing was evaluated at the rejected point


def test_qp_solver_exception_reraised_as_solver_error(rng, monkeypatch):
    def crash(self, *args, **kwargs):
        raise RuntimeError("QP solver exploded")

    monkeypatch.setattr(CvxpyBlockQP, "solve", crash)
    problem, solver, x0, state, _ = _setup(rng, fallback="none")
    with pytest.raises(SolverError, match="QP solver exploded"):
        solver.update(problem, x0, state)
    # with the default fallback both QP solvers crash: a warned safe step, not an exception
    problem, solver, x0, state, _ = _setup(rng)
    with pytest.warns(solvers.QPFallbackWarning, match="exploded"):
        x1, state, ok = solver.update(problem, x0, state)
    assert ok


def test_no_warning_on_healthy_qp_solver(rng):
    problem, solver, x0, state, ref = _setup(rng)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        x1, state, ok = solver.update(problem, x0, state)
    assert state.qp_failures == 0 and state.qp_solves == 1


@pytest.mark.parametrize("cls", [CvxpyBlockQP, DirectBlockQP])
def test_block_qp_validates_data(cls):
    qp = cls(3, 2, "nonneg")
    with pytest.raises(SolverOptionError, match="shapes"):
        qp.solve(np.ones((2, 2, 2)), np.ones((3, 2)))
    with pytest.raises(SolverOptionError, match="upper triangular"):
        qp.solve(np.ones((3, 2, 2)), np.ones((3, 2)))
    with pytest.raises(SolverOptionError, match="qp_solver"):
        qp.solve(np.tile(np.eye(2), (3, 1, 1)), np.ones((3, 2)), qp_solver="mosek")


@pytest.mark.parametrize("constraint", ["none", "nonneg", "sparse"])
def test_direct_and_cvxpy_agree_on_resolves(constraint, rng):
    """Re-solving a compiled problem with new parameter values gives the new solution."""
    n, k = 7, 3
    cv, di = CvxpyBlockQP(n, k, constraint), DirectBlockQP(n, k, constraint)
    for _ in range(3):
        R = np.triu(rng.standard_normal((n, k, k))) + 2 * np.eye(k)
        b = rng.standard_normal((n, k))
        for qp_solver in ("osqp", "clarabel"):
            a = cv.solve(R, b, qp_solver, alpha=0.5)
            d = di.solve(R, b, qp_solver, alpha=0.5)
            assert a.ok and d.ok
            np.testing.assert_allclose(a.z, d.z, atol=1e-6)
        if constraint == "none":
            np.testing.assert_allclose(a.z, np.linalg.solve(R, b[..., None])[..., 0], atol=1e-7)

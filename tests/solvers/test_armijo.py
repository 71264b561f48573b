"""The step-solver registry's core paths and the Armijo descent step."""

import numpy as np
import pytest

import solvers
from solvers import SolverOptionError, SolversError, UnknownSolverError


def quadratic_problem(A_diag, b, counter=None):
    """Rows f_i(x) = 0.5 sum_j a_ij (x_ij - b_ij)^2 with a counter of batched evaluations."""
    calls = counter if counter is not None else [0]

    def loss_and_grad(x, rows):
        calls[0] += 1
        d = x - b[rows]
        return 0.5 * np.sum(A_diag[rows] * d * d, axis=1), A_diag[rows] * d

    return solvers.StepProblem(
        loss_and_grad=loss_and_grad, n_evaluations=lambda: calls[0], n_rows=b.shape[0], n_params=b.shape[1]
    )


def test_registry_lists_armijo_and_builds_it():
    names = solvers.available_solvers()
    assert {"armijo", "armijo-nonneg"} <= set(names)
    assert set(names) <= set(solvers.registered_solvers())
    s = solvers.get_solver("armijo", initial_step=0.25)
    assert isinstance(s, solvers.ArmijoSolver) and s.initial_step == 0.25 and not s.nonneg
    assert solvers.get_solver("armijo-nonneg").nonneg


def test_unknown_name_lists_available():
    with pytest.raises(UnknownSolverError, match=r"unknown solver 'bfgs'; available: .*armijo.*armijo-nonneg") as info:
        solvers.get_solver("bfgs")
    assert isinstance(info.value, SolversError) and isinstance(info.value, KeyError)
    assert "'bfgs'" in str(info.value)


def test_resolve_solver():
    s = solvers.ArmijoSolver()
    assert solvers.resolve_solver(s) is s
    with pytest.raises(SolverOptionError, match="options can only be given with a solver name"):
        solvers.resolve_solver(s, shrink=0.3)
    with pytest.raises(SolverOptionError, match="solver must be a registered name or a StepSolver; got float"):
        solvers.resolve_solver(1.0)


def test_register_and_unregister_a_custom_solver():
    name = "test-registry-armijo-custom"
    solvers.register_solver(name, solvers.ArmijoSolver, shrink=0.25)
    try:
        assert name in solvers.available_solvers()
        assert solvers.get_solver(name).shrink == 0.25
        with pytest.raises(SolverOptionError, match=rf"a solver named '{name}' is already registered"):
            solvers.register_solver(name, solvers.ArmijoSolver)
    finally:
        solvers.unregister_solver(name)
    assert name not in solvers.registered_solvers()
    with pytest.raises(UnknownSolverError, match=rf"unknown solver '{name}'"):
        solvers.unregister_solver(name)
    with pytest.raises(SolverOptionError, match="solver name must be a non-empty string; got ''"):
        solvers.register_solver("", solvers.ArmijoSolver)
    with pytest.raises(SolverOptionError, match="must be callable; got int"):
        solvers.register_solver("test-registry-not-callable", 3)


@pytest.mark.parametrize(
    "options, fragment",
    [
        (dict(shrink=1.5), r"armijo: shrink must be a finite number in \(0, 1\); got 1\.5"),
        (dict(shrink=0.0), r"shrink must be a finite number in \(0, 1\); got 0\.0"),
        (dict(grow=0.5), r"grow must be a finite number >= 1; got 0\.5"),
        (dict(c=1.0), r"c must be a finite number in \(0, 1\); got 1\.0"),
        (dict(initial_step=0.0), r"initial_step must be a finite number > 0; got 0\.0"),
        (dict(initial_step=np.inf), r"initial_step must be a finite number > 0; got inf"),
        (dict(max_backtracks=0), r"max_backtracks must be an integer >= 1; got 0"),
    ],
)
def test_armijo_bad_options(options, fragment):
    with pytest.raises(SolverOptionError, match=fragment):
        solvers.ArmijoSolver(**options)
    with pytest.raises(SolverOptionError, match=fragment):
        solvers.get_solver("armijo", **options)


def test_armijo_minimises_a_quadratic_monotonically(rng):
    # c = 1e-4 accepts steps close to 2/L, where stiff directions contract slowly: check
    # geometric convergence of the loss rather than a fixed number of digits in x
    A = rng.uniform(0.5, 4.0, size=(6, 3))
    b = rng.standard_normal((6, 3))
    res = solvers.ArmijoSolver().run(quadratic_problem(A, b), np.zeros((6, 3)), 200, tol=0.0)
    assert isinstance(res, solvers.SolverResult)
    h = np.asarray(res.loss_history)
    assert h[-1] < 1e-6 * h[0]
    np.testing.assert_allclose(res.coefficients, b, atol=1e-3)
    assert np.all(np.diff(h) <= 0)
    assert len(h) == res.iterations + 1
    assert res.loss.shape == (6,) and isinstance(res.n_evaluations, (int, np.integer)) and res.n_evaluations > 0
    assert res.status in ("converged", "max_iter", "stalled")
    assert res.solve_time >= 0


def test_armijo_rows_are_independent(rng):
    A = rng.uniform(0.5, 4.0, size=(4, 3))
    b = rng.standard_normal((4, 3))
    together = solvers.ArmijoSolver().run(quadratic_problem(A, b), np.zeros((4, 3)), 15).coefficients
    for i in range(4):
        alone = solvers.ArmijoSolver().run(quadratic_problem(A[i : i + 1], b[i : i + 1]), np.zeros((1, 3)), 15)
        np.testing.assert_allclose(alone.coefficients[0], together[i], rtol=1e-13)


def test_armijo_sufficient_decrease_and_step_adaptation(rng):
    A = np.full((1, 2), 2.0)
    b = np.array([[1.0, -1.0]])
    s = solvers.ArmijoSolver(initial_step=10.0)
    problem = quadratic_problem(A, b)
    state = s.init_state(problem, np.zeros((1, 2)))
    x, state, progressed = s.update(problem, np.zeros((1, 2)), state)
    assert progressed
    # step 10 overshoots (the curvature is 2): backtracking to 0.625 (< 2/2 * (1 - c)) is accepted
    assert state.step[0] == pytest.approx(0.625)
    x2, state2, _ = s.update(problem, x, state)
    assert state2.step[0] <= 2 * state.step[0]
    assert state2.loss[0] < state.loss[0]


def test_armijo_nonneg_projects(rng):
    A = np.ones((3, 4))
    b = rng.standard_normal((3, 4))
    res = solvers.ArmijoSolver(nonneg=True).run(quadratic_problem(A, b), np.full((3, 4), -1.0), 100)
    assert np.all(res.coefficients >= 0)
    np.testing.assert_allclose(res.coefficients, np.maximum(b, 0), atol=1e-6)
    assert solvers.ArmijoSolver(nonneg=True).name == "armijo-nonneg"


def test_armijo_warm_state_carries_step_sizes(rng):
    A = rng.uniform(0.5, 4.0, size=(3, 2))
    b = rng.standard_normal((3, 2))
    problem = quadratic_problem(A, b)
    first = solvers.ArmijoSolver().run(problem, np.zeros((3, 2)), 3)
    s = solvers.ArmijoSolver()
    state = s.init_state(problem, first.coefficients, previous=first.state)
    np.testing.assert_array_equal(state.step, first.state.step)


def test_stalled_rows_are_reported():
    def loss_and_grad(x, rows):  # a wrong gradient: no step can satisfy the Armijo condition
        return np.sum(x * x, axis=1), -np.ones_like(x)

    problem = solvers.StepProblem(loss_and_grad=loss_and_grad, n_evaluations=lambda: 0, n_rows=2, n_params=2)
    res = solvers.ArmijoSolver(max_backtracks=3).run(problem, np.zeros((2, 2)), 5)
    assert res.status == "stalled" and res.iterations == 1
    np.testing.assert_array_equal(res.coefficients, 0.0)


@pytest.mark.parametrize(
    "x0, max_iter, fragment",
    [
        (np.zeros((2, 2)), 5, r"x0 must have shape \(3, 2\); got \(2, 2\)"),
        (np.zeros((3, 2)), -1, r"max_iter must be an integer >= 0; got -1"),
        (np.zeros((3, 2)), 2.0, r"max_iter must be an integer >= 0; got 2\.0"),
    ],
)
def test_run_validation(rng, x0, max_iter, fragment):
    problem = quadratic_problem(np.ones((3, 2)), np.zeros((3, 2)))
    with pytest.raises(SolverOptionError, match=fragment):
        solvers.ArmijoSolver().run(problem, x0, max_iter)

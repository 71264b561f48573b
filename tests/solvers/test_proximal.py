"""Proximal Armijo descent and the proximal map of unit-norm columns (solvers.proximal)."""

import numpy as np
import pytest

import solvers
from solvers import SolverOptionError


def quadratic_problem(b, counter=None):
    """Rows f_i(x) = ||x_i - b_i||^2."""
    calls = counter if counter is not None else [0]

    def loss_and_grad(x, rows):
        calls[0] += 1
        d = x - b[rows]
        return np.sum(d * d, axis=1), 2.0 * d

    return solvers.StepProblem(loss_and_grad=loss_and_grad, n_evaluations=lambda: calls[0], n_rows=b.shape[0],
                               n_params=b.shape[1])


def _prox_objective(d, v, thr):
    """What the prox minimises on the sphere, per column: ||d - v||^2 / 2 + thr ||d||_1."""
    return 0.5 * np.sum((d - v) ** 2, axis=0) + thr * np.sum(np.abs(d), axis=0)


def _random_feasible(rng, p, k, nonneg, m):
    X = rng.normal(size=(m, p, k))
    if nonneg:
        X = np.abs(X)
    X[rng.random(X.shape) < 0.5] = 0.0
    X[:, 0, :] += 1e-3  # no zero column
    return X / np.linalg.norm(X, axis=1, keepdims=True)


@pytest.mark.parametrize("nonneg", [False, True])
@pytest.mark.parametrize("alpha", [0.0, 0.3])
def test_prox_is_the_minimiser_on_the_feasible_set(rng, nonneg, alpha):
    p, k = 6, 3
    prox, penalty = solvers.unit_columns_prox(p, k, nonneg=nonneg, alpha=alpha)
    v = rng.normal(size=(2, p * k))
    t = np.array([0.5, 2.0])
    z = prox(v, t)
    Z = z.reshape(2, p, k)
    np.testing.assert_allclose(np.linalg.norm(Z, axis=1), 1.0, atol=1e-12)
    if nonneg:
        assert np.all(Z >= 0)
    np.testing.assert_allclose(penalty(z), alpha * np.abs(z).sum(axis=1))
    others = _random_feasible(rng, p, k, nonneg, 2000)
    for r in range(2):
        V = v[r].reshape(p, k)
        best = _prox_objective(Z[r], V, t[r] * alpha)
        trials = np.array([_prox_objective(o, V, t[r] * alpha) for o in others])
        assert np.all(trials >= best[None, :] - 1e-12)


@pytest.mark.parametrize("nonneg, expected", [(True, [0.0, 1.0, 0.0]), (False, [0.0, 0.0, -1.0])])
def test_prox_below_the_threshold_is_the_unit_vector_at_the_largest_entry(nonneg, expected):
    prox, _ = solvers.unit_columns_prox(3, 1, nonneg=nonneg, alpha=1.0)
    z = prox(np.array([[-0.2, 0.5, -0.9]]), np.array([1.0]))
    np.testing.assert_array_equal(z[0], expected)


def test_prox_at_zero_step_projects():
    prox, _ = solvers.unit_columns_prox(3, 2, nonneg=True, alpha=5.0)
    v = np.array([[3.0, -1.0, -4.0, 2.0, 0.0, 0.0]])  # columns (3, -4, 0) and (-1, 2, 0)
    np.testing.assert_allclose(prox(v, np.zeros(1)).reshape(3, 2), [[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])


@pytest.mark.parametrize("nonneg", [False, True])
@pytest.mark.parametrize("alpha", [0.0, 0.4])
def test_solver_reaches_the_constrained_minimiser_of_a_quadratic(rng, nonneg, alpha):
    """min ||x - b||^2 + alpha ||x||_1 on unit (nonnegative) columns is prox(b, 1/2) in closed form."""
    p, k = 5, 2
    prox, penalty = solvers.unit_columns_prox(p, k, nonneg=nonneg, alpha=alpha)
    b = rng.normal(size=(3, p * k))
    solver = solvers.ProximalArmijoSolver(prox=prox, prox_penalty=penalty, initial_step=0.3, grow=1.0)
    res = solver.run(quadratic_problem(b), rng.normal(size=b.shape), max_iter=300, separable=True)
    np.testing.assert_allclose(res.coefficients, prox(b, np.full(3, 0.5)), atol=1e-8)
    assert np.all(np.diff(res.loss_history) <= 1e-12)  # the total (with the penalty) never rises
    expected = np.sum((res.coefficients - b) ** 2, axis=1) + penalty(res.coefficients)
    np.testing.assert_allclose(res.loss, expected, rtol=1e-12)
    assert np.all(solver.optimality(res.coefficients, 2 * (res.coefficients - b)) < 1e-7)


def test_solver_projects_the_start_and_is_row_separable(rng):
    p, k = 4, 2
    prox, penalty = solvers.unit_columns_prox(p, k, nonneg=True, alpha=0.1)
    b = rng.normal(size=(3, p * k))
    solver = solvers.ProximalArmijoSolver(prox=prox, prox_penalty=penalty)
    x0 = rng.normal(size=b.shape)
    first = solver.run(quadratic_problem(b), x0, max_iter=0)
    np.testing.assert_array_equal(first.coefficients, prox(x0, np.zeros(3)))
    batch = solver.run(quadratic_problem(b), x0, max_iter=30, separable=True)
    for i in range(3):
        alone = solver.run(quadratic_problem(b[i:i + 1]), x0[i:i + 1], max_iter=30, separable=True)
        np.testing.assert_array_equal(batch.coefficients[i], alone.coefficients[0])


def test_optimality_is_positive_away_from_a_stationary_point(rng):
    prox, _ = solvers.unit_columns_prox(3, 1)
    solver = solvers.ProximalArmijoSolver(prox=prox)
    x = prox(rng.normal(size=(1, 3)), np.zeros(1))
    assert solver.optimality(x, -x)[0] == pytest.approx(0.0, abs=1e-15)  # the gradient pushes along x: stationary
    assert solver.optimality(x, rng.normal(size=(1, 3)))[0] > 1e-3


@pytest.mark.parametrize("kwargs, fragment", [
    ({}, "prox must be callable"),
    ({"prox": 3}, "prox must be callable"),
    ({"prox": lambda v, t: v, "prox_penalty": "l1"}, "prox_penalty must be callable"),
    ({"prox": lambda v, t: v, "nonneg": True}, "nonneg is not taken"),
    ({"prox": lambda v, t: v, "shrink": 2.0}, "shrink"),
])
def test_solver_bad_options(kwargs, fragment):
    with pytest.raises(SolverOptionError, match=fragment):
        solvers.ProximalArmijoSolver(**kwargs)


@pytest.mark.parametrize("args, kwargs, fragment", [
    ((0, 2), {}, "n_params"),
    ((3, 1.5), {}, "n_columns"),
    ((3, 2), {"nonneg": "yes"}, "nonneg must be True or False"),
    ((3, 2), {"alpha": -0.1}, "alpha"),
    ((3, 2), {"alpha": np.inf}, "alpha"),
])
def test_unit_columns_prox_bad_arguments(args, kwargs, fragment):
    with pytest.raises(SolverOptionError, match=fragment):
        solvers.unit_columns_prox(*args, **kwargs)


def _unit(v, t):
    return solvers.unit_columns_prox(3, 2)[0](v, t)


@pytest.mark.parametrize("prox, fragment", [
    (lambda v, t: np.full_like(v, np.nan),
     r"prox\(v, t\) at the starting point \(t = 0, the projection\) returned non-finite values \(NaN or inf\) for "
     r"finite v, in 2 of 2 row\(s\) \(rows \[0, 1\] of v, steps t = \[0.0, 0.0\]\); it must return finite proximal points"),
    (lambda v, t: _unit(v, t) if np.all(t <= 1) else np.full_like(v, np.nan),
     r"prox\(v, t\) at a proximal-gradient step returned non-finite values \(NaN or inf\) for finite v, in 2 of 2 "),
    (lambda v, t: _unit(v, t) if np.all(t <= 1) else np.where(np.arange(v.shape[0])[:, None] == 1, np.inf, _unit(v, t)),
     r"prox\(v, t\) at a proximal-gradient step returned non-finite values \(NaN or inf\) for finite v, in 1 of 2 "
     r"row\(s\) \(rows \[1\] of v, steps t = \[3.0\]\)"),
    (lambda v, t: _unit(v, t)[:, :-1],
     r"prox\(v, t\) at the starting point \(t = 0, the projection\) returned shape \(2, 5\) for v of shape \(2, 6\); it must return "
     r"the proximal points, one row of 6 per row of v"),
    (lambda v, t: _unit(v, t) if np.all(t <= 1) else _unit(v, t).ravel(),
     r"prox\(v, t\) at a proximal-gradient step returned shape \(12,\) for v of shape \(2, 6\)"),
    (lambda v, t: None, r"prox\(v, t\) at the starting point \(t = 0, the projection\) returned NoneType \(shape \(\)\) "
                        r"for v of shape \(2, 6\)"),
    (lambda v, t: [["a"] * 6] * 2, r"prox\(v, t\) at the starting point \(t = 0, the projection\) returned list, not an "
                                   r"array of numbers"),
])
def test_a_prox_that_returns_non_finite_points_or_another_shape_is_named(rng, prox, fragment):
    """A user's prox returning NaN used to reach the problem's objective (in the library, blamed on
    the planner's Q); one of another shape gave numpy's broadcasting error."""
    b = rng.normal(size=(2, 6))
    solver = solvers.ProximalArmijoSolver(prox=prox, initial_step=3.0)
    with pytest.raises(solvers.SolverError, match=r"^armijo-prox: " + fragment):
        solver.run(quadratic_problem(b), _unit(b, np.zeros(2)), max_iter=5, separable=True)


@pytest.mark.parametrize("penalty, fragment", [
    (lambda x: np.zeros(x.shape[0] + 1), r"prox_penalty\(x\) returned shape \(3,\) for x of shape \(2, 6\); it must return "
                                         r"one value per row, shape \(2,\)"),
    (lambda x: np.array([0.0, np.nan]), r"prox_penalty\(x\) returned NaN in rows \[1\] of x"),
    (lambda x: "l1", r"prox_penalty\(x\) returned str, not an array of numbers"),
])
def test_a_prox_penalty_of_another_shape_or_nan_is_named(rng, penalty, fragment):
    b = rng.normal(size=(2, 6))
    solver = solvers.ProximalArmijoSolver(prox=_unit, prox_penalty=penalty)
    with pytest.raises(solvers.SolverError, match=r"^armijo-prox: " + fragment):
        solver.run(quadratic_problem(b), _unit(b, np.zeros(2)), max_iter=5, separable=True)


def test_optimality_checks_prox_too(rng):
    solver = solvers.ProximalArmijoSolver(prox=lambda v, t: v[:, :-1])
    with pytest.raises(solvers.SolverError, match=r"prox\(v, t\) in the optimality measure \(t = 1\) returned shape \(1, 2\)"):
        solver.optimality(np.ones((1, 3)), np.zeros((1, 3)))


def test_a_bad_prox_in_a_factirl_fit_is_the_librarys_error_naming_prox():
    fo = pytest.importorskip("factirl_opt")
    mdp = fo.GridWorld(size=3)
    demos = fo.sample_demonstrations(mdp, np.random.default_rng(0).normal(size=(3, 9, 4)), n_demos=2, length=5, rng=1)
    good, _ = solvers.unit_columns_prox(36, 2)
    for prox, fragment in ((lambda v, t: np.full_like(v, np.nan), "non-finite values"),
                           (lambda v, t: good(v, t)[:, :-1], r"returned shape \(1, 71\) for v of shape \(1, 72\)")):
        model = fo.FactIRL(2, d_solver=solvers.ProximalArmijoSolver(prox=prox), max_iter=2, flat_max_iter=3)
        with pytest.raises(fo.exceptions.SolverError, match=r"armijo-prox: prox\(v, t\) .*" + fragment):
            model.fit(mdp, demos)

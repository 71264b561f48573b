"""Robustness of the Gauss-Newton QP steps: zero, tiny and huge Jacobians, zero residuals,
saturated rows (the step bound), silent QP solvers, and non-finite evaluations."""

import warnings

import numpy as np
import pytest

import factirl_opt as fo
import solvers
from solvers import SolverError
from solvers._base import limit_step
from solvers.gauss_newton import rescale_subproblems

from solver_problems import GN, K, N, exact_step, linear_problem


def counting(residual_fn, jacobian_fn, n, k):
    """A StepProblem from per-row residual and Jacobian functions (loss = ||r||^2)."""
    count = [0]

    def residual_jacobian(x, rows):
        count[0] += 1
        r, J = residual_fn(x, rows), jacobian_fn(x, rows)
        return np.sum(r * r, axis=1), r, J

    def loss_and_grad(x, rows):
        loss, r, J = residual_jacobian(x, rows)
        return loss, 2.0 * np.einsum("nmk,nm->nk", J, r)

    return solvers.StepProblem(loss_and_grad, lambda: count[0], n, k, residual_jacobian=residual_jacobian)


def saturating_problem(k=2, m=3, seed=0):
    """``r_i(h) = sigmoid(A h) - 2``: the target is out of reach, the loss keeps decreasing as
    ``A h`` grows, and the Jacobian ``sigmoid' A`` vanishes (saturated Boltzmann policies)."""
    A = np.abs(np.random.default_rng(seed).standard_normal((m, k))) + 0.5

    def sig(x, rows):
        return 0.5 * (1.0 + np.tanh(0.5 * (x @ A.T)))  # no overflow for any x

    def residual(x, rows):
        return sig(x, rows) - 2.0

    def jacobian(x, rows):
        s = sig(x, rows)
        return (s * (1.0 - s))[:, :, None] * A[None]

    return A, residual, jacobian


def assert_silent(capfd):
    out, err = capfd.readouterr()
    assert out == "" and err == "", (out, err)


@pytest.mark.parametrize("name", GN)
def test_saturated_rows_take_bounded_steps(name, capfd):
    A, residual, jacobian = saturating_problem()
    # the rows' A h: 0, ~5, ~40 (J ~ 1e-17 relative), ~1e3 (J exactly 0)
    x0 = np.array([[0.0, 0.0], [1.0, 1.0], [8.0, 8.0], [300.0, 300.0]])
    problem = counting(residual, jacobian, 4, 2)
    solver = solvers.get_solver(name)
    state = solver.init_state(problem, solver.project(x0))
    loss0 = state.loss.copy()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        x1, state, progressed = solver.update(problem, x0, state)
    assert progressed and np.all(np.isfinite(x1)) and np.all(np.isfinite(state.loss))
    radius = solver.max_step_norm * np.maximum(1.0, np.linalg.norm(x0, axis=1))
    assert np.all(np.linalg.norm(x1 - x0, axis=1) <= radius * (1 + 1e-12))
    assert np.all(state.loss <= loss0)
    if solver.constraint == "sparse":  # J == 0: only the L1 penalty can still decrease
        assert np.all(np.abs(x1[3]) <= np.abs(x0[3]))
    else:  # J == 0: no progress, no NaN; the nearly saturated row still moves (bounded)
        np.testing.assert_array_equal(x1[3], x0[3])
        assert state.loss[2] < loss0[2]
    assert state.bounded_steps >= 1
    assert_silent(capfd)


@pytest.mark.parametrize("name", GN)
@pytest.mark.parametrize("scale_J, scale_r", [(0.0, 1.0), (1e-200, 1.0), (1e-60, 1.0), (1e-60, 1e-60), (1e100, 1e100), (1.0, 0.0)])
def test_extreme_jacobians_and_residuals(name, scale_J, scale_r, capfd):
    """r = A x - y with A scaled by scale_J; scale_r = 0 starts at a zero residual."""
    rng = np.random.default_rng(3)
    solver = solvers.get_solver(name)
    x0 = solver.project(rng.standard_normal((N, K)))
    A = rng.standard_normal((N, 7, K)) * scale_J
    y = rng.standard_normal((N, 7)) * scale_r if scale_r else np.einsum("nmk,nk->nm", A, x0)
    problem = counting(lambda x, rows: np.einsum("nmk,nk->nm", A[rows], x) - y[rows], lambda x, rows: A[rows].copy(), N, K)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = solver.run(problem, x0, 6)
    hist = np.array(res.loss_history)
    assert np.all(np.isfinite(res.coefficients)) and np.all(np.isfinite(hist))
    assert np.all(np.diff(hist) <= 1e-12 * max(hist[0], 1e-300))
    radius = (1 + solver.max_step_norm) ** res.iterations * np.maximum(1.0, np.linalg.norm(x0, axis=1))
    assert np.all(np.linalg.norm(res.coefficients, axis=1) <= radius)
    if (scale_J == 0.0 or scale_r == 0.0) and solver.constraint != "sparse":
        np.testing.assert_array_equal(res.coefficients, x0)  # nothing to gain: no move
    assert_silent(capfd)


def test_huge_consistent_scale_gives_the_same_steps():
    """Scaling J and r by 1e100 leaves every Gauss-Newton step unchanged (lam is relative)."""
    rng = np.random.default_rng(5)
    A, y = rng.standard_normal((N, 7, K)), rng.standard_normal((N, 7))
    runs = []
    for s in (1.0, 1e100, 1e-100):
        problem = counting(lambda x, rows, s=s: s * (np.einsum("nmk,nk->nm", A[rows], x) - y[rows]), lambda x, rows, s=s: s * A[rows], N, K)
        runs.append(solvers.get_solver("gn-qp-clarabel").run(problem, np.zeros((N, K)), 5).coefficients)
    np.testing.assert_allclose(runs[1], runs[0], rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(runs[2], runs[0], rtol=1e-6, atol=1e-8)


def test_jacobian_too_large_to_square_is_a_clear_error():
    problem = counting(lambda x, rows: np.ones((len(rows), 2)), lambda x, rows: np.full((len(rows), 2, 2), 1e200), 3, 2)
    with pytest.raises(SolverError, match=r"gn-qp-osqp: the Jacobian of rows \[0, 1, 2\] is too large to square \(max \|J\| = 1e\+200\)"):
        solvers.get_solver("gn-qp-osqp").run(problem, np.zeros((3, 2)), 2)


def test_step_bound_option_and_default_leave_exact_steps_unchanged(rng):
    """The bound acts only on long steps: with the default the first step is the exact
    damped step (as in the conformance suite); a small radius shortens it."""
    problem, A, y = linear_problem(rng)
    x0 = rng.standard_normal((N, K))
    solver = solvers.get_solver("gn-qp-clarabel", damping=0.05)
    state = solver.init_state(problem, x0)
    ref = exact_step(A, y, x0, state.lam.copy(), "none", 0.0)
    x1, state, _ = solver.update(problem, x0, state)
    np.testing.assert_allclose(x1, ref, atol=1e-6)
    assert state.bounded_steps == 0
    tight = solvers.get_solver("gn-qp-clarabel", damping=0.05, max_step_norm=0.1)
    state = tight.init_state(problem, x0)
    x1, state, _ = tight.update(problem, x0, state)
    steps = np.linalg.norm(x1 - x0, axis=1)
    assert np.all(steps <= 0.1 * np.maximum(1.0, np.linalg.norm(x0, axis=1)) * (1 + 1e-12))
    assert state.bounded_steps > 0 and np.all(state.loss < problem.residual_jacobian(x0, np.arange(N))[0])


def test_limit_step():
    x = np.array([[0.0, 0.0], [3.0, 4.0], [1.0, 0.0]])
    z = np.array([[30.0, 40.0], [3.0, 5.0], [1.0, 0.5]])
    out, short = limit_step(x, z, 10.0)
    np.testing.assert_allclose(out[0], [6.0, 8.0])  # radius 10 * max(1, 0)
    np.testing.assert_array_equal(out[1:], z[1:])
    assert short.tolist() == [True, False, False]
    same, short = limit_step(x, z, None)
    assert same is z and not short.any()


def test_rescale_caps_the_l1_weight_exactly():
    R = np.array([np.eye(2) * 1e-200, np.eye(2)])
    b = np.array([[1e-200, 0.0], [1.0, 0.0]])
    Rs, bs, alphas = rescale_subproblems(R, b, 0.5)
    assert np.all(np.isfinite(alphas))
    assert alphas[0] == pytest.approx(2.0)  # the weight from which z = 0 is optimal
    assert alphas[1] == 0.5
    _, _, zero = rescale_subproblems(R, b, 0.0)
    assert np.all(zero == 0.0)


@pytest.mark.parametrize("interface", ["cvxpy", "direct"])
@pytest.mark.parametrize("qp_solver", ["osqp", "clarabel"])
def test_qp_solvers_are_silent(qp_solver, interface, capfd, rng):
    problem, A, y = linear_problem(rng)
    solvers.get_solver(f"gn-qp-{qp_solver}-sparse", interface=interface).run(problem, np.zeros((N, K)), 3)
    assert_silent(capfd)


def _factirl_data():
    m = fo.GridWorld(4)
    D = fo.random_dictionary(64, 3, rng=0)
    R = fo.task_rewards(D, fo.random_coefficients(6, 3, rng=1), 16, 4)
    return m, fo.sample_demonstrations(m, R, 5, 8, rng=2)


@pytest.mark.parametrize("beta, bound", [(1e4, 1e3), (100.0, 1e3)])
def test_factirl_gauss_newton_at_large_beta(beta, bound, capfd):
    """At beta = 1e4 the fit used to fail (overflowing rescaling reported as a bad ``alpha``,
    OSQP printing errors); at beta = 100 the coefficients reached ~8e12."""
    m, demos = _factirl_data()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = fo.FactIRL(n_primitives=3, beta=beta, max_iter=10, flat_max_iter=10, solver="gn-qp-osqp").fit(m, demos)
    assert np.all(np.isfinite(model.loss_history_)) and np.all(np.isfinite(model.coefficients_))
    assert np.max(np.abs(model.coefficients_)) < bound
    assert_silent(capfd)


# -- non-finite evaluations ---------------------------------------------------------------------


def _nan_beyond(limit, n=3, k=2, what="loss", jac_scale=1.0):
    """Residual ``x - 1`` whose loss (``what="loss"``) or only derivatives (``"derivative"``)
    are NaN wherever some ``|x_j| > limit``; ``jac_scale < 1`` reports a Jacobian too small,
    so that Gauss-Newton steps overshoot."""
    count = [0]

    def residual_jacobian(x, rows):
        count[0] += 1
        r = x - 1.0
        J = np.broadcast_to(jac_scale * np.eye(k), (len(rows), k, k)).copy()
        bad = np.any(np.abs(x) > limit, axis=1)
        loss = np.sum(r * r, axis=1)
        if what == "loss":
            r[bad], loss[bad] = np.nan, np.nan
        else:
            J[bad] = np.nan
        return loss, r, J

    def loss_and_grad(x, rows):
        loss, r, J = residual_jacobian(x, rows)
        return loss, 2.0 * np.einsum("nmk,nm->nk", J, r)

    return solvers.StepProblem(loss_and_grad, lambda: count[0], n, k, residual_jacobian=residual_jacobian)


@pytest.mark.parametrize("name", ["armijo", "armijo-nonneg", "gn-qp-osqp", "gn-qp-clarabel-nonneg"])
def test_non_finite_start_is_a_clear_error(name):
    problem = _nan_beyond(5.0)
    x0 = np.zeros((3, 2))
    x0[[0, 2], 0] = 9.0
    with pytest.raises(SolverError, match=rf"{name}: the objective returned a non-finite loss at the starting point, rows \[0, 2\]"):
        solvers.get_solver(name).run(problem, x0, 3)


def test_non_finite_derivative_at_start():
    def lg(x, rows):
        g = 2 * x
        g[0, 0] = np.inf
        return np.sum(x * x, axis=1), g

    problem = solvers.StepProblem(lg, lambda: 0, 2, 2)
    with pytest.raises(SolverError, match=r"non-finite derivative at the starting point, rows \[0\]"):
        solvers.ArmijoSolver().run(problem, np.ones((2, 2)), 2)


@pytest.mark.parametrize("what", ["loss", "derivative"])
@pytest.mark.parametrize("name", ["armijo", "gn-qp-osqp", "gn-qp-clarabel"])
def test_non_finite_trial_points_are_rejected(name, what):
    """The minimiser (1, 1) is inside the finite region |x| <= 1.5, but the first trials
    (Armijo's step 50; Gauss-Newton's step ~10x too long, its Jacobian being 10x too small)
    land outside: they must be rejected, never accepted, and the run must stay finite."""
    gn = name != "armijo"
    problem = _nan_beyond(1.5, what=what, jac_scale=0.1 if gn else 1.0)
    solver = solvers.get_solver(name, **({} if gn else {"initial_step": 50.0}))
    x0 = np.full((3, 2), -1.0)
    evaluated = []
    inner = problem.residual_jacobian
    problem = solvers.StepProblem(
        problem.loss_and_grad, problem.n_evaluations, 3, 2, residual_jacobian=lambda x, rows: evaluated.append(x.copy()) or inner(x, rows)
    )
    res = solver.run(problem, x0, 30)
    if gn:
        assert np.max(np.abs(np.concatenate(evaluated))) > 1.5  # a trial did land outside
    hist = np.array(res.loss_history)
    assert np.all(np.isfinite(hist)) and np.all(np.diff(hist) <= 0)
    assert np.all(np.abs(res.coefficients) <= 1.5)
    np.testing.assert_allclose(res.coefficients, 1.0, atol=1e-3)


def test_wrong_shapes_from_the_problem_are_reported():
    problem = solvers.StepProblem(lambda x, rows: (np.zeros(len(rows) + 1), x), lambda: 0, 2, 2)
    with pytest.raises(SolverError, match=r"problem.loss_and_grad returned a loss of shape \(3,\) for 2 rows"):
        solvers.ArmijoSolver().run(problem, np.ones((2, 2)), 1)
    problem = solvers.StepProblem(lambda x, rows: (np.zeros(len(rows)), x[:, :1]), lambda: 0, 2, 2)
    with pytest.raises(SolverError, match=r"returned output 2 of shape \(2, 1\); expected \(2, 2\)"):
        solvers.ArmijoSolver().run(problem, np.ones((2, 2)), 1)


# --- compiled block QPs shared per thread ---------------------------------------------------


@pytest.mark.parametrize("interface", ["cvxpy", "direct"])
def test_compiled_block_qps_are_shared_per_thread_and_results_do_not_depend_on_history(interface):
    """A new solver re-uses the thread's compiled problem, never another solver's warm start."""
    import threading

    from solvers.gauss_newton import compiled_block_qp

    from solver_problems import exp_problem

    name = "gn-qp-osqp-nonneg"  # OSQP warm-starts; the nonneg variant has an active set
    runs = []
    for history in (False, True):
        if history:  # another solver of the same shape solves something else first
            other, _, _ = exp_problem(np.random.default_rng(7))
            solvers.get_solver(name, interface=interface).run(other, np.zeros((N, K)), 3)
            workspace = getattr(compiled_block_qp(interface, N, K, "nonneg"), "_osqp", None)
        problem, _, _ = exp_problem(np.random.default_rng(1))
        solver = solvers.get_solver(name, interface=interface)
        runs.append(solver.run(problem, np.zeros((N, K)), 5).coefficients)
        assert solver._block_qp(N, K) is compiled_block_qp(interface, N, K, "nonneg")
        if history and interface == "direct":  # OSQP set up anew for the new solver, then updated
            assert compiled_block_qp(interface, N, K, "nonneg")._osqp is not workspace
    np.testing.assert_array_equal(runs[0], runs[1])
    mine = compiled_block_qp(interface, N, K, "nonneg")
    other_thread = []
    t = threading.Thread(target=lambda: other_thread.append(compiled_block_qp(interface, N, K, "nonneg")))
    t.start()
    t.join()
    assert other_thread[0] is not mine and compiled_block_qp(interface, N, K, "nonneg") is mine


def test_the_compiled_cache_is_bounded(monkeypatch):
    from solvers import gn_subproblem

    monkeypatch.setattr(gn_subproblem, "COMPILED_CACHE_SIZE", 2)
    first = gn_subproblem.compiled_block_qp("direct", 2, 1, "none")
    gn_subproblem.compiled_block_qp("direct", 3, 1, "none")
    assert gn_subproblem.compiled_block_qp("direct", 2, 1, "none") is first  # most recently used: kept
    gn_subproblem.compiled_block_qp("direct", 4, 1, "none")
    assert gn_subproblem.compiled_block_qp("direct", 2, 1, "none") is first
    assert len(gn_subproblem._compiled.problems) == 2

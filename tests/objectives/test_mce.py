"""The maximum causal entropy objective: soft values, loss, adjoint gradient, learners.

References: an independent soft value iteration written here (plain numpy on the dense
transitions, thousands of sweeps) and central finite differences. The MCE loss is smooth in
the rewards (no greedy ties to avoid), so any random reward is a valid check point.
"""

import warnings

import numpy as np
from helpers import central_difference, random_statistics, rel_err
import pytest
import scipy.sparse as sp

import factirl_opt as fo
from factirl_opt.exceptions import FactIRLError, ValidationError
from factirl_opt.objectives import MCEObjective, get_objective, mce as mce_module, soft_values
from factirl_opt.planning import DensePlanner, get_planner
from factirl_opt.objectives.problems import dictionary_problem, weights_problem

BETA = 2.0




def reference_soft_vi(P, gamma, R, beta, sweeps=5000):
    """Independent soft value iteration on dense P (S, A, S) for one reward (S, A): V, log pi."""
    S, A, _ = P.shape
    P2 = P.reshape(S * A, S)
    V = np.zeros(S)
    for _ in range(sweeps):
        Q = R + gamma * (P2 @ V).reshape(S, A)
        m = Q.max(axis=1)
        V = m + np.log(np.sum(np.exp(beta * (Q - m[:, None])), axis=1)) / beta
    Q = R + gamma * (P2 @ V).reshape(S, A)
    return V, beta * (Q - V[:, None])


def random_sparse_mdp(rng, S=9, A=3, gamma=0.85):
    """Sparse (S*A, S) dynamics: state 0 absorbing, every row 1-3 successors, many self-loops."""
    rows, cols, vals = [], [], []
    for s in range(S):
        for a in range(A):
            if s == 0:
                succ = np.array([0])
            else:
                succ = rng.choice(S, size=int(rng.integers(1, 4)), replace=False)
                if a == 0:
                    succ = np.union1d(succ, [s])  # a self-loop in every state
            p = rng.dirichlet(np.ones(succ.size))
            rows += [s * A + a] * succ.size
            cols += list(succ)
            vals += list(p)
    return fo.TabularMDP(sp.csr_matrix((vals, (rows, cols)), shape=(S * A, S)), gamma)


@pytest.fixture(params=["dense", "sparse", "sparse-lu", "grid"])
def model(request, rng, random_mdp, grid3):
    """(mdp, planner): a dense random MDP, a sparse one on both planners, the sparse 3x3 grid."""
    if request.param == "dense":
        return random_mdp, "auto"
    if request.param == "grid":
        return grid3, "sparse-lu"
    return random_sparse_mdp(rng), "dense" if request.param == "sparse" else "sparse-lu"


# --- soft values and loss ----------------------------------------------------------------------


def test_loss_matches_independent_soft_value_iteration(rng, model):
    mdp, planner = model
    P = mdp.transitions
    for beta in (0.5, BETA, 10.0):
        mu, pi_hat = random_statistics(rng, mdp, 3)
        R = rng.standard_normal((3, mdp.n_states, mdp.n_actions))
        loss, grad = fo.mce_loss(mdp, R, mu, pi_hat, beta, planner=planner)
        assert loss.shape == (3,) and grad.shape == R.shape
        for i in range(3):
            V_ref, log_pi_ref = reference_soft_vi(P, mdp.gamma, R[i], beta)
            expected = -np.sum(mu[i][:, None] * pi_hat[i] * log_pi_ref)
            assert abs(loss[i] - expected) <= 1e-9 * max(1.0, abs(expected))
            Q, V, log_pi = soft_values(get_planner(mdp, planner), R[i : i + 1], beta)
            np.testing.assert_allclose(V[0], V_ref, rtol=0, atol=1e-9 * max(1.0, np.abs(V_ref).max()))
            np.testing.assert_allclose(log_pi[0], log_pi_ref, rtol=0, atol=1e-9)


def test_soft_values_solve_the_soft_bellman_equation_to_1e12(rng, model):
    mdp, planner = model
    pl = get_planner(mdp, planner)
    R = 10.0 * rng.standard_normal((4, mdp.n_states, mdp.n_actions))
    Q, V, log_pi = soft_values(pl, R, BETA)
    _, TV, _ = mce_module.soft_backup(pl, R, V, BETA)
    assert np.all(np.abs(TV - V).max(axis=1) <= 1e-12 * np.maximum(1.0, np.abs(V).max(axis=1)))
    np.testing.assert_allclose(np.exp(log_pi).sum(axis=2), 1.0, rtol=0, atol=1e-14)
    np.testing.assert_allclose(log_pi, BETA * (Q - V[:, :, None]), rtol=0, atol=1e-12)


def test_loss_is_the_entropy_and_gradient_zero_when_the_data_is_the_soft_optimal_policy(rng, model):
    """J is a cross entropy in pi: minimal (the entropy of pi_hat) with zero gradient at pi_hat = pi."""
    mdp, planner = model
    R = rng.standard_normal((2, mdp.n_states, mdp.n_actions))
    _, _, log_pi = soft_values(get_planner(mdp, planner), R, BETA)
    pi = np.exp(log_pi)
    mu = rng.dirichlet(np.ones(mdp.n_states), size=2)
    loss, grad = fo.mce_loss(mdp, R, mu, pi, BETA, planner=planner)
    np.testing.assert_allclose(loss, -np.einsum("ns,nsa->n", mu, pi * log_pi), rtol=1e-12)
    assert np.max(np.abs(grad)) < 1e-12
    other = rng.dirichlet(np.ones(mdp.n_actions), size=(2, mdp.n_states))
    assert np.all(fo.mce_loss(mdp, R, mu, other, BETA, planner=planner)[0] > loss)


def test_batched_equals_single_and_planners_agree(rng):
    mdp = random_sparse_mdp(rng)
    mu, pi_hat = random_statistics(rng, mdp, 3)
    R = rng.standard_normal((3, mdp.n_states, mdp.n_actions))
    loss, grad = fo.mce_loss(mdp, R, mu, pi_hat, BETA, planner="sparse-lu")
    loss_d, grad_d = fo.mce_loss(mdp, R, mu, pi_hat, BETA, planner="dense")
    np.testing.assert_allclose(loss_d, loss, rtol=1e-12)
    np.testing.assert_allclose(grad_d, grad, rtol=1e-10, atol=1e-13)
    for i in range(3):
        li, gi = fo.mce_loss(mdp, R[i], mu[i], pi_hat[i], BETA)
        np.testing.assert_allclose(li[0], loss[i], rtol=1e-12)
        np.testing.assert_allclose(gi[0], grad[i], rtol=1e-10, atol=1e-13)


def test_warm_start_policy_does_not_change_the_result(rng, random_mdp):
    mu, pi_hat = random_statistics(rng, random_mdp, 2)
    R = rng.standard_normal((2, random_mdp.n_states, random_mdp.n_actions))
    loss, grad = fo.mce_loss(random_mdp, R, mu, pi_hat, BETA)
    for warm in (rng.dirichlet(np.ones(3), size=(2, 6)), np.eye(3)[rng.integers(0, 3, size=(2, 6))]):
        loss_w, grad_w = fo.mce_loss(random_mdp, R, mu, pi_hat, BETA, policy=warm)
        np.testing.assert_allclose(loss_w, loss, rtol=1e-12)
        np.testing.assert_allclose(grad_w, grad, rtol=1e-9, atol=1e-13)


def test_objective_warm_starts_from_its_last_values_and_counts(rng, grid3):
    mu, pi_hat = random_statistics(rng, grid3, 3)
    obj = get_objective("mce")(grid3, mu, pi_hat, BETA)
    assert isinstance(obj, MCEObjective) and obj.name == "mce" and not obj.least_squares
    R = rng.standard_normal((3, grid3.n_states, grid3.n_actions))
    loss, grad = obj.loss_and_grad(R)
    assert obj.n_evaluations == 1 and obj._warm.shape == (3, grid3.n_states)
    obj.loss_and_grad(R)  # cached: not counted
    assert obj.n_evaluations == 1
    R2 = R + 0.1 * rng.standard_normal(R.shape)
    loss2, grad2 = obj.loss_and_grad(R2[1:], rows=np.array([1, 2]))  # warm-started rows
    cold2, cold_grad2 = fo.mce_loss(grid3, R2[1:], mu[1:], pi_hat[1:], BETA)
    np.testing.assert_allclose(loss2, cold2, rtol=1e-12)
    np.testing.assert_allclose(grad2, cold_grad2, rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose(obj.loss_and_grad(R)[0], loss, rtol=1e-12)


# --- gradients -------------------------------------------------------------------------------


def test_tabular_gradient_matches_finite_differences(rng, model):
    mdp, planner = model
    mu, pi_hat = random_statistics(rng, mdp, 2)
    R = rng.standard_normal((2, mdp.n_states, mdp.n_actions))
    _, grad = fo.mce_loss(mdp, R, mu, pi_hat, BETA, planner=planner)
    for i in range(2):
        fd = central_difference(lambda r: fo.mce_loss(mdp, r, mu[i], pi_hat[i], BETA, planner=planner)[0][0], R[i])
        assert rel_err(grad[i], fd) < 1e-6


def test_gradient_at_large_beta_matches_finite_differences(rng, grid3):
    mu, pi_hat = random_statistics(rng, grid3, 1)
    R = 0.2 * rng.standard_normal((grid3.n_states, grid3.n_actions))
    _, grad = fo.mce_loss(grid3, R, mu, pi_hat, 20.0)
    fd = central_difference(lambda r: fo.mce_loss(grid3, r, mu, pi_hat, 20.0)[0][0], R)
    assert rel_err(grad[0], fd) < 1e-6


def _factors(rng, mdp, n, k):
    return rng.standard_normal((mdp.n_params, k)), rng.standard_normal((n, k))


def test_feature_weight_and_coefficient_gradients(rng, model):
    """dJ/dw = F^T dJ/dR (GradIRL features; FactIRL H-step with F = Phi D, eq. 12) vs FD."""
    mdp, planner = model
    n, k = 2, 3
    F, w = _factors(rng, mdp, n, k)
    mu, pi_hat = random_statistics(rng, mdp, n)
    problem = weights_problem(MCEObjective(mdp, mu, pi_hat, BETA, planner=planner), F)
    assert problem.residual_jacobian is None  # not least squares: no Gauss-Newton
    rows = np.arange(n)
    loss, grad = problem.loss_and_grad(w, rows)
    assert grad.shape == (n, k)
    for i in range(n):
        fd = central_difference(lambda wi: problem.loss_and_grad(wi[None], rows[i : i + 1])[0][0], w[i])
        assert rel_err(grad[i], fd) < 1e-6
    R = (w @ F.T).reshape(n, mdp.n_states, mdp.n_actions)
    loss_R, y = fo.mce_loss(mdp, R, mu, pi_hat, BETA, planner=planner)
    np.testing.assert_allclose(loss, loss_R, rtol=1e-12)
    np.testing.assert_allclose(grad, y.reshape(n, -1) @ F, rtol=1e-10, atol=1e-13)


def test_dictionary_gradient(rng, model):
    """dJ/dD = Phi^T sum_i y_i h_i^T (eq. 11), tabular and with base features, vs FD."""
    mdp, planner = model
    n, k = 3, 2
    mu, pi_hat = random_statistics(rng, mdp, n)
    obj = MCEObjective(mdp, mu, pi_hat, BETA, planner=planner)
    for Phi in (None, rng.standard_normal((mdp.n_params, 4))):
        p = mdp.n_params if Phi is None else Phi.shape[1]
        D, H = rng.standard_normal((p, k)) / np.sqrt(p), rng.standard_normal((n, k))
        problem = dictionary_problem(obj, H, Phi)
        loss, grad = problem.loss_and_grad(D.reshape(1, -1), np.arange(1))
        assert loss.shape == (1,) and grad.shape == (1, p * k)
        fd = central_difference(lambda x: problem.loss_and_grad(x[None], np.arange(1))[0][0], D.ravel())
        assert rel_err(grad[0], fd) < 1e-6


# --- invariance and numerical stability -----------------------------------------------------


def test_potential_shaping_leaves_loss_policy_and_gradient_unchanged(rng, model):
    mdp, planner = model
    pl = get_planner(mdp, planner)
    mu, pi_hat = random_statistics(rng, mdp, 2)
    R = rng.standard_normal((2, mdp.n_states, mdp.n_actions))
    phi = 3.0 * rng.standard_normal((2, mdp.n_states))
    R_shaped = R + mdp.gamma * pl.backup(phi) - phi[:, :, None]
    loss, grad = fo.mce_loss(mdp, R, mu, pi_hat, BETA, planner=planner)
    loss_s, grad_s = fo.mce_loss(mdp, R_shaped, mu, pi_hat, BETA, planner=planner)
    np.testing.assert_allclose(loss_s, loss, rtol=1e-10)
    np.testing.assert_allclose(grad_s, grad, rtol=1e-8, atol=1e-11)
    _, V, log_pi = soft_values(pl, R, BETA)
    _, V_s, log_pi_s = soft_values(pl, R_shaped, BETA)
    np.testing.assert_allclose(log_pi_s, log_pi, rtol=0, atol=1e-10)
    np.testing.assert_allclose(V_s, V - phi, rtol=0, atol=1e-10)


@pytest.mark.parametrize("scale, beta", [(1e3, 5.0), (1.0, 1e3), (1e3, 1e3), (1e3, 1e-3)])
def test_stable_at_large_reward_scale_and_beta(rng, grid4, scale, beta):
    mu, pi_hat = random_statistics(rng, grid4, 3)
    R = scale * rng.standard_normal((3, grid4.n_states, grid4.n_actions))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loss, grad = fo.mce_loss(grid4, R, mu, pi_hat, beta)
        Q, V, log_pi = soft_values(get_planner(grid4), R, beta)
    assert np.all(np.isfinite(loss)) and np.all(np.isfinite(grad)) and np.all(np.isfinite(log_pi))
    assert np.all(loss >= 0)
    np.testing.assert_allclose(np.exp(log_pi).sum(axis=2), 1.0, atol=1e-12)
    _, TV, _ = mce_module.soft_backup(get_planner(grid4), R, V, beta)
    assert np.all(np.abs(TV - V).max(axis=1) <= 1e-12 * np.maximum(1.0, np.abs(V).max(axis=1)))
    # the soft values approach the hard ones as beta grows: |V_soft - V*| <= log(A) / (beta (1 - gamma))
    if beta >= 1e3:
        Q_star, _ = fo.optimal_q(grid4, R)
        assert np.max(np.abs(V - Q_star.max(axis=2))) <= np.log(4) / (beta * (1 - grid4.gamma)) + 1e-9 * scale


def test_overflowing_beta_times_reward_raises_instead_of_nan(rng, grid3):
    mu, pi_hat = random_statistics(rng, grid3, 1)
    R = 1e290 * rng.standard_normal((grid3.n_states, grid3.n_actions))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # numpy reports the overflow; we raise
        with pytest.raises(FactIRLError, match="overflow|converge"):
            fo.mce_loss(grid3, R, mu, pi_hat, 1e30)


# --- the Newton iteration: guard and bound ----------------------------------------------------


class _OneBadSolve(DensePlanner):
    """A dense planner whose first solve fails (returns NaN), counting its solves."""

    def __init__(self, mdp):
        super().__init__(mdp)
        self.bad_left, self.solves = 1, 0

    def system(self, policy):
        system, planner = super().system(policy), self

        class _Bad:
            def solve(self, B):
                planner.solves += 1
                if planner.bad_left:
                    planner.bad_left -= 1
                    return np.full_like(B, np.nan)
                return system.solve(B)

            def solve_transpose(self, B):
                return system.solve_transpose(B)

        return _Bad()


def test_guard_replaces_a_failed_newton_step_by_a_sweep(rng, random_mdp):
    R = rng.standard_normal((2, random_mdp.n_states, random_mdp.n_actions))
    Q, V, log_pi = soft_values(get_planner(random_mdp, "dense"), R, BETA)
    bad = _OneBadSolve(random_mdp)
    Q_b, V_b, log_pi_b = soft_values(bad, R, BETA)
    assert bad.bad_left == 0 and bad.solves > 0
    np.testing.assert_allclose(V_b, V, rtol=0, atol=1e-11)
    np.testing.assert_allclose(log_pi_b, log_pi, rtol=0, atol=1e-11)


def test_newton_converges_in_few_steps_cold_and_warm(rng):
    """Soft policy iteration: a handful of solves on the 5x5 grid, at gamma 0.99 too."""
    for gamma in (0.9, 0.99):
        mdp = fo.GridWorld(5, gamma=gamma)
        counter = _OneBadSolve(mdp)
        counter.bad_left = 0
        R = rng.standard_normal((3, mdp.n_states, mdp.n_actions))
        _, V, _ = soft_values(counter, R, 5.0)
        assert counter.solves <= 15
        counter.solves = 0
        soft_values(counter, R + 0.01 * rng.standard_normal(R.shape), 5.0, V)
        assert counter.solves <= 6


def test_unconverged_soft_values_raise(rng, grid3):
    mu, pi_hat = random_statistics(rng, grid3, 1)
    R = 10.0 * rng.standard_normal((grid3.n_states, grid3.n_actions))
    with pytest.raises(FactIRLError, match=r"did not converge in 1 iterations: task 0 has residual"):
        fo.mce_loss(grid3, R, mu, pi_hat, BETA, max_iter=1)


# --- validation -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "change, fragment",
    [
        ({"beta": 0.0}, "beta must be"),
        ({"beta": np.inf}, "beta must be"),
        ({"policy": np.zeros((9, 4))}, "stochastic policy"),
        ({"policy": np.zeros((9,), dtype=int)}, "stochastic policy must have shape"),
        ({"policy": np.full((2, 9, 4), 0.25)}, r"shape \(1, 9, 4\)"),
        ({"max_iter": 0}, "max_iter must be an integer >= 1"),
        ({"rewards": np.zeros((9, 3))}, "rewards must have shape"),
        ({"mu_hat": np.full(9, 0.5)}, "mu_hat must sum to 1"),
        ({"pi_hat": np.ones((9, 4))}, "pi_hat"),
        ({"planner": "magic"}, "unknown planner 'magic'"),
    ],
)
def test_validation(rng, grid3, change, fragment):
    mu, pi_hat = random_statistics(rng, grid3, 1)
    kwargs = dict(rewards=np.zeros((9, 4)), mu_hat=mu[0], pi_hat=pi_hat[0], beta=BETA)
    kwargs.update(change)
    with pytest.raises(ValidationError, match=fragment):
        fo.mce_loss(grid3, **kwargs)


def test_needs_an_mdp():
    with pytest.raises(ValidationError, match="mdp must be a TabularMDP"):
        fo.mce_loss(np.eye(3), np.zeros((3, 1)), np.ones(3) / 3, np.ones((3, 1)), BETA)


def test_registry_lists_mce_and_refuses_least_squares_calls(rng, grid3):
    assert "mce" in fo.available_objectives() and get_objective("mce") is MCEObjective
    mu, pi_hat = random_statistics(rng, grid3, 1)
    obj = MCEObjective(grid3, mu, pi_hat, BETA)
    with pytest.raises(ValidationError, match="least-squares objective"):
        obj.linearize(np.zeros((1, 9, 4)))
    with pytest.raises(ValidationError, match="least-squares objective"):
        obj.residual_jacobian(np.zeros((1, 9, 4)), None, np.eye(36))


# --- learners ---------------------------------------------------------------------------------


def test_flat_mce_recovers_the_expert_policy_from_many_demonstrations():
    """A greedy expert, 300 demonstrations of 10 steps per task on the 4x4 grid: every state
    is visited often, the likelihood drives the learnt soft policy towards the expert's actions,
    and the greedy policy of the learnt reward is the expert's (deviation 0)."""
    mdp = fo.GridWorld(4)
    tasks = fo.synthetic_tasks(mdp, 4, 300, 10, n_primitives=3, rng=3)
    flat = fo.GradIRL(objective="mce", max_iter=100).fit(mdp, tasks.demos)
    dev = fo.deviation(mdp, tasks.rewards, flat.rewards_)
    assert np.all(dev <= 1e-9 * np.abs(fo.optimal_score(mdp, tasks.rewards)).max())
    _, expert = fo.optimal_q(mdp, tasks.rewards)
    _, learnt = fo.optimal_q(mdp, flat.rewards_)
    np.testing.assert_array_equal(learnt, expert)
    assert np.all(np.diff(flat.loss_history_) <= 1e-12)


@pytest.fixture(scope="module")
def small_tasks():
    mdp = fo.GridWorld(4)
    return mdp, fo.synthetic_tasks(mdp, 12, 5, 8, n_primitives=2, rng=7)


def test_gradirl_runs_with_mce_tabular_and_features(small_tasks):
    mdp, tasks = small_tasks
    flat = fo.GradIRL(objective="mce", max_iter=30).fit(mdp, tasks.demos)
    assert flat.rewards_.shape == (12, 16, 4) and flat.loss_history_[-1] < flat.loss_history_[0]
    mu, pi_hat = fo.empirical_statistics(mdp, tasks.demos)
    np.testing.assert_allclose(flat.loss_, fo.mce_loss(mdp, flat.rewards_, mu, pi_hat, 5.0)[0], rtol=1e-10)
    feats = fo.GradIRL(objective="mce", features=tasks.dictionary, max_iter=30).fit(mdp, tasks.demos)
    assert feats.weights_.shape == (12, 2) and feats.loss_history_[-1] < feats.loss_history_[0]


def test_lbfgs_runs_on_mce(small_tasks):
    solvers = pytest.importorskip("solvers")
    if "lbfgs" not in solvers.available_solvers():
        pytest.skip("no lbfgs solver registered")
    mdp, tasks = small_tasks
    flat = fo.GradIRL(objective="mce", solver="lbfgs", max_iter=20).fit(mdp, tasks.demos)
    assert flat.loss_history_[-1] < 0.5 * flat.loss_history_[0]
    fact = fo.FactIRL(n_primitives=2, objective="mce", solver="lbfgs", d_solver="lbfgs", init="random",
                      max_iter=3, rng=0).fit(mdp, tasks.demos)
    assert fact.loss_history_[-1] < fact.loss_history_[0]


def test_factirl_fits_and_transfers_with_mce(small_tasks):
    mdp, tasks = small_tasks
    fact = fo.FactIRL(n_primitives=2, objective="mce", max_iter=5, flat_max_iter=20, rng=0).fit(mdp, tasks.demos)
    assert fact.dictionary_.shape == (64, 2) and fact.loss_history_[-1] < fact.loss_history_[0]
    test = fo.synthetic_tasks(mdp, 3, 1, 8, dictionary=tasks.dictionary, rng=8)
    h = fact.transfer(mdp, test.demos, max_iter=20)
    assert h.shape == (3, 2) and fact.transfer_loss_history_[-1] < fact.transfer_loss_history_[0]
    mu, pi_hat = fo.empirical_statistics(mdp, test.demos)
    np.testing.assert_allclose(fact.transfer_loss_, fo.mce_loss(mdp, fact.transfer_rewards_, mu, pi_hat, 5.0)[0],
                               rtol=1e-10)


@pytest.mark.parametrize("h_solver, fragment", [("gn-qp-osqp", "least-squares"), ("gn-cg", "least-squares")])
def test_gauss_newton_h_steps_refuse_mce(small_tasks, h_solver, fragment):
    solvers = pytest.importorskip("solvers")
    if h_solver not in solvers.available_solvers():
        pytest.skip(f"{h_solver} not available")
    mdp, tasks = small_tasks
    with pytest.raises(FactIRLError, match=fragment):
        fo.FactIRL(n_primitives=2, objective="mce", solver=h_solver, init="random", max_iter=2,
                   rng=0).fit(mdp, tasks.demos)


def test_gauss_newton_refusal_names_the_solvers_that_apply(small_tasks, monkeypatch):
    pytest.importorskip("cvxpy")
    mdp, tasks = small_tasks
    applies = r"needs a least-squares objective .* 'mce' objective has none; use a gradient solver: armijo, armijo-nonneg, lbfgs"
    with pytest.raises(FactIRLError, match="solver 'gn-qp-osqp' is a Gauss-Newton solver: it " + applies):
        fo.FactIRL(n_primitives=2, objective="mce", solver="gn-qp-osqp", init="random", max_iter=2,
                   rng=0).fit(mdp, tasks.demos)
    with pytest.raises(FactIRLError, match="d_solver 'gn-cg'"):
        fo.FactIRL(n_primitives=2, objective="mce", d_solver="gn-cg").fit(mdp, tasks.demos)
    with pytest.raises(FactIRLError, match="solver 'gn-cg'"):
        fo.GradIRL(objective="mce", solver="gn-cg").fit(mdp, tasks.demos)
    # refused before any work: the PCA initialisation's flat fit never runs
    monkeypatch.setattr(fo.GradIRL, "fit", lambda *a, **k: pytest.fail("the flat learner ran"))
    with pytest.raises(FactIRLError, match="Gauss-Newton"):
        fo.FactIRL(n_primitives=2, objective="mce", solver="gn-qp-clarabel", init="pca").fit(mdp, tasks.demos)

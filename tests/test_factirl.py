"""FactIRL, the factorial learner: fit, initialisations, transfer."""

import warnings

import numpy as np
import pytest

import factirl_opt as fo
from helpers import five_dictionary_tasks
from factirl_opt.exceptions import NotFittedError, UnknownSolverError, ValidationError
from factirl_opt.learners.start import FLAT_SOLVER

K = 2


@pytest.fixture
def data(rng, grid3):
    return five_dictionary_tasks(rng, grid3, K)


def assert_non_increasing(history):
    h = np.asarray(history)
    assert np.all(np.diff(h) <= 1e-10 * np.abs(h[:-1])), h


@pytest.mark.parametrize("init", ["pca", "random"])
def test_fit_shapes_and_history(data, init):
    mdp, _, demos = data
    model = fo.FactIRL(n_primitives=K, init=init, max_iter=8, flat_max_iter=10, rng=0)
    assert model.fit(mdp, demos) is model
    assert model.dictionary_.shape == (36, K)
    assert model.coefficients_.shape == (5, K)
    assert model.rewards_.shape == (5, 9, 4)
    np.testing.assert_allclose(model.rewards_.reshape(5, -1), model.coefficients_ @ model.dictionary_.T)
    assert model.loss_.shape == (5,)
    assert len(model.loss_history_) == model.n_iter_ + 1
    assert_non_increasing(model.loss_history_)
    assert model.loss_history_[-1] < model.loss_history_[0]
    assert isinstance(model.n_evaluations_, int) and model.n_evaluations_ > 0
    mu, pi = fo.empirical_statistics(mdp, demos)
    np.testing.assert_allclose(model.loss_, fo.policy_matching_loss(mdp, model.rewards_, mu, pi, 5.0)[0], rtol=1e-9)


def test_pca_init_counts_the_flat_fit_and_reuses_flat_rewards(data):
    mdp, _, demos = data
    start = fo.Start()  # the start's flat fit: FLAT_SOLVER, its tol and saturation rule, no gradient rule
    flat = fo.GradIRL(max_iter=10, solver=FLAT_SOLVER, tol=start.flat_tol, stol=start.flat_stol, gtol=0.0).fit(mdp, demos)
    own = fo.FactIRL(n_primitives=K, max_iter=3, flat_max_iter=10).fit(mdp, demos)
    given = fo.FactIRL(n_primitives=K, max_iter=3).fit(mdp, demos, flat_rewards=flat.rewards_)
    np.testing.assert_allclose(own.rewards_, given.rewards_, rtol=1e-12, atol=1e-14)
    assert own.n_evaluations_ == given.n_evaluations_ + flat.n_evaluations_


@pytest.mark.parametrize("shrink", [False, True])
def test_pca_init_starts_from_the_pca_of_flat_rewards(data, shrink):
    mdp, _, demos = data
    flat = fo.GradIRL(max_iter=10).fit(mdp, demos)
    model = fo.FactIRL(n_primitives=K, max_iter=0, pca_shrink=shrink).fit(mdp, demos, flat_rewards=flat.rewards_)
    D, H = fo.pca_dictionary(flat.rewards_.reshape(5, -1), K)
    np.testing.assert_allclose(model.coefficients_ @ model.dictionary_.T, H @ D.T, atol=1e-12)  # halving does not help
    assert model.n_evaluations_ == 1 + 2 * shrink  # the start, and the unscaled and halved trials


def test_pca_shrink_halves_an_oversized_start(data):
    mdp, _, demos = data
    big = 64 * fo.GradIRL(max_iter=10).fit(mdp, demos).rewards_  # far into the saturated region
    D, H = fo.pca_dictionary(big.reshape(5, -1), K)
    kept = fo.FactIRL(n_primitives=K, max_iter=0, pca_shrink=False).fit(mdp, demos, flat_rewards=big)
    shrunk = fo.FactIRL(n_primitives=K, max_iter=0).fit(mdp, demos, flat_rewards=big)
    np.testing.assert_allclose(kept.coefficients_ @ kept.dictionary_.T, H @ D.T, atol=1e-12)
    factor = np.sum(shrunk.coefficients_ @ shrunk.dictionary_.T) / np.sum(H @ D.T)
    j = int(round(-np.log2(factor)))
    assert j >= 1 and factor == pytest.approx(2.0 ** -j, rel=1e-12)
    assert shrunk.loss_history_[0] < kept.loss_history_[0]
    assert shrunk.n_evaluations_ == 1 + j + 2  # the start, then trials 2**0 .. 2**-(j+1)


def test_shrink_coefficients_stops_at_the_first_rise():
    H = np.full((2, 2), 4.0)  # sum 16: halving reaches sum 1 (loss 0) after 4 trials, the 5th rises
    out, j, calls = fo.learners.factirl.shrink_coefficients(lambda X: (X.sum() - 1.0) ** 2, H)
    assert (j, calls) == (4, 6)
    np.testing.assert_array_equal(out, H / 16)
    out, j, calls = fo.learners.factirl.shrink_coefficients(lambda X: (X.sum() - 16.0) ** 2, H)
    assert (j, calls) == (0, 2) and out is not H
    np.testing.assert_array_equal(out, H)
    _, j, calls = fo.learners.factirl.shrink_coefficients(lambda X: X.sum() ** 2, H, max_halvings=5)
    assert (j, calls) == (5, 6)


def test_tuple_init(rng, data):
    mdp, _, demos = data
    D0, H0 = rng.standard_normal((36, K)), rng.standard_normal((5, K))
    model = fo.FactIRL(n_primitives=K, init=(D0, H0), max_iter=0).fit(mdp, demos)
    np.testing.assert_allclose(model.rewards_.reshape(5, -1), H0 @ D0.T, rtol=1e-12)
    assert model.n_evaluations_ == 1
    fitted = fo.FactIRL(n_primitives=K, init=(D0, H0), max_iter=5).fit(mdp, demos)
    assert fitted.loss_history_[-1] < fitted.loss_history_[0]


def test_same_seed_same_result(data):
    mdp, _, demos = data
    a = fo.FactIRL(n_primitives=K, init="random", max_iter=4, rng=7).fit(mdp, demos)
    b = fo.FactIRL(n_primitives=K, init="random", max_iter=4, rng=7).fit(mdp, demos)
    c = fo.FactIRL(n_primitives=K, init="random", max_iter=4, rng=8).fit(mdp, demos)
    np.testing.assert_array_equal(a.dictionary_, b.dictionary_)
    np.testing.assert_array_equal(a.coefficients_, b.coefficients_)
    assert not np.allclose(a.dictionary_, c.dictionary_)


def test_transfer_after_fit(rng, data):
    mdp, R, demos = data
    model = fo.FactIRL(n_primitives=K, max_iter=5, flat_max_iter=10).fit(mdp, demos)
    new = fo.sample_demonstrations(mdp, R[:3], 1, 8, rng)
    h = model.transfer(mdp, new, max_iter=20)
    assert h.shape == (3, K)
    np.testing.assert_array_equal(h, model.transfer_coefficients_)
    np.testing.assert_allclose(model.transfer_rewards_.reshape(3, -1), h @ model.dictionary_.T)
    assert_non_increasing(model.transfer_loss_history_)
    assert model.transfer_loss_history_[-1] < model.transfer_loss_history_[0]
    assert isinstance(model.transfer_n_evaluations_, int)
    assert model.transfer_loss_.shape == (3,)


def test_transfer_with_a_hand_set_dictionary_recovers_the_task(rng, grid3):
    """With the true dictionary fixed, one long demonstration pins down a near-optimal reward."""
    D = fo.random_dictionary(36, K, rng)
    R = fo.task_rewards(D, fo.random_coefficients(4, K, rng=rng), 9, 4)
    demos = fo.sample_demonstrations(grid3, R, 5, 10, rng)
    model = fo.FactIRL(n_primitives=K)
    model.dictionary_ = D
    h = model.transfer(grid3, demos, max_iter=50)
    assert h.shape == (4, K)
    learnt = fo.task_rewards(D, h, 9, 4)
    assert fo.deviation(grid3, R, learnt).mean() < fo.deviation(grid3, R, -learnt).mean()
    assert model.transfer_loss_history_[-1] < 0.5 * model.transfer_loss_history_[0]


def test_transfer_before_fit_raises(data):
    mdp, _, demos = data
    with pytest.raises(NotFittedError, match="no dictionary_: call fit first"):
        fo.FactIRL(n_primitives=K).transfer(mdp, demos)


def test_transfer_validation(data):
    mdp, _, demos = data
    model = fo.FactIRL(n_primitives=K)
    model.dictionary_ = np.ones((35, K))
    with pytest.raises(ValidationError, match=r"dictionary_ must have shape \(p, k\) with p = 36.*got \(35, 2\)"):
        model.transfer(mdp, demos)
    model.dictionary_ = np.ones((36, K))
    with pytest.raises(ValidationError, match=r"max_iter must be an integer >= 0; got -3"):
        model.transfer(mdp, demos, max_iter=-3)


def test_pca_dictionary(rng):
    W = rng.standard_normal((6, 2)) @ rng.standard_normal((2, 10))  # rank 2
    D, H = fo.pca_dictionary(W, 2)
    np.testing.assert_allclose(D.T @ D, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(H @ D.T, W, atol=1e-10)
    D4, _ = fo.pca_dictionary(W, 4, rng=0)  # rank-deficient: completed orthonormally
    np.testing.assert_allclose(D4.T @ D4, np.eye(4), atol=1e-12)
    with pytest.raises(ValidationError, match=r"n_components=11 exceeds the parameter dimension d=10"):
        fo.pca_dictionary(W, 11)
    with pytest.raises(ValidationError, match=r"parameters must be a 2-d array; got shape \(10,\)"):
        fo.pca_dictionary(W[0], 1)


@pytest.mark.parametrize(
    "kwargs, error, fragment",
    [
        (dict(pca_shrink="yes"), ValidationError, r"pca_shrink must be True or False; got 'yes'"),
        (dict(init="kmeans"), ValidationError, r"init must be one of \('pca', 'random'\) or a tuple \(D0, H0\); got 'kmeans'"),
        (dict(init=(np.ones((36, K)),)), ValidationError, r"init given as a tuple must be \(D0, H0\)"),
        (dict(init=(np.ones((36, K)), np.ones((4, K)))), ValidationError, r"init \(D0, H0\) must have shapes \(36, 2\) and \(5, 2\); got \(36, 2\) and \(4, 2\)"),
        (dict(init=(np.ones((30, K)), np.ones((5, K)))), ValidationError, r"init \(D0, H0\) must have shapes \(36, 2\) and \(5, 2\); got \(30, 2\)"),
        (dict(n_primitives=0), ValidationError, r"n_primitives must be an integer >= 1; got 0"),
        (dict(n_primitives=37), ValidationError, r"n_primitives=37 exceeds the reward dimension p=36"),
        (dict(beta=-1.0), ValidationError, r"beta must be a finite number > 0; got -1\.0"),
        (dict(max_iter=-1), ValidationError, r"max_iter must be an integer >= 0; got -1"),
        (dict(inner_steps=0), ValidationError, r"inner_steps must be an integer >= 1; got 0"),
        (dict(flat_max_iter=1.5), ValidationError, r"flat_max_iter must be an integer >= \d; got 1\.5"),
        (dict(tol=-1.0), ValidationError, r"tol must be a finite number >= 0; got -1\.0"),
        (dict(solver="nope"), UnknownSolverError, r"unknown solver 'nope'; available: .*armijo"),
        (dict(rng="seed"), ValidationError, r"rng must be a numpy Generator.*got str"),
    ],
)
def test_validation(data, kwargs, error, fragment):
    mdp, _, demos = data
    with pytest.raises(error, match=fragment):
        fo.FactIRL(**{"n_primitives": K, "max_iter": 1, "flat_max_iter": 2, **kwargs}).fit(mdp, demos)


def test_bad_flat_rewards_shape(data):
    mdp, _, demos = data
    with pytest.raises(ValidationError, match=r"flat_rewards must have shape \(n, S, A\) = \(5, 9, 4\); got \(4, 9, 4\)"):
        fo.FactIRL(n_primitives=K, max_iter=1).fit(mdp, demos, flat_rewards=np.zeros((4, 9, 4)))


# --- seeded regression: factorial beats flat on train tasks (paper fig. 1 claim) -------------


def train_deviations(seed, size, n_tasks, n_demos, length):
    rng = np.random.default_rng(seed)
    mdp = fo.GridWorld(size=size)
    D = fo.random_dictionary(mdp.n_params, 5, rng)
    R = fo.task_rewards(D, fo.random_coefficients(n_tasks, 5, rng=rng), mdp.n_states, mdp.n_actions)
    demos = fo.sample_demonstrations(mdp, R, n_demos, length, rng)
    flat = fo.GradIRL().fit(mdp, demos)
    fact = fo.FactIRL(n_primitives=5, rng=seed).fit(mdp, demos, flat_rewards=flat.rewards_)
    return fo.deviation(mdp, R, flat.rewards_).mean(), fo.deviation(mdp, R, fact.rewards_).mean()


@pytest.mark.parametrize("seed", [0, 1])
def test_factorial_beats_flat_on_train_tasks(seed):
    # 5x5 grid, 50 tasks, 5 demos of 10 steps: measured ratio 0.40-0.43 over seeds 0-2
    flat, fact = train_deviations(seed, size=5, n_tasks=50, n_demos=5, length=10)
    assert fact < 0.7 * flat, (flat, fact)


@pytest.mark.slow
def test_factorial_beats_flat_at_paper_scale():
    # 10x10 grid, 100 tasks, 10 demos of 10 steps (python -m factirl_opt.lab.bench fit); ~0.15
    flat, fact = train_deviations(0, size=10, n_tasks=100, n_demos=10, length=10)
    assert fact < 0.5 * flat, (flat, fact)


def test_transfer_with_a_per_call_solver(data):
    mdp, _, demos = data
    model = fo.FactIRL(n_primitives=K, max_iter=3, rng=0).fit(mdp, demos)
    h_default = model.transfer(mdp, demos[:2])
    h_gn = model.transfer(mdp, demos[:2], solver="gn-qp-clarabel", max_iter=10)
    assert h_gn.shape == h_default.shape == (2, K)
    assert model.solver == "armijo"  # the model's own solver is unchanged
    assert np.array_equal(model.transfer(mdp, demos[:2]), h_default)
    h_nonneg = model.transfer(mdp, demos[:2], solver="gn-qp-clarabel-nonneg")
    assert np.all(h_nonneg >= 0)
    with pytest.raises(ValidationError, match="solver_options given without solver"):
        model.transfer(mdp, demos[:2], solver_options={"alpha": 0.1})
    with pytest.raises(UnknownSolverError, match="available"):
        model.transfer(mdp, demos[:2], solver="no-such-solver")


# --- the alternating loop: stopping rules, records, solver forms -------------------------------


def _pca_start(mdp, demos, k=K):
    flat = fo.GradIRL(max_iter=10).fit(mdp, demos)
    return fo.pca_dictionary(flat.rewards_.reshape(len(demos), -1), k)


def test_fit_records_the_stop_and_the_evaluations(data):
    mdp, _, demos = data
    D0, H0 = _pca_start(mdp, demos)
    fit = fo.fit_factorial(mdp, demos, D0, H0, max_iter=4, gtol=0.0)
    assert fit.status == "max_iter" and fit.reason == "max_iter=4 outer iterations done" and fit.n_iter == 4
    ev = fit.evaluation_history
    assert len(ev) == len(fit.loss_history) == 5 and ev[0] == 1 and ev[-1] == fit.n_evaluations
    assert all(b > a for a, b in zip(ev, ev[1:]))  # every outer iteration evaluates Q*
    # the relative-decrease rule: a large tol stops after the first iteration that decreased
    fit = fo.fit_factorial(mdp, demos, D0, H0, max_iter=10, tol=0.99, gtol=0.0)
    dec = fo.fit_factorial(mdp, demos, D0, H0, max_iter=1, gtol=0.0).loss_history  # inner runs do not use tol
    assert fit.status == "converged" and fit.n_iter == 1 and fit.loss_history == dec
    assert fit.reason == f"relative decrease {(dec[0] - dec[1]) / dec[0]:.3g} <= tol=0.99"
    model = fo.FactIRL(n_primitives=K, max_iter=10, tol=0.99).fit(mdp, demos, flat_rewards=fo.task_rewards(D0, H0, 9, 4))
    assert model.status_ == "converged" and model.stop_reason_.startswith("relative decrease")


def test_gradient_norm_rule_and_measure(data):
    """fit.gradient_norm is the norm of (dJ/dH, dJ/dD) at the last point (eqs. 11-12, computed
    here by the step problems); gtol stops the loop once it falls to gtol x its initial value."""
    from factirl_opt.learners.gradirl import make_objective
    from factirl_opt.objectives.problems import dictionary_problem, weights_problem

    mdp, _, demos = data
    D0, H0 = _pca_start(mdp, demos)
    fit = fo.fit_factorial(mdp, demos, D0, H0, max_iter=3, tol=0.0, gtol=0.0)
    assert_non_increasing(fit.loss_history)  # so the best point is the last one
    obj = make_objective(mdp, demos, 5.0)
    gH = weights_problem(obj, fit.dictionary).loss_and_grad(fit.coefficients, np.arange(5))[1]
    gD = dictionary_problem(obj, fit.coefficients).loss_and_grad(fit.dictionary.reshape(1, -1), np.arange(1))[1]
    assert fit.gradient_norm == pytest.approx(np.hypot(np.linalg.norm(gH), np.linalg.norm(gD)), rel=1e-10)
    start = fo.fit_factorial(mdp, demos, D0, H0, max_iter=0)
    assert start.n_iter == 0 and start.status == "max_iter" and start.gradient_norm > fit.gradient_norm
    g0 = start.gradient_norm
    ratio = fit.gradient_norm / g0
    stop = fo.fit_factorial(mdp, demos, D0, H0, max_iter=10, tol=0.0, gtol=1.0001 * ratio)
    assert stop.status == "converged" and stop.n_iter <= 3
    assert stop.reason.startswith("gradient norm") and f"x initial {g0:.3g}" in stop.reason
    with pytest.raises(ValidationError, match="gtol"):
        fo.fit_factorial(mdp, demos, D0, H0, gtol=-1.0)


def test_both_blocks_use_their_alternating_form_and_carry_over(data, monkeypatch):
    """The D-solver is used in its alternating (proximal) form as the H-solver is; each block's
    run is warm-started by the solver's carry_over of its previous run: gn-cg keeps its damping,
    L-BFGS drops its pairs and keeps only the scale of its first step."""
    import solvers

    mdp, _, demos = data
    D0, H0 = _pca_start(mdp, demos)
    seen = []
    original = solvers.StepSolver.run

    def spy(self, problem, x0, max_iter, state=None, **kw):
        seen.append((self.name, problem.n_rows, getattr(self, "damping", None), state))
        return original(self, problem, x0, max_iter, state=state, **kw)

    monkeypatch.setattr(solvers.StepSolver, "run", spy)
    fo.fit_factorial(mdp, demos, D0, H0, d_solver="gn-cg", max_iter=2, tol=0.0)
    d_runs = [s for s in seen if s[1] == 1]
    assert [s[2] for s in d_runs] == [1.0, 1.0]  # the proximal copy (damping 1), not the solver's 1e-3
    assert d_runs[0][3] is None and np.shape(d_runs[1][3].lam) == (1,)
    seen.clear()
    fo.fit_factorial(mdp, demos, D0, H0, d_solver="lbfgs", max_iter=3, tol=0.0)
    d_states = [s[3] for s in seen if s[1] == 1]
    assert d_states[0] is None
    for st in d_states[1:]:
        assert np.all(st.count == 0) and not np.any(st.s) and np.all(np.isfinite(st.first_scale))


@pytest.mark.parametrize("d_solver", ["lbfgs", "gn-cg"])
def test_d_solvers_fit_and_never_worsen_the_best_point(data, d_solver):
    mdp, R, demos = data
    D0, H0 = _pca_start(mdp, demos)
    fit = fo.fit_factorial(mdp, demos, D0, H0, d_solver=d_solver, max_iter=8)
    assert min(fit.loss_history) == pytest.approx(fit.loss.sum(), rel=1e-12)
    assert fit.loss.sum() < 0.1 * fit.loss_history[0]
    assert fit.status in ("converged", "max_iter") and fit.reason


@pytest.mark.parametrize("scale", [1e200, 1e160])
def test_an_init_dictionary_too_large_to_normalise_is_refused(scale):
    from factirl_opt.learners.dictionary import check_dictionary_norms

    D0 = np.ones((36, 2))
    check_dictionary_norms(D0 * 1e150, "init D0")  # large, but its norms are finite
    D0[3, 1] = scale
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy overflow warning: the error says it
        with pytest.raises(ValidationError, match=rf"init D0 is too large to normalise.*entry {scale:.3g}".replace("+", r"\+")):
            check_dictionary_norms(D0, "init D0")


def test_a_tabular_model_transfers_to_a_list_of_its_own_mdp(data):
    grid3, _, demos = data
    model = fo.FactIRL(n_primitives=K, max_iter=2, flat_max_iter=2, rng=0).fit(grid3, demos)
    alone = model.transfer(grid3, demos[:2], max_iter=3)
    np.testing.assert_array_equal(model.transfer([grid3, grid3], demos[:2], max_iter=3), alone)
    equal = fo.GridWorld(size=3, p_success=0.7, gamma=0.9)  # another object with the same signature
    assert equal is not grid3 and equal.signature() == grid3.signature()
    np.testing.assert_array_equal(model.transfer([grid3, equal], demos[:2], max_iter=3), alone)
    with pytest.raises(ValidationError, match="fitted without features .* transfers only to that MDP"):
        model.transfer([grid3, fo.GridWorld(size=3, p_success=0.5)], demos[:2])
    with pytest.raises(ValidationError, match="got 2 MDPs for 3 tasks"):
        model.transfer([grid3, grid3], demos[:3])


@pytest.mark.parametrize("reward", ["state-action", "state"])
def test_a_tabular_model_refuses_other_maps_of_the_same_size(data, reward):
    """Tabular (or state) rewards live on the states of the model's own MDP: as ``fit`` refuses them
    across environments, ``transfer`` refuses every other map, even one of the same sizes."""
    grid3, _, demos = data
    model = fo.FactIRL(n_primitives=K, reward=reward, max_iter=2, flat_max_iter=2, rng=0).fit(grid3, demos)
    P = np.array(grid3.transitions)
    P[4] = np.eye(9)[4][None, :].repeat(4, axis=0)  # a wall around the centre cell: every move stays put
    other = fo.TabularMDP(P, grid3.gamma)
    assert (other.n_states, other.n_actions) == (grid3.n_states, grid3.n_actions) and other.signature() != grid3.signature()
    for mdps in ([grid3, other], [other, grid3], [other, other], other):
        with pytest.raises(ValidationError, match="another MDP|transfers only to that MDP"):
            model.transfer(mdps, demos[:2], max_iter=2)
    with pytest.raises(ValidationError, match="transfers only to that MDP"):
        model.transfer([grid3, other], demos[:2], features=np.ones((9, K)))
    assert model.transfer([grid3, grid3], demos[:2], max_iter=2).shape == (2, K)

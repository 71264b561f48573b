"""Active demonstration requests (factirl_opt.learners.active)."""

import numpy as np
import pytest

import factirl_opt as fo
from helpers import transfer_tasks_on_a_grid
from factirl_opt.exceptions import ValidationError
from factirl_opt.learners.active import (
    demonstrated_states, demonstrator_policy, information_gains, linearised_regret, model_policy, policy_entropy_starts,
    regret_reductions, regret_terms, request_starts, start_occupancy, state_information, value_variance_reductions,
    _best_starts, _gain_bounds, _visited_log_determinants,
)
from factirl_opt.planning import get_planner, plan


def _fit_both_objectives(size, n_train, n_test, length, rng, **params):
    """A k = 2 FactIRL per objective fitted on ``n_train`` synthetic tasks of a grid, each transferred
    to ``n_test`` one-demonstration tasks: ``(mdp, test tasks, {objective: model})``."""
    mdp, train, test = transfer_tasks_on_a_grid(size, n_train, n_test, length, rng)
    models = {}
    for objective in ("policy-matching", "mce"):
        model = fo.FactIRL(n_primitives=2, objective=objective, max_iter=5, rng=0, **params).fit(mdp, train.demos)
        model.transfer(mdp, test.demos)
        models[objective] = model
    return mdp, test, models


@pytest.fixture(scope="module")
def fitted():
    return _fit_both_objectives(4, 12, 3, 8, rng=3)


def test_start_occupancy_counts_expected_visits(grid3):
    pl = get_planner(grid3)
    pi = np.full((grid3.n_states, grid3.n_actions), 1.0 / grid3.n_actions)
    occ = start_occupancy(pl, pi, np.array([0, 4]), 5)
    np.testing.assert_allclose(occ.sum(axis=1), 5.0)
    assert occ[0, 0] >= 1.0 and occ[1, 4] >= 1.0
    # one step: the start itself; two steps: plus the state distribution after one move
    P_pi = np.einsum("sa,sat->st", pi, grid3.transitions if isinstance(grid3.transitions, np.ndarray)
                     else grid3.transitions.toarray().reshape(grid3.n_states, grid3.n_actions, grid3.n_states))
    np.testing.assert_allclose(start_occupancy(pl, pi, np.array([2]), 2)[0], np.eye(grid3.n_states)[2] + P_pi[2])


@pytest.mark.parametrize("planner", ["dense", "sparse-lu"])
@pytest.mark.parametrize("n_starts, length", [(1, 6), (9, 2), (9, 6)])  # the pullback per step; the explicit P_pi
def test_start_occupancy_routes_are_the_matrix_powers(grid3, planner, n_starts, length):
    pl = get_planner(grid3, planner)
    pi = np.random.default_rng(0).dirichlet(np.ones(grid3.n_actions), size=grid3.n_states)
    T = grid3.transitions if isinstance(grid3.transitions, np.ndarray) else grid3.transitions.toarray()
    P_pi = np.einsum("sa,sat->st", pi, T.reshape(grid3.n_states, grid3.n_actions, grid3.n_states))
    starts = np.arange(n_starts) % grid3.n_states
    expected = sum(np.linalg.matrix_power(P_pi, t) for t in range(length))[starts]
    np.testing.assert_allclose(start_occupancy(pl, pi, starts, length), expected, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_request_starts_ranks_by_information_gain(fitted, objective):
    mdp, test, models = fitted
    model = models[objective]
    starts = model.request_starts(mdp, test.demos, n_requests=4)
    assert len(starts) == 3 and all(s.shape == (4,) and s.dtype.kind == "i" for s in starts)
    for post, s, demos in zip(model.transfer_posterior_, starts, test.demos):
        gains = information_gains(post, objective, model.beta, np.arange(mdp.n_states), len(demos[0]))
        assert np.all(gains >= -1e-12)
        np.testing.assert_array_equal(s, np.argsort(-gains, kind="stable")[:4])
        assert np.all(np.diff(gains[s]) <= 1e-12)


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_information_is_the_posteriors_curvature_per_pair(fitted, objective):
    # a demonstration that visits the states as the task's own did adds the likelihood's curvature
    mdp, test, models = fitted
    model = models[objective]
    post = model.transfer_posterior_[0]
    _, info, _ = state_information(post, objective, model.beta)
    from factirl_opt.learners.transfer_likelihood import demonstration_curvature, transfer_problem
    problem = transfer_problem(model, mdp, test.demos)
    _, _, G = demonstration_curvature(problem, post.mean[None], [0])
    mu = problem.objective.mu[0]
    np.testing.assert_allclose(post.n_pairs * np.einsum("s,sde->de", mu, info), post.scaling * G[0], rtol=1e-6)


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_value_criterion_is_the_expected_reduction_of_the_values_variance(fitted, objective):
    mdp, test, models = fitted
    model = models[objective]
    post = model.transfer_posterior_[1]
    cands = np.arange(mdp.n_states)
    red = value_variance_reductions(post, objective, model.beta, cands, 8)
    assert red.shape == (mdp.n_states,) and np.all(red >= -1e-12)
    # against the definition, for one candidate: trace(M Sigma) - trace(M (Lambda + H_s)^-1)
    pl, info, pi = state_information(post, objective, model.beta)
    _, _, dQ = model_policy(post, objective, model.beta)
    dV = np.einsum("sa,sad->sd", pi, dQ)
    M = dV.T @ dV / mdp.n_states
    H = np.einsum("y,yde->de", start_occupancy(pl, pi, np.array([5]), 8)[0], info)
    after = np.linalg.inv(np.linalg.inv(post.covariance) + H)
    assert red[5] == pytest.approx(np.trace(M @ post.covariance) - np.trace(M @ after), rel=1e-8)
    starts = request_starts(model, mdp, test.demos, 2, criterion="value")
    assert starts[1].tolist() == np.argsort(-red, kind="stable")[:2].tolist()


def test_candidates_restrict_and_are_checked(fitted):
    mdp, test, models = fitted
    model = models["policy-matching"]
    got = model.request_starts(mdp, test.demos, n_requests=5, candidates=np.array([3, 7]))
    assert all(set(s.tolist()) <= {3, 7} and s.size == 2 for s in got)
    per_task = model.request_starts(mdp, test.demos, candidates=[np.array([1]), np.array([2]), np.array([5])])
    assert [s.tolist() for s in per_task] == [[1], [2], [5]]
    with pytest.raises(ValidationError, match=r"states in \[0, 16\)"):
        model.request_starts(mdp, test.demos, candidates=np.array([0, 16]))
    with pytest.raises(ValidationError, match="non-empty 1-d array of state indices"):
        model.request_starts(mdp, test.demos, candidates=np.array([0.5]))
    with pytest.raises(ValidationError, match="n_requests"):
        model.request_starts(mdp, test.demos, n_requests=0)


def test_per_task_candidates_of_different_lengths(fitted):
    """The documented "sequence of n_new arrays" may hold arrays of different lengths (numpy's
    "inhomogeneous shape" error before); each task's requests come from its own candidates."""
    mdp, test, models = fitted
    model = models["policy-matching"]
    ragged = [np.array([1, 4, 9]), np.array([2]), [5, 6]]
    got = model.request_starts(mdp, test.demos, n_requests=3, candidates=ragged)
    assert [sorted(s.tolist()) for s in got] == [[1, 4, 9], [2], [5, 6]]
    one = model.request_starts(mdp, test.demos, n_requests=1, candidates=ragged)
    for task, (s, c) in enumerate(zip(one, ragged)):  # the best of the task's own candidates, as if given alone
        alone = model.request_starts(mdp, test.demos, n_requests=1, candidates=np.asarray(c))[task]
        assert s.tolist() == alone.tolist()
    with pytest.raises(ValidationError, match=r"sequence of n_new = 3 arrays .* got 2"):
        model.request_starts(mdp, test.demos, candidates=ragged[:2])
    with pytest.raises(ValidationError, match=r"candidates of task 1 must be states in \[0, 16\)"):
        model.request_starts(mdp, test.demos, candidates=[np.array([1]), np.array([2, 16]), np.array([5])])
    with pytest.raises(ValidationError, match="criterion must be one of information, value, regret"):
        request_starts(model, mdp, test.demos, criterion="entropy")


def test_request_starts_for_tasks_other_than_the_transfers(fitted):
    mdp, test, models = fitted
    model = models["policy-matching"]
    other = [d.copy() for d in test.demos[:2]]  # other objects: their posterior is built here
    starts = model.request_starts(mdp, other, n_requests=2)
    assert len(starts) == 2 and all(s.shape == (2,) for s in starts)


def test_request_starts_needs_a_prior(fitted):
    mdp, test, _ = fitted
    model = fo.FactIRL(n_primitives=2, max_iter=2, rng=0).fit(mdp, test.demos[:1])
    with pytest.raises(ValidationError, match="at least 2 training tasks"):
        model.request_starts(mdp, test.demos)


def test_policy_entropy_starts(fitted):
    mdp, test, models = fitted
    model = models["policy-matching"]
    starts = policy_entropy_starts(model.transfer_posterior_, "policy-matching", model.beta, n_requests=3)
    assert len(starts) == 3 and all(s.shape == (3,) for s in starts)


def test_demonstrator_policy_greedy_is_one_hot_on_the_argmax(fitted):
    pi = np.array([[0.2, 0.5, 0.3], [0.6, 0.1, 0.3]])
    np.testing.assert_array_equal(demonstrator_policy(pi, "greedy"), [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    assert demonstrator_policy(pi) is pi
    with pytest.raises(ValidationError, match="policy must be one of"):
        demonstrator_policy(pi, "softmax")


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_greedy_policy_ranks_by_the_greedy_episodes_gain(fitted, objective):
    mdp, test, models = fitted
    model = models[objective]
    boltzmann = model.request_starts(mdp, test.demos, n_requests=mdp.n_states)
    greedy = model.request_starts(mdp, test.demos, n_requests=mdp.n_states, policy="greedy")
    assert any(not np.array_equal(b, g) for b, g in zip(boltzmann, greedy))
    for post, s, demos in zip(model.transfer_posterior_, greedy, test.demos):
        pl, info, pi = state_information(post, objective, model.beta)
        occ = start_occupancy(pl, demonstrator_policy(pi, "greedy"), np.arange(mdp.n_states), len(demos[0]))
        assert np.allclose(occ.sum(axis=1), len(demos[0]))
        gains = information_gains(post, objective, model.beta, np.arange(mdp.n_states), len(demos[0]), "greedy")
        np.testing.assert_array_equal(s, np.argsort(-gains, kind="stable"))
    with pytest.raises(ValidationError, match="policy must be one of boltzmann, greedy; got 'soft'"):
        model.request_starts(mdp, test.demos, policy="soft")
    with pytest.raises(ValidationError, match="policy must be one of"):
        request_starts(model, mdp, test.demos, criterion="value", policy=None)


def test_demonstrated_states_are_the_visited_ones(fitted):
    mdp, test, _ = fitted
    known = demonstrated_states(mdp, test.demos[0])
    assert known.shape == (mdp.n_states,) and known.dtype == bool
    np.testing.assert_array_equal(np.flatnonzero(known), np.unique(np.asarray(test.demos[0])[..., 0]))


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
@pytest.mark.parametrize("criterion", ["information", "value"])
def test_skipping_demonstrated_states_removes_their_information(fitted, objective, criterion):
    mdp, test, models = fitted
    model = models[objective]
    post = model.transfer_posterior_[2]
    score = information_gains if criterion == "information" else value_variance_reductions
    cands = np.arange(mdp.n_states)
    known = demonstrated_states(mdp, test.demos[2])
    skipped = score(post, objective, model.beta, cands, 8, known=known)
    # against the definition: the expected curvature over the states not yet demonstrated
    pl, info, pi = state_information(post, objective, model.beta)
    H = np.einsum("cy,yde->cde", start_occupancy(pl, pi, cands, 8), np.where(known[:, None, None], 0.0, info))
    Lam = np.linalg.inv(post.covariance)
    if criterion == "information":
        want = np.linalg.slogdet(Lam + H)[1] - np.linalg.slogdet(Lam)[1]
    else:
        _, _, dQ = model_policy(post, objective, model.beta)
        dV = np.einsum("sa,sad->sd", pi, dQ)
        M = dV.T @ dV / mdp.n_states
        want = np.trace(M @ post.covariance) - np.einsum("de,ced->c", M, np.linalg.inv(Lam + H))
    np.testing.assert_allclose(skipped, want, rtol=1e-6, atol=1e-10)
    # every state known: no demonstration adds anything; none known: the counted criterion
    np.testing.assert_allclose(score(post, objective, model.beta, cands, 8, known=np.ones(mdp.n_states, bool)), 0.0,
                               atol=1e-10)
    np.testing.assert_allclose(score(post, objective, model.beta, cands, 8, known=np.zeros(mdp.n_states, bool)),
                               score(post, objective, model.beta, cands, 8), rtol=1e-12)
    starts = request_starts(model, mdp, test.demos, mdp.n_states, criterion=criterion, demonstrated="skip")
    L = len(test.demos[2][0])
    np.testing.assert_array_equal(starts[2], np.argsort(-score(post, objective, model.beta, cands, L, known=known),
                                                        kind="stable"))


def test_demonstrated_is_checked(fitted):
    mdp, test, models = fitted
    with pytest.raises(ValidationError, match="demonstrated must be one of count, skip; got 'once'"):
        request_starts(models["policy-matching"], mdp, test.demos, demonstrated="once")


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_regret_terms_against_planning(fitted, objective):
    mdp, test, models = fitted
    post = models[objective].transfer_posterior_[0]
    gaps, E, rho = regret_terms(post)
    S, A = mdp.n_states, mdp.n_actions
    d = post.mean.shape[0]
    assert gaps.shape == (S, A) and E.shape == (S, A, d) and rho.shape == (S,)
    assert np.all(gaps >= 0) and np.all(gaps.min(axis=1) == 0)
    # the discounted visits from a uniform start sum to 1 / (1 - gamma)
    assert rho.sum() == pytest.approx(1.0 / (1.0 - mdp.gamma), rel=1e-10)
    # the gaps' tangents against central differences of the planned Q* (the greedy policy unchanged)
    pl = get_planner(mdp)
    v = np.random.default_rng(0).standard_normal(d)
    eps = 1e-6
    Qp, Qm = (plan(pl, post.rewards(post.mean + t * v)).Q[0] for t in (eps, -eps))
    pol = plan(pl, post.mean_rewards()[None]).policy[0]
    fd = ((Qp - Qp[np.arange(S), pol][:, None]) - (Qm - Qm[np.arange(S), pol][:, None])) / (2 * eps)
    np.testing.assert_allclose(np.einsum("sad,d->sa", E, v), fd, rtol=1e-5, atol=1e-7)
    # the performance difference: the regret of pi_m under another reward is the rho-weighted loss of its actions
    other = post.rewards(post.mean + v)[0]
    res = plan(pl, other[None])
    loss = res.V[0] - res.Q[0][np.arange(S), pol]
    assert float(rho @ loss) == pytest.approx(float(fo.deviation(mdp, other, post.mean_rewards())), rel=1e-8)


def test_linearised_regret_is_the_expected_loss_of_the_linear_model():
    rng = np.random.default_rng(1)
    gaps = np.array([[0.0, 0.3, 1.2], [0.5, 0.0, 0.0]])
    E = rng.standard_normal((2, 3, 2))
    E[0, 0] = E[1, 1] = 0.0  # the greedy actions' own gaps have no tangent
    E[1, 2] = 0.0  # a tie known for sure: no loss
    rho = np.array([0.7, 1.9])
    C = np.array([[0.5, 0.1], [0.1, 0.3]])
    z = rng.multivariate_normal(np.zeros(2), C, size=400_000)
    mc = sum(rho[y] * np.maximum(-gaps[y, a] + z @ E[y, a], 0.0).mean() for y in range(2) for a in range(3))
    assert linearised_regret(gaps, E, rho, C) == pytest.approx(mc, rel=1e-2)
    np.testing.assert_allclose(linearised_regret(gaps, E, rho, np.stack([C, 0 * C])), [linearised_regret(gaps, E, rho, C), 0.0])


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_regret_criterion_is_the_expected_reduction_of_the_linearised_regret(fitted, objective):
    mdp, test, models = fitted
    model = models[objective]
    post = model.transfer_posterior_[1]
    cands = np.arange(mdp.n_states)
    red = regret_reductions(post, objective, model.beta, cands, 8)
    assert red.shape == (mdp.n_states,) and np.all(red >= -1e-12)
    pl, info, pi = state_information(post, objective, model.beta)
    H = np.einsum("y,yde->de", start_occupancy(pl, pi, np.array([5]), 8)[0], info)
    after = np.linalg.inv(np.linalg.inv(post.covariance) + H)
    terms = regret_terms(post)
    assert red[5] == pytest.approx(linearised_regret(*terms, post.covariance) - linearised_regret(*terms, after), rel=1e-6)
    starts = request_starts(model, mdp, test.demos, 3, criterion="regret")
    L = len(test.demos[1][0])
    assert starts[1].tolist() == np.argsort(-regret_reductions(post, objective, model.beta, cands, L), kind="stable")[:3].tolist()


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_factirl_request_starts_passes_criterion_and_demonstrated_through(fitted, objective):
    mdp, test, models = fitted
    model = models[objective]
    S = mdp.n_states
    for options in ({"criterion": "value"}, {"criterion": "regret", "demonstrated": "skip"},
                    {"criterion": "information", "demonstrated": "skip", "policy": "greedy"}):
        got = model.request_starts(mdp, test.demos, S, **options)
        want = request_starts(model, mdp, test.demos, S, **options)
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w)
    # the options change the ranking (else passing them through would be untested)
    default = model.request_starts(mdp, test.demos, S)
    value = model.request_starts(mdp, test.demos, S, criterion="value")
    skip = model.request_starts(mdp, test.demos, S, demonstrated="skip")
    assert any(not np.array_equal(d, v) for d, v in zip(default, value))
    assert any(not np.array_equal(d, k) for d, k in zip(default, skip))
    with pytest.raises(ValidationError, match="criterion must be one of"):
        model.request_starts(mdp, test.demos, criterion="entropy")
    with pytest.raises(ValidationError, match="demonstrated must be one of count, skip; got 'once'"):
        model.request_starts(mdp, test.demos, demonstrated="once")


@pytest.fixture(scope="module")
def residual_fitted():
    return _fit_both_objectives(3, 10, 2, 6, rng=5, residual_penalty=0.5, transfer_max_iter=20)


@pytest.mark.filterwarnings("ignore::factirl_opt.exceptions.MaxIterWarning")
@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
@pytest.mark.parametrize("known", [False, True])
def test_information_gains_over_the_rows_match_the_parameters_determinants(residual_fitted, objective, known):
    # a residual model (d = k + S*A): the gains over the visited rows, as log det(Lambda + H_s) - log det(Lambda)
    mdp, test, models = residual_fitted
    model = models[objective]
    cands = np.arange(mdp.n_states)
    for i, post in enumerate(model.transfer_posterior_):
        assert post.mean.size == 2 + mdp.n_states * mdp.n_actions
        mask = demonstrated_states(mdp, test.demos[i], i) if known else None
        gains = information_gains(post, objective, model.beta, cands, 4, known=mask)
        pl, info, pi = state_information(post, objective, model.beta)
        if known:
            info = np.where(mask[:, None, None], 0.0, info)
        occ = start_occupancy(pl, pi, cands, 4)
        Lam = np.linalg.inv(post.covariance)
        H = np.einsum("cy,yde->cde", occ, info)
        dense = np.linalg.slogdet(Lam[None] + H)[1] - np.linalg.slogdet(Lam)[1]
        np.testing.assert_allclose(gains, dense, rtol=1e-8, atol=1e-9)


@pytest.mark.parametrize("S, r, rank", [(6, 3, 18), (7, 2, 5), (5, 1, 5), (9, 3, 4)])
def test_visited_log_determinants_match_the_dense_determinant_over_all_rows(S, r, rank):
    # log det(I + O^1/2 K O^1/2) over all S*r rows, against the visited block's factorisation of
    # K_vv + O^-1 (unvisited states, occupancies from 1e-250 to 20, full and low-rank K)
    rng = np.random.default_rng(S * 100 + r * 10 + rank)
    X = rng.standard_normal((S * r, rank)) * rng.uniform(0.1, 10.0, rank)
    K = X @ X.T
    occ = rng.uniform(0.0, 3.0, (12, S)) * (rng.uniform(size=(12, S)) < 0.7)
    occ[0] = 0.0  # an episode that visits no state left: no information
    occ[1] = 20.0
    occ[2, :2] = [1e-250, 1e-12]
    occ[3] = 0.0
    occ[3, 1] = 2.5
    w = np.sqrt(np.repeat(occ, r, axis=1))
    dense = np.linalg.slogdet(np.eye(S * r) + w[:, :, None] * K[None] * w[:, None, :])[1]
    got = _visited_log_determinants(K.reshape(S, r, S, r), occ)
    np.testing.assert_allclose(got, dense, rtol=1e-11, atol=1e-12)
    assert got[0] == 0.0 and np.all(got[1:] > 0.0)


def test_requests_and_the_posterior_run_with_blas_limited_as_the_transfer(fitted, monkeypatch):
    # entry points like fit and transfer: under FACTIRL_BLAS_THREADS (1), whatever the process's count
    from factirl_opt import _threads
    from factirl_opt.learners import active, factirl

    mdp, test, models = fitted
    model = models["policy-matching"]
    seen = []

    def probe(post, *args):
        seen.append([lib.num_threads for lib in _threads._blas_libraries()])
        return np.zeros(len(args[2]))

    def posterior_probe(est):
        seen.append([lib.num_threads for lib in _threads._blas_libraries()])
        return posts

    posts = model.transfer_posterior_
    monkeypatch.setenv("FACTIRL_BLAS_THREADS", "1")
    monkeypatch.setitem(active.CRITERIA, "information", probe)
    monkeypatch.setattr(factirl, "cached_transfer_posterior", posterior_probe)
    with _threads.limit_blas_threads(2) as outside:
        model.request_starts(mdp, test.demos)
        assert model.transfer_posterior_ is posts
        assert [lib.num_threads for lib in _threads._blas_libraries()] == outside
    assert outside == [2] * len(outside)
    # each task's gains, the posterior read by request_starts and the one read here
    assert seen == [[1] * len(outside)] * (len(test.demos) + 2)


@pytest.mark.filterwarnings("ignore::factirl_opt.exceptions.MaxIterWarning")
@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
@pytest.mark.parametrize("demonstrated", ["count", "skip"])
def test_residual_requests_are_the_first_of_the_information_ranking(residual_fitted, objective, demonstrated):
    # the requests of a residual posterior (its n best without every gain) against the full ranking
    mdp, test, models = residual_fitted
    model = models[objective]
    for n in (1, 3, mdp.n_states):
        starts = model.request_starts(mdp, test.demos, n, demonstrated=demonstrated)
        for i, (post, s) in enumerate(zip(model.transfer_posterior_, starts)):
            known = demonstrated_states(mdp, test.demos[i], i) if demonstrated == "skip" else None
            gains = information_gains(post, objective, model.beta, np.arange(mdp.n_states), len(test.demos[i][0]),
                                      known=known)
            np.testing.assert_array_equal(s, np.argsort(-gains, kind="stable")[:n])


def _random_visits(S, r, rank, n_candidates, seed):
    """A PSD ``K`` (S, r, S, r) of the given rank and expected visits (c, S) with unvisited states and a wide range."""
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((S * r, rank)) * rng.uniform(0.1, 3.0, rank)
    occ = rng.uniform(0.0, 2.0, (n_candidates, S)) ** 3 * (rng.uniform(size=(n_candidates, S)) < 0.8)
    return (X @ X.T).reshape(S, r, S, r), occ


@pytest.mark.parametrize("slack", [0.0, 0.05, 0.5, 5.0])
def test_gain_bounds_enclose_the_gains_within_the_slack(slack):
    K, occ = _random_visits(8, 3, 24, 30, seed=int(slack * 100))
    gains = _visited_log_determinants(K, occ)
    lower, upper = _gain_bounds(K, occ, slack)
    assert np.all(lower <= gains + 1e-12) and np.all(gains <= upper + 1e-12)
    assert np.all(upper - lower <= slack + 1e-12)
    if slack == 0.0:
        np.testing.assert_array_equal(lower, gains)
    else:
        assert np.any(lower < gains - 1e-9)  # a tail was left out (else the bounds would be untested)


@pytest.mark.parametrize("n", [1, 3, 7, 40])
@pytest.mark.parametrize("slack", [0.05, 0.5, 50.0])
def test_best_starts_are_the_first_of_the_full_ranking(n, slack):
    # one or two posteriors' (K, occ) (a marginal over two dictionaries); repeated candidates tie
    terms = [_random_visits(9, 3, 20, 40, seed=1), _random_visits(9, 3, 27, 40, seed=2)]
    for t in terms:
        t[1][[5, 17, 30]] = t[1][11]
    for used in (terms[:1], terms):
        gains = np.mean([_visited_log_determinants(K, occ) for K, occ in used], axis=0)
        full = np.argsort(-gains, kind="stable")[:n]
        np.testing.assert_array_equal(_best_starts(used, n, slack), full)


def test_visited_log_determinants_refuse_a_block_that_is_not_positive_definite():
    K = -10.0 * np.eye(4).reshape(2, 2, 2, 2)
    with pytest.raises(np.linalg.LinAlgError, match="visited block of candidate 0 is not positive definite"):
        _visited_log_determinants(K, np.ones((1, 2)))


@pytest.mark.filterwarnings("ignore::factirl_opt.exceptions.MaxIterWarning")
def test_marginal_requests_average_the_criterion_over_the_dictionaries(fitted):
    mdp, test, models = fitted
    S = mdp.n_states
    plain = models["policy-matching"]
    for a, b in zip(plain.request_starts(mdp, test.demos, S, marginal=True), plain.request_starts(mdp, test.demos, S)):
        np.testing.assert_array_equal(a, b)  # no ensemble: the conditional ranking
    model = fo.FactIRL(n_primitives=2, max_iter=5, rng=0, posterior=fo.PosteriorSettings(n_dictionaries=2))
    model.fit(mdp, transfer_tasks_on_a_grid(4, 12, 3, 8, 3)[1].demos)
    model.transfer(mdp, test.demos)
    got = model.request_starts(mdp, test.demos, S, marginal=True)
    cands = np.arange(S)
    for i, post in enumerate(model.transfer_posterior_):
        assert len(post.members) == 2
        L = len(test.demos[i][0])
        gains = np.mean([information_gains(q, "policy-matching", model.beta, cands, L) for q in (post, *post.members)], axis=0)
        np.testing.assert_array_equal(got[i], np.argsort(-gains, kind="stable"))
    own = model.request_starts(mdp, test.demos, S)
    assert any(not np.array_equal(g, o) for g, o in zip(got, own))
    with pytest.raises(ValidationError, match="marginal"):
        model.request_starts(mdp, test.demos, marginal="yes")

"""MultiIntentIRL: the E-step against brute force, weighted statistics, monotone EM with MCE,
recovery of well-separated intentions, the clustering scores, and the error paths."""

import numpy as np
import pytest
from scipy.special import logsumexp

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError
from factirl_opt.learners.em import e_step, episode_counts, kmeans, kmeans_plus_plus, log_policies, weighted_statistics
from factirl_opt.learners.multi_intent_fit import WeightedObjective
from factirl_opt.objectives import MCEObjective, Objective, PolicyMatchingObjective
from factirl_opt.planning import get_planner


def _episodes(rng, S, A, lengths):
    return [np.stack([rng.integers(0, S, L), rng.integers(0, A, L)], axis=1) for L in lengths]


def _soft_policy_reference(mdp, R, beta, sweeps=3000):
    """Soft-optimal policy by plain soft value iteration (independent of the Newton solver)."""
    S, A = mdp.n_states, mdp.n_actions
    P = mdp.transitions.reshape(S, A, S)
    V = np.zeros(S)
    for _ in range(sweeps):
        Q = R + mdp.gamma * P @ V
        V = logsumexp(beta * Q, axis=1) / beta
    Q = R + mdp.gamma * P @ V
    return np.exp(beta * Q - logsumexp(beta * Q, axis=1, keepdims=True))


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_e_step_matches_brute_force_products(objective):
    rng = np.random.default_rng(0)
    mdp = fo.GridWorld(3)
    S, A, K, beta = mdp.n_states, mdp.n_actions, 3, 2.0
    R = rng.normal(size=(K, S, A))
    episodes = _episodes(rng, S, A, [1, 4, 7, 3, 5])
    mix = np.array([0.2, 0.5, 0.3])
    if objective == "mce":
        pol = np.array([_soft_policy_reference(mdp, R[c], beta) for c in range(K)])
    else:
        Q, _ = fo.optimal_q(mdp, R)
        pol = np.exp(beta * Q) / np.exp(beta * Q).sum(axis=2, keepdims=True)
    lik = np.array([[np.prod([pol[c, s, a] for s, a in ep]) for c in range(K)] for ep in episodes])
    joint = lik * mix
    ref_resp = joint / joint.sum(axis=1, keepdims=True)
    counts = episode_counts(np.concatenate(episodes), np.array([len(e) for e in episodes]), S, A)
    L, resp, total = e_step(counts, log_policies(get_planner(mdp), R, beta, objective), mix)
    np.testing.assert_allclose(np.exp(L), lik, rtol=1e-8)
    np.testing.assert_allclose(resp, ref_resp, rtol=1e-8, atol=1e-14)
    assert total == pytest.approx(np.sum(np.log(joint.sum(axis=1))), rel=1e-10)


def test_e_step_stays_finite_for_peaked_policies_and_zero_weights():
    mdp = fo.GridWorld(3)
    R = np.zeros((2, mdp.n_states, mdp.n_actions))
    R[0, :, 0] = 1.0
    R[1, :, 1] = 1.0
    log_pi = log_policies(get_planner(mdp), R, 1e4, "policy-matching")  # exp underflows: log space must not
    assert np.all(np.isfinite(log_pi))
    counts = episode_counts(np.array([[0, 1], [1, 1]]), np.array([2]), mdp.n_states, mdp.n_actions)
    L, resp, total = e_step(counts, log_pi, np.array([0.5, 0.5]))
    assert L[0, 0] < -1e3 and np.isfinite(total)
    np.testing.assert_allclose(resp, [[0.0, 1.0]], atol=1e-300)
    _, resp0, _ = e_step(counts, log_pi, np.array([1.0, 0.0]))  # a zero mixture weight: zero responsibility
    np.testing.assert_array_equal(resp0, [[1.0, 0.0]])


def test_weighted_statistics_of_hard_responsibilities_are_the_groups_statistics():
    rng = np.random.default_rng(1)
    mdp = fo.GridWorld(3)
    S, A = mdp.n_states, mdp.n_actions
    episodes = _episodes(rng, S, A, [3, 5, 2, 6, 4])
    labels = np.array([0, 1, 0, 1, 1])
    counts = episode_counts(np.concatenate(episodes), np.array([len(e) for e in episodes]), S, A)
    mu, pi, steps = weighted_statistics(counts, np.eye(2)[labels], S, A)
    ref_mu, ref_pi = fo.empirical_statistics(mdp, [[episodes[j] for j in np.flatnonzero(labels == c)] for c in range(2)])
    np.testing.assert_allclose(mu, ref_mu, atol=1e-15)
    np.testing.assert_allclose(pi, ref_pi, atol=1e-15)
    np.testing.assert_array_equal(steps, [5, 15])
    mu, pi, steps = weighted_statistics(counts, np.eye(3)[labels], S, A)  # intention 2 has no weight
    assert steps[2] == 0.0 and mu[2].sum() == pytest.approx(1.0)


def test_weighted_objective_scales_loss_gradient_and_linearisation():
    rng = np.random.default_rng(2)
    mdp = fo.GridWorld(3)
    S, A = mdp.n_states, mdp.n_actions
    mu = rng.dirichlet(np.ones(S), size=2)
    pi = rng.dirichlet(np.ones(A), size=(2, S))
    base = PolicyMatchingObjective(mdp, mu, pi, 3.0)
    ref = PolicyMatchingObjective(mdp, mu, pi, 3.0)
    w = np.array([0.3, 1.7])
    obj = WeightedObjective(base, w)
    R = rng.normal(size=(2, S, A))
    loss, grad = obj.loss_and_grad(R)
    l0, g0 = ref.loss_and_grad(R)
    np.testing.assert_allclose(loss, w * l0)
    np.testing.assert_allclose(grad, w[:, None, None] * g0)
    loss1, grad1 = obj.loss_and_grad(R[1:], np.array([1]))
    np.testing.assert_allclose(loss1, w[1:] * l0[1:])
    lin = obj.linearize(R)
    np.testing.assert_allclose(lin.loss, np.sum(lin.residual ** 2, axis=1))
    np.testing.assert_allclose(2.0 * lin.vjp(lin.residual), grad, rtol=1e-8, atol=1e-12)
    V, U = rng.normal(size=(2, S, A)), rng.normal(size=lin.residual.shape)
    assert np.sum(lin.jvp(V) * U) == pytest.approx(np.sum(V * lin.vjp(U)), rel=1e-9)
    F = rng.normal(size=(S * A, 3))
    lossj, res, jac = obj.residual_jacobian(R, np.arange(2), F)
    np.testing.assert_allclose(res, lin.residual)
    np.testing.assert_allclose(2.0 * np.einsum("nm,nmp->np", res, jac), grad.reshape(2, -1) @ F, rtol=1e-7, atol=1e-12)


def test_adjusted_rand_index_hand_computed():
    # contingency [[2, 1, 0], [0, 1, 2]]: index 2, rows 6, cols 3, C(6, 2) = 15,
    # expected 6 * 3 / 15 = 1.2, max (6 + 3) / 2 = 4.5 -> (2 - 1.2) / (4.5 - 1.2) = 8 / 33
    assert fo.adjusted_rand_index([0, 0, 0, 1, 1, 1], [0, 0, 1, 1, 2, 2]) == pytest.approx(8 / 33)
    assert fo.adjusted_rand_index([0, 0, 1, 1, 2], [5, 5, 3, 3, 9]) == 1.0  # renaming
    assert fo.adjusted_rand_index([0, 0, 0], [1, 1, 1]) == 1.0  # both trivial
    assert fo.adjusted_rand_index([0, 0, 1, 1], [0, 1, 0, 1]) == pytest.approx(-0.5)
    with pytest.raises(fo.exceptions.ValidationError, match="same length"):
        fo.adjusted_rand_index([0, 1], [0, 1, 2])


def test_match_intentions_is_the_least_cost_assignment():
    cost = np.array([[4.0, 1.0, 3.0], [2.0, 0.0, 5.0], [3.0, 2.0, 2.0]])
    np.testing.assert_array_equal(fo.match_intentions(cost), [1, 0, 2])
    np.testing.assert_array_equal(fo.match_intentions(cost[:, :2]), [1, 0, -1])


def test_kmeans_recovers_separated_blobs():
    rng = np.random.default_rng(3)
    centres = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    truth = np.repeat(np.arange(3), 20)
    X = centres[truth] + rng.normal(scale=0.5, size=(60, 2))
    assert fo.adjusted_rand_index(truth, kmeans(X, 3, rng)) == 1.0
    seeds = kmeans_plus_plus(np.vstack([X, X[:1]]), 3, rng)
    assert len({tuple(s) for s in seeds}) == 3


def _separated_problem(n_demos=6, length=8, seed=4):
    """Two intentions on a 4x4 grid, heading to opposite corners."""
    mdp = fo.GridWorld(4, p_success=0.9)
    S, A = mdp.n_states, mdp.n_actions
    R = np.zeros((2, S, A))
    R[0, 0] = 1.0
    R[1, S - 1] = 1.0
    demos = fo.sample_demonstrations(mdp, R, n_demos, length, rng=seed)
    return mdp, R, demos


@pytest.mark.parametrize("n_primitives", [None, 2])
def test_labels_recover_well_separated_intentions(n_primitives):
    mdp, R, demos = _separated_problem()
    episodes = [ep for d in demos for ep in d]
    truth = np.repeat([0, 1], len(demos[0]))
    em = fo.MultiIntentIRL(2, n_primitives=n_primitives, rng=0, max_iter=10, m_step_max_iter=30).fit(mdp, episodes)
    assert fo.adjusted_rand_index(truth, em.labels_) == 1.0
    assert em.responsibilities_.shape == (len(episodes), 2) and em.rewards_.shape == (2, mdp.n_states, mdp.n_actions)
    np.testing.assert_allclose(em.responsibilities_.sum(axis=1), 1.0)
    np.testing.assert_allclose(em.mixture_weights_, [0.5, 0.5], atol=0.05)
    assert em.best_log_likelihood_ == max(em.log_likelihood_) and em.n_iter_ == len(em.log_likelihood_)
    dev = fo.deviation(mdp, R, em.rewards_[fo.match_intentions(-np.eye(2)[truth].T @ np.eye(2)[em.labels_])])
    assert np.all(dev < fo.deviation(mdp, R, np.zeros_like(R)))
    if n_primitives is None:
        assert em.weights_.shape == (2, mdp.n_params) and not hasattr(em, "dictionary_")
    else:
        assert em.dictionary_.shape == (mdp.n_params, 2) and em.coefficients_.shape == (2, 2)


@pytest.mark.parametrize("n_primitives", [None, 2])
def test_log_likelihood_never_decreases_with_mce(n_primitives):
    mdp = fo.GridWorld(4)
    tasks = fo.synthetic_tasks(mdp, 3, 4, 6, n_primitives=3, rng=5)
    episodes = [ep for d in tasks.demos for ep in d]
    em = fo.MultiIntentIRL(3, n_primitives=n_primitives, objective="mce", init="random", rng=1, tol=0.0,
                           max_iter=8 if n_primitives is None else 4, m_step_max_iter=40 if n_primitives is None else 15,
                           m_step_tol=1e-10).fit(mdp, episodes)
    ll = np.array(em.log_likelihood_)
    assert len(ll) >= 3
    assert np.all(np.diff(ll) >= -1e-9 * np.abs(ll[:-1])), ll


def test_episode_layouts_agree_and_given_start():
    mdp, _, demos = _separated_problem(n_demos=3, length=5)
    stacked = np.concatenate(demos)  # (6, 5, 2)
    kw = dict(rng=0, max_iter=3, m_step_max_iter=10)
    a = fo.MultiIntentIRL(2, **kw).fit(mdp, stacked)
    b = fo.MultiIntentIRL(2, **kw).fit(mdp, list(stacked))
    np.testing.assert_array_equal(a.responsibilities_, b.responsibilities_)
    ragged = [ep[: 2 + j % 3] for j, ep in enumerate(stacked)]
    fo.MultiIntentIRL(2, init=np.array([0, 0, 0, 1, 1, 1]), **kw).fit(mdp, ragged)
    fo.MultiIntentIRL(2, init=np.full((6, 2), 0.5), n_init=2, **kw).fit(mdp, ragged)


def test_to_factirl_transfers_from_the_learnt_dictionary():
    mdp, R, demos = _separated_problem(n_demos=3, length=6)
    em = fo.MultiIntentIRL(2, n_primitives=2, rng=0, max_iter=3, m_step_max_iter=10).fit(mdp, np.concatenate(demos))
    model = em.to_factirl()
    np.testing.assert_array_equal(model.dictionary_, em.dictionary_)
    h = model.transfer(mdp, [demos[0]], max_iter=5)
    assert h.shape == (1, 2) and np.all(np.isfinite(h))
    with pytest.raises(fo.exceptions.NotFittedError, match="n_primitives"):
        fo.MultiIntentIRL(2, rng=0, max_iter=2, m_step_max_iter=5).fit(mdp, np.concatenate(demos)).to_factirl()
    with pytest.raises(fo.exceptions.NotFittedError):
        fo.MultiIntentIRL(2).to_factirl()


@pytest.mark.parametrize("kwargs, episodes, match", [
    (dict(n_intentions=0), None, "n_intentions"),
    (dict(n_intentions=7), None, "exceeds the number of episodes"),
    (dict(n_intentions=2.5), None, "n_intentions"),
    (dict(n_intentions=2, objective="nope"), None, "unknown objective"),
    (dict(n_intentions=2, init="kmeans"), None, "init must be one of"),
    (dict(n_intentions=2, init=np.array([0, 1, 2, 0, 1, 0])), None, "init labels"),
    (dict(n_intentions=2, init=np.ones((6, 2))), None, "init responsibilities"),
    (dict(n_intentions=2, n_primitives=500), None, "n_primitives=500 exceeds"),
    (dict(n_intentions=2, n_primitives=0), None, "n_primitives"),
    (dict(n_intentions=2, max_iter=0), None, "max_iter"),
    (dict(n_intentions=2, n_init=0), None, "n_init"),
    (dict(n_intentions=1), [], "empty"),
    (dict(n_intentions=1), np.zeros((4, 2), dtype=int), "shape"),
    (dict(n_intentions=1), [np.array([[0, 9]])], "action"),
    (dict(n_intentions=1), [np.array([[99, 0]])], "state"),
    (dict(n_intentions=1), [np.zeros((0, 2), dtype=int)], "L >= 1"),
    (dict(n_intentions=1), "episodes", "episodes"),
])
def test_error_paths(kwargs, episodes, match):
    mdp, _, demos = _separated_problem(n_demos=3, length=4)
    eps = np.concatenate(demos) if episodes is None else episodes
    with pytest.raises(fo.exceptions.ValidationError, match=match):
        fo.MultiIntentIRL(**kwargs).fit(mdp, eps)


def test_wrong_mdp_and_non_policy_objective():
    _, _, demos = _separated_problem(n_demos=3, length=4)
    with pytest.raises(fo.exceptions.ValidationError, match="TabularMDP"):
        fo.MultiIntentIRL(2).fit("grid", np.concatenate(demos))
    with pytest.raises(fo.exceptions.ValidationError, match="state"):  # episodes of a larger MDP
        fo.MultiIntentIRL(1).fit(fo.GridWorld(2), np.concatenate(demos))

    class Other(Objective):  # an objective with no policy model (no log_policy)
        name = "other"

    assert not Other.models_policy() and MCEObjective.models_policy()
    with pytest.raises(fo.exceptions.ValidationError, match="scores"):
        fo.MultiIntentIRL(2, objective=Other).fit(fo.GridWorld(4), np.concatenate(demos))


def test_agreement_clustering_separates_conflicting_episodes():
    from factirl_opt.learners.em import agreement_clustering

    S, A = 5, 2
    # episodes 0-1 take action 0 in states 0-2, episodes 2-3 action 1 there; 4 agrees with 0 on state 3
    eps = [np.array([[0, 0], [1, 0]]), np.array([[1, 0], [2, 0], [3, 0]]), np.array([[0, 1], [2, 1]]),
           np.array([[1, 1], [2, 1]]), np.array([[3, 0], [4, 0]])]
    counts = episode_counts(np.concatenate(eps), np.array([len(e) for e in eps]), S, A)
    for seed in range(5):
        labels = agreement_clustering(counts, S, A, 2, np.random.default_rng(seed))
        assert fo.adjusted_rand_index([0, 0, 1, 1, 0], labels) == 1.0
    assert sorted(agreement_clustering(counts, S, A, 5, np.random.default_rng(0))) == [0, 1, 2, 3, 4]


def test_features_state_rewards_and_callback():
    mdp, _, demos = _separated_problem(n_demos=3, length=5)
    eps = np.concatenate(demos)
    rng = np.random.default_rng(6)
    seen = []
    em = fo.MultiIntentIRL(2, features=rng.normal(size=(mdp.n_states, 3)), rng=0, max_iter=3, m_step_max_iter=5,
                           callback=lambda it, ll: seen.append((it, ll))).fit(mdp, eps)
    assert em.weights_.shape == (2, 3) and em.features_sha256_ is not None
    assert [it for it, _ in seen] == list(range(1, em.n_iter_ + 1)) and [ll for _, ll in seen] == em.log_likelihood_
    em = fo.MultiIntentIRL(2, n_primitives=2, reward="state", rng=0, max_iter=2, m_step_max_iter=5).fit(mdp, eps)
    assert em.dictionary_.shape == (mdp.n_states, 2)
    np.testing.assert_array_equal(em.rewards_[:, :, 0], em.rewards_[:, :, 1])


def test_weighted_mce_loss_is_the_expected_complete_data_negative_log_likelihood():
    # sum_c w_c J_c = -(1/N) sum_j sum_c r_jc log p(tau_j | c): the M-step minimises EM's objective exactly
    rng = np.random.default_rng(7)
    mdp = fo.GridWorld(3)
    S, A, K = mdp.n_states, mdp.n_actions, 3
    episodes = _episodes(rng, S, A, [4, 6, 3, 5, 2, 7])
    lengths = np.array([len(e) for e in episodes])
    counts = episode_counts(np.concatenate(episodes), lengths, S, A)
    resp = rng.dirichlet(np.ones(K), size=len(episodes))
    R = rng.normal(size=(K, S, A))
    mu, pi, steps = weighted_statistics(counts, resp, S, A)
    np.testing.assert_allclose(steps, resp.T @ lengths)
    obj = WeightedObjective(MCEObjective(mdp, mu, pi, 2.0), steps / steps.sum())
    L, _, _ = e_step(counts, log_policies(get_planner(mdp), R, 2.0, "mce"), np.full(K, 1.0 / K))
    assert obj.loss_and_grad(R)[0].sum() == pytest.approx(-np.sum(resp * L) / lengths.sum(), rel=1e-10)


def test_sparse_model_gives_the_dense_fit():
    import scipy.sparse as sp

    mdp, _, demos = _separated_problem(n_demos=3, length=5)
    S, A = mdp.n_states, mdp.n_actions
    sparse = fo.TabularMDP(sp.csr_matrix(mdp.transitions.reshape(S * A, S)), mdp.gamma)
    kw = dict(rng=0, max_iter=3, m_step_max_iter=5)
    a = fo.MultiIntentIRL(2, **kw).fit(mdp, np.concatenate(demos))
    b = fo.MultiIntentIRL(2, planner="sparse-lu", **kw).fit(sparse, np.concatenate(demos))
    np.testing.assert_array_equal(a.labels_, b.labels_)
    np.testing.assert_allclose(b.rewards_, a.rewards_, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("episodes, match", [
    ([np.array([[0, 1], [1, 2]]), np.array([[0, 1], [9, 2]])], r"^episodes\[1\], step 1: state 9 is out of range \[0, 9\)$"),
    ([np.array([[0, 1], [1, 7]])], r"^episodes\[0\], step 1: action 7 is out of range \[0, 4\)$"),
    (np.zeros((2, 3, 2), dtype=int) + [0, 9], r"^episodes\[0\], step 0: action 9 is out of range"),
    ([np.array([[0, 1]]), np.zeros(3, dtype=int)], r"^episodes\[1\] must have shape \(L, 2\) with L >= 1; got \(3,\)"),
    ([[0, 1], [1, 2]], r"^episodes is a single episode \(a list of \(state, action\) pairs\), not a list of episodes: "
                       r"pass \[episodes\]$"),
    ([], "^episodes are empty"),
])
def test_unlabeled_episodes_are_named_as_given_not_as_a_task(episodes, match):
    with pytest.raises(ValidationError, match=match) as info:
        fo.MultiIntentIRL(n_intentions=1, max_iter=1).fit(fo.GridWorld(size=3), episodes)
    assert "task" not in str(info.value)

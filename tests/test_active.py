"""Active demonstration requests (factirl_opt.learners.active)."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.datasets.synthetic import synthetic_tasks
from factirl_opt.exceptions import ValidationError
from factirl_opt.learners.active import (
    demonstrator_policy, information_gains, model_policy, policy_entropy_starts, request_starts, start_occupancy, state_information,
    value_variance_reductions,
)
from factirl_opt.planning import get_planner


@pytest.fixture(scope="module")
def fitted():
    mdp = fo.GridWorld(size=4, p_success=0.8, gamma=0.9)
    train = synthetic_tasks(mdp, 12, 4, 8, n_primitives=2, rng=3)
    test = synthetic_tasks(mdp, 3, 1, 8, dictionary=train.dictionary, rng=4)
    models = {}
    for objective in ("policy-matching", "mce"):
        model = fo.FactIRL(n_primitives=2, objective=objective, max_iter=5, rng=0).fit(mdp, train.demos)
        model.transfer(mdp, test.demos)
        models[objective] = model
    return mdp, test, models


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
    from factirl_opt.learners.posterior import demonstration_curvature, transfer_problem
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
    with pytest.raises(ValidationError, match="criterion must be one of information, value"):
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

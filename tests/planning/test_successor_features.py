"""Successor features of fixed policies, GPI actions and the exact improvement step."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError
from factirl_opt.planning import get_planner
from factirl_opt.planning.successor_features import (
    gpi_actions, improve_policies, library_values, successor_features,
)


@pytest.fixture
def grid():
    return fo.GridWorld(size=5, p_success=0.7, gamma=0.9)


def _q_of_policy(mdp, R, policy):
    """``Q^pi`` (n, S, A) of policies on rewards R (n, S, A) by independent dense evaluation."""
    V = fo.policy_evaluation(mdp, R, policy, planner="dense")
    return R + mdp.gamma * np.einsum("sat,nt->nsa", mdp.transitions, V)


@pytest.mark.parametrize("planner", ["dense", "sparse-lu"])
@pytest.mark.parametrize("kind", ["greedy", "boltzmann"])
def test_successor_features_match_policy_evaluation_per_primitive(grid, rng, planner, kind):
    S, A, k, L = grid.n_states, grid.n_actions, 3, 4
    phi = rng.normal(size=(k, S, A))
    if kind == "greedy":
        policy = fo.optimal_q(grid, rng.normal(size=(L, S, A)))[1]
    else:
        policy = fo.boltzmann_policy(fo.optimal_q(grid, rng.normal(size=(L, S, A)))[0], 5.0)
    psi = successor_features(grid, phi, policy, planner=planner)
    assert psi.shape == (L, S, A, k)
    for j in range(k):  # each column: the action values of the policies on primitive j
        Q = _q_of_policy(grid, np.broadcast_to(phi[j], (L, S, A)).copy(), policy)
        np.testing.assert_allclose(psi[..., j], Q, rtol=0, atol=1e-9)
    h = rng.normal(size=k)  # and any mix: psi h is Q^pi of Phi D h
    Q = _q_of_policy(grid, np.broadcast_to(np.tensordot(h, phi, 1), (L, S, A)).copy(), policy)
    np.testing.assert_allclose(psi @ h, Q, rtol=0, atol=1e-9)


def test_successor_features_of_one_policy_and_state_features(grid, rng):
    S, A = grid.n_states, grid.n_actions
    phi = rng.normal(size=(2, S))
    pol = rng.integers(A, size=S)
    psi = successor_features(grid, phi, pol)
    assert psi.shape == (S, A, 2)
    np.testing.assert_allclose(psi, successor_features(grid, np.repeat(phi[:, :, None], A, axis=2), pol[None])[0])


@pytest.mark.parametrize("features, policy, fragment", [
    (np.zeros((2, 3, 4)), np.zeros(25, dtype=int), "features must have shape"),
    (np.zeros((2, 25, 4)), np.zeros(24, dtype=int), "policy must have shape"),
    (np.zeros((2, 25, 4)), np.full(25, 7), "actions"),
    (np.zeros((2, 25, 4)), np.full((25, 4), 0.5), "sum"),
])
def test_successor_features_refuse_bad_inputs(grid, features, policy, fragment):
    with pytest.raises(ValidationError, match=fragment):
        successor_features(grid, features, policy)


def test_gpi_actions_are_greedy_on_the_best_library_values(rng):
    L, S, A, k, n = 3, 7, 4, 2, 5
    psi, H = rng.normal(size=(L, S, A, k)), rng.normal(size=(n, k))
    expected = np.argmax(np.max(np.einsum("lsak,nk->nlsa", psi, H), axis=1), axis=2)
    for block in (64, 8 * A * n, 2**20):  # blocks of one state, of one task chunk's row, of everything
        np.testing.assert_array_equal(gpi_actions(psi, H, block), expected)


def test_library_values_with_shared_and_per_task_starts(grid, rng):
    S, A, k = grid.n_states, grid.n_actions, 2
    phi = rng.normal(size=(k, S, A))
    pol = rng.integers(A, size=(3, S))
    psi = successor_features(grid, phi, pol)
    H = rng.normal(size=(4, k))
    rho = rng.dirichlet(np.ones(S), size=4)
    V = np.stack([fo.policy_evaluation(grid, np.broadcast_to(np.tensordot(h, phi, 1), (3, S, A)).copy(), pol) for h in H])
    np.testing.assert_allclose(library_values(psi, pol, H, np.full(S, 1 / S)), V.mean(axis=2), atol=1e-12)
    np.testing.assert_allclose(library_values(psi, pol, H, rho), np.einsum("ns,nls->nl", rho, V), atol=1e-12)


def test_improvement_step_is_a_policy_iteration_sweep(grid, rng):
    R = rng.normal(size=(3, grid.n_states, grid.n_actions))
    planner = get_planner(grid, "dense")
    pol = rng.integers(grid.n_actions, size=(3, grid.n_states))
    new, V = improve_policies(planner, R, pol)
    np.testing.assert_allclose(V, fo.policy_evaluation(grid, R, pol), atol=1e-12)
    assert np.all(fo.policy_evaluation(grid, R, new) >= V - 1e-12)
    optimal = fo.optimal_q(grid, R)[1]
    np.testing.assert_array_equal(improve_policies(planner, R, optimal)[0], optimal)  # a fixed point

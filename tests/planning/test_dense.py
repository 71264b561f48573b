"""The dense planner: batched dense systems, chunked, and its refusal of large sparse models."""

import numpy as np
import pytest
import scipy.sparse as sp

import factirl_opt as fo
from factirl_opt import planning
from factirl_opt.exceptions import ValidationError
from factirl_opt.planning import dense


def test_solves_reach_relative_residual_1e_12_in_chunks(monkeypatch, sparse_transitions, residual_of):
    rng = np.random.default_rng(3)
    mdp = fo.TabularMDP(sparse_transitions(rng, S=30, A=3), 0.95)
    pl = planning.get_planner(mdp, "dense")
    policy = rng.integers(0, 3, size=(5, 30))
    B = rng.standard_normal((5, 30, 2))
    whole = pl.system(policy).solve(B)
    monkeypatch.setattr(dense, "DENSE_CHUNK_BYTES", 8 * 30 * 30 * 2)  # two tasks per chunk
    chunked = pl.system(policy)
    np.testing.assert_allclose(chunked.solve(B), whole, rtol=1e-13, atol=1e-13)
    assert residual_of(mdp, chunked, policy, B) <= 1e-12


def test_policy_matrix_rows_are_the_policy_rows(sparse_transitions):
    rng = np.random.default_rng(4)
    mdp = fo.TabularMDP(sparse_transitions(rng, S=12, A=3), 0.9)
    pl = planning.get_planner(mdp, "dense")
    det = rng.integers(0, 3, size=(2, 12))
    P3 = mdp.transitions
    np.testing.assert_array_equal(pl.policy_matrix(det)[1, 5], P3[5, det[1, 5]])
    stoch = rng.dirichlet(np.ones(3), size=(2, 12))
    np.testing.assert_allclose(pl.policy_matrix(stoch)[0, 5], stoch[0, 5] @ P3[5])


def test_refuses_a_sparse_model_too_large_to_densify(monkeypatch):
    monkeypatch.setattr(dense, "DENSE_CHUNK_BYTES", 1024)
    grid = fo.GridWorld(5)
    with pytest.raises(ValidationError, match=r"dense planner needs the \(S, A, S\) = \(25, 4, 25\) transitions.*'sparse-lu' or 'auto'"):
        dense.DensePlanner(grid)
    dense.DensePlanner(fo.TabularMDP(grid.transitions, grid.gamma))  # a dense model is already dense

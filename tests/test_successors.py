"""Successor lists (Levine's toolkit, ELIRL) to and from TabularMDP."""

import numpy as np
import pytest
import scipy.sparse as sp

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError
from factirl_opt.datasets.objectworld import objectworld_transitions
from factirl_opt.mdp import from_successors, to_successors


def toolkit_objectworld_lists(n, determinism):
    """Objectworld successor lists as the MATLAB toolkit lays them out (1-based, K = 5).

    States ``(y - 1) n + x`` (y the row); the five successors of every action are the cells
    reached by stay, y + 1, x + 1, y - 1, x - 1 (clipped at the walls, so repeated there),
    with the action's own move at probability ``determinism`` and the others at
    ``(1 - determinism) / 4``.
    """
    S = n * n
    sa_s = np.zeros((S, 5, 5))
    for y in range(1, n + 1):
        for x in range(1, n + 1):
            s = (y - 1) * n + x
            land = [s, (min(n, y + 1) - 1) * n + x, (y - 1) * n + min(n, x + 1), (max(1, y - 1) - 1) * n + x,
                    (y - 1) * n + max(1, x - 1)]
            sa_s[s - 1] = np.array(land, dtype=float)[None, :]
    probs = np.full((5, 5), (1.0 - determinism) / 4.0)
    np.fill_diagonal(probs, determinism)
    sa_p = np.broadcast_to(probs, (S, 5, 5)).copy()
    return sa_s, sa_p


def test_toolkit_objectworld_equals_library_objectworld():
    n, det = 6, 0.7
    sa_s, sa_p = toolkit_objectworld_lists(n, det)
    mdp = from_successors(sa_s, sa_p, 0.9, index_base=1)
    assert mdp.is_sparse and mdp.n_states == n * n and mdp.n_actions == 5
    # toolkit actions (stay, down, right, up, left) -> library actions (stay, up, down, left, right)
    to_library = np.array([0, 2, 4, 1, 3])
    lib = objectworld_transitions(n, det).toarray().reshape(n * n, 5, n * n)
    got = mdp.transitions
    np.testing.assert_allclose(got, lib[:, to_library], rtol=0, atol=1e-15)
    np.testing.assert_allclose(got.sum(axis=2), 1.0, rtol=0, atol=1e-12)


def test_repeated_successors_are_summed_not_lost():
    # corner state 0 of a 2x2 grid: "up" and "left" both bounce back to 0
    sa_s = np.array([[[0, 0, 1]], [[1, 1, 1]]])
    sa_p = np.array([[[0.25, 0.5, 0.25]], [[0.2, 0.3, 0.5]]])
    mdp = from_successors(sa_s, sa_p, 0.5)
    np.testing.assert_array_equal(mdp.transitions, [[[0.75, 0.25]], [[0.0, 1.0]]])
    assert mdp.transition_matrix.nnz == 3


def test_gridworld_round_trip_and_one_based():
    grid = fo.GridWorld(size=4, p_success=0.8, gamma=0.95)
    sa_s, sa_p = to_successors(grid)
    assert sa_s.dtype == np.int64 and sa_s.shape == sa_p.shape and sa_s.shape[:2] == (16, 4)
    for base in (0, 1):
        back = from_successors(*to_successors(grid, index_base=base), grid.gamma, index_base=base)
        assert back.signature() == grid.signature()
    assert to_successors(grid, index_base=1)[0].min() == 1


def test_dense_model_and_zero_probability_padding():
    rng = np.random.default_rng(0)
    P = rng.random((3, 2, 3))
    P[0, 0, 1] = 0.0
    P /= P.sum(axis=2, keepdims=True)
    mdp = fo.TabularMDP(P, 0.9)
    sa_s, sa_p = to_successors(mdp)
    assert sa_s.shape == (3, 2, 3) and sa_p[0, 0, 2] == 0.0  # padded list
    sa_s[0, 0, 2] = 99  # padding carries no mass: not checked
    np.testing.assert_allclose(from_successors(sa_s, sa_p, 0.9).transitions, P, rtol=0, atol=1e-15)


@pytest.mark.parametrize(
    "sa_s, sa_p, gamma, base, match",
    [
        (np.zeros((2, 1)), np.ones((2, 1)), 0.9, 0, r"shape \(S, A, K\)"),
        (np.zeros((2, 1, 1)), np.ones((2, 1, 2)), 0.9, 0, "shape of sa_s"),
        (np.zeros((0, 1, 1)), np.ones((0, 1, 1)), 0.9, 0, "at least one"),
        (np.array([[[0, 2]], [[1, 1]]]), np.full((2, 1, 2), 0.5), 0.9, 0, r"\(s, a, k\) = \(0, 0, 1\)"),
        (np.array([[[1, 0]], [[1, 1]]]), np.full((2, 1, 2), 0.5), 0.9, 1, r"\(0, 0, 1\).*numbered 1..2"),
        (np.array([[[0, 0.5]], [[1, 1]]]), np.full((2, 1, 2), 0.5), 0.9, 0, "integer states"),
        (np.zeros((2, 1, 2), int), np.array([[[0.5, 0.4]], [[0.5, 0.5]]]), 0.9, 0, r"\(s, a\) = \(0, 0\) sums to 0.9"),
        (np.zeros((2, 1, 2), int), np.array([[[1.5, -0.5]], [[0.5, 0.5]]]), 0.9, 0, "nonnegative"),
        (np.zeros((2, 1, 2), int), np.array([[[np.nan, 1]], [[0.5, 0.5]]]), 0.9, 0, "finite"),
        (np.zeros((2, 1, 1), int), np.ones((2, 1, 1)), 1.0, 0, "gamma"),
        (np.zeros((2, 1, 1), int), np.ones((2, 1, 1)), 0.9, 2, "index_base"),
        (np.zeros((2, 1, 1), int), np.ones((2, 1, 1)), 0.9, True, "index_base"),
    ],
)
def test_errors(sa_s, sa_p, gamma, base, match):
    with pytest.raises(ValidationError, match=match):
        from_successors(sa_s, sa_p, gamma, index_base=base)


def test_to_successors_errors():
    with pytest.raises(ValidationError, match="TabularMDP"):
        to_successors(np.eye(2))
    with pytest.raises(ValidationError, match="index_base"):
        to_successors(fo.GridWorld(size=2), index_base=-1)


def test_sparse_input_is_csr():
    sa_s, sa_p = toolkit_objectworld_lists(3, 1.0)
    mdp = from_successors(sa_s, sa_p, 0.9, index_base=1)
    assert sp.issparse(mdp.transition_matrix) and mdp.transition_matrix.format == "csr"

"""TabularMDP validation and the grid world's dynamics (DESIGN section 2)."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import FactIRLError, ValidationError

UP, DOWN, LEFT, RIGHT = range(4)


def reference_grid(size, p):
    """Independent construction of DESIGN section 2's dynamics, move by move."""
    S = size * size
    P = np.zeros((S, 4, S))
    moves = {UP: (-1, 0), DOWN: (1, 0), LEFT: (0, -1), RIGHT: (0, 1)}
    for r in range(size):
        for c in range(size):
            s = r * size + c
            dest = {a: (r + dr) * size + (c + dc) for a, (dr, dc) in moves.items() if 0 <= r + dr < size and 0 <= c + dc < size}
            for a in range(4):
                if a in dest:
                    P[s, a, dest[a]] += p
                    for t in dest.values():
                        P[s, a, t] += (1 - p) / len(dest)
                else:
                    for t in dest.values():
                        P[s, a, t] += 1 / len(dest)
    return P


@pytest.mark.parametrize("size, p", [(2, 0.7), (3, 0.7), (5, 0.0), (4, 1.0), (10, 0.7)])
def test_grid_matches_independent_reference(size, p):
    mdp = fo.GridWorld(size=size, p_success=p)
    np.testing.assert_allclose(mdp.transitions, reference_grid(size, p), atol=1e-15)
    np.testing.assert_allclose(mdp.transitions.sum(axis=2), 1.0, atol=1e-12)
    assert mdp.n_states == size * size and mdp.n_actions == 4 and mdp.n_params == 4 * size * size


def test_grid_hand_computed_corner_edge_interior(grid3):
    P = grid3.transitions
    # corner (0, 0) = state 0: feasible down -> 3, right -> 1
    assert P[0, DOWN, 3] == pytest.approx(0.7 + 0.3 / 2)
    assert P[0, DOWN, 1] == pytest.approx(0.3 / 2)
    assert P[0, UP, 3] == pytest.approx(0.5) and P[0, UP, 1] == pytest.approx(0.5)  # into the wall
    assert P[0, LEFT, 3] == pytest.approx(0.5) and P[0, LEFT, 1] == pytest.approx(0.5)
    assert np.count_nonzero(P[0, UP]) == 2
    # edge (0, 1) = state 1: feasible down -> 4, left -> 0, right -> 2
    assert P[1, LEFT, 0] == pytest.approx(0.7 + 0.1)
    assert P[1, LEFT, 2] == pytest.approx(0.1) and P[1, LEFT, 4] == pytest.approx(0.1)
    np.testing.assert_allclose(P[1, UP, [0, 2, 4]], 1 / 3)
    assert P[1, UP, 1] == 0.0  # never stays put
    # interior (1, 1) = state 4
    assert P[4, UP, 1] == pytest.approx(0.7 + 0.075)
    np.testing.assert_allclose(P[4, UP, [3, 5, 7]], 0.075)
    assert P[4, RIGHT, 5] == pytest.approx(0.775)
    assert P[4, :, 4].sum() == 0.0


def test_grid_defaults_and_repr():
    g = fo.GridWorld()
    assert (g.size, g.p_success, g.gamma) == (10, 0.7, 0.9)
    assert "GridWorld(size=10" in repr(g)
    assert not g.transitions.flags.writeable


def test_state_cell_round_trip(rng):
    g = fo.GridWorld(size=4)
    for s in range(g.n_states):
        r, c = g.state_to_cell(s)
        assert g.cell_to_state(r, c) == s
        assert (r, c) == divmod(s, 4)
    states = rng.integers(0, 16, size=10)
    rows, cols = g.state_to_cell(states)
    np.testing.assert_array_equal(g.cell_to_state(rows, cols), states)
    assert g.state_to_cell(13) == (3, 1)
    assert g.cell_to_state(0, 3) == 3


@pytest.mark.parametrize("state", [16, -1, 2.0])
def test_state_to_cell_rejects_bad_states(state):
    with pytest.raises(ValidationError, match=r"states must be integers in \[0, 16\)"):
        fo.GridWorld(size=4).state_to_cell(state)


@pytest.mark.parametrize("row, col, name", [(4, 0, "row"), (0, -1, "col"), (1.5, 0, "row")])
def test_cell_to_state_rejects_bad_cells(row, col, name):
    with pytest.raises(ValidationError, match=rf"{name} must be integers in \[0, 4\)"):
        fo.GridWorld(size=4).cell_to_state(row, col)


# --- TabularMDP ------------------------------------------------------------------------------


def test_tabular_mdp_accepts_valid_and_copies(rng):
    P = rng.dirichlet(np.ones(3), size=(3, 2))
    mdp = fo.TabularMDP(P, 0.5)
    P[0, 0] = 0.0
    assert mdp.transitions[0, 0].sum() == pytest.approx(1.0)  # defensive copy
    assert mdp.transitions_flat.shape == (6, 3)
    assert (mdp.n_states, mdp.n_actions, mdp.gamma) == (3, 2, 0.5)
    assert fo.TabularMDP(mdp.transitions.tolist(), 0).gamma == 0.0


def _valid(rng):
    return rng.dirichlet(np.ones(3), size=(3, 2))


@pytest.mark.parametrize(
    "make, fragment",
    [
        (lambda P: P[0], r"shape \(S, A, S\) \(or be a scipy.sparse \(S\*A, S\) matrix\); got ndim=2, shape \(2, 3\)"),
        (lambda P: P[None], r"got ndim=4"),
        (lambda P: np.ones((3, 2, 4)) / 4, r"got \(3, 2, 4\) \(last axis 4 != 3 states\)"),
        (lambda P: np.zeros((0, 2, 0)), r"at least one state and one action; got shape \(0, 2, 0\)"),
        (lambda P: np.where(np.arange(3) == 1, np.nan, P), r"must be finite; found nan at index \(0, 0, 1\)"),
        (lambda P: np.where(np.arange(3) == 2, np.inf, P), r"must be finite; found inf at index \(0, 0, 2\)"),
        (lambda P: P * np.array([2.0, -1.0, 0.0]) + np.array([0, 0, 0]), r"nonnegative; found -.* at index \(0, 0, 1\)"),
        (lambda P: P * 1.01, r"must sum to 1 .*row \(s=\d, a=\d\) sums to 1\.01"),
        (lambda P: "abc", r"numeric array"),
    ],
)
def test_tabular_mdp_bad_transitions(rng, make, fragment):
    with pytest.raises(ValidationError, match=fragment):
        fo.TabularMDP(make(_valid(rng)), 0.9)


def test_tabular_mdp_row_sum_tolerance(rng):
    P = _valid(rng)
    P[1, 1, 0] += 1e-11  # within 1e-9: accepted
    fo.TabularMDP(P, 0.9)
    P[1, 1, 0] += 1e-7
    with pytest.raises(ValidationError, match=r"row \(s=1, a=1\)"):
        fo.TabularMDP(P, 0.9)


@pytest.mark.parametrize("gamma, fragment", [(1.0, "1.0"), (-0.1, "-0.1"), (1.5, "1.5"), (np.nan, "nan"), ("high", "'high'"), (None, "None")])
def test_tabular_mdp_bad_gamma(rng, gamma, fragment):
    with pytest.raises(ValidationError, match=r"gamma must .*" + fragment):
        fo.TabularMDP(_valid(rng), gamma)


@pytest.mark.parametrize("size", [1, 0, -3, 2.5, True, "10", None])
def test_grid_bad_size(size):
    with pytest.raises(ValidationError, match=r"size must be an integer >= 2; got " + repr(size).replace(".", r"\.")):
        fo.GridWorld(size=size)


@pytest.mark.parametrize("p", [-0.1, 1.5, "x", None, np.nan])
def test_grid_bad_p_success(p):
    with pytest.raises(ValidationError, match=r"p_success must be a probability in \[0, 1\]; got " + repr(p).replace(".", r"\.")):
        fo.GridWorld(size=3, p_success=p)


def test_grid_bad_gamma():
    with pytest.raises(ValidationError, match=r"gamma must be a finite number in \[0, 1\); got 1\.0"):
        fo.GridWorld(size=3, gamma=1.0)


def test_validation_errors_are_library_and_value_errors():
    with pytest.raises(FactIRLError):
        fo.GridWorld(size=1)
    with pytest.raises(ValueError):
        fo.GridWorld(size=1)

"""TabularMDP: validation, immutability, pickling, signatures; the grid world's dynamics (docs/maths.md §9)."""

import ast
import copy
import pickle
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import factirl_opt as fo
from factirl_opt.mdp import tabular as mdp_module
from factirl_opt import planning
from factirl_opt.exceptions import FactIRLError, ValidationError

UP, DOWN, LEFT, RIGHT = range(4)


def reference_grid(size, p):
    """Independent construction of the grid's dynamics, move by move."""
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


# --- sparse dynamics: validation and the grid world --------------------------------------------


def sparse_rows(rows):
    return sp.csr_matrix(np.array(rows, dtype=float))


@pytest.mark.parametrize(
    "rows, fragment",
    [
        ([[1, 0], [0.5, 0.5], [1.5, -0.5], [0, 1]], r"nonnegative; found -0.5 in row 2 \(s=1, a=0\), column 1"),
        ([[1, 0], [0.5, 0.5], [0, 1], [np.nan, 1]], r"finite; found nan in row 3 \(s=1, a=1\), column 0"),
        ([[1, 0], [0.5, 0.4], [0, 1], [0, 1]], r"row 1 \(s=0, a=1\) sums to 0\.9"),
        ([[1, 0], [0, 1], [0, 0], [0, 1]], r"row 2 \(s=1, a=0\) sums to 0\.0"),
        ([[1, 0, 0], [0, 1, 0]], r"shape \(S\*A, S\) with S, A >= 1; got \(2, 3\)"),
        ([[1, 0], [0, 1], [1, 0]], r"shape \(S\*A, S\) with S, A >= 1; got \(3, 2\)"),
    ],
)
def test_sparse_transitions_validation(rows, fragment):
    with pytest.raises(ValidationError, match=fragment):
        fo.TabularMDP(sparse_rows(rows), 0.9)


def test_sparse_transitions_kept_sparse_and_canonical():
    P = sp.csr_matrix(([0.5, 0.5, 1.0, 0.0, 1.0, 1.0], ([0, 0, 1, 2, 2, 3], [1, 0, 0, 0, 1, 0])), shape=(4, 2))
    mdp = fo.TabularMDP(P, 0.5)
    assert mdp.is_sparse and sp.issparse(mdp.transition_matrix) and np.shares_memory(mdp.csr().data, mdp.transition_matrix.data)
    assert mdp.n_states == 2 and mdp.n_actions == 2
    assert mdp.transition_matrix.nnz == 5  # the explicit zero is dropped
    np.testing.assert_array_equal(mdp.transitions, P.toarray().reshape(2, 2, 2))


def reference_grid_sparse(size, p):
    """The grid's dynamics cell by cell, as a dict {(s*A + a, s'): probability}."""
    moves = fo.GridWorld.MOVES
    out = {}
    for r in range(size):
        for c in range(size):
            s = r * size + c
            dest = {a: (r + dr) * size + (c + dc) for a, (dr, dc) in enumerate(moves) if 0 <= r + dr < size and 0 <= c + dc < size}
            for a in range(len(moves)):
                row = s * len(moves) + a
                for t in dest.values():
                    out[row, t] = out.get((row, t), 0.0) + ((1 - p) if a in dest else 1.0) / len(dest)
                if a in dest:
                    out[row, dest[a]] += p
    return out


@pytest.mark.parametrize("size, p", [(2, 0.7), (5, 0.0), (7, 1.0), (12, 0.7)])
def test_grid_sparse_dynamics_equal_cell_by_cell_reference(size, p):
    P = fo.GridWorld(size, p_success=p).transition_matrix.tocoo()
    ref = {k: v for k, v in reference_grid_sparse(size, p).items() if v != 0.0}
    got = dict(zip(zip(P.row.tolist(), P.col.tolist()), P.data.tolist()))
    assert set(got) == set(ref)
    assert max(abs(got[k] - ref[k]) for k in ref) <= 1e-15


@pytest.mark.parametrize("sparse", [True, False])
def test_complex_dynamics_are_refused(sparse):
    P = np.eye(2)[:, None, :].repeat(2, axis=1).astype(complex)  # (2, 2, 2), real part valid
    P[0, 0] += 1e-3j
    dynamics = sp.csr_matrix(P.reshape(4, 2)) if sparse else P
    with pytest.raises(ValidationError, match="complex"):
        fo.TabularMDP(dynamics, 0.9)


# --- immutability, pickling, signatures ------------------------------------------------------


def models():
    rng = np.random.default_rng(3)
    dense = fo.TabularMDP(rng.dirichlet(np.ones(4), size=(4, 2)), 0.8)
    return {"dense": dense, "sparse": fo.TabularMDP(sp.csr_matrix(dense.transition_matrix), 0.8), "grid": fo.GridWorld(13)}


@pytest.mark.parametrize("kind", ["dense", "sparse", "grid"])
@pytest.mark.parametrize("name", ["gamma", "_P", "_dense", "size", "new_attribute"])
def test_models_are_immutable(kind, name):
    model = models()[kind]
    fo.optimal_q(model, np.ones((model.n_states, model.n_actions)))
    with pytest.raises(ValidationError, match=f"{type(model).__name__} is immutable: cannot set '{name}'; build a new model"):
        setattr(model, name, 0.5)
    with pytest.raises(ValidationError, match="is immutable: cannot delete 'gamma'"):
        del model.gamma
    assert model.gamma == 0.8 if kind != "grid" else model.gamma == 0.9


@pytest.mark.parametrize("kind", ["dense", "sparse", "grid"])
def test_dynamics_arrays_are_read_only(kind):
    model = models()[kind]
    P = model.transition_matrix
    arrays = (P.data, P.indices, P.indptr) if sp.issparse(P) else (P, model.transitions)
    arrays += (model.csr().data, model.csr().indices, model.csr().indptr, model.transitions)
    for arr in arrays:
        with pytest.raises(ValueError, match="read-only"):
            arr[0] = 0


@pytest.mark.parametrize("kind", ["dense", "sparse", "grid"])
@pytest.mark.parametrize("how", ["pickle", "deepcopy"])
def test_planned_models_pickle_and_copy_without_their_caches(kind, how):
    model = models()[kind]
    R = np.random.default_rng(4).standard_normal((3, model.n_states, model.n_actions))
    Q, pol = fo.optimal_q(model, R, planner="sparse-lu")
    fo.sample_demonstrations(model, R, 1, 3, 0)
    model.transitions, model.csr()
    twin = pickle.loads(pickle.dumps(model)) if how == "pickle" else copy.deepcopy(model)
    assert set(vars(twin)) <= {"_P", "_dense", "_shape", "gamma", "size", "p_success"}  # no cache carried
    assert type(twin) is type(model) and twin.signature() == model.signature()
    Q2, pol2 = fo.optimal_q(twin, R, planner="sparse-lu")
    np.testing.assert_array_equal(Q2, Q)
    np.testing.assert_array_equal(pol2, pol)
    with pytest.raises(ValidationError, match="immutable"):
        twin.gamma = 0.5
    P = twin.transition_matrix
    with pytest.raises(ValueError, match="read-only"):
        (P.data if sp.issparse(P) else P)[0] = 0


def optimal_values(model):
    return fo.optimal_q(model, np.ones((model.n_states, model.n_actions)), planner="sparse-lu")[0]


def test_a_planned_model_goes_to_a_process_pool():
    model = models()["grid"]
    expected = optimal_values(model)
    with ProcessPoolExecutor(2) as pool:
        for got in pool.map(optimal_values, [model, model]):
            np.testing.assert_array_equal(got, expected)


def test_signature_keys_are_defined_once():
    grid = fo.GridWorld(3)
    assert tuple(grid.signature()) == mdp_module.SIGNATURE_KEYS
    other = fo.GridWorld(3, gamma=0.5)
    with pytest.raises(ValidationError, match=r"fitted on another MDP \(gamma: fitted 0\.9, given 0\.5\)"):
        mdp_module.check_signature(grid.signature(), other)


def test_validation_does_not_import_the_model_module():
    tree = ast.parse(Path(fo.__file__).with_name("_validation.py").read_text())
    type_only = [node for node in tree.body if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)]
    skipped = {id(n) for block in type_only for n in ast.walk(block)}  # annotations only, never run
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and id(node) not in skipped}
    assert not any(name and name.endswith("mdp") for name in imported)
    with pytest.raises(ValidationError, match="mdp must be a TabularMDP; got dict"):
        fo.optimal_q({}, np.zeros((2, 2)))

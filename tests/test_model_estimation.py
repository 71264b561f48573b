"""Models estimated from logged transitions: layouts, the Dirichlet posterior mean against a
brute-force reference, recovery of a known model, held-out log-likelihood, and every refusal."""

import numpy as np
import pytest
import scipy.sparse as sp

import factirl_opt as fo
from factirl_opt.mdp import estimation as model_estimation
from factirl_opt.exceptions import ValidationError
from factirl_opt.mdp.estimation import (
    as_transitions,
    estimate_mdp,
    sample_transitions,
    transition_counts,
    transition_log_likelihood,
)


def _reference(transitions, S, A, prior_rows, c):
    """Posterior mean by a Python loop over transitions and rows (dense (S, A, S))."""
    n = np.zeros((S, A, S))
    for s, a, t in transitions:
        n[s, a, t] += 1
    P = np.empty((S, A, S))
    for s in range(S):
        for a in range(A):
            total = n[s, a].sum()
            if total == 0 and c == 0:
                P[s, a] = prior_rows[s, a]
            else:
                P[s, a] = (n[s, a] + c * prior_rows[s, a]) / (total + c)
    return P


def _self_loop_rows(S, A):
    rows = np.zeros((S, A, S))
    rows[np.arange(S), :, np.arange(S)] = 1.0
    return rows


@pytest.fixture
def small_data(rng):
    # 4 states, 3 actions; state 3 is never left and action 2 of state 0 never tried
    tr = rng.integers(0, [3, 2, 4], size=(40, 3))
    return np.vstack([tr, [[0, 1, 3], [2, 0, 2]]])


# ----------------------------------------------------------------------------- layouts


def test_layouts_give_the_same_transitions():
    ep = np.array([[0, 1], [2, 0], [1, 1]])
    expected = np.array([[0, 1, 2], [2, 0, 1]])
    np.testing.assert_array_equal(as_transitions([ep]), expected)  # consecutive steps, last action dropped
    with_final = np.vstack([expected, [[1, 1, 3]]])
    np.testing.assert_array_equal(as_transitions([(ep, 3)]), with_final)
    np.testing.assert_array_equal(as_transitions([[ep, np.int64(3)]]), with_final)
    np.testing.assert_array_equal(as_transitions([with_final]), with_final)  # an (L, 3) episode
    np.testing.assert_array_equal(as_transitions(with_final), with_final)  # (N, 3) rows
    np.testing.assert_array_equal(as_transitions(with_final.tolist()), with_final)  # a list of rows
    np.testing.assert_array_equal(as_transitions(with_final.astype(float)), with_final)  # whole-number floats
    np.testing.assert_array_equal(as_transitions(np.stack([ep, ep])), np.vstack([expected, expected]))  # (m, L, 2)
    np.testing.assert_array_equal(as_transitions(with_final[None]), with_final)  # (m, L, 3)
    mixed = as_transitions([ep.tolist(), (ep, 3), np.array([[0, 0]]), with_final])  # length-1 episode gives none
    np.testing.assert_array_equal(mixed, np.vstack([expected, with_final, with_final]))
    assert mixed.dtype == np.int64


def test_episodes_from_sample_demonstrations_are_accepted():
    mdp = fo.GridWorld(3)
    demos = fo.sample_demonstrations(mdp, np.zeros((2, 9, 4)), 5, 6, rng=0)  # two tasks, each (5, 6, 2)
    tr = as_transitions(demos, 9, 4)  # the library's demos_per_task, as they are
    assert tr.shape == (50, 3)
    np.testing.assert_array_equal(tr[:5, 2], demos[0][0, 1:, 0])
    np.testing.assert_array_equal(tr[25:30, 2], demos[1][0, 1:, 0])
    np.testing.assert_array_equal(as_transitions(demos[1], 9, 4), tr[25:])
    assert np.all(mdp.transitions[tr[:, 0], tr[:, 1], tr[:, 2]] > 0)


@pytest.mark.parametrize(
    "data, match",
    [
        (np.array([[0, 1], [1, 0]]), r"shape \(2, 2\) holds \(state, action\) steps without next states"),
        ([], "data is empty"),
        (np.zeros((0, 3), dtype=int), r"no transitions \(shape \(0, 3\)\)"),
        ([np.array([[0, 1]]), np.array([[1, 0]])], "holds no transitions.*length 1"),
        ([np.zeros((3, 4), dtype=int)], r"episode 0 must be an \(L, 3\) array.*got shape \(3, 4\)"),
        ([np.zeros((0, 2), dtype=int)], r"episode 0 must be .*with L >= 1, or an \(episode, final_state\) pair; got shape \(0, 2\)"),
        ([np.zeros((0, 3), dtype=int)], "holds no transitions"),
        ([(np.zeros((0, 2), dtype=int), 1)], r"episode 0 is an \(episode, final_state\) pair.*got \(0, 2\)"),
        ([(np.zeros((2, 3), dtype=int), 1)], r"episode 0 is an \(episode, final_state\) pair.*got \(2, 3\)"),
        (np.zeros(5, dtype=int), r"got an array of shape \(5,\)"),
        (np.zeros((2, 2, 4), dtype=int), r"data, episodes 0 to 1: a 3-d array of episodes must have shape \(m, L, 2\) or \(m, L, 3\); got \(2, 2, 4\)"),
        ([np.zeros((1, 2), dtype=int), np.zeros((2, 2, 4), dtype=int)], r"data, episodes 1 to 2: a 3-d array"),
        ([np.zeros((2, 2, 2), dtype=int), np.zeros((2, 5), dtype=int)], r"data, episode 2 must be an \(L, 3\) array"),
        (np.zeros((3, 1, 2), dtype=int), "holds no transitions"),
        (np.array([[[0, 1, 2]], [[0, 1, 2.5]]]), r"data, transition 1: next state 2.5 is not an integer"),
        ([1, [2, 3]], "ragged or non-numeric"),
        ([[0, 1, 2], [0, 1]], "ragged or non-numeric"),
        ([0, 1, 2], "got a list that is neither"),
        (np.array([["a", "b", "c"]]), "must hold integers; got dtype <U1"),
        ([np.array([[0.5, 1, 2]])], r"transition 0: state 0.5 is not an integer"),
        (np.array([[0, 1, 2], [0, 1, np.nan]]), "row 1: next state nan is not an integer"),
        (np.array([[0, 1, 2], [0, -1, 2]]), r"row 1: action -1 is out of range \[0, 2\)"),
        (np.array([[4, 1, 2]]), r"row 0: state 4 is out of range \[0, 4\)"),
        (np.array([[0, 1, 7]]), r"row 0: next state 7 is out of range \[0, 4\)"),
        (np.array([[0, 2, 1]]), r"row 0: action 2 is out of range \[0, 2\)"),
    ],
)
def test_bad_data_is_refused(data, match):
    with pytest.raises(ValidationError, match=match):
        as_transitions(data, 4, 2)
    with pytest.raises(ValidationError, match=match):
        estimate_mdp(data, 4, 2, 0.9)


def test_demonstrations_plus_exploration_transitions():
    mdp = fo.GridWorld(3)
    demos = fo.sample_demonstrations(mdp, np.zeros((2, 9, 4)), 4, 5, rng=0)
    for M in (0, 30):
        extra = sample_transitions(mdp, M, rng=1)
        tr = as_transitions([*demos, extra], 9, 4)
        np.testing.assert_array_equal(tr, np.vstack([as_transitions(demos), extra]))
        assert estimate_mdp([*demos, extra], 9, 4, 0.9).n_states == 9


def test_unbounded_values_must_be_nonnegative():
    np.testing.assert_array_equal(as_transitions([[10**6, 5, 3]]), [[10**6, 5, 3]])
    with pytest.raises(ValidationError, match=r"row 0: next state -3 is not a valid index"):
        as_transitions([[1, 0, -3]])
    with pytest.raises(ValidationError, match=r"row 0: state 1e\+20 is not a valid index"):
        as_transitions([[1e20, 0, 3]])


def test_a_single_pair_must_be_wrapped():
    with pytest.raises(ValidationError, match=r"single \(episode, final_state\) pair: give a list of episodes"):
        as_transitions((np.array([[0, 1], [1, 0]]), 2))


def test_transition_counts():
    counts = transition_counts([[0, 1, 1], [0, 1, 1], [1, 0, 0]], 2, 2)
    assert sp.isspmatrix_csr(counts) and counts.shape == (4, 2)
    np.testing.assert_array_equal(counts.toarray(), [[0, 0], [0, 2], [1, 0], [0, 0]])


# ----------------------------------------------------------------------------- estimates


@pytest.mark.parametrize("c", [0.0, 0.5, 3.0])
@pytest.mark.parametrize("prior", ["self-loop", "uniform", "model"])
def test_posterior_mean_matches_brute_force(small_data, rng, prior, c):
    S, A = 4, 3
    if prior == "model":
        rows = rng.random((S, A, S)) * (rng.random((S, A, S)) < 0.6)
        rows[..., 0] += 0.1
        rows /= rows.sum(axis=2, keepdims=True)
        arg = fo.TabularMDP(rows, 0.5)
    else:
        rows = _self_loop_rows(S, A) if prior == "self-loop" else np.full((S, A, S), 1.0 / S)
        arg = prior
    mdp = estimate_mdp(small_data, S, A, 0.95, prior=arg, pseudo_count=c)
    assert mdp.is_sparse and mdp.gamma == 0.95
    np.testing.assert_allclose(mdp.transitions, _reference(small_data, S, A, rows, c), rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.asarray(mdp.transition_matrix.sum(axis=1)).ravel(), 1.0, atol=1e-14)


def test_untried_pairs_get_the_prior_mean(small_data):
    S, A = 4, 3
    for c in (0.0, 1.0):
        loop = estimate_mdp(small_data, S, A, 0.9, "self-loop", pseudo_count=c).transitions
        np.testing.assert_array_equal(loop[3], np.eye(S)[[3, 3, 3]])  # a state never left is absorbing
        np.testing.assert_array_equal(loop[0, 2], np.eye(S)[0])
        np.testing.assert_allclose(estimate_mdp(small_data, S, A, 0.9, "uniform", pseudo_count=c).transitions[3], 0.25)


def test_sparsity_of_the_priors():
    tr = np.array([[0, 0, 1], [1, 1, 0]])
    S, A = 50, 2
    assert estimate_mdp(tr, S, A, 0.9).transition_matrix.nnz == 2 + S * A  # counts + self-loops (one shared)
    dense = estimate_mdp(tr, S, A, 0.9, "uniform", pseudo_count=1.0).transition_matrix
    assert dense.nnz == S * A * S
    untried = estimate_mdp(tr, S, A, 0.9, "uniform", pseudo_count=0.0).transition_matrix
    assert untried.nnz == 2 + (S * A - 2) * S  # tried rows keep their observed support
    np.testing.assert_array_equal(untried[0].toarray(), np.eye(S)[[1]])


def test_uniform_prior_over_the_entry_limit_is_refused(monkeypatch):
    tr = np.array([[0, 0, 1]])
    monkeypatch.setattr(model_estimation, "UNIFORM_ENTRY_LIMIT", 100)
    with pytest.raises(ValidationError, match=r"dense: here 20 rows x 10 states = 200 entries, over the limit of 100"):
        estimate_mdp(tr, 10, 2, 0.9, "uniform")
    with pytest.raises(ValidationError, match="19 rows x 10 states = 190 entries"):
        estimate_mdp(tr, 10, 2, 0.9, "uniform", pseudo_count=0)
    assert estimate_mdp(tr, 10, 2, 0.9, "self-loop").n_states == 10


def test_dense_and_sparse_prior_models_agree(small_data):
    g = fo.GridWorld(2)  # 4 states, 4 actions
    tr = small_data.copy()
    dense = fo.TabularMDP(g.transitions, 0.9)
    a = estimate_mdp(tr, 4, 4, 0.9, prior=g, pseudo_count=2.0).transitions
    b = estimate_mdp(tr, 4, 4, 0.9, prior=dense, pseudo_count=2.0).transitions
    np.testing.assert_array_equal(a, b)


def test_recovers_a_known_model_with_enough_data():
    mdp = fo.GridWorld(3, p_success=0.6)
    few, many = sample_transitions(mdp, 18_000, rng=1), sample_transitions(mdp, 1_800_000, rng=2)
    for c in (1.0, 0.0):
        err_few, err_many = (np.abs(estimate_mdp(tr, 9, 4, 0.9, pseudo_count=c).transitions - mdp.transitions).max() for tr in (few, many))
        assert err_many < 1e-2 < err_few  # recovered to 1e-2 with 50 000 draws per (s, a) row, not with 500
    mle = estimate_mdp(many, 9, 4, 0.9, pseudo_count=0)
    assert mle.transition_matrix.nnz == mdp.transition_matrix.nnz  # no spurious successors


def test_sample_transitions_follow_the_model():
    mdp = fo.GridWorld(3, p_success=0.5)
    tr = sample_transitions(mdp, 200_000, rng=np.random.default_rng(3))
    assert tr.shape == (200_000, 3) and tr.dtype == np.int64
    assert np.all(mdp.transitions[tr[:, 0], tr[:, 1], tr[:, 2]] > 0)
    np.testing.assert_array_equal(sample_transitions(mdp, 50, rng=4), sample_transitions(fo.TabularMDP(mdp.transitions, 0.9), 50, rng=4))
    assert sample_transitions(mdp, 0, rng=0).shape == (0, 3)
    with pytest.raises(ValidationError, match="n_transitions must be an integer >= 0"):
        sample_transitions(mdp, -1)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"n_states": 0}, "n_states must be an integer >= 1"),
        ({"n_actions": 2.0}, "n_actions must be an integer >= 1"),
        ({"gamma": 1.0}, r"gamma must be a finite number in \[0, 1\)"),
        ({"prior": "laplace"}, r"prior must be one of \('self-loop', 'uniform'\) or a TabularMDP"),
        ({"prior": fo.GridWorld(2)}, "the prior model has 4 states and 4 actions; the data's model has 4 and 2"),
        ({"pseudo_count": -1.0}, "pseudo_count must be a finite number >= 0"),
        ({"pseudo_count": np.inf}, "pseudo_count must be a finite number >= 0"),
    ],
)
def test_bad_arguments_are_refused(kwargs, match):
    args = {"data": [[0, 1, 2]], "n_states": 4, "n_actions": 2, "gamma": 0.9} | kwargs
    with pytest.raises(ValidationError, match=match):
        estimate_mdp(**args)


# ----------------------------------------------------------------------------- log-likelihood


def test_log_likelihood_matches_brute_force(rng):
    mdp = estimate_mdp(sample_transitions(fo.GridWorld(3), 500, rng=0), 9, 4, 0.9, "uniform", pseudo_count=0.5)
    held_out = sample_transitions(fo.GridWorld(3), 300, rng=1)
    expected = np.array([np.log(mdp.transitions[s, a, t]) for s, a, t in held_out])
    for model in (mdp, fo.TabularMDP(mdp.transitions, 0.9)):
        np.testing.assert_allclose(transition_log_likelihood(model, held_out, reduction="none"), expected, rtol=1e-13)
        assert transition_log_likelihood(model, held_out) == pytest.approx(expected.sum(), rel=1e-13)
        assert transition_log_likelihood(model, held_out, "mean") == pytest.approx(expected.mean(), rel=1e-13)
    ep = held_out[:4, :2]
    assert transition_log_likelihood(mdp, [(ep, 0)]) == pytest.approx(
        np.log(mdp.transitions[ep[:, 0], ep[:, 1], np.append(ep[1:, 0], 0)]).sum())


def test_zero_probability_transitions_give_minus_infinity():
    mdp = estimate_mdp([[0, 0, 1]], 3, 1, 0.9, pseudo_count=0)  # P(1 | 0, 0) = 1
    for model in (mdp, fo.TabularMDP(mdp.transitions, 0.9)):
        logp = transition_log_likelihood(model, [[0, 0, 1], [0, 0, 2]], reduction="none")
        np.testing.assert_array_equal(logp, [0.0, -np.inf])
        assert transition_log_likelihood(model, [[0, 0, 2], [1, 0, 1]]) == -np.inf
    assert transition_log_likelihood(mdp, [[0, 0, 1], [1, 0, 1], [2, 0, 2]]) == 0.0


def test_log_likelihood_refusals():
    mdp = fo.GridWorld(2)
    with pytest.raises(ValidationError, match="reduction must be 'sum', 'mean' or 'none'; got 'max'"):
        transition_log_likelihood(mdp, [[0, 0, 1]], reduction="max")
    with pytest.raises(ValidationError, match=r"row 0: next state 4 is out of range \[0, 4\)"):
        transition_log_likelihood(mdp, [[0, 0, 4]])
    with pytest.raises(ValidationError, match="mdp must be a TabularMDP"):
        transition_log_likelihood(np.eye(2), [[0, 0, 1]])


def test_absurd_sizes_are_refused_before_allocating(monkeypatch):
    one = np.array([[0, 0, 1]])
    with pytest.raises(ValidationError, match=r"n_states x n_actions = 1000000000 x 1000 = 1000000000000 \(s, a\) rows: "
                                              r"the model needs about 8.94e\+04 GiB whatever the data, more than this machine's"):
        estimate_mdp(one, 10**9, 1000, 0.9)
    monkeypatch.setattr(model_estimation, "_memory_bytes", lambda: 2**20)  # a 1 MiB machine: 1e4 rows need 0.9 MiB
    assert estimate_mdp(one, 2500, 4, 0.9).n_states == 2500
    for fn in (lambda: estimate_mdp(one, 10**4, 2, 0.9), lambda: transition_counts(one, 10**4, 2)):
        with pytest.raises(ValidationError, match="more than this machine's 0.000977 GiB of memory; n_states and n_actions are"):
            fn()

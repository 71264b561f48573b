"""Every planner against the dense route and long value iteration, on sparse MDPs that are not grids.

The models here have absorbing states, self-loops and 1 to 4 successors per (state, action);
each is built sparse (scipy CSR, (S*A, S)) and, for the reference, dense ((S, A, S) array).
The dense planner on the dense copy is the reference route ("today's arithmetic"); every
planner in :func:`factirl_opt.available_planners` on the sparse copy must agree with it to
1e-9 (relative), and every solve must reach a relative residual of 1e-12.
"""

import tracemalloc

import numpy as np
import pytest
import scipy.sparse as sp

import factirl_opt as fo
from factirl_opt import planning
from factirl_opt.exceptions import FactIRLError, ValidationError

PLANNERS = fo.available_planners()
BETA = 5.0
EPS = 1e-6


def random_sparse_transitions(rng, S=40, A=3, n_absorbing=3):
    """(S*A, S) CSR: absorbing states, self-loops, 1-4 successors per row (Dirichlet weights)."""
    absorbing = set(rng.choice(S, n_absorbing, replace=False).tolist())
    rows, cols, vals = [], [], []
    for s in range(S):
        for a in range(A):
            if s in absorbing:
                succ, p = [s], [1.0]
            else:
                k = int(rng.integers(1, 5))
                succ = rng.choice(S, k, replace=False)
                if rng.random() < 0.3 and s not in succ:
                    succ[0] = s  # a self-loop
                p = rng.dirichlet(np.ones(k))
            rows += [s * A + a] * len(succ)
            cols += list(succ)
            vals += list(p)
    return sp.csr_matrix((vals, (rows, cols)), shape=(S * A, S))


@pytest.fixture(params=[0, 1])
def twins(request):
    """(sparse model, dense copy of the same dynamics) of a random non-grid MDP (gamma 0.9 / 0.95)."""
    rng = np.random.default_rng(100 + request.param)
    P = random_sparse_transitions(rng, S=40 + 10 * request.param, A=3 + request.param)
    gamma = (0.9, 0.95)[request.param]
    S, A = P.shape[1], P.shape[0] // P.shape[1]
    return fo.TabularMDP(P, gamma), fo.TabularMDP(P.toarray().reshape(S, A, S), gamma)


def assert_rel(x, ref, tol=1e-9):
    scale = max(float(np.max(np.abs(ref))), 1e-300)
    assert float(np.max(np.abs(np.asarray(x) - ref))) <= tol * scale


def test_available_planners_lists_auto_first():
    assert PLANNERS[0] == "auto" and {"dense", "sparse-lu"} <= set(PLANNERS)


def test_unknown_planner_lists_the_available_ones(grid3):
    with pytest.raises(ValidationError, match="unknown planner 'lu'; available: " + ", ".join(PLANNERS)):
        fo.optimal_q(grid3, np.zeros((9, 4)), planner="lu")
    with pytest.raises(ValidationError, match="unknown planner 3"):
        fo.policy_matching_loss(grid3, np.zeros((9, 4)), np.full(9, 1 / 9), np.full((9, 4), 0.25), planner=3)


def test_auto_resolves_at_the_measured_crossover():
    small = fo.GridWorld(int(np.sqrt(planning.AUTO_DENSE_MAX_STATES)))
    assert small.n_states <= planning.AUTO_DENSE_MAX_STATES
    assert planning.get_planner(small).name == "dense"
    big = fo.GridWorld(int(np.sqrt(planning.AUTO_DENSE_MAX_STATES)) + 1)
    assert planning.get_planner(big).name == "sparse-lu"


@pytest.mark.parametrize("name", PLANNERS)
def test_q_star_matches_dense_route_and_value_iteration(twins, name):
    sparse_mdp, dense_mdp = twins
    R = np.random.default_rng(1).standard_normal((4, sparse_mdp.n_states, sparse_mdp.n_actions))
    Q_ref, pol_ref = fo.optimal_q(dense_mdp, R, planner="dense")
    Q, pol = fo.optimal_q(sparse_mdp, R, planner=name)
    assert_rel(Q, Q_ref)
    np.testing.assert_array_equal(pol, pol_ref)
    assert_rel(Q, fo.value_iteration(sparse_mdp, R, tol=1e-13, planner=name))
    # warm start from a wrong policy, single task
    Q1, _ = fo.optimal_q(sparse_mdp, R[0], policy=np.argmin(Q_ref[0], axis=1), planner=name)
    assert_rel(Q1, Q_ref[0])


@pytest.mark.parametrize("name", PLANNERS)
def test_policy_values_deterministic_and_stochastic(twins, name):
    sparse_mdp, dense_mdp = twins
    rng = np.random.default_rng(2)
    S, A = sparse_mdp.n_states, sparse_mdp.n_actions
    R = rng.standard_normal((3, S, A))
    det = rng.integers(0, A, size=(3, S))
    stoch = rng.dirichlet(np.ones(A), size=(3, S))
    for policy in (det, stoch):
        V_ref = fo.policy_evaluation(dense_mdp, R, policy, planner="dense")
        assert_rel(fo.policy_evaluation(sparse_mdp, R, policy, planner=name), V_ref)
        # the Bellman equation itself: V = R_pi + gamma P_pi V
        w = stoch if policy is stoch else np.eye(A)[det]
        P3 = dense_mdp.transitions
        np.testing.assert_allclose(V_ref, np.einsum("nsa,nsa->ns", w, R) + dense_mdp.gamma * np.einsum("nsa,sat,nt->ns", w, P3, V_ref),
                                   rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", PLANNERS)
def test_loss_and_gradient_match_dense_route(twins, name, make_statistics):
    sparse_mdp, dense_mdp = twins
    rng = np.random.default_rng(3)
    mu, pi_hat = make_statistics(rng, sparse_mdp, 4)
    R = rng.standard_normal((4, sparse_mdp.n_states, sparse_mdp.n_actions))
    L_ref, G_ref = fo.policy_matching_loss(dense_mdp, R, mu, pi_hat, BETA, planner="dense")
    L, G = fo.policy_matching_loss(sparse_mdp, R, mu, pi_hat, BETA, planner=name)
    assert_rel(L, L_ref)
    assert_rel(G, G_ref)
    # warm at nearby rewards (the sparse planner's cache and low-rank updates), then back
    _, pol = fo.optimal_q(sparse_mdp, R, planner=name)
    for R2 in (R + 1e-2 * rng.standard_normal(R.shape), R):
        L_ref, G_ref = fo.policy_matching_loss(dense_mdp, R2, mu, pi_hat, BETA, planner="dense")
        L, G = fo.policy_matching_loss(sparse_mdp, R2, mu, pi_hat, BETA, policy=pol, planner=name)
        assert_rel(L, L_ref)
        assert_rel(G, G_ref)


def test_grid_loss_gradient_and_score_match_dense_route(make_statistics):
    grid = fo.GridWorld(8)
    dense = fo.TabularMDP(grid.transitions, grid.gamma)
    rng = np.random.default_rng(4)
    mu, pi_hat = make_statistics(rng, grid, 3)
    R = rng.standard_normal((3, grid.n_states, 4))
    L_ref, G_ref = fo.policy_matching_loss(dense, R, mu, pi_hat, BETA, planner="dense")
    R_hat = R + 0.3 * rng.standard_normal(R.shape)
    dev_ref = fo.deviation(dense, R, R_hat, planner="dense")
    for name in PLANNERS:
        L, G = fo.policy_matching_loss(grid, R, mu, pi_hat, BETA, planner=name)
        assert_rel(L, L_ref)
        assert_rel(G, G_ref)
        assert_rel(fo.deviation(grid, R, R_hat, planner=name), dev_ref)


@pytest.mark.parametrize("name", ["sparse-lu", "dense"])
def test_gradient_matches_finite_differences_on_sparse_model(twins, name, make_statistics, tie_free_rewards):
    sparse_mdp, _ = twins
    rng = np.random.default_rng(5)
    mu, pi_hat = make_statistics(rng, sparse_mdp, 1)
    R = tie_free_rewards(rng, sparse_mdp, (sparse_mdp.n_states, sparse_mdp.n_actions))
    _, G = fo.policy_matching_loss(sparse_mdp, R, mu[0], pi_hat[0], BETA, planner=name)
    coords = [tuple(c) for c in rng.integers(0, R.shape, size=(12, 2))]
    for idx in coords:
        Rp, Rm = R.copy(), R.copy()
        Rp[idx] += EPS
        Rm[idx] -= EPS
        fd = (fo.policy_matching_loss(sparse_mdp, Rp, mu[0], pi_hat[0], BETA, planner=name)[0][0]
              - fo.policy_matching_loss(sparse_mdp, Rm, mu[0], pi_hat[0], BETA, planner=name)[0][0]) / (2 * EPS)
        assert abs(G[0][idx] - fd) <= 1e-6 * max(1.0, float(np.max(np.abs(G))))


@pytest.mark.parametrize("name", PLANNERS)
@pytest.mark.parametrize("kind", ["deterministic", "stochastic"])
def test_adjoint_is_the_transpose_of_tangent(twins, name, kind):
    sparse_mdp, _ = twins
    rng = np.random.default_rng(6)
    n, S, A = 3, sparse_mdp.n_states, sparse_mdp.n_actions
    pl = planning.get_planner(sparse_mdp, name)
    policy = rng.integers(0, A, size=(n, S)) if kind == "deterministic" else rng.dirichlet(np.ones(A), size=(n, S))
    system = pl.system(policy)
    dR, G = rng.standard_normal((n, S, A)), rng.standard_normal((n, S, A))
    lhs = np.sum(planning.tangent(pl, system, policy, dR) * G, axis=(1, 2))
    rhs = np.sum(dR * planning.adjoint(pl, system, policy, G), axis=(1, 2))
    np.testing.assert_allclose(lhs, rhs, rtol=1e-11)
    # k directions at once equal k single directions
    dRk = rng.standard_normal((n, S, A, 2))
    dQk = planning.tangent(pl, system, policy, dRk)
    for j in range(2):
        np.testing.assert_allclose(dQk[..., j], planning.tangent(pl, system, policy, dRk[..., j]), rtol=1e-12, atol=1e-12)


def policy_matrix_dense(mdp, policy):
    """Dense (n, S, S) P_pi of deterministic (n, S) or stochastic (n, S, A) policies (test reference)."""
    P3 = mdp.transitions
    w = policy if policy.ndim == 3 else np.eye(mdp.n_actions)[policy]
    return np.einsum("nsa,sat->nst", w, P3)


def relative_residuals(mdp, system, policy, B):
    M = np.eye(mdp.n_states)[None] - mdp.gamma * policy_matrix_dense(mdp, policy)
    X, XT = system.solve(B), system.solve_transpose(B)
    res = np.linalg.norm(np.einsum("nst,nt...->ns...", M, X) - B, axis=1) / np.linalg.norm(B, axis=1)
    res_t = np.linalg.norm(np.einsum("nts,nt...->ns...", M, XT) - B, axis=1) / np.linalg.norm(B, axis=1)
    return max(res.max(), res_t.max())


@pytest.mark.parametrize("name", PLANNERS)
@pytest.mark.parametrize("gamma", [0.9, 0.99])
def test_every_solve_reaches_relative_residual_1e_12(name, gamma):
    rng = np.random.default_rng(7)
    mdp = fo.TabularMDP(random_sparse_transitions(rng, S=60, A=3), gamma)
    pl = planning.get_planner(mdp, name)
    n, S, A = 3, mdp.n_states, mdp.n_actions
    pol = rng.integers(0, A, size=(n, S))
    for policy in (pol, rng.dirichlet(np.ones(A), size=(n, S))):
        system = pl.system(policy)
        for B in (rng.standard_normal((n, S)), rng.standard_normal((n, S, 4))):
            assert relative_residuals(mdp, system, policy, B) <= 1e-12
    # a nearby policy solved from the first one's factorisation (sparse planner: low-rank update)
    near, idx = pol.copy(), rng.choice(S, 5, replace=False)
    near[:, idx] = (near[:, idx] + 1) % A
    system = pl.system(near, hints=pl.system(pol).solvers)
    assert relative_residuals(mdp, system, near, rng.standard_normal((n, S, 3))) <= 1e-12
    if pl.name == "sparse-lu":  # the updates themselves were accurate: no fallback to a new LU
        assert all(isinstance(s, planning._UpdatedFactor) and s._fresh is None for s in system.solvers)


def test_low_rank_update_falls_back_to_a_fresh_factorisation(monkeypatch):
    rng = np.random.default_rng(8)
    mdp = fo.TabularMDP(random_sparse_transitions(rng, S=30, A=3), 0.9)
    pl = planning.get_planner(mdp, "sparse-lu")
    pol = rng.integers(0, 3, size=(1, 30))
    near = pol.copy()
    near[0, :3] = (near[0, :3] + 1) % 3
    system = pl.system(near, hints=pl.system(pol).solvers)
    monkeypatch.setattr(planning, "RESIDUAL_TOL", -1.0)  # no residual is good enough: always refactorise
    B = rng.standard_normal((1, 30))
    assert relative_residuals(mdp, system, near, B) <= 1e-12
    assert isinstance(system.solvers[0]._fresh, planning._TaskFactor)


def test_factorisation_cache_hits_are_exact_and_bounded(monkeypatch, make_statistics):
    grid = fo.GridWorld(12)
    pl = planning.get_planner(grid, "sparse-lu")
    pl.clear_cache()
    rng = np.random.default_rng(9)
    R = rng.standard_normal((6, grid.n_states, 4))
    mu, pi_hat = make_statistics(rng, grid, 6)
    first = fo.policy_matching_loss(grid, R, mu, pi_hat, planner="sparse-lu")
    _, pol = fo.optimal_q(grid, R, planner="sparse-lu")
    n_cached = len(pl._cache)
    again = fo.policy_matching_loss(grid, R, mu, pi_hat, policy=pol, planner="sparse-lu")
    assert len(pl._cache) == n_cached  # all hits: nothing new factorised
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    # a budget of one group: evictions keep the accounting exact and the results unchanged
    monkeypatch.setattr(planning, "FACTOR_CACHE_BYTES", 1)
    pl.clear_cache()
    bounded = fo.policy_matching_loss(grid, R, mu, pi_hat, planner="sparse-lu")
    assert len(pl._groups) == 1
    base, keys, update = next(iter(pl._groups.values()))
    assert set(pl._cache) == set(keys) | ({update} - {None})
    assert pl._cache_bytes == base.nbytes + (0 if update is None else pl._cache[update].nbytes)
    for a, b in zip(first, bounded):
        assert_rel(b, a, 1e-12)
    planning.clear_caches(grid)
    assert not pl._cache and pl._cache_bytes == 0


def test_ordering_is_fixed_for_grids_and_per_policy_for_dense_unions():
    grid = planning.get_planner(fo.GridWorld(6), "sparse-lu")
    assert grid.permc_spec == "NATURAL"
    np.testing.assert_array_equal(np.sort(grid.order), np.arange(36))
    np.testing.assert_array_equal(grid.order[grid.inverse_order], np.arange(36))
    # actions with different successors: the union of their patterns is ~A times denser
    mixed = planning.get_planner(fo.TabularMDP(random_sparse_transitions(np.random.default_rng(10), S=30, A=4), 0.9), "sparse-lu")
    assert mixed.permc_spec == "MMD_AT_PLUS_A"
    np.testing.assert_array_equal(mixed.order, np.arange(30))


def test_value_iteration_raises_when_it_does_not_converge(grid3):
    slow = fo.GridWorld(3, gamma=0.9999)
    with pytest.raises(FactIRLError, match=r"value iteration did not reach tol=1e-12 in 50 sweeps"):
        fo.value_iteration(slow, np.ones((9, 4)), max_iter=50)


def test_policy_iteration_sweep_limit(twins):
    sparse_mdp, _ = twins
    R = np.random.default_rng(11).standard_normal((2, sparse_mdp.n_states, sparse_mdp.n_actions))
    Q, pol = fo.optimal_q(sparse_mdp, R, planner="dense")
    with pytest.raises(FactIRLError, match="policy iteration did not converge in 1 sweeps"):
        fo.optimal_q(sparse_mdp, R, policy=np.argmin(Q, axis=2), max_iter=1, planner="dense")


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
    assert mdp.is_sparse and sp.issparse(mdp.transition_matrix) and mdp.csr() is mdp.transition_matrix
    assert mdp.n_states == 2 and mdp.n_actions == 2
    assert mdp.transition_matrix.nnz == 5  # the explicit zero is dropped
    np.testing.assert_array_equal(mdp.transitions, P.toarray().reshape(2, 2, 2))


def reference_grid_sparse(size, p):
    """DESIGN section 2's dynamics cell by cell, as a dict {(s*A + a, s'): probability}."""
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


def test_large_grid_never_allocates_s_a_s():
    """64x64 (S = 4096): building, planning, sampling and scoring stay far below one (S, A, S)
    array (S*A*S*8 bytes = 512 MiB): traced peak under 200 MB (SuperLU's own C allocations,
    not traced, are one sparse factorisation per task)."""
    tracemalloc.start()
    try:
        grid = fo.GridWorld(64)
        S, A = grid.n_states, grid.n_actions
        rng = np.random.default_rng(12)
        R = rng.standard_normal((2, S, A))
        fo.optimal_q(grid, R)
        demos = fo.sample_demonstrations(grid, R, 2, 5, rng)
        mu, pi_hat = fo.empirical_statistics(grid, demos)
        fo.policy_matching_loss(grid, R + 0.1, mu, pi_hat)
        fo.deviation(grid, R, R + 0.1 * rng.standard_normal(R.shape))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 200 * 2**20 < S * A * S * 8
    assert "_dense_cache" not in grid.__dict__

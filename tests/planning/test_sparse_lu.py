"""The sparse planner: residuals of its solves, its fixed ordering, memory at scale, thread caches."""

import threading
import tracemalloc

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt import planning

PLANNERS = fo.available_planners()


@pytest.mark.parametrize("name", PLANNERS)
@pytest.mark.parametrize("gamma", [0.9, 0.99])
def test_every_solve_reaches_relative_residual_1e_12(name, gamma, sparse_transitions, residual_of):
    rng = np.random.default_rng(7)
    mdp = fo.TabularMDP(sparse_transitions(rng, S=60, A=3), gamma)
    pl = planning.get_planner(mdp, name)
    n, S, A = 3, mdp.n_states, mdp.n_actions
    pol = rng.integers(0, A, size=(n, S))
    for policy in (pol, rng.dirichlet(np.ones(A), size=(n, S))):
        system = pl.system(policy)
        for B in (rng.standard_normal((n, S)), rng.standard_normal((n, S, 4))):
            assert residual_of(mdp, system, policy, B) <= 1e-12
    # a nearby policy solved from the first one's factorisation (sparse planner: low-rank update)
    near, idx = pol.copy(), rng.choice(S, 5, replace=False)
    near[:, idx] = (near[:, idx] + 1) % A
    system = pl.system(near, hints=pl.system(pol).solvers)
    assert residual_of(mdp, system, near, rng.standard_normal((n, S, 3))) <= 1e-12
    if pl.name == "sparse-lu":  # the updates themselves were accurate: no fallback to a new LU
        assert all(isinstance(s, planning.UpdatedFactor) and s.fresh is None for s in system.solvers)


def test_ordering_is_fixed_for_grids_and_per_policy_for_dense_unions(sparse_transitions):
    grid = planning.get_planner(fo.GridWorld(6), "sparse-lu")
    assert grid.permc_spec == "NATURAL"
    np.testing.assert_array_equal(np.sort(grid.order), np.arange(36))
    np.testing.assert_array_equal(grid.order[grid.inverse_order], np.arange(36))
    # actions with different successors: the union of their patterns is ~A times denser
    mixed = planning.get_planner(fo.TabularMDP(sparse_transitions(np.random.default_rng(10), S=30, A=4), 0.9), "sparse-lu")
    assert mixed.permc_spec == "MMD_AT_PLUS_A"
    np.testing.assert_array_equal(mixed.order, np.arange(30))


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


def test_each_thread_has_its_own_factorisations():
    grid = fo.GridWorld(13)
    pl = planning.get_planner(grid, "sparse-lu")
    R = np.random.default_rng(5).standard_normal((2, grid.n_states, 4))
    Q, _ = fo.optimal_q(grid, R, planner="sparse-lu")
    mine, seen = pl.factor_cache, {}

    def other():
        seen["Q"] = fo.optimal_q(grid, R, planner="sparse-lu")[0]
        seen["cache"] = pl.factor_cache

    thread = threading.Thread(target=other)
    thread.start()
    thread.join()
    assert seen["cache"] is not mine and len(seen["cache"]) > 0 and len(mine) > 0
    np.testing.assert_array_equal(seen["Q"], Q)  # computed alone, exactly as here
    planning.clear_caches(grid)  # every thread's cache
    assert len(seen["cache"]) == 0 and len(mine) == 0


def test_stochastic_system_assembly_is_the_sparse_product_bit_for_bit():
    """The union-pattern assembly of a stochastic policy's M^T equals the sparse product it
    replaces (values and pattern), also for a policy with zeros (without the vanishing entries)."""
    from factirl_opt.datasets.objectworld import make_objectworld

    rng = np.random.default_rng(3)
    for mdp in (fo.GridWorld(7), make_objectworld(size=8, n_inner=2, n_outer=2, object_density=0.15, rng=rng).mdp()):
        planner = planning.SparseLUPlanner(mdp)
        assert planner._union_nnz is not None
        pi = rng.dirichlet(np.ones(mdp.n_actions), size=mdp.n_states)
        fast = planner.matrix_transpose(pi)
        planner._union_nnz = None  # the sparse product, same ordering
        slow = planner.matrix_transpose(pi)
        np.testing.assert_array_equal(fast.indptr, slow.indptr)
        np.testing.assert_array_equal(fast.indices, slow.indices)
        np.testing.assert_array_equal(fast.data, slow.data)
        planner._union_nnz = 1
        # zeros: one deterministic row, and a soft policy whose probabilities mostly underflow
        pi[0] = np.eye(mdp.n_actions)[0]
        logits = rng.normal(scale=400.0, size=pi.shape)
        soft = np.exp(logits - logits.max(axis=1, keepdims=True))
        for policy in (pi, soft / soft.sum(axis=1, keepdims=True)):
            assert policy.min() == 0.0
            _assert_assembly_is_the_product(planner, policy)
    # actions with distinct successors (deterministic moves): entries vanish with the policy's zeros
    mdp = fo.GridWorld(6, p_success=1.0)
    planner = planning.SparseLUPlanner(mdp)
    assert planner._union_nnz is None  # too dense a union for a fixed order: the pattern forced here
    planner._union_nnz, planner._pattern = 1, planner._stochastic_pattern()
    pi = rng.dirichlet(np.ones(mdp.n_actions), size=mdp.n_states)
    pi[::2] = np.eye(mdp.n_actions)[rng.integers(mdp.n_actions, size=len(pi[::2]))]
    full = planner.matrix_transpose(np.full_like(pi, 1.0 / mdp.n_actions))
    assert _assert_assembly_is_the_product(planner, pi).nnz < full.nnz


def _assert_assembly_is_the_product(planner, policy):
    """The planner's M^T of ``policy`` equals the sparse product's bit for bit; returns it."""
    union_nnz = planner._union_nnz
    fast = planner.matrix_transpose(policy)
    planner._union_nnz = None
    try:
        slow = planner.matrix_transpose(policy)
    finally:
        planner._union_nnz = union_nnz
    np.testing.assert_array_equal(fast.indptr, slow.indptr)
    np.testing.assert_array_equal(fast.indices, slow.indices)
    np.testing.assert_array_equal(fast.data, slow.data)
    return fast


def test_q_from_values_is_the_backup_route_bit_for_bit(sparse_transitions):
    # the sparse planner adds gamma P V to R from the product's own layout: the values of R + gamma P V
    rng = np.random.default_rng(14)
    mdp = fo.TabularMDP(sparse_transitions(rng, S=50, A=4), 0.95)
    pl = planning.get_planner(mdp, "sparse-lu")
    for n in (1, 7):
        R = 10.0 * rng.standard_normal((n, mdp.n_states, mdp.n_actions))
        V = 100.0 * rng.standard_normal((n, mdp.n_states))
        Q = pl.q_from_values(R, V)
        np.testing.assert_array_equal(Q, R + pl.gamma * pl.backup(V))
        assert Q.flags.c_contiguous and Q.shape == R.shape


def test_solutions_keep_the_layout_of_the_permuting_subscript(sparse_transitions):
    # a fit sums over these solutions (e.g. the MCE gradient's pull to features): the same values in
    # another memory order change those sums in their last bits, and a long fit's results with them
    rng = np.random.default_rng(15)
    mdp = fo.TabularMDP(sparse_transitions(rng, S=40, A=3), 0.9)
    pl = planning.get_planner(mdp, "sparse-lu")
    system = pl.system(rng.dirichlet(np.ones(3), size=(4, mdp.n_states)))
    for B in (rng.standard_normal((4, mdp.n_states)), rng.standard_normal((4, mdp.n_states, 2))):
        for X in (system.solve(B), system.solve_transpose(B)):
            assert X.strides == B[:, pl.inverse_order].strides

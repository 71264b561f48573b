"""Low-rank (Woodbury) updates: accurate, verified, and a fresh factorisation when they are not."""

import numpy as np

import factirl_opt as fo
from factirl_opt import planning
from factirl_opt.planning import lowrank


def test_low_rank_update_falls_back_to_a_fresh_factorisation(monkeypatch, sparse_transitions, residual_of):
    rng = np.random.default_rng(8)
    mdp = fo.TabularMDP(sparse_transitions(rng, S=30, A=3), 0.9)
    pl = planning.get_planner(mdp, "sparse-lu")
    pol = rng.integers(0, 3, size=(1, 30))
    near = pol.copy()
    near[0, :3] = (near[0, :3] + 1) % 3
    system = pl.system(near, hints=pl.system(pol).solvers)
    monkeypatch.setattr(lowrank, "RESIDUAL_TOL", -1.0)  # no residual is good enough: always refactorise
    B = rng.standard_normal((1, 30))
    assert residual_of(mdp, system, near, B) <= 1e-12
    assert isinstance(system.solvers[0].fresh, planning.TaskFactor)


def test_updates_are_used_within_the_rank_limit_only(sparse_transitions, residual_of):
    rng = np.random.default_rng(9)
    mdp = fo.TabularMDP(sparse_transitions(rng, S=50, A=3), 0.95)
    pl = planning.get_planner(mdp, "sparse-lu")
    pol = rng.integers(0, 3, size=(2, 50))
    hints = pl.system(pol).solvers
    for k, kind in ((lowrank.UPDATE_MAX_RANK, planning.UpdatedFactor), (lowrank.UPDATE_MAX_RANK + 1, planning.TaskFactor)):
        near = pol.copy()
        near[:, :k] = (near[:, :k] + 1) % 3
        system = pl.system(near, hints=hints)
        assert all(type(s) is kind for s in system.solvers)
        assert residual_of(mdp, system, near, rng.standard_normal((2, 50, 2))) <= 1e-12


def test_solves_take_each_task_right_hand_side_contiguous_whatever_the_layout(sparse_transitions):
    """Each task's right-hand side (S,) or (S, k) is solved C-contiguous, whatever the layout of
    B: a low-rank update's products round differently on strided vectors (a rank-1 update's
    ``Z^T b`` is a dot product; a Fortran-ordered (n, S) B, e.g. a transposed product, has
    strided rows)."""
    rng = np.random.default_rng(10)
    mdp = fo.TabularMDP(sparse_transitions(rng, S=1024, A=3), 0.95)
    pl = planning.get_planner(mdp, "sparse-lu")
    pol = rng.integers(0, 3, size=(10, 1024))
    near = pol.copy()
    near[:, 0] = (near[:, 0] + 1) % 3  # rank-1 updates
    system = pl.system(near, hints=pl.system(pol).solvers)
    assert all(type(s) is planning.UpdatedFactor for s in system.solvers)
    for B in (rng.standard_normal((10, 1024)), rng.standard_normal((10, 1024, 3))):
        for transpose in (False, True):
            blocks = np.stack([s.solve(np.ascontiguousarray(b[pl.order]), transpose) for s, b in zip(system.solvers, B)])
            for layout in (B, np.asfortranarray(B)):
                X = system.solve_transpose(layout) if transpose else system.solve(layout)
                np.testing.assert_array_equal(X, blocks[:, pl.inverse_order])

"""MCE with kept factorisations (sparse LU): chord steps, the refined adjoint, reuse between evaluations.

Every result is checked against the plain computation with fresh factorisations (guarded
Newton, one new LU per step and one for the adjoint), which the references of test_mce.py check.
"""

import numpy as np
from helpers import random_statistics
import pytest

import factirl_opt as fo
from factirl_opt.objectives import MCEObjective
from factirl_opt.objectives import mce as mce_module
from factirl_opt.planning import get_planner, planning_budget

BETA = 2.0


@pytest.fixture
def grid6():
    return fo.GridWorld(size=6, p_success=0.7, gamma=0.9)


def _fresh(planner, R, mu, pi_hat):
    """Loss and gradient with fresh factorisations only (no chord step, no refinement)."""
    point = mce_module._forward(planner, R, mu, pi_hat, BETA)
    assert point.kept is None
    return point.loss, mce_module._gradient(planner, point)


def test_chord_steps_give_the_soft_values_of_plain_newton_to_the_tolerance(rng, grid6):
    pl = get_planner(grid6, "sparse-lu")
    R = 3.0 * rng.standard_normal((3, grid6.n_states, grid6.n_actions))
    Q, V, log_pi = mce_module.soft_values(pl, R, BETA)
    Q_c, V_c, log_pi_c, kept = mce_module._soft_values(pl, R, BETA, kept=[None] * 3)
    assert all(k is not None for k in kept)
    np.testing.assert_allclose(V_c, V, rtol=0, atol=1e-11 * np.abs(V).max())
    np.testing.assert_allclose(log_pi_c, log_pi, rtol=0, atol=1e-11)
    _, TV, _ = mce_module.soft_backup(pl, R, V_c, BETA)
    assert np.all(np.abs(TV - V_c).max(axis=1) <= 1e-12 * np.maximum(1.0, np.abs(V_c).max(axis=1)))


def test_warm_start_with_kept_factorisations_takes_fewer_factorisations_same_values(rng, grid6):
    """From the last values and factorisations of nearby rewards: the same soft values, and chord
    steps instead of most factorisations."""
    pl = get_planner(grid6, "sparse-lu")
    R = rng.standard_normal((4, grid6.n_states, grid6.n_actions))
    _, V, _, kept = mce_module._soft_values(pl, R, BETA, kept=[None] * 4)
    R2 = R + 1e-3 * rng.standard_normal(R.shape)
    calls = []
    original = mce_module._newton_step

    def counting(planner, R_, *args):
        calls.append(len(R_))
        return original(planner, R_, *args)

    mce_module._newton_step = counting
    try:
        _, V2, log_pi2, _ = mce_module._soft_values(pl, R2, BETA, V0=V, kept=list(kept))
    finally:
        mce_module._newton_step = original
    _, V_ref, log_pi_ref = mce_module.soft_values(pl, R2, BETA)
    np.testing.assert_allclose(V2, V_ref, rtol=0, atol=1e-11 * np.abs(V_ref).max())
    np.testing.assert_allclose(log_pi2, log_pi_ref, rtol=0, atol=1e-11)
    assert sum(calls) < 4  # most tasks converge on chord steps alone


def test_soft_values_of_a_batch_are_each_task_alone_bit_for_bit(rng, grid6, monkeypatch):
    """Tasks of one batch that take different steps (chord steps accepted for some, refused for
    others, Newton steps for a task without a kept factorisation) get the values each task gets
    alone: the steps over part of a batch and over all of it do the same arithmetic."""
    pl = get_planner(grid6, "sparse-lu")
    scales = np.array([0.1, 1.0, 3.0, 10.0])[:, None, None]
    R0 = scales * rng.standard_normal((4, grid6.n_states, grid6.n_actions))
    _, V0, _, kept = mce_module._soft_values(pl, R0, BETA, kept=[None] * 4)
    kept[1] = None
    R = R0 + np.array([1e-3, 0.3, 1.0, 3.0])[:, None, None] * rng.standard_normal(R0.shape)
    steps = []
    chord, newton = mce_module._chord_step, mce_module._newton_step

    def counted_chord(*args):
        ok, *step = chord(*args)
        steps.append(("chord", len(ok), int(ok.sum())))
        return (ok, *step)

    def counted_newton(*args):
        steps.append(("newton", len(args[2]), len(args[2])))
        return newton(*args)

    monkeypatch.setattr(mce_module, "_chord_step", counted_chord)
    monkeypatch.setattr(mce_module, "_newton_step", counted_newton)
    batch = mce_module._soft_values(pl, R, BETA, V0, kept=list(kept))
    assert ("newton", 4, 4) not in steps and any(kind == "newton" for kind, _, _ in steps)
    assert any(kind == "chord" and 0 < accepted < n for kind, n, accepted in steps)  # part of a batch
    assert any(kind == "chord" and accepted == n == 4 for kind, n, accepted in steps)  # all of it
    for i in range(4):
        alone = mce_module._soft_values(pl, R[i:i + 1], BETA, V0[i:i + 1], kept=[kept[i]])
        for x, y in zip(alone[:3], batch[:3]):
            np.testing.assert_array_equal(x, y[i:i + 1])


def test_refined_adjoint_of_a_batch_is_each_task_alone_bit_for_bit(rng, grid6):
    """Tasks of one batch refined for different numbers of sweeps get each task's solution alone."""
    pl = get_planner(grid6, "sparse-lu")
    R0 = 2.0 * rng.standard_normal((3, grid6.n_states, grid6.n_actions))
    _, _, _, kept = mce_module._soft_values(pl, R0, BETA, kept=[None] * 3)
    R = R0 + np.array([1e-6, 1e-4, 1e-2])[:, None, None] * rng.standard_normal(R0.shape)
    pi = np.exp(mce_module.soft_values(pl, R, BETA)[2])
    B = rng.standard_normal((3, grid6.n_states))
    z, converged, sweeps = mce_module.refined_adjoint_solve(pl, kept, pi, B)
    assert converged.all()
    alone = [mce_module.refined_adjoint_solve(pl, [kept[i]], pi[i:i + 1], B[i:i + 1]) for i in range(3)]
    assert len({s for _, _, s in alone}) > 1 and sweeps == max(s for _, _, s in alone)
    for i, (z_i, converged_i, _) in enumerate(alone):
        assert converged_i.all()
        np.testing.assert_array_equal(z_i, z[i:i + 1])


def test_refined_adjoint_equals_the_fresh_one(rng, grid6):
    """The adjoint refined on a factorisation of a nearby policy equals the fresh solve."""
    pl = get_planner(grid6, "sparse-lu")
    pi = rng.dirichlet(np.ones(grid6.n_actions), size=(3, grid6.n_states))
    near = pi + 1e-2 * rng.dirichlet(np.ones(grid6.n_actions), size=pi.shape[:2])
    near /= near.sum(axis=2, keepdims=True)
    B = rng.standard_normal((3, grid6.n_states))
    z, converged, sweeps = mce_module.refined_adjoint_solve(pl, pl.system(near).solvers, pi, B)
    z_ref = pl.system(pi).solve_transpose(B)
    assert converged.all() and 1 <= sweeps <= mce_module.ADJOINT_MAX_REFINE
    np.testing.assert_allclose(z, z_ref, rtol=0, atol=1e-12 * np.abs(z_ref).max())


def test_refined_adjoint_from_a_nearby_solution_takes_fewer_sweeps_same_solution(rng, grid6):
    pl = get_planner(grid6, "sparse-lu")
    pi = rng.dirichlet(np.ones(grid6.n_actions), size=(3, grid6.n_states))
    near = pi + 1e-2 * rng.dirichlet(np.ones(grid6.n_actions), size=pi.shape[:2])
    near /= near.sum(axis=2, keepdims=True)
    B = rng.standard_normal((3, grid6.n_states))
    solvers = pl.system(near).solvers
    z_ref = pl.system(pi).solve_transpose(B)
    _, _, sweeps = mce_module.refined_adjoint_solve(pl, solvers, pi, B)
    z, converged, sweeps0 = mce_module.refined_adjoint_solve(pl, solvers, pi, B, z0=z_ref * (1 + 1e-8))
    assert converged.all() and sweeps0 < sweeps
    np.testing.assert_allclose(z, z_ref, rtol=0, atol=1e-12 * np.abs(z_ref).max())


def test_refined_adjoint_reports_a_factorisation_too_far_to_converge(rng, grid6):
    pl = get_planner(grid6, "sparse-lu")
    pi = rng.dirichlet(np.ones(grid6.n_actions), size=(2, grid6.n_states))
    far = np.zeros_like(pi)
    far[:, :, 0] = 1.0  # a deterministic policy's system: far from pi's
    B = rng.standard_normal((2, grid6.n_states))
    _, converged, _ = mce_module.refined_adjoint_solve(pl, pl.system(far).solvers, pi, B)
    assert not converged.any()


def test_gradient_falls_back_to_a_fresh_factorisation_and_keeps_it(rng, grid6):
    pl = get_planner(grid6, "sparse-lu")
    mu, pi_hat = random_statistics(rng, grid6, 2)
    R = rng.standard_normal((2, grid6.n_states, grid6.n_actions))
    loss, grad = _fresh(pl, R, mu, pi_hat)
    point = mce_module._forward(pl, R, mu, pi_hat, BETA, kept=[None, None])
    far = np.zeros((2, grid6.n_states, grid6.n_actions))
    far[:, :, 0] = 1.0
    point.kept = list(pl.system(far).solvers)  # too far: the refinement stalls
    stale = list(point.kept)
    grad_k = mce_module._gradient(pl, point)
    np.testing.assert_allclose(point.loss, loss, rtol=1e-12)
    np.testing.assert_allclose(grad_k, grad, rtol=1e-10, atol=1e-12)
    assert all(new is not old for new, old in zip(point.kept, stale))


def test_objective_reusing_factorisations_matches_fresh_losses_and_gradients(rng, grid6):
    """An objective's evaluations along a path (kept factorisations, chord steps, refined
    adjoints) agree with fresh computations at every point."""
    pl = get_planner(grid6, "sparse-lu")
    mu, pi_hat = random_statistics(rng, grid6, 3)
    obj = MCEObjective(grid6, mu, pi_hat, BETA, planner="sparse-lu")
    R = rng.standard_normal((3, grid6.n_states, grid6.n_actions))
    for step in range(6):
        rows = np.arange(3) if step % 2 == 0 else np.array([0, 2])
        loss, grad = obj.loss_and_grad(R[rows], rows)
        loss_ref, grad_ref = _fresh(pl, R[rows], mu[rows], pi_hat[rows])
        np.testing.assert_allclose(loss, loss_ref, rtol=1e-12)
        np.testing.assert_allclose(grad, grad_ref, rtol=1e-9, atol=1e-12)
        assert all(obj._kept[i] is not None for i in rows)
        R = R + 0.05 * rng.standard_normal(R.shape)
    assert obj.n_evaluations == 6 and not np.isnan(obj._z).any()  # the adjoints start from the last ones


def test_objective_drops_kept_factorisations_on_reset(rng, grid6):
    mu, pi_hat = random_statistics(rng, grid6, 2)
    obj = MCEObjective(grid6, mu, pi_hat, BETA, planner="sparse-lu")
    R = rng.standard_normal((2, grid6.n_states, grid6.n_actions))
    obj.loss_and_grad(R)
    assert all(k is not None for k in obj._kept)
    obj.reset()
    assert obj._kept is None


def test_objective_keeps_nothing_between_calls_under_a_budget_that_chunks(rng, grid6):
    mu, pi_hat = random_statistics(rng, grid6, 4)
    obj = MCEObjective(grid6, mu, pi_hat, BETA, planner="sparse-lu")
    R = rng.standard_normal((4, grid6.n_states, grid6.n_actions))
    one_task = get_planner(grid6, "sparse-lu").task_bytes()
    with planning_budget(2 * one_task):
        loss, grad = obj.loss_and_grad(R)
    assert obj._kept is None
    loss_ref, grad_ref = _fresh(get_planner(grid6, "sparse-lu"), R, mu, pi_hat)
    np.testing.assert_allclose(loss, loss_ref, rtol=1e-12)
    np.testing.assert_allclose(grad, grad_ref, rtol=1e-9, atol=1e-12)


def test_dense_planner_keeps_no_factorisation_and_matches_the_plain_path(rng):
    mdp = fo.GridWorld(size=3)
    pl = get_planner(mdp, "dense")
    mu, pi_hat = random_statistics(rng, mdp, 2)
    R = rng.standard_normal((2, mdp.n_states, mdp.n_actions))
    obj = MCEObjective(mdp, mu, pi_hat, BETA, planner="dense")
    loss, grad = obj.loss_and_grad(R)
    assert obj._kept == [None, None]
    loss_ref, grad_ref = _fresh(pl, R, mu, pi_hat)
    np.testing.assert_array_equal(loss, loss_ref)  # the same arithmetic, bit for bit
    np.testing.assert_array_equal(grad, grad_ref)


@pytest.mark.parametrize("n_actions", [1, 3, 4, 7, 8, 9])
def test_soft_backup_reduces_over_actions_as_numpy_does_bit_for_bit(rng, n_actions):
    class Identity:  # Q = R: the reductions alone
        def q_from_values(self, R, V):
            return R

    for scale, beta in ((1.0, 0.5), (100.0, 5.0), (1e4, 1e3)):
        Q = scale * rng.standard_normal((3, 40, n_actions))
        m = Q.max(axis=2, keepdims=True)
        z = beta * (Q - m)
        lse = np.log(np.exp(z).sum(axis=2, keepdims=True))
        _, TV, log_pi = mce_module.soft_backup(Identity(), Q, None, beta)
        np.testing.assert_array_equal(TV, (m + lse / beta)[:, :, 0])
        np.testing.assert_array_equal(log_pi, z - lse)

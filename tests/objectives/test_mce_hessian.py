"""The Hessian of the MCE likelihood in linear reward weights, against finite differences of its
gradient (docs/maths.md §6): shared, per-task and state features, tabular rewards, planners,
the Gauss-Newton part, several environments, and the errors."""

import numpy as np
from helpers import random_statistics, rel_err
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError
from factirl_opt.objectives import MCEObjective, PolicyMatchingObjective
from factirl_opt.objectives.environments import MultiEnvironmentObjective
from factirl_opt.objectives.problems import weights_problem

BETA = 2.0


def _gradient_fd(mdp, mu, pi_hat, F, w, planner, eps=1e-6):
    """Central differences of ``F^T dJ/dR`` (p,) at ``w``: the Hessian column by column (p, p)."""
    S, A = mdp.n_states, mdp.n_actions

    def grad(x):
        return fo.mce_loss(mdp, (F @ x).reshape(1, S, A), mu, pi_hat, BETA, planner=planner)[1].reshape(-1) @ F

    cols = [(grad(w + eps * e) - grad(w - eps * e)) / (2 * eps) for e in np.eye(len(w))]
    return np.stack(cols, axis=1)


@pytest.fixture(params=["dense", "sparse-lu"])
def planner(request):
    return request.param


@pytest.mark.parametrize("variant", ["shared", "per-task", "state"])
def test_weight_hessian_matches_finite_differences(rng, grid3, planner, variant):
    mdp, n, p = grid3, 2, 4
    S, A = mdp.n_states, mdp.n_actions
    mu, pi_hat = random_statistics(rng, mdp, n)
    if variant == "state":  # the same features for every action (the fast path)
        F = np.repeat(rng.standard_normal((S, p)), A, axis=0)
    else:
        F = rng.standard_normal((S * A, p))
    Fs = np.stack([F, rng.standard_normal((S * A, p))]) if variant == "per-task" else np.stack([F, F])
    w = rng.standard_normal((n, p))
    R = np.einsum("nmp,np->nm", Fs, w).reshape(n, S, A)
    obj = MCEObjective(mdp, mu, pi_hat, BETA, planner=planner)
    H = obj.hessian(R, np.arange(n), Fs if variant == "per-task" else F)
    assert H.shape == (n, p, p)
    np.testing.assert_array_equal(H, np.swapaxes(H, 1, 2))
    for i in range(n):
        fd = _gradient_fd(mdp, mu[i], pi_hat[i], Fs[i], w[i], planner)
        assert rel_err(H[i], fd) < 1e-6


def test_tabular_hessian_is_the_reward_hessian(rng, random_mdp):
    """Without features the Hessian is with respect to the rewards (S*A, S*A); F^T H F gives the
    weight Hessian of any features."""
    mdp = random_mdp
    S, A = mdp.n_states, mdp.n_actions
    mu, pi_hat = random_statistics(rng, mdp, 1)
    R = rng.standard_normal((1, S, A))
    obj = MCEObjective(mdp, mu, pi_hat, BETA)
    H = obj.hessian(R)[0]
    eye = np.eye(S * A)
    fd = _gradient_fd(mdp, mu[0], pi_hat[0], eye, R.reshape(-1), "auto")
    assert rel_err(H, fd) < 1e-6
    F = rng.standard_normal((S * A, 3))
    np.testing.assert_allclose(obj.hessian(R, None, F)[0], F.T @ H @ F, rtol=1e-10, atol=1e-12)


def test_gauss_newton_part_is_positive_semidefinite_and_differs_by_the_value_curvature(rng, grid3):
    """``kind="gauss-newton"`` keeps ``beta^2 c(s)`` only: PSD; with gamma -> the exact Hessian
    differs from it, and equals it when the values' curvature is switched off (gamma = 0)."""
    mu, pi_hat = random_statistics(rng, grid3, 1)
    F = rng.standard_normal((grid3.n_params, 5))
    R = (F @ rng.standard_normal(5)).reshape(1, grid3.n_states, grid3.n_actions)
    obj = MCEObjective(grid3, mu, pi_hat, BETA)
    G = obj.hessian(R, None, F, kind="gauss-newton")[0]
    H = obj.hessian(R, None, F)[0]
    assert np.linalg.eigvalsh(G)[0] >= -1e-12 * np.abs(G).max()
    assert rel_err(H, G) > 1e-3
    flat = fo.GridWorld(size=3, p_success=0.7, gamma=0.0)
    obj0 = MCEObjective(flat, mu, pi_hat, BETA)
    np.testing.assert_allclose(obj0.hessian(R, None, F)[0], obj0.hessian(R, None, F, kind="gauss-newton")[0],
                               rtol=1e-12, atol=1e-14)


def test_hessian_uses_the_cached_point_and_counts_no_evaluation(rng, grid3):
    mu, pi_hat = random_statistics(rng, grid3, 2)
    F = rng.standard_normal((grid3.n_params, 3))
    R = (rng.standard_normal((2, 3)) @ F.T).reshape(2, grid3.n_states, grid3.n_actions)
    obj = MCEObjective(grid3, mu, pi_hat, BETA, planner="sparse-lu")
    obj.loss_and_grad(R)
    before = obj.n_evaluations
    H = obj.hessian(R, None, F)
    assert obj.n_evaluations == before
    fresh = MCEObjective(grid3, mu, pi_hat, BETA, planner="sparse-lu").hessian(R, None, F)  # evaluates first
    np.testing.assert_allclose(H, fresh, rtol=1e-9, atol=1e-12)


def test_hessian_over_environments_is_each_groups(rng):
    g3, g4 = fo.GridWorld(size=3, p_success=0.7, gamma=0.9), fo.GridWorld(size=4, p_success=0.8, gamma=0.9)
    mdps = [g3, g4, g3]
    p = 3
    stats = [random_statistics(rng, m, 1) for m in mdps]
    Fs = [rng.standard_normal((m.n_params, p)) for m in mdps]
    w = rng.standard_normal((3, p))
    R = [(F @ wi).reshape(m.n_states, m.n_actions) for F, wi, m in zip(Fs, w, mdps)]
    obj = MultiEnvironmentObjective(mdps, [s[0][0] for s in stats], [s[1][0] for s in stats], BETA, "mce")
    H = obj.hessian(R, np.arange(3), Fs)
    for i, m in enumerate(mdps):
        alone = MCEObjective(m, *stats[i], BETA).hessian(R[i][None], None, Fs[i])[0]
        np.testing.assert_allclose(H[i], alone, rtol=1e-9, atol=1e-12)
    pm = MultiEnvironmentObjective(mdps, [s[0][0] for s in stats], [s[1][0] for s in stats], BETA)
    assert not pm.has_hessian
    with pytest.raises(ValidationError, match="gives no Hessian"):
        pm.hessian(R, np.arange(3), Fs)


def test_weights_problem_gives_the_hessian_of_mce_only(rng, grid3):
    mu, pi_hat = random_statistics(rng, grid3, 2)
    F = rng.standard_normal((grid3.n_params, 3))
    problem = weights_problem(MCEObjective(grid3, mu, pi_hat, BETA), F)
    w = rng.standard_normal((2, 3))
    rows = np.arange(2)
    problem.loss_and_grad(w, rows)
    H = problem.hessian(w, rows)
    R = (w @ F.T).reshape(2, grid3.n_states, grid3.n_actions)
    np.testing.assert_allclose(H, MCEObjective(grid3, mu, pi_hat, BETA).hessian(R, None, F), rtol=1e-9, atol=1e-12)
    assert weights_problem(PolicyMatchingObjective(grid3, mu, pi_hat, BETA), F).hessian is None


@pytest.mark.parametrize("kwargs, fragment", [
    (dict(kind="fisher"), "kind must be one of exact, gauss-newton"),
    (dict(features=np.ones((5, 2))), r"features must have shape \(S\*A, p\) = \(36, p\)"),
    (dict(features=np.ones((3, 36, 2))), r"or \(r, S\*A, p\) with r = 2"),
])
def test_hessian_validation(rng, grid3, kwargs, fragment):
    mu, pi_hat = random_statistics(rng, grid3, 2)
    obj = MCEObjective(grid3, mu, pi_hat, BETA)
    with pytest.raises(ValidationError, match=fragment):
        obj.hessian(np.zeros((2, grid3.n_states, grid3.n_actions)), None, **kwargs)

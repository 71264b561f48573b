"""The objective over tasks in several environments: grouping, exactness, derivatives, errors."""

import numpy as np
from helpers import central_difference, random_statistics, rel_err
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError
from factirl_opt.objectives import get_objective
from factirl_opt.objectives.environments import MultiEnvironmentObjective, multi_environment_objective
from factirl_opt.mdp.environments import check_environments, group_tasks

OBJECTIVES = ["policy-matching", "mce"]


def rewards_for(rng, mdps, tie_free_rewards):
    return [tie_free_rewards(rng, m, (m.n_states, m.n_actions)) for m in mdps]


@pytest.fixture
def mixed(rng):
    """Tasks on three environments of two sizes, interleaved: 4 states (two objects) and 9."""
    small_a, small_b, big = fo.GridWorld(size=2, gamma=0.9), fo.GridWorld(size=2, p_success=0.5, gamma=0.8), fo.GridWorld(size=3)
    mdps = [big, small_a, big, small_b, small_a]
    stats = [random_statistics(rng, m, 1) for m in mdps]
    return mdps, [s[0][0] for s in stats], [s[1][0] for s in stats]


@pytest.mark.parametrize("name", OBJECTIVES)
def test_one_shared_mdp_gives_todays_results_exactly(rng, grid3, name, tie_free_rewards):
    mu, pi = random_statistics(rng, grid3, 4)
    R = tie_free_rewards(rng, grid3, (4, 9, 4))
    today = get_objective(name)(grid3, mu, pi, 3.0)
    multi = MultiEnvironmentObjective(grid3, mu, pi, 3.0, name)
    assert not multi.ragged and multi.mdp is grid3 and multi.n_residuals == 36
    for rows in (None, [3, 1]):
        sel = slice(None) if rows is None else rows
        loss, grad = multi.loss_and_grad(R[sel], rows)
        ref_loss, ref_grad = today.loss_and_grad(R[sel], rows)
        np.testing.assert_array_equal(loss, ref_loss)
        np.testing.assert_array_equal(grad, ref_grad)
        assert isinstance(grad, np.ndarray)
    assert multi.n_evaluations == today.n_evaluations == 1  # the rows [3, 1] are served from the cache
    if name == "policy-matching":
        F = rng.standard_normal((36, 3))
        for got, ref in zip(multi.residual_jacobian(R, None, F), today.residual_jacobian(R, None, F)):
            np.testing.assert_array_equal(got, ref)
        lin, ref = multi.linearize(R[[2, 0]], [2, 0]), today.linearize(R[[2, 0]], [2, 0])
        dR, U = rng.standard_normal((2, 9, 4)), rng.standard_normal((2, 36))
        np.testing.assert_array_equal(lin.residual, ref.residual)
        np.testing.assert_array_equal(lin.jvp(dR), ref.jvp(dR))
        np.testing.assert_array_equal(lin.vjp(U), ref.vjp(U))


@pytest.mark.parametrize("name", OBJECTIVES)
def test_grouped_equals_each_environment_alone(rng, mixed, name, tie_free_rewards):
    mdps, mus, pis = mixed
    multi = MultiEnvironmentObjective(mdps, mus, pis, 2.0, name)
    groups, task_group, local = group_tasks(mdps)
    assert [m is g for m, g in zip(mdps, (groups[i] for i in task_group))] == [True] * 5
    assert task_group.tolist() == [0, 1, 0, 2, 1] and local.tolist() == [0, 0, 1, 0, 1]
    assert multi.ragged and multi.mdp is None and multi.n_residuals == 36 and multi.n_states.tolist() == [9, 4, 9, 4, 4]
    R = rewards_for(rng, mdps, tie_free_rewards)
    rows = [4, 0, 3, 2]
    loss, grad = multi.loss_and_grad([R[i] for i in rows], rows)
    assert isinstance(grad, list) and [g.shape for g in grad] == [(4, 4), (9, 4), (4, 4), (9, 4)]
    for j, i in enumerate(rows):
        alone = get_objective(name)(mdps[i], mus[i], pis[i], 2.0)
        ref_loss, ref_grad = alone.loss_and_grad(R[i][None])
        assert abs(loss[j] - ref_loss[0]) <= 1e-12 * max(1.0, abs(ref_loss[0]))
        np.testing.assert_allclose(grad[j], ref_grad[0], rtol=0, atol=1e-12)
    assert multi.n_evaluations == 3  # one batched call per environment present


@pytest.mark.parametrize("name", OBJECTIVES)
def test_gradient_matches_central_differences_on_mixed_sizes(rng, mixed, name, tie_free_rewards):
    mdps, mus, pis = mixed
    multi = MultiEnvironmentObjective(mdps, mus, pis, 2.0, name)
    R = rewards_for(rng, mdps, tie_free_rewards)
    _, grad = multi.loss_and_grad(R)
    for i in range(len(mdps)):
        def task_loss(Ri, i=i):
            return multi.loss_and_grad([Ri if j == i else R[j] for j in range(len(R))])[0][i]

        assert rel_err(grad[i], central_difference(task_loss, R[i])) < 1e-6


def test_feature_jacobian_and_products_on_mixed_sizes(rng, mixed, tie_free_rewards):
    mdps, mus, pis = mixed
    multi = MultiEnvironmentObjective(mdps, mus, pis, 2.0)
    feats = [rng.standard_normal((m.n_params, 3)) for m in mdps]
    w = 0.5 * rng.standard_normal((5, 3))
    rows = [1, 2, 3]

    def rewards(w_rows):
        return [(feats[i] @ w_rows[j]).reshape(mdps[i].n_states, 4) for j, i in enumerate(rows)]

    loss, res, jac = multi.residual_jacobian(rewards(w[rows]), rows, [feats[i] for i in rows])
    assert res.shape == (3, 36) and jac.shape == (3, 36, 3)
    np.testing.assert_allclose(loss, np.sum(res**2, axis=1), rtol=1e-12)
    assert np.all(res[0, 16:] == 0) and np.all(jac[2, 16:] == 0)  # padding of the 4-state tasks
    for j in range(3):
        def residual(wj, j=j):
            x = w[rows].copy()
            x[j] = wj
            return multi.residual_jacobian(rewards(x), rows, [feats[i] for i in rows])[1][j]

        fd = np.stack([central_difference(lambda v, c=c: residual(v)[c], w[rows][j]) for c in range(16)])
        np.testing.assert_allclose(jac[j, :16], fd, rtol=0, atol=1e-6)
    lin = multi.linearize(rewards(w[rows]), rows)
    np.testing.assert_array_equal(lin.residual, res)
    dR = [rng.standard_normal((mdps[i].n_states, 4)) for i in rows]
    U = rng.standard_normal((3, 36))
    lhs = np.sum(lin.jvp(dR) * U)
    rhs = sum(np.sum(d * g) for d, g in zip(dR, lin.vjp(U)))
    assert abs(lhs - rhs) <= 1e-10 * abs(lhs)
    jv = lin.jvp([(feats[i] @ w[i]).reshape(-1, 4) for i in rows])
    np.testing.assert_allclose(jv, np.einsum("rmp,rp->rm", jac, w[rows]), rtol=0, atol=1e-10)


def test_per_task_features_in_one_environment_equal_shared_features(rng, grid3):
    mu, pi = random_statistics(rng, grid3, 3)
    F = rng.standard_normal((36, 2))
    R = rng.standard_normal((3, 9, 4))
    a = MultiEnvironmentObjective(grid3, mu, pi, 2.0).residual_jacobian(R, None, F)
    b = MultiEnvironmentObjective(grid3, mu, pi, 2.0).residual_jacobian(R, None, [F, F, F])
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-13)


def test_from_demonstrations_equals_statistics_per_environment(rng, mixed):
    mdps = mixed[0]
    demos = [fo.sample_demonstrations(m, rng.standard_normal((m.n_states, 4)), 3, 5, rng=i)[0] for i, m in enumerate(mdps)]
    multi = multi_environment_objective(mdps, demos, 2.0)
    for i, m in enumerate(mdps):
        mu, pi = fo.empirical_statistics(m, [demos[i]])
        g, j = multi.task_group[i], multi.local_index[i]
        np.testing.assert_array_equal(multi.objectives[g].mu[j], mu[0])
        np.testing.assert_array_equal(multi.objectives[g].pi_hat[j], pi[0])


def test_errors_name_the_task(rng, mixed, grid3):
    mdps, mus, pis = mixed
    with pytest.raises(ValidationError, match="got 4 MDPs for 5 tasks"):
        MultiEnvironmentObjective(mdps[:4], mus, pis, 2.0)
    with pytest.raises(ValidationError, match="pi_hat describes 4 tasks"):
        MultiEnvironmentObjective(mdps, mus, pis[:4], 2.0)
    with pytest.raises(ValidationError, match=r"task 1 \(S = 4\): mu_hat must have shape"):
        MultiEnvironmentObjective(mdps, [mus[0]] * 5, pis, 2.0)
    with pytest.raises(ValidationError, match=r"mdps\[2\] \(task 2\) must be a TabularMDP"):
        check_environments([grid3, grid3, "grid"])
    other = fo.TabularMDP(np.full((9, 2, 9), 1 / 9), 0.9)
    with pytest.raises(ValidationError, match="task 1 has 2, task 0 has 4"):
        check_environments([grid3, other])
    with pytest.raises(ValidationError, match="needs the number of tasks"):
        check_environments(grid3)
    with pytest.raises(ValidationError, match="got 2 MDPs for 3 tasks"):
        multi_environment_objective([grid3, grid3], [np.zeros((1, 2, 2), int)] * 3, 2.0)
    demos = [np.zeros((1, 2, 2), int)] * 5
    demos[1] = np.array([[[3, 0], [4, 1]]])  # state 4 exists on the 9-state map only
    with pytest.raises(ValidationError, match="task 1"):
        multi_environment_objective(mdps, demos, 2.0)
    multi = MultiEnvironmentObjective(mdps, mus, pis, 2.0)
    R = [rng.standard_normal((m.n_states, 4)) for m in mdps]
    with pytest.raises(ValidationError, match=r"rewards of task 1 must have shape \(S, A\) = \(4, 4\)"):
        multi.loss_and_grad([R[0], R[0], R[2], R[3], R[4]])
    with pytest.raises(ValidationError, match="one array per row"):
        multi.loss_and_grad(R[:4])
    with pytest.raises(ValidationError, match=r"rows must be task indices in \[0, 5\)"):
        multi.loss_and_grad(R[:1], [5])
    with pytest.raises(ValidationError, match=r"features of task 1 must have shape \(S\*A, p\) = \(16, 2\)"):
        multi.residual_jacobian(R[:2], [0, 1], [np.zeros((36, 2)), np.zeros((36, 2))])
    with pytest.raises(ValidationError, match="S\\*A = 16 rows for task 1"):
        multi.residual_jacobian(R[:2], [0, 1], np.zeros((36, 2)))
    with pytest.raises(ValidationError, match="one per row"):
        multi.residual_jacobian(R[:2], [0, 1], [np.zeros((36, 2))])
    mce = MultiEnvironmentObjective(mdps, mus, pis, 2.0, "mce")
    for call in (lambda: mce.linearize(R), lambda: mce.residual_jacobian(R, None, np.zeros((36, 1)))):
        with pytest.raises(ValidationError, match="least-squares objective"):
            call()

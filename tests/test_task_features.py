"""Per-task reward features: rewards, chain rule, dictionary gradient, with state or state-action features."""

import warnings

import numpy as np
from helpers import central_difference, random_statistics, rel_err
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError
from factirl_opt.objectives.environments import MultiEnvironmentObjective
from factirl_opt.tasks.features import TaskFeatures, task_rewards


@pytest.fixture
def feats(rng):
    """Tasks of 4, 9 and 4 states (A = 4, p = 3): state features, state-action, state."""
    return TaskFeatures([rng.standard_normal((4, 3)), rng.standard_normal((36, 3)), rng.standard_normal((4, 3))], [4, 9, 4], 4)


def dense(tf, i):
    F = tf.matrix(i)
    return np.repeat(F, tf.n_actions, axis=0) if tf.state_features[i] else F


def test_rewards_and_pull_are_adjoint_and_match_dense_products(rng, feats):
    assert feats.ragged and feats.state_features.tolist() == [True, False, True] and feats.n_features == 3
    W = rng.standard_normal((3, 3))
    R = feats.rewards(W)
    assert [r.shape for r in R] == [(4, 4), (9, 4), (4, 4)]
    for i in range(3):
        np.testing.assert_allclose(R[i].reshape(-1), dense(feats, i) @ W[i], rtol=0, atol=1e-13)
    Y = [rng.standard_normal(r.shape) for r in R]
    G = feats.pull(Y)
    for i in range(3):
        np.testing.assert_allclose(G[i], dense(feats, i).T @ Y[i].reshape(-1), rtol=0, atol=1e-12)
        assert abs(np.sum(R[i] * Y[i]) - W[i] @ G[i]) < 1e-12
    sub = feats.pull([Y[2], Y[0]], rows=[2, 0])
    np.testing.assert_array_equal(sub, G[[2, 0]])


def test_shared_matrix_per_task_equals_task_rewards(rng):
    Phi = rng.standard_normal((9 * 4, 5))
    D, H = rng.standard_normal((5, 2)), rng.standard_normal((3, 2))
    tf = TaskFeatures([Phi] * 3, [9] * 3, 4)
    assert not tf.ragged
    np.testing.assert_allclose(tf.rewards(H @ D.T), task_rewards(Phi @ D, H, 9, 4), rtol=0, atol=1e-12)
    Y = rng.standard_normal((3, 9, 4))
    np.testing.assert_allclose(tf.dictionary_gradient(Y, H), Phi.T @ (Y.reshape(3, -1).T @ H), rtol=0, atol=1e-12)
    prods = tf.products(D)
    np.testing.assert_allclose(prods[1], Phi @ D, rtol=0, atol=1e-13)


def test_dictionary_gradient_matches_central_differences_on_mixed_sizes(rng, feats):
    """``dJ/dD`` of ``sum_i J_i(Phi_i D h_i)`` through the multi-environment objective (eq. 11)."""
    mdps = [fo.GridWorld(size=2), fo.GridWorld(size=3), fo.GridWorld(size=2, p_success=0.5)]
    stats = [random_statistics(rng, m, 1) for m in mdps]
    for name in ("policy-matching", "mce"):
        obj = MultiEnvironmentObjective(mdps, [s[0][0] for s in stats], [s[1][0] for s in stats], 2.0, name)
        H = rng.standard_normal((3, 2))
        D = 0.5 * rng.standard_normal((3, 2))

        def total(Dx):
            return obj.loss_and_grad(feats.rewards(H @ Dx.T))[0].sum()

        _, Y = obj.loss_and_grad(feats.rewards(H @ D.T))
        assert rel_err(feats.dictionary_gradient(Y, H), central_difference(total, D)) < 1e-6
        gH = feats.pull(Y) @ D  # eq. 12: dJ/dh_i = D^T Phi_i^T y_i
        fd = central_difference(lambda Hx: obj.loss_and_grad(feats.rewards(Hx @ D.T))[0].sum(), H)
        assert rel_err(gH, fd) < 1e-6


def test_products_feed_the_gauss_newton_jacobian(rng, feats):
    mdps = [fo.GridWorld(size=2), fo.GridWorld(size=3), fo.GridWorld(size=2)]
    stats = [random_statistics(rng, m, 1) for m in mdps]
    obj = MultiEnvironmentObjective(mdps, [s[0][0] for s in stats], [s[1][0] for s in stats], 2.0)
    D, H = rng.standard_normal((3, 2)), rng.standard_normal((3, 2))
    loss, res, jac = obj.residual_jacobian(feats.rewards(H @ D.T), None, feats.products(D))
    lin = obj.linearize(feats.rewards(H @ D.T))
    dH = rng.standard_normal((3, 2))
    np.testing.assert_allclose(np.einsum("rmk,rk->rm", jac, dH), lin.jvp(feats.rewards(dH @ D.T)), rtol=0, atol=1e-12)


def test_errors_name_the_task(rng):
    with pytest.raises(ValidationError, match="2 feature matrices for 3 tasks"):
        TaskFeatures([np.ones((4, 2))] * 2, [4, 4, 4], 4)
    with pytest.raises(ValidationError, match=r"task 1 must have S = 9 or S\*A = 36 rows"):
        TaskFeatures([np.ones((4, 2)), np.ones((4, 2))], [4, 9], 4)
    with pytest.raises(ValidationError, match="task 1 has 3, task 0 has 2"):
        TaskFeatures([np.ones((4, 2)), np.ones((9, 3))], [4, 9], 4)
    with pytest.raises(ValidationError, match="one .* matrix per task"):
        TaskFeatures(np.ones((4, 2)), [4], 4)
    with pytest.raises(ValidationError, match=r"features\[0\] \(task 0\) must be finite"):
        TaskFeatures([np.full((4, 2), np.nan)], [4], 4)
    tf = TaskFeatures([np.ones((4, 2)), np.ones((9, 2))], [4, 9], 4)
    with pytest.raises(ValidationError, match=r"weights must have shape \(2, 2"):
        tf.rewards(np.ones((2, 3)))
    with pytest.raises(ValidationError, match=r"gradient of task 1 must have shape \(9, 4\)"):
        tf.pull([np.ones((4, 4)), np.ones((4, 4))])
    with pytest.raises(ValidationError, match="one row per task"):
        tf.dictionary_gradient([np.ones((4, 4)), np.ones((9, 4))], np.ones((3, 1)))
    with pytest.raises(ValidationError, match=r"M must have shape \(2, k\)"):
        tf.products(np.ones((3, 1)))


@pytest.mark.parametrize("learner", ["gradirl", "factirl-pca", "factirl-random"])
@pytest.mark.parametrize("sizes", [(3, 4, 3), (3, 3, 3)])
def test_per_task_features_with_huge_values_get_the_rescale_message(learner, sizes):
    mdps = [fo.GridWorld(size=s, p_success=0.7, gamma=0.9) for s in sizes]
    rng = np.random.default_rng(0)
    Phis = [rng.random((m.n_states, 3)) for m in mdps]
    Phis[1] = Phis[1] * 1e300  # finite rewards of order 1e299-1e300: beyond what planning takes at gamma 0.9
    demos = [fo.sample_demonstrations(m, rng.normal(size=(1, m.n_states, 4)), 2, 5, rng=i)[0] for i, m in enumerate(mdps)]
    model = {"gradirl": fo.GradIRL(features=Phis, max_iter=3),
             "factirl-pca": fo.FactIRL(n_primitives=2, features=Phis, max_iter=2, flat_max_iter=2),
             # the alternation's H-step checks the rewards' scale where it plans (the joint scheme's steps do not)
             "factirl-random": fo.FactIRL(n_primitives=2, features=Phis, max_iter=2, init="random", rng=0,
                                          scheme="alternating")}[learner]
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no numpy overflow warning either: the error says it
        with pytest.raises(ValidationError, match=r"the rewards features @ .* overflow float64 \(largest \|features\| = "
                                                  r"\d.*e\+299.*: the features are far from order 1: rescale them"):
            model.fit(mdps, demos)

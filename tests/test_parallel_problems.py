"""Step problems of a sharded objective: built on the shards, evaluated from the parameters.

Reference: the same problem (:func:`factirl_opt.objectives.problems.weights_problem`,
:func:`~factirl_opt.objectives.problems.dictionary_problem`) on the unsharded objective; Jacobians compare
through their normal equations (the shards send them in reduced form).
"""

import os
import signal

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.objectives import PolicyMatchingObjective
from factirl_opt.objectives.distributed import ShardedObjective, reduced_least_squares
from factirl_opt.objectives.problems import dictionary_problem, weights_problem
from factirl_opt.tasks.features import StateBroadcast

TOL = dict(rtol=1e-10, atol=1e-12)


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(3)
    mdp = fo.GridWorld(size=4, p_success=0.7, gamma=0.9)
    demos = fo.sample_demonstrations(mdp, rng.standard_normal((5, mdp.n_states, mdp.n_actions)), 3, 6, rng)
    mu, pi = fo.empirical_statistics(mdp, demos)
    return mdp, mu, pi, rng


def pair(data):
    mdp, mu, pi, _ = data
    ref = PolicyMatchingObjective(mdp, mu, pi, 5.0, planner="sparse-lu")
    return ref, ShardedObjective(PolicyMatchingObjective(mdp, mu, pi, 5.0, planner="sparse-lu"), 2)


@pytest.mark.parametrize("kind", ["array", "tabular", "state"])
def test_weights_problem_on_shards(data, kind):
    mdp, _, _, rng = data
    S, A = mdp.n_states, mdp.n_actions
    F = {"array": rng.standard_normal((S * A, 3)), "tabular": None, "state": StateBroadcast(S, A)}[kind]
    p = {"array": 3, "tabular": S * A, "state": S}[kind]
    ref, obj = pair(data)
    try:
        a, b = weights_problem(ref, F), weights_problem(obj, F)
        assert b.n_rows == a.n_rows == 5 and b.n_params == a.n_params == p
        x, rows = 0.3 * rng.standard_normal((3, p)), np.array([4, 1, 2])
        for u, v in zip(a.loss_and_grad(x, rows), b.loss_and_grad(x, rows)):
            np.testing.assert_allclose(v, u, **TOL)
        b.loss_and_grad(x, rows)  # the same point: served from the shards' caches, not counted
        a.loss_and_grad(x, rows)
        la, ra, Ja = a.residual_jacobian(x, rows)
        lb, rb, Jb = b.residual_jacobian(x, rows)
        np.testing.assert_allclose(lb, la, **TOL)
        for u, v in zip(reduced_least_squares(ra, Ja), (rb, Jb)):
            np.testing.assert_allclose(v, u, **TOL)
        lin_a, lin_b = a.linearize(x, rows), b.linearize(x, rows)
        V = rng.standard_normal(x.shape)
        np.testing.assert_allclose(lin_b.jvp(V), lin_a.jvp(V), **TOL)
        np.testing.assert_allclose(lin_b.vjp(lin_a.residual), lin_a.vjp(lin_a.residual), **TOL)
        assert a.n_evaluations() == b.n_evaluations() == 3
    finally:
        obj.close()


@pytest.mark.parametrize("unit_norm", [False, True])
def test_dictionary_problem_on_shards(data, unit_norm):
    mdp, _, _, rng = data
    Phi, H = rng.standard_normal((mdp.n_params, 4)), rng.standard_normal((5, 2))
    ref, obj = pair(data)
    try:
        a, b = dictionary_problem(ref, H, Phi, unit_norm), dictionary_problem(obj, H, Phi, unit_norm)
        x, rows = 0.3 * rng.standard_normal((1, 8)), np.arange(1)
        for u, v in zip(a.loss_and_grad(x, rows), b.loss_and_grad(x, rows)):
            np.testing.assert_allclose(v, u, **TOL)
        lin_a, lin_b = a.linearize(x, rows), b.linearize(x, rows)
        np.testing.assert_allclose(lin_b.residual, lin_a.residual, **TOL)
        V = rng.standard_normal(x.shape)
        np.testing.assert_allclose(lin_b.jvp(V), lin_a.jvp(V), **TOL)
        np.testing.assert_allclose(lin_b.vjp(lin_a.residual), lin_a.vjp(lin_a.residual), **TOL)
        assert a.n_evaluations() == b.n_evaluations() == 2
        # per evaluation only vec(D) goes to the remote shard and its loss and gradient come back
        sent = obj.shards.bytes_sent
        b.loss_and_grad(x + 0.1, rows)
        assert obj.shards.bytes_sent - sent == x.nbytes + rows.nbytes + 8 + x.nbytes
    finally:
        obj.close()


def test_rebuilt_shard_gets_its_problems_again(data):
    mdp, _, _, rng = data
    F = rng.standard_normal((mdp.n_params, 3))
    ref, obj = pair(data)
    try:
        a, b = weights_problem(ref, F), weights_problem(obj, F)
        x, rows = 0.3 * rng.standard_normal((5, 3)), np.arange(5)
        lin_b = b.linearize(x, rows)
        proc = obj.shards.handles[1].proc
        os.kill(proc.pid, signal.SIGKILL)
        proc.join()
        for u, v in zip(a.loss_and_grad(x + 0.1, rows), b.loss_and_grad(x + 0.1, rows)):
            np.testing.assert_allclose(v, u, **TOL)
        V = rng.standard_normal(x.shape)
        np.testing.assert_allclose(lin_b.jvp(V), a.linearize(x, rows).jvp(V), **TOL)
        assert obj.shards.n_restarts == 1
    finally:
        obj.close()

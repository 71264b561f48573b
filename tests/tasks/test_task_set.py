"""The one setup path of every learner entry point: ``task_set`` reads (mdp or mdps, demos, features, reward) once."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError
from factirl_opt.learners.fitting import task_objective
from factirl_opt.tasks.basis import SharedBasis, StateBasis, TabularBasis, TaskBasis
from factirl_opt.tasks.task_set import TaskSet, environment_tasks, features_digest, task_set


@pytest.fixture(scope="module")
def grids():
    return fo.GridWorld(size=3, p_success=0.7, gamma=0.9), fo.GridWorld(size=4, p_success=0.7, gamma=0.9)


@pytest.fixture(scope="module")
def demos(grids):
    g3, _ = grids
    R = np.random.default_rng(0).normal(size=(2, 9, 4))
    return fo.sample_demonstrations(g3, R, 2, 4, rng=1)


def test_one_mdp_is_one_environment(grids, demos):
    g3, _ = grids
    tabular = task_set(g3, demos)
    assert isinstance(tabular, TaskSet) and tabular.shared and tabular.mdp is g3 and tabular.mdps is None
    assert isinstance(tabular.basis, TabularBasis) and tabular.digest is None and tabular.n_params == 36
    assert task_set([g3, g3], demos).mdp is g3  # the same object for every task: the one-MDP path
    state = task_set(g3, demos, reward="state")
    assert isinstance(state.basis, StateBasis) and state.n_params == 9 and state.digest is None
    F = np.random.default_rng(2).random((9, 3))
    feats = task_set(g3, demos, F)
    assert isinstance(feats.basis, SharedBasis) and feats.basis.features.shape == (36, 3)
    assert feats.digest == features_digest(feats.basis.features)
    W = np.random.default_rng(3).normal(size=(2, 3))
    np.testing.assert_allclose(feats.rewards(W), (feats.basis.features @ W.T).T.reshape(2, 9, 4), rtol=0, atol=1e-14)
    assert feats.signature() == g3.signature()


def test_several_mdps_or_per_task_features_are_environments(grids, demos):
    g3, g4 = grids
    d4 = fo.sample_demonstrations(g4, np.zeros((1, 16, 4)), 2, 4, rng=4)
    Phis = [np.random.default_rng(5).random((9, 2)), np.random.default_rng(6).random((16, 2))]
    tasks = task_set([g3, g4], [demos[0], d4[0]], Phis)
    assert not tasks.shared and tasks.mdps == [g3, g4] and isinstance(tasks.basis, TaskBasis)
    assert tasks.n_params == 2 and tasks.digest is None
    assert tasks.signature() == [g3.signature(), g4.signature()]
    R = tasks.rewards(np.ones((2, 2)))
    assert [r.shape for r in R] == [(9, 4), (16, 4)]
    assert task_objective(tasks, 2.0).n_tasks == 2
    shared = environment_tasks(g3, demos, Phis[0])  # one MDP object, planned as environments (transfer)
    assert not shared.shared and shared.digest == features_digest(np.repeat(Phis[0], 4, axis=0))


@pytest.mark.parametrize("args, match", [
    (lambda g3, g4, d: ([g3, g4], d, None), "need features"),
    (lambda g3, g4, d: (g3, d, np.ones((9, 2)), "state"), "takes no features"),
    (lambda g3, g4, d: ([g3, g3, g4], d, [np.ones((9, 2))] * 3), "3 MDPs for 2 tasks"),
    (lambda g3, g4, d: ("grid", d), "TabularMDP"),
    (lambda g3, g4, d: (g3, d, None, "nonsense"), "reward must be one of"),
])
def test_bad_task_sets_are_refused_naming_the_problem(grids, demos, args, match):
    with pytest.raises(ValidationError, match=match):
        task_set(*args(*grids, demos))


@pytest.mark.parametrize("entry", ["GradIRL.fit", "FactIRL.fit", "fit_factorial", "transfer_coefficients",
                                   "MultiIntentIRL.fit"])
def test_every_entry_point_refuses_what_task_set_refuses(grids, demos, entry):
    """The same input error, the same message, whichever entry point reads it (one setup path)."""
    g3, _ = grids
    F = np.ones((9, 2))
    calls = {
        "GradIRL.fit": lambda: fo.GradIRL(features=F, reward="state").fit(g3, demos),
        "FactIRL.fit": lambda: fo.FactIRL(n_primitives=1, features=F, reward="state").fit(g3, demos),
        "fit_factorial": lambda: fo.fit_factorial(g3, demos, np.ones((2, 1)), np.ones((2, 1)), beta=5.0, base_features=F,
                                                  reward="state"),
        "transfer_coefficients": lambda: fo.transfer_coefficients(g3, demos, np.ones((2, 1)), beta=5.0, base_features=F,
                                                                  reward="state"),
        "MultiIntentIRL.fit": lambda: fo.MultiIntentIRL(1, features=F, reward="state").fit(g3, list(demos[0])),
    }
    with pytest.raises(ValidationError, match="reward='state' learns one free reward per state and takes no features"):
        calls[entry]()


def test_a_row_subset_keeps_the_tasks_of_its_rows(grids, demos):
    g3, g4 = grids
    d4 = fo.sample_demonstrations(g4, np.zeros((1, 16, 4)), 2, 4, rng=4)
    Phis = [np.random.default_rng(5).random((9, 2)), np.random.default_rng(6).random((16, 2)),
            np.random.default_rng(7).random((9, 2))]
    tasks = task_set([g3, g4, g3], [demos[0], d4[0], demos[1]], Phis)
    sub = tasks.subset([2, 1])
    assert sub.n_tasks == 2 and sub.mdps == [g3, g4] and sub.demos_per_task[0] is demos[1]
    W = np.random.default_rng(8).normal(size=(2, 2))
    whole = tasks.rewards(np.stack([W[1], W[1], W[0]]))
    assert [r.shape for r in sub.rewards(W)] == [(9, 4), (16, 4)]
    np.testing.assert_array_equal(sub.rewards(W)[0], whole[2])
    np.testing.assert_array_equal(sub.rewards(W)[1], whole[1])
    shared = task_set(g3, demos).subset([1])
    assert shared.mdp is g3 and shared.n_tasks == 1 and isinstance(shared.basis, TabularBasis)
    assert task_objective(sub, 2.0).n_tasks == 2 and task_objective(shared, 2.0).n_tasks == 1
    with pytest.raises(ValidationError, match="task indices"):
        tasks.subset([3])
    with pytest.raises(ValidationError, match="task indices"):
        tasks.subset([])


def test_episodes_and_the_statistics_of_a_task_set_parsed_once(grids, demos, monkeypatch):
    g3, g4 = grids
    tasks = task_set(g3, demos)
    mu, pi = tasks.mu_hat, tasks.pi_hat
    assert len(tasks.demonstrations) == 2
    mu0, pi0 = fo.empirical_statistics(g3, demos)
    np.testing.assert_array_equal(mu, mu0)
    np.testing.assert_array_equal(pi, pi0)
    np.testing.assert_array_equal(tasks.n_pairs, [8.0, 8.0])
    import factirl_opt.tasks.trajectories as trajectories
    monkeypatch.setattr(trajectories, "_parse_task", None)  # nothing below parses the demonstrations again
    first, rest = tasks.episodes(0, 1), tasks.subset([1, 0]).episodes(1)
    assert first.basis is tasks.basis and first.mdp is g3 and rest.demos_per_task[0] is not demos[1]
    np.testing.assert_array_equal(rest.demos_per_task[0], demos[1][1:])
    monkeypatch.undo()
    for part, want in ((first, [d[:1] for d in demos]), (rest, [demos[1][1:], demos[0][1:]])):
        for got, ref in zip((part.mu_hat, part.pi_hat), fo.empirical_statistics(g3, want)):
            np.testing.assert_array_equal(got, ref)
    d4 = fo.sample_demonstrations(g4, np.zeros((1, 16, 4)), 2, 4, rng=4)
    envs = task_set([g3, g4], [demos[0], d4[0]], [np.ones((9, 2)), np.ones((16, 2))])
    mus, pis = envs.mu_hat, envs.pi_hat
    assert [m.shape for m in mus] == [(9,), (16,)] and [p.shape for p in pis] == [(9, 4), (16, 4)]
    np.testing.assert_array_equal(mus[1], fo.empirical_statistics(g4, [d4[0]])[0][0])
    np.testing.assert_array_equal(envs.episodes(1).pi_hat[1], fo.empirical_statistics(g4, [d4[0][1:]])[1][0])
    with pytest.raises(ValidationError, match="task 1, episode 0, step 0: state 9 is out of range"):
        task_set([g3, g3], [demos[0], np.full((1, 2, 2), 9)], np.ones((9, 2)))  # parsed as it is made

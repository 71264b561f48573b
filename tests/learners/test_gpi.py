"""FactIRL.gpi_policies: GPI over the successor features of a model's library (Barreto et al. 2017)."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import NotFittedError, ValidationError
from factirl_opt.learners.gpi import successor_feature_cache


@pytest.fixture(scope="module")
def grid():
    return fo.GridWorld(size=5, p_success=0.7, gamma=0.9)


def _hand_model(mdp, k, objective, seed=0):
    D = np.linalg.qr(np.random.default_rng(seed).normal(size=(mdp.n_states * mdp.n_actions, k)))[0]
    model = fo.FactIRL(k, objective=objective)
    model.dictionary_ = D
    return model, D


def _library(model):
    (entry,) = successor_feature_cache(model).values()
    return entry


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_gpi_policy_is_at_least_every_library_policy_in_every_state(grid, rng, objective):
    S, A, k = grid.n_states, grid.n_actions, 3
    model, D = _hand_model(grid, k, objective)
    H = 3.0 * rng.normal(size=(12, k))
    pol = model.gpi_policies(grid, H)
    assert pol.shape == (12, S) and np.issubdtype(pol.dtype, np.integer)
    report = model.gpi_report_
    assert report.library == [f"primitive {j}" for j in range(k)] + [f"-primitive {j}" for j in range(k)]
    R = (H @ D.T).reshape(12, S, A)
    V_gpi = fo.policy_evaluation(grid, R, pol)
    lib = _library(model)
    assert lib["policies"].ndim == (2 if objective == "policy-matching" else 3)  # greedy, or soft-optimal for MCE
    for l in range(len(report.library)):
        V_l = fo.policy_evaluation(grid, R, np.broadcast_to(lib["policies"][l], (12,) + lib["policies"].shape[1:]).copy())
        assert np.all(V_gpi >= V_l - 1e-10 * np.maximum(1, np.abs(V_l)))  # Theorem 1, state by state
        np.testing.assert_allclose(report.library_values[:, l], V_l.mean(axis=1), atol=1e-10)
    np.testing.assert_allclose(report.gpi_value, V_gpi.mean(axis=1), atol=1e-12)
    assert np.all(report.gpi_value >= report.best_library_value - 1e-10)
    np.testing.assert_allclose(report.best_library_value, report.library_values.max(axis=1))


@pytest.mark.parametrize("objective", ["policy-matching", "mce"])
def test_one_improvement_step_is_one_policy_iteration_sweep_from_gpi(grid, rng, objective):
    model, D = _hand_model(grid, 3, objective)
    H = 3.0 * rng.normal(size=(6, 3))
    start = rng.dirichlet(np.ones(grid.n_states))
    pol0 = model.gpi_policies(grid, H, start=start)
    gpi_value = model.gpi_report_.gpi_value
    pol1 = model.gpi_policies(grid, H, improvement_steps=1, start=start)
    report = model.gpi_report_
    np.testing.assert_allclose(report.gpi_value, gpi_value)
    R = (H @ D.T).reshape(6, grid.n_states, grid.n_actions)
    Q0 = R + grid.gamma * np.einsum("sat,nt->nsa", grid.transitions, fo.policy_evaluation(grid, R, pol0))
    greedy = np.argmax(Q0, axis=2)
    changed = pol1 != pol0
    np.testing.assert_array_equal(pol1[changed], greedy[changed])
    np.testing.assert_allclose(report.value, fo.policy_evaluation(grid, R, pol1) @ start, atol=1e-12)
    assert np.all(report.value >= report.gpi_value - 1e-10)
    many = model.gpi_policies(grid, H, improvement_steps=50)  # policy iteration to the end: the optimum
    np.testing.assert_allclose(fo.policy_evaluation(grid, R, many), fo.optimal_q(grid, R)[0].max(axis=2), atol=1e-9)


def test_fitted_model_library_has_the_training_tasks_and_is_configurable(grid):
    R = np.random.default_rng(1).normal(size=(4, grid.n_states, grid.n_actions))
    demos = fo.sample_demonstrations(grid, R, 3, 5, rng=2)
    model = fo.FactIRL(2, max_iter=2, rng=0).fit(grid, demos)
    H = model.coefficients_
    pol = model.gpi_policies(grid, H, evaluate=False)
    report = model.gpi_report_
    assert report.library[-4:] == [f"task {i}" for i in range(4)] and len(report.library) == 8
    assert report.gpi_value is None and report.value is None
    # each training task's own policy is in the library: GPI on its h is at least as good
    tasks = _library(model)["policies"][4:]
    Rl = model.rewards_
    np.testing.assert_array_less(fo.policy_evaluation(grid, Rl, tasks).mean(axis=1) - 1e-10,
                                 fo.policy_evaluation(grid, Rl, pol).mean(axis=1) + 1e-12)
    model.gpi_policies(grid, H, library=("primitives",))
    assert model.gpi_report_.library == ["primitive 0", "primitive 1"]
    assert len(successor_feature_cache(model)) == 2
    one = model.gpi_policies(grid, H[0])
    assert one.shape == (grid.n_states,)


def test_library_is_cached_and_follows_the_dictionary(grid, rng):
    model, D = _hand_model(grid, 2, "policy-matching")
    H = rng.normal(size=(3, 2))
    model.gpi_policies(grid, H)
    psi = _library(model)["psi"]
    model.gpi_policies(grid, H, improvement_steps=1)
    assert _library(model)["psi"] is psi  # reused, not recomputed
    model.gpi_policies(grid, H, library="primitives")
    assert len(successor_feature_cache(model)) == 2  # another library of the same model
    model.dictionary_ = D[:, ::-1].copy()
    model.gpi_policies(grid, H)
    assert len(successor_feature_cache(model)) == 1  # the earlier dictionary's libraries are dropped
    assert _library(model)["psi"] is not psi


def test_saved_model_keeps_its_libraries(grid, rng, tmp_path):
    model, _ = _hand_model(grid, 2, "mce")
    H = rng.normal(size=(3, 2))
    expected = model.gpi_policies(grid, H)
    fo.save_model(model, tmp_path / "m.npz")
    loaded = fo.load_model(tmp_path / "m.npz")
    (key, entry), = successor_feature_cache(loaded).items()
    assert key in successor_feature_cache(model)
    np.testing.assert_array_equal(entry["psi"], _library(model)["psi"])
    np.testing.assert_array_equal(loaded.gpi_policies(grid, H), expected)
    assert _library(loaded)["psi"] is entry["psi"]  # the loaded library serves: nothing planned again


def test_per_task_maps_use_the_library_of_the_map(rng):
    maps = fo.objectworld.objectworld_maps(3, size=6, rng=0)
    mdps, feats = list(maps.mdps), list(maps.features)
    R = fo.objectworld.state_action_rewards(maps.rewards, mdps[0].n_actions)
    demos = fo.sample_demonstrations(mdps, R, 3, 6, rng=1)
    model = fo.FactIRL(2, max_iter=1, start=fo.Start(init="random"), rng=0, features=feats).fit(mdps, demos)
    H = rng.normal(size=(4, 2))
    pol = model.gpi_policies([mdps[0], mdps[1], mdps[1], mdps[2]], H, features=[feats[0], feats[1], feats[1], feats[2]])
    assert pol.shape == (4, mdps[0].n_states)
    report = model.gpi_report_
    assert report.library[1][-1] == "task 1" and report.library[3][-1] == "task 2" and len(report.library[0]) == 5
    carried = model.gpi_policies(mdps[1], H, features=feats[1], library=("primitives", "tasks", "other-tasks"))
    report = model.gpi_report_
    assert report.library == ["primitive 0", "primitive 1", "task 1", "task 0 (carried)", "task 2 (carried)"]
    # a carried task's library policy is the optimal policy of its weights on this map
    (entry,) = [e for e in successor_feature_cache(model).values() if len(e["labels"]) == 5 and "carried" in e["labels"][-1]]
    w0 = model.dictionary_ @ model.coefficients_[0]
    R0 = fo.feature_rewards(feats[1], w0[None], mdps[1])[0]
    np.testing.assert_array_equal(entry["policies"][3], fo.optimal_q(mdps[1], R0)[1])
    assert np.all(report.gpi_value >= report.best_library_value - 1e-10) and carried.shape == (4, mdps[1].n_states)
    with pytest.raises(ValidationError, match="needs each new task's features"):
        model.gpi_policies(mdps[0], H)
    other = fo.objectworld.objectworld_maps(1, size=6, rng=5)
    with pytest.raises(ValidationError, match="none of the 3 fitted tasks' environments"):
        model.gpi_policies(mdps[0], H, features=other.features[0])


def test_gpi_policies_refuse_bad_inputs(grid, rng):
    with pytest.raises(NotFittedError):
        fo.FactIRL(2).gpi_policies(grid, np.zeros((1, 2)))
    model, _ = _hand_model(grid, 2, "policy-matching")
    with pytest.raises(AttributeError, match="call gpi_policies first"):
        model.gpi_report_
    for bad, fragment in [(np.zeros((2, 3)), r"shape \(n, k\)"), (np.zeros((0, 2)), "at least one task")]:
        with pytest.raises(ValidationError, match=fragment):
            model.gpi_policies(grid, bad)
    with pytest.raises(ValidationError, match="improvement_steps"):
        model.gpi_policies(grid, np.zeros((1, 2)), improvement_steps=-1)
    with pytest.raises(ValidationError, match="no training tasks"):
        model.gpi_policies(grid, np.zeros((1, 2)), library=("tasks",))
    with pytest.raises(ValidationError, match="library must be"):
        model.gpi_policies(grid, np.zeros((1, 2)), library=("primitives", "optimal"))
    with pytest.raises(ValidationError, match="dictionary_ must have shape"):
        model.gpi_policies(fo.GridWorld(size=4), np.zeros((1, 2)))
    demos = fo.sample_demonstrations(grid, rng.normal(size=(2, grid.n_states, grid.n_actions)), 2, 4, rng=0)
    fitted = fo.FactIRL(2, max_iter=1, rng=0).fit(grid, demos)
    with pytest.raises(ValidationError, match="fitted on another MDP"):
        fitted.gpi_policies(fo.GridWorld(size=5, p_success=0.8), np.zeros((1, 2)))

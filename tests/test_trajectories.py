"""The one parser of demonstration layouts, and trajectories from other libraries."""


import numpy as np
from helpers import hang_guard
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import PersistenceError, ValidationError
from factirl_opt.tasks.trajectories import demonstrations_from_trajectories, parse_demonstrations, task_steps


class Trajectory:
    """The layout of imitation's Trajectory: ``obs`` has one more entry than ``acts``."""

    def __init__(self, obs, acts):
        self.obs, self.acts = obs, acts


class EpisodeData:
    """The layout of Minari's EpisodeData: ``observations`` and ``actions`` attributes."""

    def __init__(self, observations, actions):
        self.observations, self.actions = observations, actions


@pytest.fixture(scope="module")
def setting():
    mdp = fo.GridWorld(size=4)
    rng = np.random.default_rng(3)
    R = fo.task_rewards(fo.random_dictionary(64, 2, rng=rng), fo.random_coefficients(3, 2, rng=rng), 16, 4)
    demos = fo.sample_demonstrations(mdp, R, n_demos=3, length=7, rng=rng)
    return mdp, demos


def _next_states(mdp, episode, rng):
    """One observation more: a state reached after the episode's last action."""
    s, a = episode[-1]
    return np.append(episode[:, 0], rng.choice(mdp.n_states, p=mdp.transitions[s, a]))


def _as_trajectories(mdp, demos, rng):
    """Each task's episodes in the three foreign layouts, in turn: objects, dicts, Minari-like."""
    out = []
    for i, task in enumerate(demos):
        eps = []
        for j, ep in enumerate(task):
            kind = (i + j) % 3
            if kind == 0:
                eps.append(Trajectory(_next_states(mdp, ep, rng), ep[:, 1].copy()))
            elif kind == 1:
                eps.append({"observations": ep[:, 0].tolist(), "actions": ep[:, 1].tolist()})  # equally many
            else:
                eps.append(EpisodeData(_next_states(mdp, ep, rng).astype(np.int32), ep[:, 1].astype(np.uint8)))
        out.append(eps)
    return out


# ----------------------------------------------------------------------------- round trips


def test_trajectories_round_trip_to_the_library_layout(setting):
    mdp, demos = setting
    trajs = _as_trajectories(mdp, demos, np.random.default_rng(0))
    back = demonstrations_from_trajectories(trajs, mdp=mdp)
    assert len(back) == len(demos)
    for task, original in zip(back, demos):
        assert isinstance(task, list) and len(task) == len(original)
        for ep, ref in zip(task, original):
            assert ep.dtype == np.int64 and ep.shape == (7, 2)
            np.testing.assert_array_equal(ep, ref)


def test_learners_accept_trajectories_directly(setting):
    mdp, demos = setting
    trajs = _as_trajectories(mdp, demos, np.random.default_rng(1))
    for a, b in zip(fo.empirical_statistics(mdp, trajs), fo.empirical_statistics(mdp, demos)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(fo.GradIRL(max_iter=5).fit(mdp, trajs).weights_, fo.GradIRL(max_iter=5).fit(mdp, demos).weights_)
    model = fo.FactIRL(n_primitives=2, max_iter=2, flat_max_iter=3, transfer_max_iter=3, rng=0).fit(mdp, demos)
    np.testing.assert_array_equal(model.transfer(mdp, trajs[:1]), model.transfer(mdp, demos[:1]))


def test_npz_rollouts_files_and_mappings(setting, tmp_path):
    mdp, demos = setting
    paths = []
    for j, ep in enumerate(demos[0]):
        path = tmp_path / f"rollout{j}.npz"
        obs = _next_states(mdp, ep, np.random.default_rng(j))
        np.savez(path, obs=obs, acts=ep[:, 1], rews=np.zeros(len(ep))) if j % 2 else np.savez(path, observations=ep[:, 0], actions=ep[:, 1])
        paths.append(path if j else str(path))
    back = demonstrations_from_trajectories([paths, demos[1]])  # files and a library (m, L, 2) array
    for ep, ref in zip(back[0] + back[1], list(demos[0]) + list(demos[1])):
        np.testing.assert_array_equal(ep, ref)
    with np.load(paths[1]) as npz:  # an opened .npz is a mapping: accepted as an episode anywhere
        mu, _ = fo.empirical_statistics(mdp, [[npz]])
    np.testing.assert_array_equal(mu, fo.empirical_statistics(mdp, [demos[0][1:2]])[0])
    with pytest.raises(ValidationError, match=r"demonstrations of task 0, episode 0 is a file name .*fo.demonstrations_from_trajectories"):
        fo.empirical_statistics(mdp, [paths])


def test_trajectories_save_and_load(setting, tmp_path):
    mdp, demos = setting
    trajs = _as_trajectories(mdp, demos, np.random.default_rng(2))
    back = fo.load_demonstrations(fo.save_demonstrations(trajs, tmp_path / "d.npz"))
    assert all(isinstance(task, list) for task in back)
    for task, original in zip(back, demos):
        np.testing.assert_array_equal(np.stack(task), original)


def test_docstring_example():
    demos = demonstrations_from_trajectories([[Trajectory([0, 1, 3], [1, 2]), {"obs": [2], "acts": [0]}]])
    assert [ep.tolist() for ep in demos[0]] == [[[0, 1], [1, 2]], [[2, 0]]]


# ----------------------------------------------------------------------------- trajectory errors


@pytest.mark.parametrize(
    "trajectory, match",
    [
        (Trajectory(np.zeros(3, dtype=np.float32), [1, 2]), r"observations must be integer states.*got float32 observations of shape \(3,\)"),
        (Trajectory(np.eye(16, dtype=int)[[0, 1, 2]], [1, 2]), r"got int64 observations of shape \(3, 16\) \(one row per step: one-hot.*np.argmax"),
        (Trajectory(np.zeros((3, 8, 8, 3), dtype=np.uint8), [1, 2]), r"got uint8 observations of shape \(3, 8, 8, 3\).*image"),
        (Trajectory([{"pos": 0}, {"pos": 1}], [1]), r"got object observations"),
        (Trajectory([True, False, True], [1, 2]), r"got bool observations"),
        (Trajectory([0, 1, 2], [0.5, 1.0]), r"actions must be integers.*got float64 actions of shape \(2,\)"),
        (Trajectory([0, 1, 2], [[0, 1], [1, 0]]), r"actions must be integers.*shape \(2, 2\)"),
        (Trajectory([0, 1, 2, 3], [1]), r"has 4 observations and 1 actions; expected L \+ 1 observations"),
        (Trajectory([0], []), r"has no actions \(observations of shape \(1,\)\); expected L >= 1 actions"),
        (Trajectory(5, []), r"has no actions \(observations of shape \(\)\)"),
        (Trajectory(5, [1]), r"got int64 observations of shape \(\)"),
        ({"obs": [0, 1]}, r"is a mapping but not a trajectory.*got keys \['obs'\]"),
        ({"obs": [0, 1], "observations": [0, 1], "acts": [1]}, r"needs exactly one of the keys 'obs', 'observations'"),
        (Trajectory([0, 5, 20], [1, 2]), r"task 0, episode 0, step 1: state 5 is out of range \[0, 4\)"),
        (Trajectory([-1, 0, 0], [0, 0]), r"task 0, episode 0, step 0: state -1 is out of range"),
        (Trajectory([0, 0], [7]), r"task 0, episode 0, step 0: action 7 is out of range \[0, 4\)"),
    ],
)
def test_bad_trajectories(trajectory, match):
    mdp = fo.GridWorld(size=2)  # 4 states, 4 actions
    with pytest.raises(ValidationError, match=match):
        demonstrations_from_trajectories([[trajectory]], mdp=mdp)
    with pytest.raises(ValidationError, match=match):
        fo.empirical_statistics(mdp, [[trajectory]])


def test_bad_rollout_files(setting, tmp_path):
    mdp, demos = setting
    with pytest.raises(FileNotFoundError):
        demonstrations_from_trajectories([[tmp_path / "missing.npz"]])
    (tmp_path / "junk.npz").write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(PersistenceError, match=r"episode 0 \(.*junk.npz\) is not a readable .npz rollout"):
        demonstrations_from_trajectories([[tmp_path / "junk.npz"]])
    np.save(tmp_path / "single.npy", np.arange(3))
    with pytest.raises(PersistenceError, match="holds a single array, not an .npz rollout"):
        demonstrations_from_trajectories([[tmp_path / "single.npy"]])
    saved = fo.save_demonstrations(demos, tmp_path / "ours.npz")
    with pytest.raises(PersistenceError, match="is a factirl-opt file, not a rollout: read it with fo.load_demonstrations"):
        demonstrations_from_trajectories([[saved]])
    np.savez(tmp_path / "objects.npz", obs=np.array([0, 1], dtype=object), acts=np.array([0]))
    with pytest.raises(PersistenceError, match=r"objects.npz\): a member is corrupt or unreadable"):
        demonstrations_from_trajectories([[tmp_path / "objects.npz"]])
    np.savez(tmp_path / "rewards.npz", rews=np.zeros(3))
    with pytest.raises(ValidationError, match=r"is a mapping but not a trajectory.*got keys \[\]"):
        demonstrations_from_trajectories([[tmp_path / "rewards.npz"]])


# ----------------------------------------------------------------------------- the nesting rule


def test_episodes_without_the_task_wrapper_show_both_layouts(setting):
    mdp, demos = setting
    episodes = list(demos[0])  # three (L, 2) arrays: one task's episodes, or three tasks?
    with pytest.raises(ValidationError) as info:
        fo.empirical_statistics(mdp, episodes)
    msg = str(info.value)
    assert "demos_per_task[0] is a single episode (an array of shape (7, 2)), not a task" in msg
    assert "pass [demos_per_task] (1 task of 3 episodes)" in msg
    assert "pass [[episode] for episode in demos_per_task] (3 tasks of 1 episode)" in msg
    # both suggestions, followed literally, work
    demos_per_task = episodes
    assert fo.empirical_statistics(mdp, [demos_per_task])[0].shape == (1, 16)
    assert fo.empirical_statistics(mdp, [[episode] for episode in demos_per_task])[0].shape == (3, 16)


def test_nesting_rule_for_pairs_trajectories_and_arrays(setting):
    mdp, demos = setting
    with pytest.raises(ValidationError, match=r"demos_per_task\[0\] is a single episode \(a list of \(state, action\) pairs\).*1 task of 2"):
        fo.empirical_statistics(mdp, [[(0, 1), (3, 0)], [(5, 0)]])
    with pytest.raises(ValidationError, match=r"demos_per_task\[0\] is a single episode .*Pass \[demos_per_task\] \(one task of one episode\)"):
        fo.empirical_statistics(mdp, [[(0, 1), (3, 0)]])
    with pytest.raises(ValidationError, match=r"demos_per_task\[1\] is a single episode .*only episode of task 1, wrap it in a list"):
        fo.empirical_statistics(mdp, [demos[0], demos[1][0]])
    t = Trajectory([0, 1], [1])
    with pytest.raises(ValidationError, match=r"demos_per_task\[0\] is a single episode \(a trajectory, Trajectory\).*2 tasks of 1 episode"):
        fo.empirical_statistics(mdp, [t, t])
    with pytest.raises(ValidationError, match=r"got a dict of 2 entries with keys \['obs', 'acts'\], a single trajectory: pass \[\[demos_per_task\]\]"):
        fo.empirical_statistics(mdp, {"obs": [0], "acts": [1]})
    with pytest.raises(ValidationError, match=r"trajectories_per_task\[0\] is a single episode \(a rollout file 'r.npz'\)"):
        demonstrations_from_trajectories(["r.npz"])
    with pytest.raises(ValidationError, match=r"got an array of shape \(3, 7, 2\), the layout of one task's episodes") as info:
        fo.empirical_statistics(mdp, demos[0])
    assert "pass [demos_per_task] for one task of 3 episodes, or list(demos_per_task[:, None]) for 3 tasks" in str(info.value)
    demos_per_task = demos[0]
    assert fo.empirical_statistics(mdp, [demos_per_task])[0].shape == (1, 16)
    assert fo.empirical_statistics(mdp, list(demos_per_task[:, None]))[0].shape == (3, 16)


def test_a_task_of_episodes_of_length_one_is_not_a_pair(setting):
    mdp, _ = setting
    mu, _ = fo.empirical_statistics(mdp, [[[[0, 1]], [[3, 2]]]])  # one task, two episodes of one step
    np.testing.assert_array_equal(mu[0, [0, 3]], [0.5, 0.5])


# ----------------------------------------------------------------------------- values, located


@pytest.mark.parametrize(
    "episode, match",
    [
        ([[0, 1], [2**70, 0]], r"step 1: state 1180591620717411303424 is out of range \[0, 16\)"),
        ([[0, 1], [3, -2**70]], r"step 1: action -1180591620717411303424 is out of range \[0, 4\)"),
        ([[0, 1], [None, 0]], r"step 1: state None is not an integer"),
        ([[0, 1], [1.5, 0]], r"step 1: state 1.5 is not an integer"),
        (np.array([[0, 1], [3, np.inf]]), r"step 1: action inf is not an integer"),
        (np.array([[0, 1], [1e300, 0]]), r"step 1: state 1e\+300 is out of range"),
        (np.array([[0, 1], [2**63, 0]], dtype=np.uint64), r"step 1: state 9223372036854775808 is out of range"),
        (np.array([[0, 1], [2.0**63, 0]]), r"step 1: state 9\.223372036854776e\+18 is out of range"),
        (np.array([[0, 1j]]), r"step 0: state 0j is not an integer \(the pairs have dtype complex128\)"),
        (np.array([[0, 1], [2, 3]], dtype="datetime64[s]"), r"step 0: state .* is not an integer \(the pairs have dtype datetime64\[s\]\)"),
    ],
)
def test_bad_values_are_named_with_their_place(episode, match):
    with pytest.raises(ValidationError, match=r"demonstrations of task 1, episode 0, " + match):
        fo.empirical_statistics(fo.GridWorld(size=4), [[[[0, 0]]], [episode]])


def test_whole_floats_and_small_dtypes_are_accepted_and_returned_as_int64():
    tasks = parse_demonstrations([np.array([[[0.0, 1.0]]]), [np.array([[3, 2]], dtype=np.uint8), [(4.0, 0)]]], 16, 4)
    assert [t.form for t in tasks] == ["array", "list"]
    assert all(t.steps.dtype == np.int64 for t in tasks)
    np.testing.assert_array_equal(tasks[1].steps, [[3, 2], [4, 0]])
    np.testing.assert_array_equal(tasks[1].lengths, [1, 1])
    assert [e.tolist() for e in tasks[1].episodes()] == [[[3, 2]], [[4, 0]]]


def test_task_steps_of_one_task(setting):
    mdp, demos = setting
    np.testing.assert_array_equal(task_steps(mdp, demos[0]), demos[0].reshape(-1, 2))
    with pytest.raises(ValidationError, match=r"demonstrations of task 5, episode 0, step 0: state 16 is out of range"):
        task_steps(mdp, [[[16, 0]]], task=5)


# ----------------------------------------------------------------------------- fuzzing


_VALUES = [0, 1, 3, 15, 16, -1, 0.5, 2.0, np.nan, np.inf, 2**70, True, None, "a", 1e300]


def _random_episode(rng):
    kind = rng.integers(6)
    L = int(rng.integers(0, 4))
    if kind == 0:  # a well-formed int array, maybe out of range
        return rng.integers(-1, 18, size=(L, 2))
    if kind == 1:  # a list of pairs of arbitrary values
        return [[_VALUES[rng.integers(len(_VALUES))] for _ in range(2)] for _ in range(L)]
    if kind == 2:  # a wrongly shaped array
        return rng.integers(0, 4, size=tuple(rng.integers(0, 4, size=rng.integers(0, 4))))
    if kind == 3:  # a trajectory, maybe with float or mismatched observations
        obs = rng.integers(-1, 17, size=L + int(rng.integers(0, 3)))
        return Trajectory(obs.astype(float) if rng.random() < 0.3 else obs, rng.integers(0, 5, size=L))
    if kind == 4:  # a mapping with maybe missing keys
        keys = rng.choice(["obs", "observations", "acts", "actions", "rews"], size=2, replace=False)
        return {str(k): rng.integers(0, 4, size=L + 1) for k in keys}
    return [None, "x", 3.5, {}][rng.integers(4)]


def _random_demos(rng):
    kind = rng.integers(5)
    if kind == 0:
        return rng.integers(-1, 17, size=tuple(rng.integers(0, 4, size=rng.integers(2, 6))))
    if kind == 1:
        return _random_episode(rng)
    return [[_random_episode(rng) for _ in range(rng.integers(0, 3))] if rng.random() < 0.8 else _random_episode(rng)
            for _ in range(rng.integers(0, 4))]


def test_fuzzed_layouts_give_a_validation_error_or_valid_statistics():
    mdp = fo.GridWorld(size=4)
    rng = np.random.default_rng(7)
    outcomes = {"refused": 0, "accepted": 0}
    with hang_guard(60):
        for _ in range(1500):
            demos = _random_demos(rng)
            try:
                mu, pi = fo.empirical_statistics(mdp, demos)
            except ValidationError:
                outcomes["refused"] += 1
                continue
            assert np.all(np.isfinite(mu)) and np.all(np.isfinite(pi))
            np.testing.assert_allclose(mu.sum(axis=1), 1.0)
            outcomes["accepted"] += 1
    assert min(outcomes.values()) > 20  # both branches are exercised


def test_a_mapping_of_tasks_is_reported_as_what_it_is(setting):
    mdp, demos = setting
    by_name = {"reach": demos[0], "avoid": demos[1]}
    with pytest.raises(ValidationError) as info:
        fo.empirical_statistics(mdp, by_name)
    msg = str(info.value)
    assert "got a dict of 2 entries with keys ['reach', 'avoid']" in msg
    assert "a mapping of tasks is not accepted" in msg and "list(demos_per_task.values())" in msg
    assert "single trajectory" not in msg
    # the suggestion, followed literally, works
    demos_per_task = by_name
    assert fo.empirical_statistics(mdp, list(demos_per_task.values()))[0].shape == (2, 16)
    many = {f"task{i}": demos[0] for i in range(9)}
    with pytest.raises(ValidationError, match=r"a dict of 9 entries with keys \['task0', .*'task5', \.\.\.\]"):
        fo.empirical_statistics(mdp, many)


def test_a_mapping_of_episodes_as_a_task_is_reported_as_what_it_is(setting):
    mdp, demos = setting
    episodes = {"first": demos[0][0], "second": demos[0][1]}
    with pytest.raises(ValidationError) as info:
        fo.empirical_statistics(mdp, [episodes])
    msg = str(info.value)
    assert "demonstrations of task 0 must be an int array of shape (m, L, 2) or a list of episodes" in msg
    assert "got a dict of 2 entries with keys ['first', 'second']" in msg and "list(episodes.values())" in msg


@pytest.mark.parametrize(
    "demos, fragment",
    [
        (iter([[[[0, 1]]]]), r"got list_iterator: pass list\(demos_per_task\) if it yields one entry per task"),
        (3, r"got int 3$"),
        (np.zeros((2, 2)), r"got an array of shape \(2, 2\) and dtype float64"),
        ([[[[0, 1], [2]]]], r"task 0, episode 0 must be an array of \(state, action\) pairs of shape \(L, 2\); got a list of length 2"),
        ([[np.zeros((3, 3), dtype=int)]], r"task 0, episode 0 must have shape \(L, 2\) with L >= 1; got \(3, 3\) \(an array of shape \(3, 3\) and dtype int64\)"),
        ([[[[0, 1]], 7]], r"task 0, episode 1 must have shape \(L, 2\) with L >= 1; got \(\) \(int 7\)"),
    ],
)
def test_layout_messages_name_the_input(setting, demos, fragment):
    mdp, _ = setting
    with pytest.raises(ValidationError, match=fragment):
        fo.empirical_statistics(mdp, demos)

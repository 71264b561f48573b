"""Minari datasets recorded here (minari.DataCollector, toy-text and MiniGrid environments, in a
temporary MINARI_DATASETS_PATH: nothing is downloaded) read back as episodes and transitions;
every refusal checked on duck-typed datasets."""

import subprocess
import sys
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import MissingDependencyError, PersistenceError, ValidationError
from factirl_opt.adapters.minari import LoggedEpisodes, read_minari


def _record(minari, dataset_id, env, n_episodes, seed, observation_space=None):
    """Record ``n_episodes`` of uniformly random actions; return our own log of them."""
    collector = minari.DataCollector(env, observation_space=observation_space)
    rng = np.random.default_rng(seed)
    log = []
    for i in range(n_episodes):
        obs, _ = collector.reset(seed=seed + i)
        observations, actions, done = [obs], [], False
        while not done:
            a = int(rng.integers(collector.action_space.n))
            obs, _, terminated, truncated, _ = collector.step(a)
            observations.append(obs)
            actions.append(a)
            done = terminated or truncated
        log.append((observations, np.array(actions)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # metadata (author, permalink) left unset
        collector.create_dataset(dataset_id=dataset_id, algorithm_name="uniform random actions")
    collector.close()
    return log


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Datasets recorded into a temporary local storage, with our own logs of them."""
    minari = pytest.importorskip("minari")
    pytest.importorskip("jax", reason="minari.DataCollector needs jax (minari's 'create' extra)")
    gym = pytest.importorskip("gymnasium")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("MINARI_DATASETS_PATH", str(tmp_path_factory.mktemp("minari")))
        logs = {
            "test/frozenlake/slippery-v0": _record(minari, "test/frozenlake/slippery-v0",
                                                    gym.make("FrozenLake-v1", is_slippery=True), 40, seed=0),
            "test/frozenlake/deterministic-v0": _record(minari, "test/frozenlake/deterministic-v0",
                                                         gym.make("FrozenLake-v1", is_slippery=False), 300, seed=1000),
        }
        yield SimpleNamespace(minari=minari, gym=gym, logs=logs)


def test_episodes_and_transitions_match_the_recording(recorded):
    log = recorded.logs["test/frozenlake/slippery-v0"]
    logged = read_minari("test/frozenlake/slippery-v0")
    assert isinstance(logged, LoggedEpisodes)
    assert (logged.n_states, logged.n_actions) == (16, 4)
    np.testing.assert_array_equal(logged.episode_ids, np.arange(40))
    assert len(logged.episodes) == 40
    for (observations, actions), steps, final in zip(log, logged.episodes, logged.final_states):
        assert steps.dtype == np.int64 and steps.shape == (len(actions), 2)
        np.testing.assert_array_equal(steps, np.column_stack((observations[:-1], actions)))
        assert final == observations[-1]
    expected = np.vstack([np.column_stack((obs[:-1], acts, obs[1:])) for obs, acts in log])
    np.testing.assert_array_equal(logged.transitions(), expected)
    mdp = fo.adapters.from_gymnasium("FrozenLake-v1", is_slippery=True)
    assert np.all(mdp.transitions[expected[:, 0], expected[:, 1], expected[:, 2]] > 0)
    assert fo.mdp.transition_log_likelihood(mdp, logged) == pytest.approx(np.log(mdp.transitions[tuple(expected.T)]).sum())
    mu, pi = fo.empirical_statistics(mdp, [logged.episodes])  # one task's demonstrations, as they are
    assert mu.shape == (1, 16) and pi.shape == (1, 16, 4)


def test_a_deterministic_model_is_recovered_exactly(recorded):
    logged = read_minari("test/frozenlake/deterministic-v0")
    est = fo.estimate_mdp(logged, logged.n_states, logged.n_actions, 0.9, pseudo_count=0)  # read as logged.transitions()
    # every (s, a) of a non-terminal state was tried; holes and goal, never left, get the
    # self-loop prior: absorbing, as in from_gymnasium's convention
    np.testing.assert_array_equal(est.transitions, fo.adapters.from_gymnasium("FrozenLake-v1", is_slippery=False).transitions)


def test_opened_dataset_and_selected_episodes(recorded):
    dataset = recorded.minari.load_dataset("test/frozenlake/slippery-v0")
    every = read_minari(dataset)
    some = read_minari(dataset, episode_indices=[3, 7])
    np.testing.assert_array_equal(some.episode_ids, [3, 7])
    np.testing.assert_array_equal(some.episodes[1], every.episodes[7])
    assert some.final_states.tolist() == every.final_states[[3, 7]].tolist()
    with pytest.raises(ValidationError, match="holds no episodes"):
        read_minari(dataset, episode_indices=[])


def test_a_dataset_missing_locally_is_not_downloaded(recorded):
    with pytest.raises(FileNotFoundError, match=r"'test/absent-v0' is not in local storage.*minari download test/absent-v0"):
        read_minari("test/absent-v0")


def test_minigrid_is_refused_unless_mapped(recorded, tmp_path, monkeypatch):
    pytest.importorskip("minigrid")
    gym = recorded.gym
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    base = gym.make("MiniGrid-Empty-5x5-v0", max_steps=6)
    space = gym.spaces.Dict({"direction": base.observation_space["direction"], "image": base.observation_space["image"],
                             "mission": gym.spaces.Text(max_length=64, charset=" abcdefghijklmnopqrstuvwxyz")})
    log = _record(recorded.minari, "test/minigrid/random-v0", base, 2, seed=0, observation_space=space)
    with pytest.raises(ValidationError, match=r"MiniGrid/BabyAI dataset \(env MiniGrid-Empty-5x5-v0.*fo.minigrid.from_minigrid.*observation_to_state"):
        read_minari("test/minigrid/random-v0")
    # the hook: here the agent's direction stands for a state (a model whose states the observations identify)
    logged = read_minari("test/minigrid/random-v0", observation_to_state=lambda obs: obs["direction"], n_states=4)
    np.testing.assert_array_equal(logged.episodes[0][:, 0], [o["direction"] for o in log[0][0][:-1]])
    assert (logged.n_states, logged.n_actions) == (4, 7)


def test_missing_minari_gives_the_install_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "minari", None)  # import minari raises ImportError
    with pytest.raises(MissingDependencyError, match=r'needs minari, which is not installed: pip install "minari\[hdf5\]>=0.5"'):
        read_minari("test/frozenlake/slippery-v0")


def test_import_factirl_opt_does_not_import_minari():
    code = "import sys, factirl_opt; print('minari' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# ----------------------------------------------------------------------------- refusals on duck-typed datasets


def _episode(i, observations, actions):
    return SimpleNamespace(id=i, observations=np.asarray(observations), actions=np.asarray(actions))


def _dataset(episodes, observation_space=None, action_space=None, env_id=""):
    def iterate_episodes(indices=None):
        return iter(episodes if indices is None else [episodes[i] for i in indices])

    return SimpleNamespace(observation_space=SimpleNamespace(n=3) if observation_space is None else observation_space,
                           action_space=SimpleNamespace(n=2) if action_space is None else action_space,
                           env_spec=SimpleNamespace(id=env_id), iterate_episodes=iterate_episodes)


def test_duck_typed_dataset_is_read():
    logged = read_minari(_dataset([_episode(5, [0, 2, 1], [1, 0]), _episode(6, [1, 1], [0])]))
    np.testing.assert_array_equal(logged.transitions(), [[0, 1, 2], [2, 0, 1], [1, 0, 1]])
    np.testing.assert_array_equal(logged.episode_ids, [5, 6])


@pytest.mark.parametrize(
    "dataset, kwargs, match",
    [
        (object(), {}, "dataset must be a Minari dataset id.*without observation_space, action_space, iterate_episodes"),
        (_dataset([], observation_space=SimpleNamespace(shape=(2,))), {}, "observation space .* is not Discrete.*observation_to_state"),
        (_dataset([], action_space=SimpleNamespace(shape=(1,))), {}, "action space .* is not Discrete"),
        (_dataset([], observation_space=SimpleNamespace(n=3, start=1)), {}, "observation space .* starts at 1"),
        (_dataset([], env_id="BabyAI-GoToLocal-v0"), {}, r"MiniGrid/BabyAI dataset \(env BabyAI-GoToLocal-v0"),
        (_dataset([], observation_space=SimpleNamespace(spaces={"image": 0, "direction": 0, "mission": 0})), {},
         "MiniGrid/BabyAI dataset"),
        (_dataset([]), {"observation_to_state": 3, "n_states": 3}, "observation_to_state must be callable; got int"),
        (_dataset([]), {"observation_to_state": abs}, "observation_to_state needs n_states"),
        (_dataset([]), {"n_states": 3}, "n_states is only used with observation_to_state"),
        (_dataset([]), {"observation_to_state": abs, "n_states": 0}, "n_states must be an integer >= 1"),
        (_dataset([]), {}, "holds no episodes"),
        (_dataset([_episode(4, [0], np.zeros(0, dtype=int))]), {}, "episode 4 has no actions"),
        (_dataset([_episode(4, [0, 1], [1, 1])]), {}, r"episode 4 has 2 states \(observations\) and 2 actions; expected L \+ 1 = 3"),
        (_dataset([_episode(4, [0, 1, 2], [1, 2])]), {}, r"episode 4: actions 2 at step 1 is out of range \[0, 2\)"),
        (_dataset([_episode(4, [0, 3, 2], [1, 1])]), {}, r"episode 4: states 3 at step 1 is out of range \[0, 3\)"),
        (_dataset([_episode(4, [0.0, 1.0], [1])]), {}, "episode 4: states must be a 1-d array of integers; got float64"),
        (_dataset([_episode(4, [[0, 1], [1, 0]], [1])]), {}, r"states must be a 1-d array of integers; got int64 values of shape \(2, 2\)"),
        (_dataset([_episode(4, [0, 1], [1])]), {"observation_to_state": lambda obs: obs + 5, "n_states": 6},
         r"episode 4: states 6 at step 1 is out of range \[0, 6\)"),
    ],
)
def test_refusals(dataset, kwargs, match):
    with pytest.raises(ValidationError, match=match):
        read_minari(dataset, **kwargs)


# ----------------------------------------------------------------------------- damaged datasets


def _damaged(error, after=0, **extra):
    """A duck-typed dataset whose storage fails with ``error`` after ``after`` good episodes."""

    def iterate_episodes(indices=None):
        yield from [_episode(i, [0, 1], [1]) for i in range(after)]
        raise error

    spec = SimpleNamespace(dataset_id="test/damaged-v0", data_path="/data/test/damaged-v0/data")
    return SimpleNamespace(observation_space=SimpleNamespace(n=3), action_space=SimpleNamespace(n=2), spec=spec,
                           iterate_episodes=iterate_episodes, **extra)


@pytest.mark.parametrize("error, after", [
    (OSError("Unable to synchronously open file (truncated file: eof = 21112, stored_eof = 42224)"), 0),
    (KeyError("Unable to synchronously open object (object 'episode_2' doesn't exist)"), 2),
    (ValueError("No data found in data path /data/test/damaged-v0/data"), 1),
])
def test_a_damaged_dataset_is_a_persistence_error_naming_it(error, after):
    with pytest.raises(PersistenceError, match=r"the Minari dataset 'test/damaged-v0' \(/data/test/damaged-v0/data\) cannot "
                                                  rf"be read: {type(error).__name__}: .*damaged, truncated or missing") as info:
        read_minari(_damaged(error, after))
    assert info.value.__cause__ is error


def test_errors_of_the_callers_own_code_and_ours_are_not_taken_for_damage():
    def mapping(obs):
        raise ZeroDivisionError("the caller's bug")

    with pytest.raises(ZeroDivisionError, match="the caller's bug"):
        read_minari(_dataset([_episode(4, [0, 1], [1])]), observation_to_state=mapping, n_states=3)
    with pytest.raises(KeyboardInterrupt):
        read_minari(_damaged(KeyboardInterrupt()))


def test_episode_indices_the_dataset_does_not_have_are_refused():
    ds = _damaged(OSError("never read"), total_episodes=3)
    for indices, bad in (([0, 10], 10), ([-1], -1)):
        with pytest.raises(ValidationError, match=rf"episode_indices: episode {bad} is not in the Minari dataset 'test/damaged-v0' "
                                                  r"\(/data/test/damaged-v0/data\), which has 3 episodes \(indices 0..2\)"):
            read_minari(ds, indices)
    with pytest.raises(ValidationError, match="episode_indices must be an iterable of episode indices; got int"):
        read_minari(ds, 3)


def test_damaged_files_of_a_real_dataset(tmp_path, monkeypatch):
    minari = pytest.importorskip("minari")
    from minari.data_collector import EpisodeBuffer

    gym = pytest.importorskip("gymnasium")
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    rng = np.random.default_rng(0)
    buffers = [EpisodeBuffer(observations=list(rng.integers(16, size=5)), actions=list(rng.integers(4, size=4)),
                             rewards=[0.0] * 4, terminations=[False] * 3 + [True], truncations=[False] * 4) for _ in range(3)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        minari.create_dataset_from_buffers("test/fl/damaged-v0", buffers, env=gym.make("FrozenLake-v1"), algorithm_name="random")
    data = tmp_path / "test/fl/damaged-v0/data"
    assert len(read_minari("test/fl/damaged-v0").episodes) == 3
    name = r"the Minari dataset 'test/fl/damaged-v0' \(.*test/fl/damaged-v0\) cannot be read"
    with pytest.raises(ValidationError, match="episode 3 is not in the Minari dataset 'test/fl/damaged-v0'"):
        read_minari("test/fl/damaged-v0", [3])
    hdf5 = data / "main_data.hdf5"
    hdf5.write_bytes(hdf5.read_bytes()[: hdf5.stat().st_size // 2])
    with pytest.raises(PersistenceError, match=name + r": OSError: .*truncated file"):
        read_minari("test/fl/damaged-v0")
    (data / "metadata.json").write_text("{bad json")
    with pytest.raises(PersistenceError, match=name + ": JSONDecodeError"):
        read_minari("test/fl/damaged-v0")
    (data / "metadata.json").unlink()
    with pytest.raises(PersistenceError, match=name + ": ValueError: No data found"):
        read_minari("test/fl/damaged-v0")

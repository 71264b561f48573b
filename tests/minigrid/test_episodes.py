"""The BabyAI bot's demonstrations reproduced by the enumerated models, and policies run in the
real environment."""

import importlib
import sys

import numpy as np
import pytest

minigrid = pytest.importorskip("minigrid")
gym = pytest.importorskip("gymnasium")

import factirl_opt as fo  # noqa: E402
from factirl_opt.exceptions import MissingDependencyError, ValidationError  # noqa: E402
from factirl_opt.adapters.minigrid import bot_demonstration, from_minigrid, run_policy  # noqa: E402
from factirl_opt.adapters.minigrid.episodes import _check_step  # noqa: E402

LOCAL = "BabyAI-GoToLocal-v0"


def mismatches(episode):
    """Steps whose observed next state is not where the model's row puts probability 1."""
    P = episode.model.mdp.transition_matrix
    bad = 0
    for (s, a), n in zip(episode.demonstration, episode.next_states):
        row = P.getrow(s * 3 + a)
        bad += not (row.nnz == 1 and row.indices[0] == n and row.data[0] == 1.0)
    return bad


def test_bot_episodes_are_the_models_transitions_on_50_layouts():
    """Acceptance: >= 1000 steps of the bot on 50 GoToLocal layouts, 0 transitions off the model.

    From each layout's start, and from 4 other non-terminal states drawn at random (so that
    the steps add up to over 1000; the bot solves a layout from its start in about 5 steps).
    From a few of those starts the bot picks up an object blocking its way, a step outside the
    navigation model, and bot_demonstration refuses the episode; they are counted, not used.
    """
    env = gym.make(LOCAL)
    rng = np.random.default_rng(0)
    steps = bad = wins = picked = 0
    for seed in range(50):
        episode = bot_demonstration(env, seed)
        model = episode.model
        assert episode.mission == env.unwrapped.mission == model.mission
        assert episode.demonstration[0, 0] == model.start and model.terminal[episode.next_states[-1]]
        np.testing.assert_array_equal(episode.demonstration[1:, 0], episode.next_states[:-1])
        wins += episode.success
        runs = [episode]
        for s in rng.choice(np.flatnonzero(~model.terminal), size=4, replace=False):
            try:
                runs.append(bot_demonstration(env, seed, start=tuple(model.states[s])))
            except ValidationError as exc:  # from a few starts the bot moves an object out of its way
                assert "the bot chose action 3 ('pickup')" in str(exc)
                picked += 1
                continue
            assert runs[-1].demonstration[0, 0] == s
            assert runs[-1].model.mdp.signature() == model.mdp.signature()
        for run in runs:
            steps += len(run.demonstration)
            bad += mismatches(run)
            assert run.success and len(run.demonstration) < env.unwrapped.max_steps
    print(f"{steps} bot steps, {bad} mismatches, {picked} episodes refused (pick-up)")
    assert steps >= 1000 and bad == 0
    assert wins == 50 and picked <= 5  # 3 of the 200 other starts with this rng


def test_goto_open_layout():
    episode = bot_demonstration("BabyAI-GoToOpen-v0", seed=2)
    assert 1100 <= episode.model.n_states <= 1400
    assert episode.success and mismatches(episode) == 0


def test_demonstrations_are_the_librarys_layout():
    episode = bot_demonstration(LOCAL, seed=4)
    assert episode.demonstration.dtype == np.int64 and episode.demonstration.shape[1] == 2
    mu, pi = fo.empirical_statistics(episode.model.mdp, [episode.demonstrations])
    assert mu.shape == (1, episode.model.n_states) and np.isclose(mu.sum(), 1.0)


def bot_policy(episode):
    policy = np.zeros(episode.model.n_states, dtype=np.int64)
    policy[episode.demonstration[:, 0]] = episode.demonstration[:, 1]
    return policy


def test_run_policy_with_the_bots_actions_succeeds():
    for seed in range(5):
        episode = bot_demonstration(LOCAL, seed)
        run = run_policy(LOCAL, bot_policy(episode), seed=seed, model=episode.model)
        assert run.success and run.reward > 0
        np.testing.assert_array_equal(run.actions, episode.demonstration[:, 1])
        np.testing.assert_array_equal(run.states[1:], episode.next_states)
        assert run_policy(LOCAL, bot_policy(episode), seed=seed).success  # model read from the env


def test_run_policy_constant_and_random_policies_fail():
    env = gym.make(LOCAL)
    env.reset(seed=0)
    model = from_minigrid(env)
    run = run_policy(env, np.zeros(model.n_states, dtype=int), seed=0)  # turns left forever
    assert not run.success and run.reward == 0.0
    assert len(run.actions) == env.unwrapped.max_steps  # stopped by the environment's truncation
    assert set(run.states.tolist()) == {model.start, *[model.index(*model.states[model.start][:2], d) for d in range(4)]}
    rng = np.random.default_rng(1)
    random = [run_policy(env, rng.integers(0, 3, model.n_states), seed=0, model=model).success for _ in range(5)]
    assert sum(random) < 5
    capped = run_policy(env, np.ones(model.n_states, dtype=int), seed=0, max_steps=3)  # turns right
    assert len(capped.actions) == 3 and len(capped.states) == 4


def test_run_policy_errors():
    env = gym.make(LOCAL)
    env.reset(seed=0)
    model = from_minigrid(env)
    S = model.n_states
    with pytest.raises(ValidationError, match=rf"shape \({S},\)"):
        run_policy(env, np.zeros(S + 1, dtype=int), seed=0)
    with pytest.raises(ValidationError, match="dtype float64"):
        run_policy(env, np.zeros(S), seed=0)
    with pytest.raises(ValidationError, match=r"policy\[3\] = 5"):
        run_policy(env, np.where(np.arange(S) == 3, 5, 0), seed=0)
    with pytest.raises(ValidationError, match="not the environment's current layout"):
        run_policy(env, np.zeros(S, dtype=int), seed=1, model=model)
    with pytest.raises(ValidationError, match="model must be a MiniGridModel"):
        run_policy(env, np.zeros(S, dtype=int), seed=0, model=model.mdp)
    with pytest.raises(ValidationError, match="a seed is needed"):
        run_policy(LOCAL, np.zeros(S, dtype=int))
    with pytest.raises(ValidationError, match="max_steps"):
        run_policy(env, np.zeros(S, dtype=int), seed=0, max_steps=0)
    with pytest.raises(ValidationError, match="seed"):
        run_policy(env, np.zeros(S, dtype=int), seed=-1)


def test_bot_demonstration_errors(monkeypatch):
    with pytest.raises(ValidationError, match="a seed is needed"):
        bot_demonstration(LOCAL)
    with pytest.raises(ValidationError, match="needs a BabyAI level"):
        bot_demonstration("MiniGrid-Empty-5x5-v0", seed=0)
    env = gym.make(LOCAL)
    env.reset(seed=0)
    model = from_minigrid(env)
    terminal = tuple(model.states[np.flatnonzero(model.terminal)[0]])
    with pytest.raises(ValidationError, match="is a terminal state"):
        bot_demonstration(env, 0, start=terminal)
    with pytest.raises(ValidationError, match="is not a state of this model"):
        bot_demonstration(env, 0, start=(0, 0, 0))
    with pytest.raises(ValidationError, match=r"start must be an \(x, y, direction\) triple of integers"):
        bot_demonstration(env, 0, start=5)
    with pytest.raises(ValidationError, match="closed .* door"):
        bot_demonstration("BabyAI-GoTo-v0", seed=0)
    bot = importlib.import_module("minigrid.utils.baby_ai_bot").BabyAIBot  # imported whatever ran before
    monkeypatch.setattr(bot, "replan", lambda self, action_taken=None: self.mission.unwrapped.actions.done)
    with pytest.raises(ValidationError, match=r"the bot chose action 6 \('done'\) in state .* only \('left', 'right', 'forward'\)"):
        bot_demonstration(env, 0)


def test_a_model_or_another_object_given_for_the_environment_is_refused():
    env = gym.make(LOCAL)
    env.reset(seed=0)
    model = from_minigrid(env)
    for wrong, hint in ((model, r"MiniGridModel \(a model read from an environment: pass the environment itself"),
                        (model.mdp, r"TabularMDP \(a model read"), (3, "int$")):
        for call in (lambda: bot_demonstration(wrong, 0), lambda: run_policy(wrong, np.zeros(model.n_states, dtype=int), seed=0)):
            with pytest.raises(ValidationError, match=r"env must be a MiniGrid/BabyAI environment \(a gymnasium.Env with "
                                                      r"reset and step\) or its id; got " + hint):
                call()


@pytest.mark.parametrize("env_id, reason", [("BabyAI-GoToLocl-v0", "Environment `BabyAI-GoToLocl` doesn't exist"),
                                            ("BabyAI-GoToLocal-v9", "Environment version `v9`"),
                                            ("nowhere/GoTo-v0", "Namespace nowhere not found")])
def test_an_unknown_environment_id_is_refused_naming_it(env_id, reason):
    """gymnasium's own exception (NameNotFound and the like) used to pass through."""
    for call in (lambda: bot_demonstration(env_id, seed=0), lambda: run_policy(env_id, np.zeros(3, dtype=int), seed=0)):
        with pytest.raises(ValidationError, match=rf"^env={env_id!r} is not a registered environment id: {reason}") as err:
            call()
        assert err.value.__cause__ is None and not isinstance(err.value, gym.error.Error)


def test_steps_off_the_model_raise():
    episode = bot_demonstration(LOCAL, seed=0)
    model = episode.model
    s, a = episode.demonstration[0]
    n = tuple(model.states[episode.next_states[0]])
    assert _check_step(model, s, a, n, bool(model.terminal[episode.next_states[0]]), 0) == episode.next_states[0]
    with pytest.raises(ValidationError, match=r"reached \(0, 0, 0\), which is not a state of the model"):
        _check_step(model, s, a, (0, 0, 0), False, 0)
    other = tuple(model.states[(episode.next_states[0] + 1) % model.n_states])
    with pytest.raises(ValidationError, match="the model predicts"):
        _check_step(model, s, a, other, bool(model.terminal[model.index(*other)]), 0)
    with pytest.raises(ValidationError, match="terminated=True"):
        _check_step(model, s, a, n, not model.terminal[episode.next_states[0]], 0)


def test_missing_minigrid_raises_with_the_pip_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "minigrid", None)
    for call in (lambda: bot_demonstration(LOCAL, seed=0), lambda: run_policy(LOCAL, np.zeros(3, dtype=int), seed=0)):
        with pytest.raises(MissingDependencyError, match="minigrid, which is not installed: pip install"):
            call()


def test_greedy_policy_of_the_missions_feature_reward_succeeds_in_the_environment():
    """End to end: reward 1 on the feature "front=<colour> <type>" of the mission, planned on
    the model, is a policy that the environment judges successful from the start."""
    env = gym.make(LOCAL)
    for seed in range(10):
        env.reset(seed=seed)
        model = from_minigrid(env)
        colour, kind = fo.minigrid.parse_goto_mission(model.mission)
        reward = model.features[:, model.feature_names.index(f"front={colour} {kind}")]
        np.testing.assert_array_equal(reward.astype(bool), model.success)
        _, policy = fo.optimal_q(model.mdp, np.repeat(reward[:, None], 3, axis=1))
        run = run_policy(env, policy, seed=seed, model=model)
        assert run.success and model.success[run.states[-1]]

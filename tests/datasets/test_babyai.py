"""BabyAI tasks as a library function: the same draw as the harness's world, validated parameters."""

import numpy as np
import pytest

pytest.importorskip("minigrid")

import factirl_opt as fo  # noqa: E402
from factirl_opt.exceptions import ValidationError  # noqa: E402
from factirl_opt.lab.experiments import PRESETS  # noqa: E402
from factirl_opt.lab.experiments.worlds import babyai_world  # noqa: E402


def test_babyai_tasks_is_the_draw_of_the_experiments_world():
    preset = PRESETS["babyai-quick"]
    lib = fo.datasets.babyai_tasks("BabyAI-GoToLocal-v0", 2, 2, n_test_tasks=2, gamma=preset.gamma, seed=3)
    import dataclasses

    world = babyai_world(dataclasses.replace(preset, n_test_tasks=2), 2, 2, 3)
    assert lib.seeds == world.seeds
    for a, b in zip(lib.train_demos + lib.test_demos, world.train_demos + world.test_demos):
        assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert len(lib.mdps("train")) == 2 and len(lib.features("test")) == 2


@pytest.mark.parametrize("kwargs, match", [({"n_tasks": 0}, "n_tasks"), ({"demos_per_task": 0}, "demos_per_task"),
                                           ({"n_test_tasks": 0}, "n_test_tasks"), ({"gamma": 1.0}, "gamma")])
def test_babyai_tasks_refuses_bad_parameters(kwargs, match):
    with pytest.raises(ValidationError, match=match):
        fo.datasets.babyai_tasks(**kwargs)


@pytest.mark.parametrize("env_id, match", [
    ("BabyAI-GoToNowhere-v0", r"^env_id='BabyAI-GoToNowhere-v0' is not a registered environment id: Environment "
                              r"`BabyAI-GoToNowhere` doesn't exist"),
    ("BabyAI-GoToLocal-v7", r"^env_id='BabyAI-GoToLocal-v7' is not a registered environment id: Environment version `v7`"),
    (7, r"^env_id must be a registered environment id \(a str\); got int$")])
def test_babyai_tasks_refuses_an_unknown_environment_id_naming_it(env_id, match):
    with pytest.raises(ValidationError, match=match):
        fo.datasets.babyai_tasks(env_id, n_tasks=1, demos_per_task=1, n_test_tasks=1)


class _Draws:
    """An rng whose ``integers`` returns the given layout seeds in turn."""

    def __init__(self, seeds):
        self.seeds = list(seeds)

    def integers(self, high):
        return self.seeds.pop(0)


def test_a_layout_whose_bot_leaves_the_model_from_its_start_is_refused():
    """GoToOpen layout 315: from the start, the bot picks up an object in its way at step 6 (the
    model holds no pick-up); the layout is skipped for the next draw instead of failing the whole
    draw (the `sharing-babyai-large` preset's seed 1 met one)."""
    import gymnasium

    from factirl_opt.adapters.minigrid import bot_demonstration
    from factirl_opt.datasets.babyai import _layouts

    env = gymnasium.make("BabyAI-GoToOpen-v0")
    with pytest.raises(ValidationError, match=r"step 6: the bot chose action 3 \('pickup'\)"):
        bot_demonstration(env, seed=315, gamma=0.9)
    seeds, models, firsts = _layouts(env, 1, _Draws([315, 1]), set(), 0.9)
    assert seeds == [1] and len(models) == 1
    np.testing.assert_array_equal(firsts[0].demonstration, bot_demonstration(env, seed=1, gamma=0.9).demonstration)

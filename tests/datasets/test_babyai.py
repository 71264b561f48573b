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

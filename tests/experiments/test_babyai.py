"""The BabyAI world of the experiments: layouts, demonstrations, scores in the environment, the
quick preset end to end, claims and the figure."""

import csv
import dataclasses

import numpy as np
import pytest

pytest.importorskip("minigrid")

import gymnasium as gym  # noqa: E402

from factirl_opt.exceptions import ValidationError  # noqa: E402
from factirl_opt.datasets.babyai import mission_rewards, random_success_probability  # noqa: E402
from factirl_opt.lab.experiments import babyai  # noqa: E402
from factirl_opt.lab.experiments.worlds import babyai_world  # noqa: E402
from factirl_opt.lab.experiments.babyai_figure import babyai_figure_data, plot_babyai_layout  # noqa: E402
from factirl_opt.lab.experiments.presets import PRESETS  # noqa: E402
from factirl_opt.lab.experiments.runner import run_sweep  # noqa: E402
from factirl_opt.lab.experiments.tables import ENVIRONMENT_COLUMNS, read_csv  # noqa: E402
from factirl_opt.adapters.minigrid import from_minigrid  # noqa: E402

SMALL = dataclasses.replace(PRESETS["babyai-quick"], n_test_tasks=3, n_primitives=2, flat_max_iter=5, fact_max_iter=2,
                            transfer_max_iter=5)


@pytest.fixture(scope="module")
def model():
    env = gym.make("BabyAI-GoToLocal-v0")
    env.reset(seed=3)
    return from_minigrid(env)


@pytest.fixture(scope="module")
def world():
    return babyai_world(SMALL, 3, 2, 0)


def test_mission_rewards_pay_entering_success(model):
    R = mission_rewards(model)
    P = model.mdp.transition_matrix
    for s in range(model.n_states):
        for a in range(3):
            nxt = P.indices[P.indptr[s * 3 + a]]
            assert R[s, a] == (1.0 if model.success[nxt] and not model.terminal[s] else 0.0)
    assert R.sum() > 0


def _reference_random_success(model, T):
    """Backward recursion: V_t(s) = probability of success within t steps from s."""
    P = model.mdp.transition_matrix
    nxt = np.array([[P.indices[P.indptr[s * 3 + a]] for a in range(3)] for s in range(model.n_states)])
    V = model.success.astype(float)
    for _ in range(T):
        V = np.where(model.success, 1.0, np.where(model.terminal, 0.0, V[nxt].mean(axis=1)))
    return V[model.start]


@pytest.mark.parametrize("T", [0, 1, 5, 64])
def test_random_success_probability_matches_backward_recursion(model, T):
    assert random_success_probability(model, T) == pytest.approx(_reference_random_success(model, T), abs=1e-12)


def test_random_success_probability_grows_with_steps(model):
    p = [random_success_probability(model, T) for T in (0, 10, 64, 1000)]
    assert p[0] == 0.0 and np.all(np.diff(p) >= 0) and 0 < p[-1] <= 1 + 1e-12


def test_world_layouts_and_demonstrations(world):
    train, test = world.seeds["train"], world.seeds["test"]
    assert len(train) == 3 and len(test) == 3 and not set(train) & set(test)
    for split, m in (("train", 2), ("test", 1)):
        for model, demos in zip(world.models[split], world.demos(split)):
            assert len(demos) == m
            P = model.mdp.transition_matrix
            for demo in demos:
                assert demo.ndim == 2 and demo.shape[1] == 2 and len(demo) >= 1
                nxt = [P.indices[P.indptr[s * 3 + a]] for s, a in demo]
                np.testing.assert_array_equal(nxt[:-1], demo[1:, 0])  # consecutive, on the model
                assert not model.terminal[demo[:, 0]].any()
        assert all(f.shape[1] == 127 for f in world.features(split))
    for model, demos in zip(world.models["test"], world.test_demos):
        assert demos[0][0, 0] != model.start  # the test demonstration starts elsewhere
    assert world.train_demos[0][0][0, 0] == world.models["train"][0].start  # the first training one from the start


def test_world_points_share_test_layouts_and_prefixes(world):
    smaller = babyai_world(SMALL, 2, 2, 0)
    assert smaller.seeds["test"] == world.seeds["test"]
    assert smaller.seeds["train"] == world.seeds["train"][:2]
    for a, b in zip(smaller.test_demos, world.test_demos):
        np.testing.assert_array_equal(a[0], b[0])
    assert babyai_world(SMALL, 2, 2, 1).seeds["test"] != world.seeds["test"]


def test_scores_of_the_missions_rewards(world):
    dev, extra = world.scores("test", world.test_rewards)
    np.testing.assert_allclose(dev, 0.0, atol=1e-12)
    assert extra["success_rate"] == 1.0  # greedy on the mission's reward: a shortest path to the target
    assert set(extra) == set(ENVIRONMENT_COLUMNS)
    assert 0.0 <= extra["random_success_rate"] < 1.0 and extra["bot_success_rate"] == 1.0


def test_scores_of_a_reward_that_never_moves(world):
    still = [np.tile([1.0, 0.0, 0.0], (m.n_states, 1)) for m in world.models["test"]]  # spin left forever
    dev, extra = world.scores("test", still)
    assert extra["success_rate"] == 0.0 and np.all(dev > 0)


def test_split_is_checked(world):
    with pytest.raises(ValidationError, match="split"):
        world.demos("validation")


def test_quick_preset_end_to_end(tmp_path):
    res = run_sweep("babyai-quick", tmp_path, progress=False)
    assert res["n_computed"] == 1
    rows = read_csv(tmp_path / "results.csv")
    names = {(r["split"], r["learner"]) for r in rows}
    assert names == {(lr.split, lr.name) for lr in babyai.LINEUP.learners}
    for r in rows:
        for c in ENVIRONMENT_COLUMNS:
            assert 0.0 <= r[c] <= 1.0
        assert r["deviation"] >= 0
    summary = read_csv(tmp_path / "summary.csv")
    assert "success_rate_mean" in summary[0]
    with open(tmp_path / "results.csv") as fh:
        assert next(csv.reader(fh))[-3:] == list(ENVIRONMENT_COLUMNS)
    claims = babyai.babyai_claims(rows, PRESETS["babyai-quick"])
    assert len(claims) == 2 and all(c["seeds"].endswith("/1") for c in claims)
    again = run_sweep("babyai-quick", tmp_path, progress=False)  # resumed: nothing recomputed
    assert again["n_computed"] == 0


def test_figure(tmp_path):
    data = babyai_figure_data(SMALL, seed=0, n_tasks=3, task=1)
    assert set(data["learners"]) == {"flat, features", "factorial, features"}
    for learnt in data["learners"].values():
        assert len(learnt["values"]) == len(data["states"]) and learnt["path"][0] == data["start"]
        assert isinstance(learnt["success"], bool)
    path = plot_babyai_layout(data, tmp_path / "layout.png")
    assert (tmp_path / "layout.png").stat().st_size > 0 and path.endswith("layout.png")

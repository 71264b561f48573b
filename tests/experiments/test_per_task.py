"""The world with a map per task: its ground truth, line-up, fresh-map scores, tables, claims and presets."""

import dataclasses

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError
from factirl_opt.lab.experiments import PRESETS, Preset, get_lineup, make_ground_truth, read_csv, run_one, run_sweep
from factirl_opt.lab.experiments.claims import evaluate_claims
from factirl_opt.lab.experiments.learner_names import (FACTORIAL_FEATURES, FACTORIAL_MCE_FEATURES, FLAT_FEATURES,
                                                   FLAT_GROUND_TRUTH, FLAT_MCE_FEATURES)
from factirl_opt.lab.experiments.per_task import NEW_MAP_COLUMNS, PRIMITIVES, WeightsFit, add_new_map_scores
from factirl_opt.lab.experiments.runner import RunSpec
from factirl_opt.lab.experiments.tables import (NEW_MAP_RESULT_COLUMNS, NEW_MAP_SUMMARY_COLUMNS, RESULT_COLUMNS,
                                            SUMMARY_COLUMNS, write_tables)
from factirl_opt.datasets.objectworld import state_action_rewards

#: the MCE rows take L-BFGS for the presets' Gauss-Newton H-steps (tested in test_runner)
pytestmark = pytest.mark.filterwarnings("ignore::factirl_opt.lab.experiments.runner.SolverSubstitutionWarning")

QUICK = PRESETS["objectworld-per-task-quick"]
#: a per-task world small enough for unit tests (seconds)
TINY = dataclasses.replace(QUICK, name="per-task-tiny", grid_size=6, object_density=0.2, demo_length=6,
                           demos_sweep=(3,), tasks_sweep=(3, 5), default_tasks=5, default_demos=3, n_test_tasks=3,
                           flat_max_iter=5, fact_max_iter=2, transfer_max_iter=5, n_seeds=1)


@pytest.fixture(scope="module")
def gt():
    return make_ground_truth(TINY, 5, 3, 0)


def test_every_task_has_its_own_map_and_the_test_tasks_unseen_ones(gt):
    train, test = gt.task_maps["train"], gt.task_maps["test"]
    assert (train.n_tasks, test.n_tasks) == (5, 3)
    S, p = 36, 5 * (5 + 2)
    assert all(F.shape == (S, p) for F in train.features + test.features)
    objects = [w.objects.tolist() for w in train.worlds + test.worlds]
    assert all(objects[i] != objects[j] for i in range(8) for j in range(i))  # a layout per task
    assert len({id(m) for m in train.mdps}) == 1 and gt.mdp is train.mdps[0]  # same dynamics: one batch
    assert gt.features is None and gt.dictionary is train.primitives
    R = state_action_rewards(train.rewards, 5)
    assert np.array_equal(gt.train_rewards, R) and gt.test_rewards.shape == (3, S, 5)
    assert [d.shape for d in gt.train_demos] == [(3, 6, 2)] * 5 and [d.shape for d in gt.test_demos] == [(1, 6, 2)] * 3
    assert all(a is b for a, b in zip(gt.mdps("test"), test.mdps))


def test_fresh_maps_keep_the_tasks_and_draw_new_layouts(gt):
    for split in ("train", "test"):
        maps, fresh = gt.task_maps[split], gt.fresh(split)
        assert np.array_equal(fresh.coefficients, maps.coefficients)
        assert all(a.objects.tolist() != b.objects.tolist() for a, b in zip(maps.worlds, fresh.worlds))
        again = gt.fresh(split)  # the same fresh maps at every call
        assert all(np.array_equal(a, b) for a, b in zip(again.features, fresh.features))
    assert gt.fresh("train").worlds[0].objects.tolist() != gt.fresh("test").worlds[0].objects.tolist()
    with pytest.raises(ValidationError, match="split must be 'train' or 'test'"):
        gt.fresh("valid")
    shared = make_ground_truth(PRESETS["objectworld-tiny"], 3, 2, 0)
    assert shared.mdps("train") is shared.mdp
    with pytest.raises(ValidationError, match="one map for every task: it has no fresh maps"):
        shared.fresh("train")


def test_the_same_seed_gives_the_same_world_and_another_seed_another():
    a, b, c = (make_ground_truth(TINY, 3, 2, s) for s in (4, 4, 5))
    assert all(np.array_equal(x, y) for x, y in zip(a.task_maps["train"].features, b.task_maps["train"].features))
    assert all(np.array_equal(x, y) for x, y in zip(a.train_demos, b.train_demos))
    assert not np.array_equal(a.train_rewards, c.train_rewards)


def test_lineup_rows_and_the_world_they_need():
    lineup = get_lineup("objectworld-per-task")
    names = (FLAT_FEATURES, FLAT_MCE_FEATURES, FLAT_GROUND_TRUTH, FACTORIAL_FEATURES, "factorial, features, random init",
             FACTORIAL_MCE_FEATURES, "factorial MCE, features, random init")
    assert lineup.names("train") == names
    assert lineup.names("test") == names[:2] + names[3:] + names[2:3]
    objectives = {(lr.split, lr.name): lr.objective for lr in lineup.learners}
    assert {n for (s, n), o in objectives.items() if o == "mce"} == {n for n in names if "MCE" in n}
    needs = {(lr.split, lr.name): lr.needs for lr in lineup.learners}
    assert needs["train", FACTORIAL_MCE_FEATURES] == (("train", FLAT_MCE_FEATURES),)
    assert needs["test", FACTORIAL_FEATURES] == (("train", FACTORIAL_FEATURES),)
    assert lineup.value_maps == ()
    with pytest.raises(ValidationError, match="runs in the world\\(s\\) objectworld-per-task; got world 'objectworld'"):
        Preset(name="x", world="objectworld", lineup="objectworld-per-task")


def test_new_map_scores_are_the_deviation_of_the_weights_on_fresh_maps(gt):
    fresh = gt.fresh("test")
    mdps, true = list(fresh.mdps), state_action_rewards(fresh.rewards, 5)
    rng = np.random.default_rng(0)
    W = rng.normal(size=(3, 35))
    fits = {("test", "a"): WeightsFit(None, None, 0, W, "features"),
            ("test", "truth"): WeightsFit(None, None, 0, 2.0 * fresh.coefficients, PRIMITIVES)}
    rows = [dict(split="test", learner="a"), dict(split="test", learner="truth")]
    add_new_map_scores(gt, TINY, fits, rows)
    R = np.stack([F @ w for F, w in zip(fresh.features, W)])
    expected = fo.deviation(mdps, true, R)
    assert rows[0]["new_maps_deviation"] == pytest.approx(np.mean(expected), rel=1e-12)
    assert rows[0]["new_maps_deviation_std"] == pytest.approx(np.std(expected), rel=1e-12)
    assert rows[0]["new_maps_deviation"] > 0
    assert rows[1]["new_maps_deviation"] == pytest.approx(0.0, abs=1e-9)  # the true coefficients, scaled: optimal


def test_a_run_scores_every_learner_on_own_and_new_maps():
    rec = run_one(TINY, RunSpec(3, 3, 0, TINY.solvers))
    lineup = get_lineup("objectworld-per-task")
    assert [(r["split"], r["learner"]) for r in rec["rows"]] == [(lr.split, lr.name) for lr in lineup.learners]
    for r in rec["rows"]:
        assert r["n_scored_tasks"] == (3 if r["split"] == "train" else TINY.n_test_tasks)
        assert all(np.isfinite(r[c]) and r[c] >= 0 for c in ("deviation", *NEW_MAP_COLUMNS))
    assert "figure3" not in rec


def test_tables_add_the_new_map_columns_only_for_that_world(tmp_path):
    row = dict(split="train", learner="a", n_tasks=3, demos_per_task=2, seed=0, h_solver="armijo", n_scored_tasks=3,
               deviation=1.5, deviation_std=0.5, loss=0.25, n_evaluations=7)
    timing = dict(split="train", learner="a", n_tasks=3, demos_per_task=2, seed=0, h_solver="armijo", fit_time=0.1)
    rec = dict(rows=[row], timings=[timing], spec=dict(h_solver="armijo", seed=0))
    write_tables(tmp_path, [rec])
    assert (tmp_path / "results.csv").read_text().splitlines()[0] == ",".join(RESULT_COLUMNS)
    assert (tmp_path / "summary.csv").read_text().splitlines()[0] == ",".join(SUMMARY_COLUMNS)
    rec2 = dict(rec, rows=[dict(row, seed=1, deviation=2.5)], timings=[dict(timing, seed=1)])
    for r, v in ((row, 4.0), (rec2["rows"][0], 6.0)):
        r.update(new_maps_deviation=v, new_maps_deviation_std=1.0)
    write_tables(tmp_path, [rec, rec2])
    assert (tmp_path / "results.csv").read_text().splitlines()[0] == ",".join(NEW_MAP_RESULT_COLUMNS)
    [summary] = read_csv(tmp_path / "summary.csv")
    assert tuple(summary) == NEW_MAP_SUMMARY_COLUMNS
    assert (summary["deviation_mean"], summary["new_maps_deviation_mean"]) == (2.0, 5.0)
    assert summary["new_maps_deviation_std"] == pytest.approx(np.std([4.0, 6.0], ddof=1))
    assert [r["new_maps_deviation"] for r in read_csv(tmp_path / "results.csv")] == [4.0, 6.0]


def test_per_task_sweep_end_to_end_writes_tables_and_claims(tmp_path):
    from factirl_opt.lab.experiments.claims import write_claims

    res = run_sweep(TINY, tmp_path, progress=False)
    assert res["n_runs"] == 2
    rows = read_csv(tmp_path / "results.csv")
    assert len(rows) == 2 * 14 and all(np.isfinite(r["new_maps_deviation"]) for r in rows)
    claims = evaluate_claims(rows, TINY)
    assert {c["point"] for c in claims} == {"5 tasks, 3 demos", "3 tasks, 3 demos"}
    assert any("new maps" in c["claim"] for c in claims) and any("own maps" in c["claim"] for c in claims)
    text = open(write_claims(tmp_path, TINY)).read()
    assert text.startswith("# Claims with a map per task")
    again = run_sweep(TINY, tmp_path, progress=False)  # resumed: every run reused, same tables
    assert again["n_computed"] == 0 and read_csv(tmp_path / "results.csv") == rows


def test_presets_at_elirls_scale_and_quick():
    full = PRESETS["objectworld-per-task"]
    assert (full.grid_size, full.default_tasks, full.default_demos, full.demo_length) == (32, 100, 32, 16)
    assert (full.n_test_tasks, full.n_seeds, full.tasks_sweep) == (100, 3, (10, 20, 50, 100))
    shared = PRESETS["objectworld"]
    assert dataclasses.replace(full, name="objectworld", world="objectworld", lineup="objectworld") == shared
    assert (QUICK.grid_size, QUICK.n_seeds, QUICK.world, QUICK.lineup) == (8, 3, "objectworld-per-task",
                                                                           "objectworld-per-task")
    names = ("objectworld", "objectworld-quick", "objectworld-per-task", "objectworld-per-task-quick")
    assert len({PRESETS[n].fingerprint() for n in names}) == 4


# --- the quick preset's orderings ----------------------------------------------------------


@pytest.fixture(scope="module")
def quick_scores(tmp_path_factory):
    out = tmp_path_factory.mktemp("per-task-quick")
    run_sweep(QUICK, out, jobs=1, progress=False)
    rows = [r for r in read_csv(out / "summary.csv")
            if (r["n_tasks"], r["demos_per_task"]) == (QUICK.default_tasks, QUICK.default_demos)]
    return {(r["split"], r["learner"], where): r[column] for r in rows
            for where, column in (("own", "deviation_mean"), ("new", "new_maps_deviation_mean"))}


def test_quick_the_true_primitives_are_the_floor_on_own_maps(quick_scores):
    train = [v for (s, lr, w), v in quick_scores.items() if s == "train" and w == "own" and lr != FLAT_GROUND_TRUTH]
    assert quick_scores["train", FLAT_GROUND_TRUTH, "own"] < 0.5 * min(train)
    assert quick_scores["test", FLAT_GROUND_TRUTH, "own"] < 0.8 * quick_scores["test", FACTORIAL_FEATURES, "own"]


def test_quick_factorial_mce_carries_better_to_new_maps(quick_scores):
    """On fresh maps of the training tasks, the MCE dictionary beats flat MCE and its random start."""
    fact = quick_scores["train", FACTORIAL_MCE_FEATURES, "new"]
    assert fact < 0.9 * quick_scores["train", FLAT_MCE_FEATURES, "new"]
    assert fact < 0.9 * quick_scores["train", "factorial MCE, features, random init", "new"]

"""The "which learner when" line-ups: flat, factorial with the preset's k and the adaptive learner
(k and the residual penalty chosen by validation), their presets, claims and benchmark."""

import dataclasses
import glob
import json
import math
import os

import numpy as np
import pytest

from factirl_opt.exceptions import ValidationError
from factirl_opt.learners.transfer import TRANSFER_STOL
from factirl_opt.lab import bench
from factirl_opt.lab.benchmarks.which_learner import benchmark_verdicts, sharing_table
from factirl_opt.lab.experiments import PRESETS, get_lineup, make_ground_truth, run_one, run_sweep
from factirl_opt.lab.experiments.claims import SHARING_MARGINS, evaluate_claims, sharing_verdicts
from factirl_opt.lab.experiments.learner_names import (ADAPTIVE, ADAPTIVE_FEATURES, FACTORIAL, FACTORIAL_FEATURES, FLAT,
                                                       FLAT_FEATURES)
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.lab.experiments.lineup import Learner
from factirl_opt.lab.experiments.presets import SHARING_PRESETS
from factirl_opt.lab.experiments.runner import RunSpec
from factirl_opt.learners.solver_settings import SolverSettings
from factirl_opt.tasks.features import feature_rewards

pytestmark = pytest.mark.filterwarnings("ignore::factirl_opt.lab.experiments.runner.SolverSubstitutionWarning")


def test_every_sharing_preset_runs_flat_factorial_and_adaptive_train_and_test():
    for name in SHARING_PRESETS:
        lineup = get_lineup(PRESETS[name].lineup)
        for split in ("train", "test"):
            names = lineup.names(split)
            assert len(names) == 3 and (names == (FLAT, FACTORIAL, ADAPTIVE)
                                        or names == (FLAT_FEATURES, FACTORIAL_FEATURES, ADAPTIVE_FEATURES)), name
        adaptive = [lr for lr in lineup.learners if lr.adaptive]
        assert [lr.split for lr in adaptive] == ["train", "test"] and all(lr.solvers == "factorial" for lr in adaptive)
        assert PRESETS[name].n_seeds == 3
    assert PRESETS["sharing-grid"].tasks_sweep == (5, 20, 100) and PRESETS["sharing-grid"].demos_sweep == (10,)


def test_only_a_factorial_row_can_be_adaptive():
    with pytest.raises(ValidationError, match="only a FactIRL row .* can be adaptive; got solvers='flat'"):
        Learner("train", "x", lambda *a: None, adaptive=True)


def test_adaptive_options_ask_for_validation_and_keep_the_rest():
    preset = PRESETS["sharing-grid"]
    fixed = factorial_options(preset, SolverSettings())
    auto = factorial_options(preset, SolverSettings(), adaptive=True)
    assert fixed["n_primitives"] == preset.n_primitives and "residual_penalty" not in fixed
    assert auto["n_primitives"] == "auto" and auto["residual_penalty"] == "auto"
    assert {k: v for k, v in auto.items() if k not in ("n_primitives", "residual_penalty", "solver")} == \
        {k: v for k, v in fixed.items() if k not in ("n_primitives", "solver")}
    # its flat model transfers as the line-up's flat learner does
    # (the D-step and the fixed learner's flat start: the paper's, pinned)
    assert auto["solver"] == SolverSettings(d_solver="armijo", flat_solver=preset.flat_solver)
    assert fixed["solver"] == SolverSettings(d_solver="armijo", flat_solver="armijo")
    assert auto["transfer_stol"] == fixed["transfer_stol"] == TRANSFER_STOL  # the sharing presets' converged transfer
    ow = PRESETS["sharing-objectworld-quick"]
    assert factorial_options(ow, SolverSettings(), adaptive=True, features=True)["solver"].flat_solver == ow.flat_features_solver


def _rows(values, column="deviation"):
    """Result rows of one point: ``values[seed] = (flat, factorial, adaptive)``."""
    out = []
    for seed, triple in enumerate(values):
        for name, v in zip((FLAT, FACTORIAL, ADAPTIVE), triple):
            out.append(dict(split="test", learner=name, n_tasks=5, demos_per_task=10, seed=seed, **{column: v}))
    return out


def test_verdicts_on_deviation_allow_ten_percent_of_the_better_one():
    rows = _rows([(10.0, 12.0, 10.99), (10.0, 8.0, 8.81), (10.0, 9.0, 8.5)])
    v = sharing_verdicts(rows)
    assert [x["best"] for x in v] == [10.0, 8.0, 9.0]
    assert [x["no_worse"] for x in v] == [True, False, True]
    assert [x["beats_both"] for x in v] == [False, False, True]
    assert SHARING_MARGINS["deviation"] == 0.10


def test_verdicts_on_success_rate_allow_five_points_below_the_better_one():
    rows = _rows([(0.95, 0.7, 0.91), (0.95, 0.7, 0.89), (0.6, 0.65, 0.7)], column="success_rate")
    v = sharing_verdicts(rows, column="success_rate")
    assert [x["best"] for x in v] == [0.95, 0.95, 0.65]
    assert [x["no_worse"] for x in v] == [True, False, True]
    assert [x["beats_both"] for x in v] == [False, False, True]


def test_verdicts_leave_out_points_with_a_learner_missing():
    rows = [r for r in _rows([(1.0, 2.0, 1.5), (1.0, 2.0, 1.5)]) if not (r["seed"] == 1 and r["learner"] == FACTORIAL)]
    assert [x["seed"] for x in sharing_verdicts(rows)] == [0]


def test_sharing_claims_hold_only_on_every_seed():
    preset = PRESETS["sharing-grid"]
    rows = _rows([(10.0, 12.0, 10.5), (10.0, 12.0, 11.5)])
    claims = evaluate_claims(rows, preset)
    no_worse, beats = claims
    assert "within 10% of the better of flat and factorial" in no_worse["claim"]
    assert (no_worse["holds"], no_worse["seeds"]) == (False, "1/2") and (beats["holds"], beats["seeds"]) == (False, "0/2")
    babyai = _rows([(0.9, 0.7, 0.93)], column="success_rate")
    for r in babyai:
        r["learner"] = {FLAT: FLAT_FEATURES, FACTORIAL: FACTORIAL_FEATURES, ADAPTIVE: ADAPTIVE_FEATURES}[r["learner"]]
    no_worse, beats = evaluate_claims(babyai, PRESETS["sharing-babyai"])
    assert "within 0.05" in no_worse["claim"] and "(success rate)" in no_worse["measured"]
    assert no_worse["holds"] and beats["holds"]


def test_a_run_records_what_the_adaptive_learner_chose():
    preset = PRESETS["sharing-tiny"]
    record = run_one(preset, RunSpec(8, 5, 0))
    chosen = [r for r in record["rows"] if r["learner"] == ADAPTIVE]
    assert [r["split"] for r in chosen] == ["train", "test"]
    for r in chosen:
        assert r["n_primitives"] in (1, 2, 4) and (r["residual_penalty"] in (0.0, 1e-2, 1.0) or math.isinf(r["residual_penalty"]))
    assert chosen[0]["n_primitives"] == chosen[1]["n_primitives"]
    assert all("n_primitives" not in r for r in record["rows"] if r["learner"] != ADAPTIVE)


def test_per_task_weights_include_the_residuals():
    from factirl_opt.lab.experiments.lineup import RunContext
    from factirl_opt.lab.experiments.per_task import FEATURES, factorial_map_features, transfer_map_features

    preset = dataclasses.replace(PRESETS["sharing-objectworld-per-task-quick"], name="per-task-sharing-tiny", grid_size=6,
                                 object_density=0.2, demo_length=6, demos_sweep=(3,), tasks_sweep=(4,), default_tasks=4,
                                 default_demos=3, n_test_tasks=2, flat_max_iter=5, fact_max_iter=2, transfer_max_iter=5)
    gt = make_ground_truth(preset, 4, 3, 0)
    ctx = RunContext(gt, RunSpec(4, 3, 0))
    lineup = get_lineup(preset.lineup)
    for lr in lineup.learners:
        if lr.name != ADAPTIVE_FEATURES and not (lr.split == "train" and lr.name == FLAT_FEATURES):
            continue
        ctx.learner = lr
        fit = lr.build(gt, preset, ctx)
        ctx.rewards[lr.split, lr.name] = fit.rewards
        if lr.adaptive:
            model = ctx.models[lr.name]
            res = model.residuals_ if lr.split == "train" else model.transfer_residuals_
            maps = gt.task_maps[lr.split]
            assert fit.on == FEATURES
            again = feature_rewards(list(maps.features), np.asarray(fit.weights), list(maps.mdps))
            np.testing.assert_allclose(np.asarray(again), np.asarray(fit.rewards), atol=1e-10)
            assert res.shape == np.asarray(fit.weights).shape
    assert {"train", "test"} <= {split for split, _ in ctx.rewards}


def test_which_learner_benchmark_quick(tmp_path, capsys):
    out = tmp_path / "wl"
    assert bench.main(["which-learner", "--quick", "--out", str(out)]) == 0
    res = json.loads(capsys.readouterr().out)
    (tiny,) = res["benchmarks"].values()
    assert tiny["column"] == "deviation" and len(tiny["verdicts"]) == 3  # 3 points, one seed
    assert tiny["auto_cost_ratio"] > 1 and tiny["auto_cost_clock"] == "cpu"  # the search fits candidates on folds
    for v in tiny["verdicts"]:
        assert v["best"] == min(v["flat"], v["factorial"])
        assert v["no_worse"] == (v["adaptive"] <= 1.1 * v["best"]) and v["beats_both"] == (v["adaptive"] < v["best"])
    table = (out / "which-learner.md").read_text()
    assert table.count("| sharing-tiny |") == 3 and (out / "sharing-tiny" / "claims.md").exists()
    assert bench.main(["which-learner", "--quick", "--out", str(out)]) == 0  # resumed: nothing recomputed
    again = json.loads(capsys.readouterr().out)
    assert again["benchmarks"]["sharing-tiny"]["n_computed"] == 0
    assert again["benchmarks"]["sharing-tiny"]["verdicts"] == tiny["verdicts"]


@pytest.mark.parametrize("argv", [["which-learner", "--presets", "paper"], ["which-learner", "--seeds", "0"],
                                  ["which-learner", "--jobs", "-2"]])
def test_which_learner_options_are_checked_by_the_parser(argv):
    with pytest.raises(SystemExit) as exc:
        bench.build_parser().parse_args(argv)
    assert exc.value.code == 2


def test_the_committed_which_learner_table_is_that_of_its_records():
    """``results/which-learner``: every point of every benchmark has its three seeds, and the README's
    table and tally are the verdicts of the committed records, as ``table.py`` computes them (a record
    added without the README, or a figure edited by hand, fails here)."""
    root = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "results",
                        "which-learner")
    if not os.path.isdir(os.path.join(root, "runs")):
        pytest.skip("no committed results/ in this checkout")
    results = {}
    for name in sorted(SHARING_PRESETS):  # table.py's order: the folders sorted
        records = [json.load(open(f)) for f in sorted(glob.glob(os.path.join(root, "runs", name, "*.json")))]
        seeds = {}
        for r in records:
            seeds.setdefault((r["spec"]["n_tasks"], r["spec"]["demos_per_task"]), set()).add(r["spec"]["seed"])
        assert seeds == {point: {0, 1, 2} for point in PRESETS[name].points()}, name
        results[name] = benchmark_verdicts([row for r in records for row in r["rows"]])
    readme = open(os.path.join(root, "README.md")).read()
    assert sharing_table(results).strip() in readme
    verdicts = [v for res in results.values() for v in res["verdicts"]]
    no_worse, beats = sum(v["no_worse"] for v in verdicts), sum(v["beats_both"] for v in verdicts)
    assert f"No worse on {no_worse} of {len(verdicts)} (point, seed) pairs; better than both on {beats}." in readme

"""The scale benchmark in tiny configurations: every field, ratios consistent with the times.

Timings are not asserted (machines are noisy); structure, consistency and the non-timing
numbers (gradient agreement between planners, policy changes) are.
"""

import argparse
import json
import math
import re
import sys

import numpy as np
import pytest

from factirl_opt.lab import bench
from factirl_opt.lab.benchmarks import BENCHMARKS, scale, scale_evaluations, scale_jobs
from factirl_opt.exceptions import MissingDependencyError, ValidationError
from factirl_opt.objectives import distributed

PLANNER_KEYS = {"resolved", "cold_plan_s", "warm_s", "warm_perturbed_s", "runs"}
SIZE_KEYS = {"n_states", "n_actions", "default_resolves_to", "build_s", "demonstrations_s", "score_s", "planners",
             "changed_tasks", "max_changed_states", "grad_max_rel_diff", "peak_rss_mb"}


def run_scale(capsys, *extra):
    argv = ["scale", "--sizes", "4", "13", "--tasks", "3", "--n-demos", "2", "--length", "3", "--repeats", "2",
            "--fit-min-size", "4", "--in-process", *extra]
    assert bench.main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_registered():
    assert BENCHMARKS["scale"] == "scale"


def test_scale_benchmark_fields_and_consistency(capsys, tmp_path):
    plot = tmp_path / "scale.png"
    out = run_scale(capsys, "--dense-max-states", "100", "--plot", str(plot))
    assert out["benchmark"] == "scale" and out["default_planner"] == "auto"
    assert set(out["sizes"]) == {"4x4", "13x13"}
    for key, entry in out["sizes"].items():
        side = int(key.split("x")[0])
        assert set(entry) == SIZE_KEYS
        assert entry["n_states"] == side * side and entry["n_actions"] == 4
        for field in ("build_s", "demonstrations_s", "score_s", "peak_rss_mb"):
            assert entry[field] > 0
        assert set(entry["planners"]) == {"dense", "sparse-lu", "auto"}
        measured = [name for name in ("dense", "sparse-lu") if "skipped" not in entry["planners"][name]]
        for name in measured:
            p = entry["planners"][name]
            assert set(p) == PLANNER_KEYS and p["resolved"] == name
            assert all(p[f] > 0 for f in ("cold_plan_s", "warm_s", "warm_perturbed_s"))
            assert 1 <= p["runs"] <= 2
        # auto is the planner it resolves to
        auto = entry["planners"]["auto"]
        assert auto["same_as"] == auto["resolved"] == entry["default_resolves_to"]
        assert {k: v for k, v in auto.items() if k != "same_as"} == entry["planners"][auto["resolved"]]
        assert 0 <= entry["changed_tasks"] <= 3 and entry["max_changed_states"] >= 0
        # the planners compute the same gradient (relative to the first planner run)
        assert set(entry["grad_max_rel_diff"]) == set(measured) and entry["grad_max_rel_diff"][measured[0]] == 0.0
        assert max(entry["grad_max_rel_diff"].values()) < 1e-9
    small, big = out["sizes"]["4x4"], out["sizes"]["13x13"]
    assert small["default_resolves_to"] == "dense" and big["default_resolves_to"] == "sparse-lu"
    # dense runs only up to --dense-max-states, and says why it was skipped
    assert "warm_s" in small["planners"]["dense"]
    assert big["planners"]["dense"] == {"skipped": "S = 169 > --dense-max-states 100"}
    # ratios are the times' ratios, only where dense ran
    for suffix, key in (("", "warm_s"), ("_perturbed", "warm_perturbed_s")):
        assert set(out["ratio_dense_over_default" + suffix]) == {"4x4"}
        assert out["ratio_dense_over_default" + suffix]["4x4"] == pytest.approx(
            small["planners"]["dense"][key] / small["planners"]["auto"][key])
        # the exponent is the least-squares slope of log(time of auto) vs log(S) over sizes >= 4
        S = np.log([16, 169])
        t = np.log([small["planners"]["auto"][key], big["planners"]["auto"][key]])
        assert math.isfinite(out["exponent_default" + suffix])
        assert out["exponent_default" + suffix] == pytest.approx((t[1] - t[0]) / (S[1] - S[0]))
    assert out["ratio_dense_over_default"]["4x4"] == 1.0  # auto is the dense planner there
    assert out["exponent_sizes"] == [4, 13]
    assert len(out["load_average"]["before"]) == 3 and len(out["load_average"]["after"]) == 3
    settings = out["settings"]
    assert settings["sizes"] == [4, 13] and settings["tasks"] == 3 and settings["dense_max_states"] == 100
    assert "this process" in settings["memory"] and "1e-3" in settings["warm"]
    assert plot.stat().st_size > 0


def test_exponent_needs_two_sizes_and_dense_runs_by_default_up_to_1024_states(capsys):
    out = run_scale(capsys, "--fit-min-size", "13")
    assert out["exponent_default"] is None and out["exponent_default_perturbed"] is None and out["exponent_sizes"] == [13]
    assert set(out["ratio_dense_over_default"]) == {"4x4", "13x13"}  # dense fits both by default


def test_fresh_process_per_size():
    """Without --in-process every size is measured in a spawned process (its own peak memory)."""
    parser = argparse.ArgumentParser()
    scale.add_arguments(parser)
    args = parser.parse_args(["--sizes", "3", "--tasks", "2", "--n-demos", "1", "--length", "2", "--repeats", "1"])
    out = scale.run(args)
    assert "fresh process" in out["settings"]["memory"]
    entry = out["sizes"]["3x3"]
    assert entry["n_states"] == 9 and entry["peak_rss_mb"] > 0


FIT_KEYS = {"n_states", "n_actions", "n_features", "build_s", "demonstrations_s", "fit_s", "fit_s_per_iter", "n_iter",
            "n_evaluations", "status", "loss_history", "planning_bytes_per_task", "tasks_per_chunk", "peak_rss_before_fit_mb", "peak_rss_mb"}


def run_fit(capsys, *extra):
    argv = ["scale", "--sizes", "5", "--tasks", "4", "--n-demos", "3", "--length", "4", "--fit-iter", "2", "--in-process",
            *extra]
    assert bench.main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_fit_mode_under_a_budget_matches_the_unbounded_fit(capsys):
    free = run_fit(capsys)
    tight = run_fit(capsys, "--max-bytes", "1")  # one task per chunk
    assert free["mode"] == tight["mode"] == "fit" and set(free["sizes"]) == {"5x5"}
    a, b = free["sizes"]["5x5"], tight["sizes"]["5x5"]
    assert set(a) == set(b) == FIT_KEYS
    assert a["n_states"] == 25 and a["n_actions"] == 5 and a["n_features"] == 4 * 7  # (N - 1)(c1 + c2)
    assert a["n_iter"] == b["n_iter"] == 2 and len(a["loss_history"]) == 3 and a["n_evaluations"] == b["n_evaluations"]
    np.testing.assert_allclose(b["loss_history"], a["loss_history"], rtol=1e-10)
    assert a["tasks_per_chunk"] == {"jacobian": 4, "gradient": 4} and b["tasks_per_chunk"] == {"jacobian": 1, "gradient": 1}
    assert a["fit_s_per_iter"] == pytest.approx(a["fit_s"] / 2) and a["planning_bytes_per_task"] > 0
    assert free["settings"]["max_bytes"] is None and tight["settings"]["max_bytes"] == 1
    assert tight["settings"]["fit_iter"] == 2 and tight["settings"]["fit"]["solver"] == "gn-qp-clarabel"
    # in one process, the summed peak is that process's
    assert tight["peak_rss_summed_mb"]["5x5"] >= b["peak_rss_mb"] >= b["peak_rss_before_fit_mb"] > 0


@pytest.mark.parametrize("extra, message", [
    (["--max-bytes", "0", "--fit-iter", "1"], "argument --max-bytes: must be a whole number >= 1 (1e5 accepted); got '0'"),
    (["--max-bytes", "2.5", "--fit-iter", "1"], "argument --max-bytes: must be a whole number >= 1 (1e5 accepted); got '2.5'"),
    (["--fit-iter", "-1"], "argument --fit-iter: must be an integer >= 0; got '-1'"),
    (["--tasks", "0", "--fit-iter", "1"], "argument --tasks: must be an integer >= 1; got '0'"),
    (["--jobs", "0", "--fit-iter", "1"], "argument --jobs: must be an integer >= 1 (or -1: every core); got '0'"),
    (["--jobs", "1", "-2", "--fit-iter", "1"], "argument --jobs: must be an integer >= 1 (or -1: every core); got '-2'"),
    (["--tasks", "3", "0", "--evaluations"], "argument --tasks: must be an integer >= 1; got '0'"),
])
def test_bad_values_are_refused_by_the_parser(extra, message, capsys):
    parser = argparse.ArgumentParser()
    scale.add_arguments(parser)
    with pytest.raises(SystemExit) as exc:
        parser.parse_args(["--sizes", "3", *extra])
    assert exc.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.parametrize("extra, message", [
    (["--max-bytes", "1e9"], "--max-bytes 1000000000 applies to fits only"),
])
def test_bad_fit_options_are_refused(extra, message):
    parser = argparse.ArgumentParser()
    scale.add_arguments(parser)
    with pytest.raises(ValidationError, match=message):
        scale.run(parser.parse_args(["--sizes", "3", *extra]))


CONFIG_KEYS = {"n_jobs", "backend", "wall_s", "median_s", "speed_up", "cpu_driver_s", "cpu_children_s", "n_evaluations",
               "n_iter", "final_loss", "sharded", "bytes_sent", "bytes_setup", "bytes_per_evaluation", "n_restarts", "max_abs_diff"}
SIDE_ARGS = ["--sizes", "8", "--tasks", "4", "--n-demos", "3", "--length", "4", "--fit-iter", "1", "--in-process"]


def run_side(capsys, *extra):
    assert bench.main(["scale", *SIDE_ARGS, *extra]) == 0
    return json.loads(capsys.readouterr().out)


def check_configuration(entry, ref, repeats):
    assert set(entry) == CONFIG_KEYS
    assert len(entry["wall_s"]) == len(entry["cpu_driver_s"]) == len(entry["cpu_children_s"]) == repeats
    assert entry["median_s"] == pytest.approx(float(np.median(entry["wall_s"])))
    assert entry["speed_up"] == pytest.approx(ref["median_s"] / entry["median_s"])
    assert all(t > 0 for t in entry["wall_s"]) and all(c >= 0 for c in entry["cpu_driver_s"])
    # the same fit: same evaluations and iterations, same learnt arrays
    assert entry["n_evaluations"] == ref["n_evaluations"] and entry["n_iter"] == ref["n_iter"] == 1
    assert entry["max_abs_diff"] < 1e-10
    assert entry["final_loss"] == pytest.approx(ref["final_loss"], rel=1e-10)


def test_fits_side_by_side_per_n_jobs(capsys):
    out = run_side(capsys, "--jobs", "1", "2", "--repeats", "2")
    assert out["mode"] == "fit-jobs" and set(out["sizes"]) == {"8x8"}
    size = out["sizes"]["8x8"]
    assert size["reference"] == "n_jobs=1" and list(size["configurations"]) == ["n_jobs=1", "n_jobs=2"]
    one, two = size["configurations"]["n_jobs=1"], size["configurations"]["n_jobs=2"]
    for entry in (one, two):
        check_configuration(entry, one, 2)
    assert one["speed_up"] == 1.0 and one["max_abs_diff"] == 0.0
    assert (one["n_jobs"], one["backend"], two["n_jobs"], two["backend"]) == (1, "processes", 2, "processes")
    # n_jobs=1 evaluates in this process: nothing sharded; n_jobs=2 reports the bytes sent to its worker
    assert not one["sharded"] and one["bytes_sent"] is one["bytes_per_evaluation"] is None
    assert two["sharded"] and two["bytes_sent"] > 0 and two["bytes_setup"] > 0 and two["n_restarts"] == 0
    assert 0 < two["bytes_per_evaluation"] <= two["bytes_sent"]
    assert out["settings"]["configurations"] == ["n_jobs=1", "n_jobs=2"] and out["settings"]["repeats"] == 2
    assert out["settings"]["dask_cluster"] is None
    # the same world, demonstrations and fit as the plain --fit-iter mode
    plain = run_side(capsys)["sizes"]["8x8"]
    assert (plain["n_states"], plain["n_features"], plain["n_evaluations"]) == (size["n_states"], size["n_features"],
                                                                                one["n_evaluations"])
    assert plain["loss_history"][-1] == one["final_loss"]


def test_fit_on_a_local_dask_cluster_matches_n_jobs_1(capsys):
    pytest.importorskip("distributed")
    out = run_side(capsys, "--dask", "--repeats", "1")  # --dask alone: compared with n_jobs=1
    size = out["sizes"]["8x8"]
    assert list(size["configurations"]) == ["n_jobs=1", "dask"]
    one, dask = size["configurations"]["n_jobs=1"], size["configurations"]["dask"]
    check_configuration(dask, one, 1)
    assert dask["backend"] == "dask" and dask["n_jobs"] is None
    assert dask["sharded"] and dask["bytes_sent"] > 0 and dask["n_restarts"] == 0
    assert "LocalCluster(n_workers=2" in out["settings"]["dask_cluster"]


def test_dask_without_the_extra_names_the_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed raises ImportError
    parser = argparse.ArgumentParser()
    scale.add_arguments(parser)
    with pytest.raises(MissingDependencyError, match=re.escape('pip install -e ".[dask]"')):
        scale.run(parser.parse_args(["--sizes", "3", "--fit-iter", "1", "--dask"]))


def test_traffic_recorder_restores_close():
    original = distributed.ShardedObjective.close
    with scale_jobs.record_traffic() as records:
        assert distributed.ShardedObjective.close is not original and records == []
    assert distributed.ShardedObjective.close is original


@pytest.mark.parametrize("extra, message", [
    (["--jobs", "1", "2"], "--jobs and --dask apply to fits only"),
    (["--dask"], "--jobs and --dask apply to fits only"),
])
def test_bad_jobs_options_are_refused(extra, message):
    parser = argparse.ArgumentParser()
    scale.add_arguments(parser)
    with pytest.raises(ValidationError, match=message):
        scale.run(parser.parse_args(["--sizes", "3", *extra]))


@pytest.mark.parametrize("bad", [True, 1.5, "2"])
def test_check_jobs_refuses_non_integers(bad):
    with pytest.raises(ValidationError, match="--jobs values must be positive integers or -1"):
        scale_jobs.check_jobs([1, bad])


EVAL_ARGS = ["--evaluations", "--sizes", "6", "8", "--tasks", "3", "6", "--n-demos", "3", "--length", "4"]
EVAL_CONFIG_KEYS = {"n_jobs", "backend", "cold_s", "warm_s", "warm_median_s", "peak_rss_mb", "peak_rss_summed_mb",
                    "workers_uss_mb", "peak_reset", "max_abs_diff"}


def run_evaluations(capsys, *argv):
    assert bench.main(["scale", *argv]) == 0
    return json.loads(capsys.readouterr().out)


def check_exponents(out, label, sizes, tasks):
    """The exponents are the least-squares slopes of the logs, against tasks per size and states per tasks."""
    for key in ("warm_median_s", "peak_rss_summed_mb"):
        exps = out["exponents"][label][key]
        assert set(exps["tasks"]) == {f"{s}x{s}" for s in sizes} and set(exps["states"]) == {str(n) for n in tasks}
        for s in sizes:
            pts = [(out["sizes"][f"{s}x{s}"][str(n)]["n_tasks"], out["sizes"][f"{s}x{s}"][str(n)]["configurations"][label][key])
                   for n in tasks]
            expected = np.polyfit(*np.log(np.array(pts).T), 1)[0] if len(tasks) > 1 else None
            assert exps["tasks"][f"{s}x{s}"] == (None if expected is None else pytest.approx(expected))
            assert expected is None or math.isfinite(expected)
        for n in tasks:
            pts = [(out["sizes"][f"{s}x{s}"][str(n)]["n_states"], out["sizes"][f"{s}x{s}"][str(n)]["configurations"][label][key])
                   for s in sizes]
            expected = np.polyfit(*np.log(np.array(pts).T), 1)[0] if len(sizes) > 1 else None
            assert exps["states"][str(n)] == (None if expected is None else pytest.approx(expected))


def test_evaluations_per_tasks_states_and_n_jobs(capsys):
    out = run_evaluations(capsys, *EVAL_ARGS, "--jobs", "1", "2", "--repeats", "2")
    assert out["mode"] == "evaluations" and set(out["sizes"]) == {"6x6", "8x8"}
    for side in (6, 8):
        for n in (3, 6):
            point = out["sizes"][f"{side}x{side}"][str(n)]
            assert (point["n_states"], point["n_actions"], point["n_tasks"]) == (side * side, 5, n)
            assert point["n_features"] == (side - 1) * 7  # the fits' Objectworld features
            assert list(point["configurations"]) == ["n_jobs=1", "n_jobs=2"]
            one, two = point["configurations"]["n_jobs=1"], point["configurations"]["n_jobs=2"]
            for entry in (one, two):
                assert set(entry) == EVAL_CONFIG_KEYS and entry["backend"] == "processes"
                assert len(entry["warm_s"]) == 2 and entry["warm_median_s"] == pytest.approx(np.median(entry["warm_s"]))
                assert entry["cold_s"] > 0 and all(t > 0 for t in entry["warm_s"])
                assert entry["peak_reset"] is True
                assert entry["peak_rss_summed_mb"] == pytest.approx(sum(entry["peak_rss_mb"].values()))
                assert all(v > 0 for v in entry["peak_rss_mb"].values())
            # n_jobs=1 is this process alone; n_jobs=2 adds its shard process
            assert list(one["peak_rss_mb"]) == ["driver"] and one["workers_uss_mb"] == []
            assert list(two["peak_rss_mb"]) == ["driver", "shard 1"] and len(two["workers_uss_mb"]) == 1
            # the sharded evaluation is the serial one
            assert one["max_abs_diff"] == 0.0 and two["max_abs_diff"] < 1e-10
    for label in ("n_jobs=1", "n_jobs=2"):
        check_exponents(out, label, [6, 8], [3, 6])
    settings = out["settings"]
    assert settings["tasks"] == [3, 6] and settings["configurations"] == ["n_jobs=1", "n_jobs=2"]
    assert settings["repeats"] == 2 and settings["dask_cluster"] is None and "VmHWM" in settings["memory"]


def test_evaluations_on_a_local_dask_cluster_match_n_jobs_1(capsys):
    pytest.importorskip("distributed")
    out = run_evaluations(capsys, "--evaluations", "--sizes", "6", "--tasks", "4", "--n-demos", "2", "--length", "3",
                          "--dask", "--repeats", "1")
    point = out["sizes"]["6x6"]["4"]
    assert list(point["configurations"]) == ["n_jobs=1", "dask"]
    dask = point["configurations"]["dask"]
    assert set(dask) == EVAL_CONFIG_KEYS and dask["backend"] == "dask" and dask["n_jobs"] is None
    assert list(dask["peak_rss_mb"]) == ["driver", "worker 0", "worker 1"] and len(dask["workers_uss_mb"]) == 2
    assert dask["peak_rss_summed_mb"] == pytest.approx(sum(dask["peak_rss_mb"].values()))
    assert dask["max_abs_diff"] < 1e-10
    # one size and one number of tasks: no exponent
    assert out["exponents"]["dask"]["warm_median_s"] == {"tasks": {"6x6": None}, "states": {"4": None}}
    assert "LocalCluster(n_workers=2" in out["settings"]["dask_cluster"]


def test_growth_exponent_is_the_log_log_slope():
    x = [3, 6, 12]
    assert scale_evaluations.growth_exponent(x, [2.0 * v**1.5 for v in x]) == pytest.approx(1.5)
    assert scale_evaluations.growth_exponent([3, 3], [1.0, 2.0]) is None  # one distinct x
    assert scale_evaluations.growth_exponent([3, 6], [1.0, None]) is None  # a figure missing


def test_peak_memory_of_processes():
    peak = scale_evaluations.peak_rss_mb()
    assert peak is None or peak > 0
    if peak is not None:  # Linux: the peak resets to at most what it was
        assert scale_evaluations.reset_peak() is True
        assert 0 < scale_evaluations.peak_rss_mb() <= peak + 1
    gone = 2**22 + 12345  # above Linux's default pid_max: no such process
    assert scale_evaluations.peak_rss_mb(gone) is None and scale_evaluations.reset_peak(gone) is False
    memory = scale_evaluations.process_memory([gone])
    assert memory["peak_rss_summed_mb"] is None and list(memory["peak_rss_mb"]) == ["driver", "shard 1"]


@pytest.mark.parametrize("extra, message", [
    (["--tasks", "3", "6"], r"--tasks takes several distinct values with --evaluations only; got \[3, 6\]"),
    (["--tasks", "3", "3", "--evaluations"], r"several distinct values .*got \[3, 3\]"),
    (["--evaluations", "--fit-iter", "1"], "--evaluations and --fit-iter 1 are separate modes"),
])
def test_bad_evaluations_options_are_refused(extra, message):
    parser = argparse.ArgumentParser()
    scale.add_arguments(parser)
    with pytest.raises(ValidationError, match=message):
        scale.run(parser.parse_args(["--sizes", "3", *extra]))


def test_evaluations_under_a_planning_budget(capsys):
    out = run_evaluations(capsys, "--evaluations", "--sizes", "6", "--tasks", "3", "--n-demos", "2", "--length", "3",
                          "--jobs", "1", "2", "--repeats", "1", "--max-bytes", "1")  # one task per chunk
    assert out["settings"]["max_bytes"] == 1
    assert out["sizes"]["6x6"]["3"]["configurations"]["n_jobs=2"]["max_abs_diff"] < 1e-10

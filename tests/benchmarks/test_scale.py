"""The scale benchmark in tiny configurations: every field, ratios consistent with the times.

Timings are not asserted (machines are noisy); structure, consistency and the non-timing
numbers (gradient agreement between planners, policy changes) are.
"""

import argparse
import json
import math

import numpy as np
import pytest

from factirl_opt import bench
from factirl_opt.benchmarks import BENCHMARKS, scale
from factirl_opt.exceptions import ValidationError

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
    assert tight["settings"]["fit_iter"] == 2 and tight["settings"]["fit"]["h_solver"] == "gn-qp-clarabel"
    # in one process, the summed peak is that process's
    assert tight["peak_rss_summed_mb"]["5x5"] >= b["peak_rss_mb"] >= b["peak_rss_before_fit_mb"] > 0


@pytest.mark.parametrize("extra, message", [
    (["--max-bytes", "0", "--fit-iter", "1"], "--max-bytes .*got 0"),
    (["--max-bytes", "2.5", "--fit-iter", "1"], "--max-bytes .*got 2.5"),
    (["--max-bytes", "1e9"], "--max-bytes 1000000000.0 applies to fits only"),
    (["--fit-iter", "-1"], "--fit-iter must be an integer >= 0; got -1"),
    (["--tasks", "0", "--fit-iter", "1"], "--tasks must be >= 1; got 0"),
])
def test_bad_fit_options_are_refused(extra, message):
    parser = argparse.ArgumentParser()
    scale.add_arguments(parser)
    with pytest.raises(ValidationError, match=message):
        scale.run(parser.parse_args(["--sizes", "3", *extra]))

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

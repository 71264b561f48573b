"""The benchmarks of how much tasks share: ``bench dictionary`` (constrained dictionaries against the true primitives) and
``bench auto-cost`` (the cost of auto against one fixed fit), in their tiny configurations."""

import json

import numpy as np
import pytest

from factirl_opt.lab import bench
from factirl_opt.lab.benchmarks import dictionary as dictionary_bench


def test_dictionary_benchmark_quick(capsys):
    assert bench.main(["dictionary", "--quick", "--truths", "nonneg-sparse"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["settings"]["truths"] == ["nonneg-sparse"] and out["settings"]["seeds"] == dictionary_bench.QUICK["seeds"]
    (row,) = out["runs"]
    assert set(row["variants"]) == set(dictionary_bench.VARIANTS)
    for name, v in row["variants"].items():
        assert 0.0 <= v["match"] <= 1.0 + 1e-12 and v["test_deviation"] >= 0 and v["train_deviation"] >= 0
        assert (v["zero_fraction"] == 0) == (name == "none")
    summary = out["summary"]["nonneg-sparse"]
    assert summary["sparse"]["match"] == pytest.approx(row["variants"]["sparse"]["match"])
    assert 0.0 <= summary["pca start"]["match"] <= 1.0 + 1e-12


@pytest.mark.parametrize("kind", dictionary_bench.TRUTHS)
def test_true_dictionaries(kind):
    D = dictionary_bench.true_dictionary(kind, 30, 4, 0.05, np.random.default_rng(0))
    assert D.shape == (30, 4) and np.all(np.linalg.norm(D, axis=0) > 0)
    if kind == "nonneg-sparse":
        assert np.all(D >= 0) and np.mean(D == 0) > 0.8


@pytest.mark.parametrize("argv", [["dictionary", "--variants", "positive"], ["dictionary", "--alpha", "0"],
                                  ["dictionary", "--density", "1.5"]])
def test_dictionary_benchmark_options_are_checked_by_the_parser(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        bench.build_parser().parse_args(argv)
    assert exc.value.code == 2


def test_auto_cost_benchmark_quick(capsys):
    from factirl_opt.lab.benchmarks import auto_cost

    assert bench.main(["auto-cost", "--quick", "--searches", "full", "race"]) == 0
    out = json.loads(capsys.readouterr().out)
    (seed,) = out["seeds"].values()
    assert set(seed["time_ratio"]) == {"full", "race"} and set(seed["cpu_time_s"]) == {"fixed", "full", "race"}
    assert seed["calls_ratio"]["full"] == pytest.approx(seed["planner_calls"]["full"] / seed["planner_calls"]["fixed"])
    full, race = seed["chosen"]["full"], seed["chosen"]["race"]
    assert full["candidate_fits"] == 3 * full["candidates"] and race["candidate_fits"] < full["candidate_fits"]
    # the race scores its contenders as the full search does: it keeps the full search's winner here
    assert (race["n_primitives"], race["residual_penalty"]) == (full["n_primitives"], full["residual_penalty"])
    assert seed["planner_calls"]["race"] < seed["planner_calls"]["full"]
    assert auto_cost.DEFAULTS["preset"] in auto_cost.GRID_PRESETS

"""The gpi benchmark: GPI policies against planning each new task, on the tiny worlds."""

import json

import numpy as np
import pytest

from factirl_opt.lab import bench


def run_bench(capsys, argv):
    assert bench.main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_gpi_benchmark_quick_measures_cpu_and_losses_on_every_world(capsys):
    out = run_bench(capsys, ["gpi", "--quick", "--n-new", "6", "--plan-chunk", "4"])
    assert set(out["worlds"]) == {"grid-tiny", "objectworld-per-task-tiny", "objectworld-tiny"}
    for name, rows in out["worlds"].items():
        row = rows["0"]
        assert row["n_new"] == 6 and row["theorem_violations"] == 0
        assert row["cpu_gpi_over_plan"] == pytest.approx(row["gpi_cpu_s"] / row["plan_cpu_s"])
        assert row["learnt_loss"]["plan"] == 0.0
        for key in ("gpi", "gpi1"):  # the planned policy is optimal for the learnt reward
            assert row["learnt_loss"][key] >= -1e-9
        assert row["learnt_loss"]["gpi1"] <= row["learnt_loss"]["gpi"] + 1e-9  # improvement never hurts
        assert row["best_library_learnt_loss"] >= row["learnt_loss"]["gpi"] - 1e-9  # the theorem, on average
        assert all(np.isfinite(v) and v >= -1e-9 for v in row["true_loss"].values())
    per_task = out["worlds"]["objectworld-per-task-tiny"]["0"]
    assert per_task["n_maps"] == 4 and per_task["library_size"] == [11] * 4  # 2k primitives +- and the map's task


def test_gpi_benchmark_library_option(capsys):
    out = run_bench(capsys, ["gpi", "--quick", "--worlds", "grid-tiny", "--n-new", "3", "--library", "primitives"])
    row = out["worlds"]["grid-tiny"]["0"]
    assert row["library"] == ["primitives"] and row["library_size"] == [5]


@pytest.mark.parametrize("argv, fragment", [(["--worlds", "maze"], "invalid choice: 'maze'"),
                                            (["--n-new", "0"], "--n-new"),
                                            (["--library", "optimal"], "invalid choice: 'optimal'")])
def test_gpi_benchmark_options_are_checked_by_the_parser(capsys, argv, fragment):
    with pytest.raises(SystemExit) as exc:
        bench.main(["gpi", *argv])
    assert exc.value.code == 2
    assert fragment in capsys.readouterr().err

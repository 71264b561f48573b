"""The benchmarks, in tiny configurations through the one benchmark parser.

Timings are not asserted (machines are noisy): the JSON structure, the consistency of the
derived numbers with the measured ones, and the non-timing results (gradient agreement,
deviations, losses, the factorial learner's advantage) are.
"""

import json
import math

import pytest

from factirl_opt import bench
from factirl_opt.benchmarks import BENCHMARKS, add_option, resolve_settings
from factirl_opt.benchmarks import fit as fit_bench
from factirl_opt.benchmarks import solvers as solvers_bench
from factirl_opt.cli import main as cli_main

FIT_ENTRY = {"time_s", "n_evaluations", "n_iter", "final_loss", "mean_train_deviation"}


def run_bench(capsys, argv):
    assert bench.main(argv) == 0
    return json.loads(capsys.readouterr().out)


def _finite_numbers(obj, where="out"):
    """Every number in a JSON document (bools aside) is finite."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            _finite_numbers(v, f"{where}[{k!r}]")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            _finite_numbers(v, f"{where}[{i}]")
    elif isinstance(obj, float):
        assert math.isfinite(obj), where


def test_gradient_benchmark(capsys):
    out = run_bench(capsys, ["gradient", "--sizes", "3", "4", "--repeats", "1", "--min-time", "0", "--n-demos", "2", "--length", "3"])
    assert set(out) == {"benchmark", "grid", "ratio_fixed_point", "ratio_forward_direct", "sizes", "settings"}
    assert out["benchmark"] == "gradient" and out["grid"] == "3x3" and set(out["sizes"]) == {"3x3", "4x4"}
    _finite_numbers(out)
    for key in ("ratio_fixed_point", "ratio_forward_direct"):
        assert out[key] == out["sizes"]["3x3"][key] > 0
    for size, e in out["sizes"].items():
        n = int(size.split("x")[0])
        assert e["n_states"] == n * n and e["n_params"] == 4 * n * n and e["loss"] > 0
        assert e["ratio_fixed_point"] == pytest.approx(e["fixed_point_s"] / e["adjoint_s"])
        assert e["ratio_forward_direct"] == pytest.approx(e["forward_direct_s"] / e["adjoint_s"])
        b = e["breakdown"]
        assert b["gradient_part_ratio_fixed_point"] == pytest.approx(b["fixed_point_phi_s"] / b["adjoint_gradient_part_s"])
        assert b["gradient_part_ratio_forward_direct"] == pytest.approx(b["forward_direct_phi_s"] / b["adjoint_gradient_part_s"])
        assert 0 < b["planning_share_of_adjoint"] <= 1 and 0 < b["planning_share_of_forward_direct"] <= 1
        assert all(isinstance(r, int) and r >= 1 for r in e["runs"].values())
        # the three routes compute the same gradient
        assert max(e["max_abs_diff_vs_adjoint"].values()) < 1e-8
    assert out["settings"]["sizes"] == [3, 4] and out["settings"]["repeats"] == 1


def test_gradient_benchmark_defaults_to_10x10_when_present(capsys):
    out = run_bench(capsys, ["gradient", "--sizes", "4", "10", "--repeats", "1", "--min-time", "0", "--budget", "0"])
    assert out["grid"] == "10x10"
    assert out["ratio_fixed_point"] == out["sizes"]["10x10"]["ratio_fixed_point"]
    assert out["sizes"]["10x10"]["runs"]["fixed_point"] == 1  # over budget: run once


def test_fit_benchmark_quick(capsys):
    out = run_bench(capsys, ["fit", "--quick"])
    assert set(out) == {"benchmark", "total_s", "flat", "factorial", "deviation_ratio_factorial_over_flat",
                        "data_time_s", "settings"}
    assert set(out["flat"]) == FIT_ENTRY | {"status"} and set(out["factorial"]) == FIT_ENTRY
    _finite_numbers(out)
    s = out["settings"]
    assert s["quick"] and {k: s[k] for k in fit_bench.QUICK} == fit_bench.QUICK
    for learner, budget in (("flat", s["flat_max_iter"]), ("factorial", s["max_iter"])):
        e = out[learner]
        assert e["time_s"] > 0 and e["final_loss"] >= 0 and e["mean_train_deviation"] >= 0
        assert isinstance(e["n_evaluations"], int) and e["n_evaluations"] >= e["n_iter"] >= 1 and e["n_iter"] <= budget
    assert out["total_s"] == pytest.approx(out["flat"]["time_s"] + out["factorial"]["time_s"])
    ratio = out["deviation_ratio_factorial_over_flat"]
    assert ratio == pytest.approx(out["factorial"]["mean_train_deviation"] / out["flat"]["mean_train_deviation"])
    # the quick setting (16 tasks sharing 2 primitives) keeps the paper's point: factorial beats flat
    assert ratio < 0.7


def test_fit_benchmark_explicit_options_win_over_quick(capsys):
    out = run_bench(capsys, ["fit", "--quick", "--n-tasks", "5", "--max-iter", "2", "--size", "3"])
    s = out["settings"]
    assert (s["n_tasks"], s["max_iter"], s["size"]) == (5, 2, 3)  # explicit
    assert (s["n_demos"], s["length"], s["flat_max_iter"]) == (5, 6, 20)  # --quick's
    assert out["factorial"]["n_iter"] <= 2


def test_fit_benchmark_options(capsys):
    out = run_bench(capsys, ["fit", "--size", "3", "--n-tasks", "3", "--n-demos", "2", "--length", "3", "-k", "2",
                             "--flat-max-iter", "3", "--max-iter", "2", "--blas-threads", "0"])
    s = out["settings"]
    assert (s["size"], s["n_tasks"], s["n_demos"], s["length"], s["n_primitives"]) == (3, 3, 2, 3, 2)
    assert not s["quick"] and s["inner_steps"] == fit_bench.DEFAULTS["inner_steps"]
    assert out["factorial"]["n_iter"] <= 2 and out["flat"]["n_iter"] <= 3


def test_solvers_benchmark_quick_settings_keep_explicit_options():
    args = bench.build_parser().parse_args(["solvers", "--quick", "--size", "4", "--alphas", "0", "1"])
    s = resolve_settings(args, solvers_bench.DEFAULTS, solvers_bench.QUICK)
    assert s["size"] == 4 and s["alphas"] == [0.0, 1.0]
    assert s["transfer_tasks"] == solvers_bench.QUICK["transfer_tasks"]
    s = resolve_settings(bench.build_parser().parse_args(["solvers"]), solvers_bench.DEFAULTS, solvers_bench.QUICK)
    assert s["size"] == 10 and s["alphas"] == solvers_bench.DEFAULTS["alphas"]


def test_add_option_help_shows_default_and_quick_once():
    import argparse

    p = argparse.ArgumentParser()
    action = add_option(p, "--n-tasks", type=int, defaults={"n_tasks": 100}, quick={"n_tasks": 6}, help="training tasks")
    assert action.default is None and action.help == "training tasks (default: 100; --quick: 6)"


def test_one_parser_for_both_entry_points(capsys):
    with pytest.raises(SystemExit) as exc:
        bench.main(["--help"])
    assert exc.value.code == 0
    direct = capsys.readouterr().out
    with pytest.raises(SystemExit):
        cli_main(["bench", "--help"])
    via_cli = capsys.readouterr().out
    assert direct.startswith("usage: python -m factirl_opt.bench") and via_cli.startswith("usage: factirl-opt bench")
    assert direct.split("\n", 1)[1] == via_cli.split("\n", 1)[1]  # same parser, only the program name differs
    for name in BENCHMARKS:
        assert name in direct


def test_unimportable_benchmark_is_listed_not_fatal(monkeypatch, capsys):
    monkeypatch.setitem(BENCHMARKS, "ghost", "no_such_benchmark_module")
    parser = bench.build_parser()
    assert "unavailable: ghost" in parser.epilog
    assert parser.parse_args(["fit", "--quick"])._module is fit_bench


def test_blas_thread_limit_is_restored():
    from threadpoolctl import threadpool_info

    from factirl_opt._threads import limit_blas_threads

    def counts():
        return [d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"]

    before = counts()
    with limit_blas_threads(1) as inside:
        # (the limiter inspects the loaded libraries once: one loaded later by another test is not in ``inside``)
        assert inside and all(n == 1 for n in inside) and counts().count(1) >= len(inside)
    assert counts() == before

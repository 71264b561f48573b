"""The benchmarks, in tiny configurations through the one benchmark parser.

Timings are not asserted (machines are noisy): the JSON structure, the consistency of the
derived numbers with the measured ones, and the non-timing results (gradient agreement,
deviations, losses, the factorial learner's advantage) are.
"""

import json
import math

import pytest

from factirl_opt.lab import bench
from factirl_opt.lab.benchmarks import (
    BENCHMARKS, add_option, fit as fit_bench, resolve_settings, solvers as solvers_bench,
)
from factirl_opt.lab.cli import main as cli_main

FIT_ENTRY = {"time_s", "n_evaluations", "n_linear_solves", "n_iter", "status", "final_loss", "mean_train_deviation"}
COMBO_ENTRY = FIT_ENTRY | {"h_solver", "d_solver", "stop_reason", "deviation_ratio_over_flat", "evaluations_ratio_vs_reference",
                           "linear_solves_ratio_vs_reference", "qualifies"}


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
                        "combinations", "reference", "best", "skipped", "data_time_s", "settings"}
    assert set(out["flat"]) == FIT_ENTRY and set(out["factorial"]) == COMBO_ENTRY
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


def test_fit_benchmark_compares_every_combination(capsys):
    """(H armijo | gn-qp-clarabel) x (D armijo | lbfgs | gn-cg) side by side from one start."""
    import solvers

    out = run_bench(capsys, ["fit", "--quick", "--max-iter", "4"])
    combos, s = out["combinations"], out["settings"]
    assert s["d_solver"] == "armijo" and s["h_solvers"] == ["armijo", "gn-qp-clarabel"]
    assert s["d_solvers"] == ["armijo", "lbfgs", "gn-cg"]
    expected = [f"{h}|{d}" for h in s["h_solvers"] for d in s["d_solvers"]]
    available = set(solvers.available_solvers())
    assert sorted(combos) == sorted(e for e in expected if set(e.split("|")) <= available)
    assert out["skipped"] == [e for e in expected if e not in combos]
    assert out["reference"] == "armijo|armijo" and out["factorial"] == combos["armijo|armijo"]
    ref = combos["armijo|armijo"]
    for name, e in combos.items():
        assert set(e) == COMBO_ENTRY and f"{e['h_solver']}|{e['d_solver']}" == name
        assert 1 <= e["n_iter"] <= 4 and e["status"] in ("converged", "max_iter", "stalled") and e["stop_reason"]
        # every Q* evaluation solves at least one Bellman system per task (policy evaluation)
        assert e["n_linear_solves"] >= e["n_evaluations"] * s["n_tasks"]
        assert e["evaluations_ratio_vs_reference"] == pytest.approx(e["n_evaluations"] / ref["n_evaluations"])
        assert e["linear_solves_ratio_vs_reference"] == pytest.approx(e["n_linear_solves"] / ref["n_linear_solves"])
        assert e["deviation_ratio_over_flat"] == pytest.approx(e["mean_train_deviation"] / out["flat"]["mean_train_deviation"])
        assert e["qualifies"] == (e["final_loss"] <= ref["final_loss"]
                                  and e["mean_train_deviation"] <= fit_bench.DEVIATION_SLACK * ref["mean_train_deviation"])
    qualified = [k for k, e in combos.items() if e["qualifies"]]
    assert "armijo|armijo" in qualified
    assert out["best"] == min(qualified, key=lambda k: (combos[k]["n_evaluations"], combos[k]["time_s"]))
    # gn-cg's matrix-free products are linear solves that Q* evaluations do not show
    if "armijo|gn-cg" in combos:
        per_eval = {k: combos[k]["n_linear_solves"] / combos[k]["n_evaluations"] for k in ("armijo|armijo", "armijo|gn-cg")}
        assert per_eval["armijo|gn-cg"] > per_eval["armijo|armijo"]


def test_fit_benchmark_selected_pair_and_errors(capsys):
    out = run_bench(capsys, ["fit", "--quick", "--max-iter", "2", "--h-solvers", "armijo", "--d-solvers", "lbfgs",
                             "--d-solver", "gn-cg"])
    # the reference and the selected pair are always fitted
    assert sorted(out["combinations"]) == ["armijo|armijo", "armijo|gn-cg", "armijo|lbfgs"]
    assert out["factorial"] == out["combinations"]["armijo|gn-cg"] and out["factorial"]["d_solver"] == "gn-cg"
    with pytest.raises(SystemExit) as exc:  # refused by the parser, before any fit
        bench.build_parser().parse_args(["fit", "--quick", "--d-solvers", "no-such-solver"])
    assert exc.value.code == 2 and "argument --d-solvers: unknown solver 'no-such-solver'" in capsys.readouterr().err


def test_counting_planner_counts_every_task_system():
    import numpy as np

    from factirl_opt import GridWorld
    from factirl_opt.planning import CountingPlanner, get_planner, optimal_q, plan

    mdp = GridWorld(size=3)
    planner = CountingPlanner(get_planner(mdp))
    R = np.random.default_rng(0).standard_normal((4, mdp.n_states, mdp.n_actions))
    res = plan(planner, R)
    assert planner.n_solves >= 4  # at least one policy evaluation of each task
    np.testing.assert_allclose(res.Q, optimal_q(mdp, R)[0], rtol=1e-12, atol=1e-12)
    before = planner.n_solves
    res.system.solve_transpose(np.ones((4, mdp.n_states)))
    assert planner.n_solves == before + 4 and planner.name == get_planner(mdp).name


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
    assert direct.startswith("usage: python -m factirl_opt.lab.bench") and via_cli.startswith("usage: factirl-opt bench")
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


@pytest.mark.slow
def test_fit_benchmark_paper_scale_acceptance(capsys):
    """The faster-fits benchmark at paper scale (the defaults, one run): Armijo H-step with the gn-cg D-step
    reaches a final loss no higher than Armijo/Armijo's, a train deviation within 5% of it, with
    at most a third of its Q* evaluations (measured: 454 vs 2976, loss 0.069 vs 0.210)."""
    out = run_bench(capsys, ["fit", "--h-solvers", "armijo", "--d-solvers", "gn-cg"])
    ref, e = out["combinations"]["armijo|armijo"], out["combinations"]["armijo|gn-cg"]
    assert e["qualifies"] and out["best"] == "armijo|gn-cg"
    assert e["final_loss"] <= ref["final_loss"] and 3 * e["n_evaluations"] <= ref["n_evaluations"]
    assert e["mean_train_deviation"] <= 1.05 * ref["mean_train_deviation"]

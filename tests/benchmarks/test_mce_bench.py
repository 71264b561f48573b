"""The mce benchmark: FactIRL with policy matching and with MCE on Objectworld maps, in a tiny configuration."""

import json

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.lab import bench
from factirl_opt.lab.benchmarks import mce as mce_bench
from factirl_opt.exceptions import ValidationError
from factirl_opt.planning import CountingPlanner, get_planner

COUNTS = {"n_systems", "n_stochastic_systems", "n_forward", "n_transpose", "n_forward_calls", "n_transpose_calls"}


def run_bench(capsys, argv):
    assert bench.main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_mce_benchmark_quick_fits_both_objectives_and_counts_their_planning(capsys):
    out = run_bench(capsys, ["mce", "--quick", "--repeats", "2"])
    assert out["benchmark"] == "mce" and out["settings"]["quick"]
    fits = out["fits"]
    assert list(fits) == ["policy-matching", "mce"]
    for name, e in fits.items():
        assert COUNTS <= set(e) and e["time_s"] == min(e["times_s"]) and len(e["times_s"]) == 2
        assert e["cpu_s"] == min(e["cpus_s"]) > 0 and len(e["cpus_s"]) == 2
        assert e["n_iter"] <= mce_bench.QUICK["max_iter"] and e["final_loss"] > 0 and e["mean_train_deviation"] >= 0
        assert e["n_linear_solves"] == e["n_forward"] + e["n_transpose"] > 0
        assert e["forward_calls_per_evaluation"] == pytest.approx(e["n_forward_calls"] / e["n_evaluations"])
    # MCE plans stochastic (soft) policies only, policy matching deterministic (greedy) ones only
    assert fits["mce"]["n_stochastic_systems"] == fits["mce"]["n_systems"] > 0
    assert fits["policy-matching"]["n_stochastic_systems"] == 0
    assert out["ratio_mce_over_pm"] == pytest.approx(fits["mce"]["time_s"] / fits["policy-matching"]["time_s"])
    assert out["cpu_ratio_mce_over_pm"] == pytest.approx(fits["mce"]["cpu_s"] / fits["policy-matching"]["cpu_s"])
    assert out["deviation_ratio_mce_over_pm"] == pytest.approx(
        fits["mce"]["mean_train_deviation"] / fits["policy-matching"]["mean_train_deviation"])


def test_mce_benchmark_one_objective_has_no_ratio(capsys):
    out = run_bench(capsys, ["mce", "--quick", "--objectives", "mce", "--max-iter", "1"])
    assert list(out["fits"]) == ["mce"] and "ratio_mce_over_pm" not in out and "cpu_ratio_mce_over_pm" not in out
    assert out["settings"]["fact_max_iter"] == 1


def test_mce_benchmark_compares_flat_solvers_and_transfers_to_new_maps(capsys):
    out = run_bench(capsys, ["mce", "--quick", "--flat-solvers", "default", "newton", "--n-test-tasks", "2",
                             "--repeats", "2"])
    fits = out["fits"]
    assert list(fits) == ["policy-matching", "policy-matching, flat newton", "mce", "mce, flat newton"]
    assert [e["flat_solver"] for e in fits.values()] == ["lbfgs", "newton", "lbfgs", "newton"]
    for e in fits.values():
        assert e["mean_transfer_deviation"] >= 0 and e["transfer_n_evaluations"] > 0 and e["transfer_cpu_s"] >= 0
    assert out["settings"]["flat_solvers"] == ["default", "newton"] and out["settings"]["n_test_tasks"] == 2
    assert out["cpu_ratio_mce_over_pm"] == pytest.approx(fits["mce"]["cpu_s"] / fits["policy-matching"]["cpu_s"])
    none = run_bench(capsys, ["mce", "--quick", "--objectives", "mce", "--n-test-tasks", "0", "--max-iter", "1",
                              "--h-solvers", "default", "newton"])
    assert list(none["fits"]) == ["mce", "mce, H newton"] and none["fits"]["mce, H newton"]["h_solver"] == "newton"
    assert "mean_transfer_deviation" not in none["fits"]["mce"]


def test_mce_benchmark_compares_schemes_and_scores_the_training_tasks_on_fresh_maps(capsys):
    out = run_bench(capsys, ["mce", "--quick", "--objectives", "mce", "--flat-solvers", "armijo", "default", "lbfgs",
                             "--schemes", "alternating", "default", "joint", "--n-test-tasks", "0", "--flat-tol", "1e-3"])
    assert out["settings"]["flat_tol"] == 1e-3
    fits = out["fits"]
    # the preset's fit (an L-BFGS flat start, the joint scheme) is fitted once, under the objective's name
    assert list(fits) == ["mce, flat armijo, alternating", "mce, flat armijo", "mce, alternating", "mce"]
    assert [(e["flat_solver"], e["scheme"]) for e in fits.values()] == [("armijo", "alternating"), ("armijo", "joint"),
                                                                         ("lbfgs", "alternating"), ("lbfgs", "joint")]
    assert out["settings"]["schemes"] == ["alternating", "default", "joint"]
    assert out["settings"]["preset_fits"] == {"mce": {"flat_solver": "lbfgs", "scheme": "joint"}}
    assert fits["mce, alternating"]["final_loss"] != fits["mce"]["final_loss"]
    for e in fits.values():
        assert np.isfinite(e["mean_new_maps_deviation"]) and e["mean_new_maps_deviation"] >= 0


def test_mce_benchmark_default_fit_is_the_presets_factirl(monkeypatch):
    """The default entry fits FactIRL as the preset's line-up does (its flat solver on features, its
    scheme); an H-step solver the joint scheme refuses alternates instead of failing."""
    from factirl_opt.lab.experiments.presets import PRESETS

    seen = []

    class SpyFactIRL(fo.FactIRL):
        def fit(self, *args, **kw):
            settings = fo.SolverSettings.of(self.solver)
            seen.append((settings.flat_solver, self.scheme, settings.h_solver))
            raise RuntimeError("stop")

    monkeypatch.setattr(mce_bench, "FactIRL", SpyFactIRL)
    preset = PRESETS["objectworld-per-task"]
    gt = type("GT", (), {"mdps": lambda self, split: [fo.GridWorld(2)], "task_maps": {"train": type("M", (), {"features": []})},
                         "train_demos": []})()
    for objective in mce_bench.OBJECTIVES:
        with pytest.raises(RuntimeError, match="stop"):
            mce_bench.fit_once(preset, gt, objective, 0)
    with pytest.raises(RuntimeError, match="stop"):
        mce_bench.fit_once(preset, gt, "policy-matching", 0, h_solver="gn-qp-clarabel-nonneg")
    assert seen == [("lbfgs", "joint", "gn-qp-clarabel"), ("lbfgs", "joint", "lbfgs"),
                    ("lbfgs", "alternating", "gn-qp-clarabel-nonneg")]
    assert mce_bench.resolved_run(PRESETS["objectworld-per-task-quick"], "mce") == ("lbfgs", "alternating")


def test_new_maps_deviation_scores_the_learnt_weights_on_the_fresh_maps(capsys):
    """mean_new_maps_deviation is the deviation of the weights D h_i on the fresh maps' features,
    against the same tasks' true rewards there (not on the training maps)."""
    from factirl_opt.datasets.objectworld import state_action_rewards
    from factirl_opt.lab.experiments.worlds import objectworld_per_task
    from factirl_opt.tasks.features import feature_rewards

    args = bench.build_parser().parse_args(["mce", "--quick"])
    s = mce_bench.resolve_settings(args, mce_bench.DEFAULTS, mce_bench.QUICK)
    preset = mce_bench.benchmark_preset(s)
    gt = objectworld_per_task(preset, s["n_tasks"], s["n_demos"], s["seed"])
    model = mce_bench.fit_once(preset, gt, "mce", 1)[0]
    fresh = gt.fresh("train")
    mdps = list(fresh.mdps)
    learnt = feature_rewards(list(fresh.features), model.coefficients_ @ model.dictionary_.T, mdps)
    expected = fo.deviation(mdps, state_action_rewards(fresh.rewards, mdps[0].n_actions), learnt, planner=preset.planner)
    assert mce_bench.new_maps_deviation(model, gt, preset) == pytest.approx(float(np.mean(expected)), rel=1e-12)
    on_training_maps = fo.deviation(gt.mdps("train"), gt.train_rewards, np.asarray(model.rewards_), planner=preset.planner)
    assert mce_bench.new_maps_deviation(model, gt, preset) != pytest.approx(float(np.mean(on_training_maps)))


def test_mce_benchmark_refuses_a_preset_without_a_map_per_task(capsys):
    with pytest.raises(SystemExit):
        bench.build_parser().parse_args(["mce", "--quick", "--preset", "objectworld-quick"])
    assert "argument --preset: invalid choice: 'objectworld-quick'" in capsys.readouterr().err
    args = bench.build_parser().parse_args(["mce", "--quick"])
    args.preset = "objectworld-quick"  # given programmatically: refused by the library
    with pytest.raises(ValidationError, match="not a world with a map per task"):
        mce_bench.run(args)


@pytest.mark.parametrize("argv, fragment", [(["--n-tasks", "0"], "argument --n-tasks: must be an integer >= 1; got '0'"),
                                            (["--repeats", "0"], "argument --repeats: must be an integer >= 1; got '0'"),
                                            (["--flat-solvers", "bfgs"], "argument --flat-solvers: invalid choice: 'bfgs'"),
                                            (["--schemes", "both"], "argument --schemes: invalid choice: 'both'"),
                                            (["--schemes", "default", "alternate"], "invalid choice: 'alternate'"),
                                            (["--flat-tol", "-1"], "argument --flat-tol"),
                                            (["--n-test-tasks", "-1"], "argument --n-test-tasks"),
                                            (["--blas-threads", "-3"], "argument --blas-threads")])
def test_mce_benchmark_options_are_checked_by_the_parser(capsys, argv, fragment):
    with pytest.raises(SystemExit) as exit_:
        bench.build_parser().parse_args(["mce", "--quick", *argv])
    assert exit_.value.code == 2 and fragment in capsys.readouterr().err


def test_counting_planner_counts_and_passes_results_through(rng):
    mdp = fo.GridWorld(3)
    inner = get_planner(mdp, "sparse-lu")
    counting = CountingPlanner(inner)
    policy = rng.dirichlet(np.ones(mdp.n_actions), size=(2, mdp.n_states))
    B = rng.standard_normal((2, mdp.n_states))
    x = counting.system(policy).solve(B)
    np.testing.assert_array_equal(x, inner.system(policy).solve(B))
    counting.system(policy[:1]).solve_transpose(B[:1])
    assert counting.counts() == dict(n_systems=3, n_stochastic_systems=3, n_forward=2, n_transpose=1,
                                     n_forward_calls=1, n_transpose_calls=1)

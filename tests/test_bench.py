"""The gradient and fit benchmarks, in tiny configurations through the dispatcher.

Timings are not asserted (machines are noisy); the JSON structure and the non-timing numbers
(gradient agreement, deviations) are.
"""

import json

import pytest

pytest.importorskip("factirl_opt.benchmarks.solvers")  # bench.main imports every benchmark module

from factirl_opt import bench  # noqa: E402


def run_bench(capsys, argv):
    assert bench.main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_gradient_benchmark(capsys):
    out = run_bench(capsys, ["gradient", "--sizes", "3", "4", "--repeats", "1", "--min-time", "0", "--n-demos", "2", "--length", "3"])
    assert out["benchmark"] == "gradient" and out["grid"] == "3x3"
    assert set(out["sizes"]) == {"3x3", "4x4"}
    for key in ("ratio_fixed_point", "ratio_forward_direct"):
        assert out[key] == out["sizes"]["3x3"][key] > 0
    for size, entry in out["sizes"].items():
        n = int(size.split("x")[0])
        assert entry["n_states"] == n * n and entry["n_params"] == 4 * n * n
        for key in ("adjoint_s", "fixed_point_s", "forward_direct_s"):
            assert entry[key] > 0
        assert set(entry["breakdown"]) >= {"planning_q_star_s", "adjoint_gradient_part_s", "fixed_point_phi_s", "forward_direct_phi_s"}
        assert entry["ratio_fixed_point"] == pytest.approx(entry["fixed_point_s"] / entry["adjoint_s"])
        # the three routes compute the same gradient
        assert max(entry["max_abs_diff_vs_adjoint"].values()) < 1e-8
    assert out["settings"]["sizes"] == [3, 4]


def test_gradient_benchmark_defaults_to_10x10_when_present(capsys):
    out = run_bench(capsys, ["gradient", "--sizes", "4", "10", "--repeats", "1", "--min-time", "0", "--budget", "0"])
    assert out["grid"] == "10x10"
    assert out["ratio_fixed_point"] == out["sizes"]["10x10"]["ratio_fixed_point"]
    assert out["sizes"]["10x10"]["runs"]["fixed_point"] == 1


def test_fit_benchmark_quick(capsys):
    out = run_bench(capsys, ["fit", "--quick", "--seed", "3"])
    assert out["benchmark"] == "fit"
    assert out["settings"]["quick"] and out["settings"]["n_tasks"] == 6
    for learner in ("flat", "factorial"):
        entry = out[learner]
        assert entry["time_s"] > 0 and entry["mean_train_deviation"] >= 0
        assert isinstance(entry["n_evaluations"], int) and entry["n_evaluations"] > 0
    assert out["total_s"] == pytest.approx(out["flat"]["time_s"] + out["factorial"]["time_s"])
    assert out["deviation_ratio_factorial_over_flat"] == pytest.approx(
        out["factorial"]["mean_train_deviation"] / out["flat"]["mean_train_deviation"]
    )


def test_fit_benchmark_options(capsys):
    out = run_bench(capsys, ["fit", "--size", "3", "--n-tasks", "3", "--n-demos", "2", "--length", "3", "-k", "2",
                             "--flat-max-iter", "3", "--max-iter", "2", "--blas-threads", "0"])
    s = out["settings"]
    assert (s["size"], s["n_tasks"], s["n_demos"], s["length"], s["n_primitives"]) == (3, 3, 2, 3, 2)
    assert out["factorial"]["n_iter"] <= 2 and out["flat"]["n_iter"] <= 3


def test_blas_thread_limit_is_restored():
    from threadpoolctl import threadpool_info

    from factirl_opt._threads import limit_blas_threads

    def counts():
        return [d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"]

    before = counts()
    with limit_blas_threads(1) as inside:
        assert all(n == 1 for n in inside) and counts() == inside
    assert counts() == before

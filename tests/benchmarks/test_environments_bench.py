"""The environments benchmark: per-task maps against one map, same tasks and budget, one run."""

import json

from factirl_opt.lab import bench
from factirl_opt.lab.benchmarks import environments as env_bench


def test_environments_benchmark_quick_in_process(capsys):
    assert bench.main(["environments", "--quick", "--in-process"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["benchmark"] == "environments" and set(out["routes"]) == set(env_bench.ROUTES)
    s = out["settings"]
    assert s["quick"] and {k: s[k] for k in env_bench.QUICK} == env_bench.QUICK
    for route in out["routes"].values():
        assert route["n_iter"] == env_bench.QUICK["max_iter"] and route["status"] == "max_iter"
        # the kernel's RSS counters are cached per thread (up to 64 pages each), so the peak read by
        # getrusage can trail /proc's current figure by a fraction of a MB
        assert route["fit_s"] > 0 and route["peak_rss_mb"] >= route["rss_before_fit_mb"] - 4.0 and route["rss_before_fit_mb"] > 0
    assert out["ratio"] == out["routes"]["per_task_maps"]["fit_s"] / out["routes"]["one_map"]["fit_s"]

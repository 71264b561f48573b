"""The active benchmark: deviation after each added demonstration per start strategy, in a tiny configuration."""

import json

import numpy as np
import pytest

from factirl_opt.lab import bench


def run_bench(capsys, argv):
    assert bench.main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_active_benchmark_quick_records_every_strategy_and_the_calibration(capsys):
    out = run_bench(capsys, ["active", "--quick", "--calibration", "--max-demos", "3"])
    row = out["worlds"]["grid"]["0"]
    assert set(row["strategies"]) == {"requested", "requested-value", "random", "entropy", "requested-regret",
                                      "requested-value-skip"}
    for st in row["strategies"].values():
        assert len(st["deviation"]) == len(st["map_deviation"]) == 3
        assert np.all(np.isfinite(st["deviation"])) and min(st["deviation"]) >= 0
        assert len(st["starts"]) == 2 and all(len(s) == row["n_test"] for s in st["starts"])
    cost = row["request_cost"]
    assert cost["request_over_transfer"] == pytest.approx(cost["request_cpu_s"] / cost["transfer_cpu_s"])
    cal = row["calibration"]
    assert 0 <= cal["coverage_90"] <= 1 and -1 <= cal["spearman"] <= 1 and cal["n_samples"] == 20


def test_active_benchmark_random_starts_depend_on_the_seed_only(capsys):
    argv = ["active", "--quick", "--strategies", "random", "--cost-repeats", "1"]
    a, b = run_bench(capsys, argv), run_bench(capsys, argv)
    assert a["worlds"]["grid"]["0"]["strategies"] == b["worlds"]["grid"]["0"]["strategies"]


@pytest.mark.parametrize("argv, fragment", [(["--worlds", "maze"], "invalid choice: 'maze'"),
                                            (["--max-demos", "0"], "--max-demos"),
                                            (["--strategies", "oracle"], "invalid choice: 'oracle'")])
def test_active_benchmark_options_are_checked_by_the_parser(capsys, argv, fragment):
    with pytest.raises(SystemExit):
        bench.build_parser().parse_args(["active", "--quick", *argv])
    assert fragment in capsys.readouterr().err


def test_active_benchmark_requested_strategies_pass_their_options(monkeypatch):
    from factirl_opt.lab.benchmarks import active

    seen = []

    def fake(model, mdp, demos, n_requests, **kw):
        seen.append(kw)
        return [np.array([0]) for _ in demos]

    monkeypatch.setattr(active, "request_starts", fake)
    monkeypatch.setattr(active, "_deviations", lambda *a: (np.zeros(1), np.zeros(1)))

    class Model:
        transfer_posterior_ = None

        def transfer(self, *a, **k):
            return self

    class GT:
        test_demos = [np.zeros((1, 3, 2), dtype=int)]
        test_rewards = np.zeros((1, 4, 4))

    import factirl_opt as fo
    mdp = fo.GridWorld(size=2)
    s = {"max_demos": 2}
    active.strategy_run(Model(), GT(), None, mdp, None, 1, "requested-value-skip", s, 0)
    active.strategy_run(Model(), GT(), None, mdp, None, 1, "requested-regret", s, 0, policy="greedy")
    active.strategy_run(Model(), GT(), None, mdp, None, 1, "requested", s, 0, criterion="value")
    assert [{k: v for k, v in kw.items() if k != "features"} for kw in seen] == [
        {"policy": "boltzmann", "criterion": "value", "demonstrated": "skip"},
        {"policy": "greedy", "criterion": "regret"},
        {"policy": "boltzmann", "criterion": "value"}]

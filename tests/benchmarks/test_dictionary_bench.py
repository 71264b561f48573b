"""``bench dictionary``: constrained dictionaries against the true primitives, in its tiny configuration."""

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

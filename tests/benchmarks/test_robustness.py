"""``bench robustness``: learning on estimated models, scoring on the true one.

The quick configuration runs once (module fixture); its tables' structure, the estimated
models' convergence to the true model, and the learners' convergence to the true model's
result as M grows are checked. Timings are not asserted.
"""

import csv
import json
import math

import numpy as np
import pytest

from factirl_opt import GridWorld, estimate_mdp
from factirl_opt.lab import bench
from factirl_opt.mdp import sample_transitions
from factirl_opt.lab.benchmarks import robustness as rb

BIG = 1_000_000


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("robustness")
    result = rb.run(bench.build_parser().parse_args(["robustness", "--quick", "--out", str(out)]))
    return result, out


def _read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_quick_tables_and_figure(quick):
    result, out = quick
    assert result["benchmark"] == "robustness" and result["settings"]["quick"] and result["settings"]["preset"] == "fast"
    assert result["settings"]["seeds"] == [0] and result["settings"]["extra"] == [0, BIG]
    rows = _read(out / "robustness.csv")
    assert list(rows[0]) == ["seed", "M", "learner", "split", "deviation"]
    assert {(r["M"], r["learner"], r["split"]) for r in rows} == {(m, lr, sp) for m in ("true", "0", str(BIG))
                                                                   for lr, sp in rb.LEARNERS}
    assert len(rows) == 12 and all(r["seed"] == "0" and float(r["deviation"]) >= 0 for r in rows)
    summary = _read(out / "summary.csv")
    assert list(summary[0]) == ["M", "learner", "split", "n_seeds", "deviation_mean", "deviation_std"]
    by_key = {(r["M"], r["learner"], r["split"]): r for r in rows}
    for r in summary:  # one seed: the mean is the row, the std 0
        assert float(r["deviation_mean"]) == float(by_key[r["M"], r["learner"], r["split"]]["deviation"])
        assert r["n_seeds"] == "1" and float(r["deviation_std"]) == 0.0
    models = _read(out / "models.csv")
    assert [m["M"] for m in models] == ["true", "0", str(BIG)]
    assert models[1]["n_transitions"] == str(8 * 20 * 9 + 4 * 9)  # every demonstration's transitions (L = 10)
    assert int(models[2]["n_transitions"]) == int(models[1]["n_transitions"]) + BIG
    png = (out / "robustness.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    assert [str(p) for p in (out / "robustness.csv", out / "models.csv", out / "summary.csv", out / "robustness.png")] == result["files"]


def test_estimated_models_approach_the_true_one(quick):
    models = {m["M"]: m for m in quick[0]["models"]}
    truth, demos_only, big = models["true"], models[0], models[BIG]
    assert truth["max_abs_error"] == 0 and truth["heldout_ruled_out"] == 0
    # from the demonstrations alone, untried pairs are self-loops: held-out moves are ruled out
    assert demos_only["heldout_ruled_out"] > 0.1 and demos_only["heldout_loglik"] == -math.inf
    assert demos_only["max_abs_error"] == 1.0
    assert big["heldout_ruled_out"] == 0 and big["max_abs_error"] < 0.02
    assert big["heldout_loglik"] == pytest.approx(truth["heldout_loglik"], abs=5e-3)


def test_train_deviation_approaches_the_true_models(quick):
    """With 10^6 exploration transitions the train learners' deviations are those of the true
    model to within 0.1, and much closer to them than with the demonstrations' transitions alone."""
    dev = {(r["M"], r["learner"], r["split"]): r["deviation"] for r in quick[0]["rows"]}
    gap = {M: sum(abs(dev[M, lr, "train"] - dev["true", lr, "train"]) for lr in ("flat", "factorial")) for M in (0, BIG)}
    for lr in ("flat", "factorial"):
        assert abs(dev[BIG, lr, "train"] - dev["true", lr, "train"]) < 0.1
    assert gap[BIG] < 0.5 * gap[0]


def test_json_on_stdout(quick, capsys, tmp_path):
    # the JSON (summary, models, fit times) of the entry point; -inf log-likelihoods are kept
    assert bench.main(["robustness", "--quick", "--extra", "0", "--n-tasks", "2", "--n-demos", "2", "--n-test-tasks", "1",
                       "--n-heldout", "100"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"benchmark", "total_s", "summary", "models", "rows", "fit_s", "files", "settings"}
    assert out["files"] == [] and set(out["fit_s"]["0"]) == {"true", "0"} and len(out["rows"]) == 8


def test_exploration_sequence_is_nested_and_deterministic():
    mdp = GridWorld(size=3)
    ss = np.random.SeedSequence(5)
    long = rb.exploration_sequence(mdp, 2 * rb.EXPLORATION_BLOCK + 7, ss)
    short = rb.exploration_sequence(mdp, rb.EXPLORATION_BLOCK + 3, ss)
    assert long.shape == (2 * rb.EXPLORATION_BLOCK + 7, 3) and np.array_equal(long[: len(short)], short)
    assert rb.exploration_sequence(mdp, 0, ss).shape == (0, 3)


def test_model_scores_against_a_reference():
    mdp = GridWorld(size=3)
    heldout = sample_transitions(mdp, 500, rng=1)
    est = estimate_mdp(sample_transitions(mdp, 200, rng=2), mdp.n_states, mdp.n_actions, mdp.gamma)
    scores = rb.model_scores(mdp, est, heldout)
    P, Q = est.transitions.reshape(-1, mdp.n_states), mdp.transitions.reshape(-1, mdp.n_states)
    with np.errstate(divide="ignore"):
        logp = np.log(P[heldout[:, 0] * mdp.n_actions + heldout[:, 1], heldout[:, 2]])
    assert scores["max_abs_error"] == pytest.approx(np.abs(P - Q).max())
    assert scores["heldout_ruled_out"] == pytest.approx(np.mean(np.isinf(logp)))
    assert scores["heldout_loglik_possible"] == pytest.approx(logp[np.isfinite(logp)].mean())
    assert scores["heldout_loglik"] == (-math.inf if np.isinf(logp).any() else pytest.approx(logp.mean()))


def test_summarize_orders_and_aggregates():
    rows = [{"seed": s, "M": M, "learner": lr, "split": sp, "deviation": float(s + (1 if M == "true" else M))}
            for s in (0, 1, 2) for M in (10, "true", 0) for lr, sp in rb.LEARNERS]
    summary = rb.summarize(rows)
    assert [(r["M"], r["learner"], r["split"]) for r in summary[:3]] == [("true", "flat", "train"), (0, "flat", "train"),
                                                                         (10, "flat", "train")]
    assert summary[2]["deviation_mean"] == 11.0 and summary[2]["deviation_std"] == pytest.approx(1.0)
    assert len(summary) == 12 and all(r["n_seeds"] == 3 for r in summary)


@pytest.mark.parametrize("argv, match", [
    (["--pseudo-count", "-1"], "argument --pseudo-count: must be a finite number >= 0; got '-1'"),
    (["--size", "1"], "argument --size: must be an integer >= 2; got '1'"),
    (["--n-tasks", "0"], "argument --n-tasks: must be an integer >= 1; got '0'"),
])
def test_bad_settings_are_usage_errors(argv, match, capsys):
    with pytest.raises(SystemExit) as exc:  # refused by the parser, before any work
        bench.build_parser().parse_args(["robustness", "--quick", "--extra", "0", *argv])
    assert exc.value.code == 2 and match in capsys.readouterr().err


@pytest.mark.parametrize("value", ["-5", "1.5", "many"])
def test_bad_extra_is_a_usage_error(value, capsys):
    with pytest.raises(SystemExit):
        bench.build_parser().parse_args(["robustness", "--extra", value])
    assert "--extra" in capsys.readouterr().err


@pytest.mark.filterwarnings("ignore:FactIRL.transfer stalled")  # 2 demos of 2 tasks: a meaningless dictionary
def test_objectworld_runs():
    args = bench.build_parser().parse_args(["robustness", "--quick", "--world", "objectworld", "--size", "8", "--n-tasks", "2",
                                            "--n-demos", "2", "--n-test-tasks", "1", "--extra", "0", "--n-heldout", "100"])
    out = rb.run(args)
    assert out["settings"]["preset"] == "objectworld-quick" and out["settings"]["grid_size"] == 8
    assert {(r["M"], r["learner"], r["split"]) for r in out["rows"]} == {(m, lr, sp) for m in ("true", 0) for lr, sp in rb.LEARNERS}
    assert all(math.isfinite(r["deviation"]) and r["deviation"] >= 0 for r in out["rows"])
    assert out["models"][1]["n_transitions"] == 2 * 2 * 15 + 15  # demonstrations of 16 steps

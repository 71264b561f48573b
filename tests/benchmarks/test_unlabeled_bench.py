"""The unlabeled benchmark: labelled FactIRL, EM without and with a dictionary, on the same draws."""

import json

import numpy as np

import factirl_opt as fo
from factirl_opt import bench
from factirl_opt.benchmarks import unlabeled


def test_unlabeled_benchmark_quick(capsys):
    assert bench.main(["unlabeled", "--quick"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["benchmark"] == "unlabeled" and out["settings"]["quick"]
    assert [(r["n_tasks"], r["seed"]) for r in out["rows"]] == [(2, 0)]
    learners = out["rows"][0]["learners"]
    assert set(learners) == set(unlabeled.LEARNERS) and learners["labelled"]["ari"] == 1.0
    for name, row in learners.items():
        assert -1.0 <= row["ari"] <= 1.0 and row["train_deviation"] >= 0
        assert (row["transfer_deviation"] is None) == (name == "em_flat")
    assert learners["em_shared"]["n_iter"] <= unlabeled.QUICK["em_max_iter"]


def test_matched_deviation_pairs_each_task_with_its_own_reward():
    mdp = fo.GridWorld(4)
    tasks = fo.synthetic_tasks(mdp, 3, 1, 3, n_primitives=2, rng=0)
    R = np.asarray(tasks.rewards)
    assert unlabeled.matched_deviation(mdp, R, R[::-1]) < 1e-9  # renamed intentions, same rewards
    swapped = unlabeled.matched_deviation(mdp, R, R[[0, 0, 0]])  # one reward for all: two tasks pay
    assert swapped > 0

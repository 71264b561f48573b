"""Regression test on reproduced scores: the paper's orderings (section 4) at a small scale.

The ``test`` preset is the paper's world and learners at 50 training tasks with 10
demonstrations each and 50 test tasks with one demonstration each (one seed, fixed: the
scores are deterministic). Measured there: train flat 3.62, factorial 1.40, ground truth 0.07;
test flat 13.5, features from ex. 12.4, PCA features 9.3, factorial 6.3, ground truth 4.8.
The margins below leave room for harmless numerical changes and catch a learner that stops
learning. The ``objectworld-quick`` preset's orderings run by default (about 35 s); the opt-in
(``--runslow``) test runs the ``quick`` preset.
"""

import pytest

from factirl_opt.lab.experiments import read_csv, run_sweep


@pytest.fixture(scope="module")
def scores(tmp_path_factory):
    out = tmp_path_factory.mktemp("orderings")
    run_sweep("test", out, jobs=1, progress=False)
    return {(r["split"], r["learner"]): r["deviation_mean"] for r in read_csv(out / "summary.csv")}


def test_train_factorial_beats_flat(scores):
    assert scores["train", "factorial"] < 0.7 * scores["train", "flat"]
    assert scores["train", "factorial"] < 0.7 * scores["train", "flat, PCA features"]


def test_train_ground_truth_is_best(scores):
    others = [v for (s, lr), v in scores.items() if s == "train" and lr != "flat, ground truth"]
    assert scores["train", "flat, ground truth"] < 0.5 * min(others)


@pytest.mark.parametrize("baseline", ["flat", "flat, PCA features", "flat, features from ex."])
def test_test_factorial_beats_baseline(scores, baseline):
    assert scores["test", "factorial"] < 0.8 * scores["test", baseline]


def test_test_ground_truth_is_best(scores):
    others = [v for (s, lr), v in scores.items() if s == "test" and lr != "flat, ground truth"]
    assert scores["test", "flat, ground truth"] < 0.9 * min(others)


@pytest.mark.slow
def test_quick_preset_runs_every_learner_and_figure_with_the_papers_orderings(tmp_path):
    """The README's first command: every learner and figure; the main orderings at its default point."""
    from factirl_opt.lab.experiments import PRESETS, TEST_LEARNERS, TRAIN_LEARNERS
    from factirl_opt.lab.experiments.claims import evaluate_claims
    from factirl_opt.lab.experiments.figures import plot_all

    run_sweep("quick", tmp_path, progress=False)
    rows = read_csv(tmp_path / "results.csv")
    assert {r["learner"] for r in rows if r["split"] == "train"} == set(TRAIN_LEARNERS)
    assert {r["learner"] for r in rows if r["split"] == "test"} == set(TEST_LEARNERS)
    assert len(plot_all(tmp_path)) == 6
    p = PRESETS["quick"]
    at_default = [c for c in evaluate_claims(rows, p) if c["point"] == f"{p.default_tasks} tasks, {p.default_demos} demos"]
    assert len(at_default) == 8 and all(c["holds"] for c in at_default), at_default


def test_objectworld_quick_preset_orderings(tmp_path):
    """The Objectworld orderings at the objectworld-quick default point (20 tasks x 16 demos, 16x16, 3 seeds;
    about 35 s, so it runs by default).

    Measured (results/objectworld-quick, mean over 3 seeds): test factorial on features 6.99, flat
    on features 8.32, flat tabular 9.69, true primitives 4.45; train 1.01, 1.05, 1.38, 0.17 (on
    training tasks the factorial learner only ties flat on features at this size). The floor's
    margin is 0.7 since the flat fits stop task by task (4.45 / 6.99 = 0.64 on test).

    The factorial fits are sensitive to the BLAS kernels' rounding (the flat ones are not): the same
    run gives 6.99 on the machine of the committed results, 7.47 with OpenBLAS's SkylakeX kernels
    and 7.83 with its Haswell kernels on an AMD EPYC, against flat tabular 9.69 everywhere. The
    margin against flat tabular is 0.85 so that the ordering, not one machine's rounding, is tested.
    """
    from factirl_opt.lab.experiments import PRESETS

    p = PRESETS["objectworld-quick"]
    run_sweep(p, tmp_path, progress=False)
    at = {(r["split"], r["learner"]): r["deviation_mean"] for r in read_csv(tmp_path / "summary.csv")
          if (r["n_tasks"], r["demos_per_task"]) == (p.default_tasks, p.default_demos)}
    assert at["test", "factorial, features"] < 0.95 * at["test", "flat, features"]
    assert at["test", "factorial, features"] < 0.85 * at["test", "flat"]
    assert at["train", "factorial, features"] < 0.9 * at["train", "flat"]
    for split in ("train", "test"):
        assert at[split, "flat, ground truth"] < 0.7 * at[split, "factorial, features"]

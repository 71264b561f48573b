"""The unlabeled benchmark: labelled FactIRL, EM without and with a dictionary, on the same draws."""

import json

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.lab import bench
from factirl_opt.lab.benchmarks import unlabeled


def test_unlabeled_benchmark_quick(capsys):
    assert bench.main(["unlabeled", "--quick"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["benchmark"] == "unlabeled" and out["settings"]["quick"]
    assert [(r["n_tasks"], r["seed"]) for r in out["rows"]] == [(2, 0)]
    learners = out["rows"][0]["learners"]
    assert set(learners) == set(unlabeled.DEFAULTS["learners"]) and learners["labelled"]["ari"] == 1.0
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


def _settings(*argv):
    return unlabeled.settings(bench.build_parser().parse_args(["unlabeled", *argv]))


def test_objectworld_quick_runs_every_learner_on_the_maps_features(capsys, monkeypatch):
    seen = []

    def spy(cls):
        class Spy(cls):
            def fit(self, mdp, demos, *args, **kwargs):
                seen.append((cls.__name__, None if self.features is None else np.shape(self.features)))
                return super().fit(mdp, demos, *args, **kwargs)
        return Spy

    monkeypatch.setattr(unlabeled, "FactIRL", spy(fo.FactIRL))
    monkeypatch.setattr(unlabeled, "MultiIntentIRL", spy(fo.MultiIntentIRL))
    assert bench.main(["unlabeled", "--quick", "--world", "objectworld"]) == 0
    out = json.loads(capsys.readouterr().out)
    q = unlabeled.WORLD_QUICK["objectworld"]
    assert out["settings"]["world"] == "objectworld" and out["settings"]["size"] == q["size"]
    assert out["settings"]["n_demos"] == q["n_demos"] and out["settings"]["length"] == q["length"]
    p = (q["size"] - 1) * (unlabeled.QUICK["n_primitives"] + 2)  # Levine's features: (N-1)(c1+c2)
    assert seen == [("FactIRL", (q["size"] ** 2, p)), ("MultiIntentIRL", (q["size"] ** 2, p)),
                    ("MultiIntentIRL", (q["size"] ** 2, p))]
    learners = out["rows"][0]["learners"]
    assert set(learners) == set(unlabeled.DEFAULTS["learners"])
    for name, row in learners.items():
        assert -1.0 <= row["ari"] <= 1.0 and row["train_deviation"] >= 0
        assert (row["transfer_deviation"] is None) == (name == "em_flat")


def test_objectworld_draws_share_the_map_and_nest_the_tasks():
    s = _settings("--quick", "--world", "objectworld", "--n-demos", "2", "--n-test", "2")
    small, large = unlabeled.draw_objectworld(s, 2, 3), unlabeled.draw_objectworld(s, 3, 3)
    S, A = small.mdp.n_states, small.mdp.n_actions
    assert S == s["size"] ** 2 and np.array_equal(small.features, large.features)
    assert small.rewards.shape == (2, S, A) and np.allclose(small.rewards, small.rewards[:, :, :1])  # state rewards
    np.testing.assert_array_equal(large.rewards[:2], small.rewards)
    np.testing.assert_array_equal(small.test_rewards, large.test_rewards)
    assert small.test_rewards.shape == (2, S, A) and [np.shape(d) for d in small.test_demos] == [(1, s["length"], 2)] * 2
    assert [np.shape(d) for d in small.demos] == [(2, s["length"], 2)] * 2
    other = unlabeled.draw_objectworld(s, 2, 4)
    assert not np.array_equal(other.features, small.features)  # another seed, another map


def test_grid_draw_is_the_synthetic_tasks_recipe():
    s = _settings("--quick")
    draw = unlabeled.draw_grid(s, 3, 7)
    tasks = fo.synthetic_tasks(fo.GridWorld(s["size"]), 3, s["n_demos"], s["length"], n_primitives=s["n_primitives"], rng=7)
    test = fo.synthetic_tasks(fo.GridWorld(s["size"]), s["n_test"], 1, s["length"], dictionary=tasks.dictionary, rng=10_007)
    assert draw.features is None
    np.testing.assert_array_equal(draw.rewards, tasks.rewards)
    np.testing.assert_array_equal(draw.test_rewards, test.rewards)
    for got, want in zip(draw.demos + draw.test_demos, tasks.demos + test.demos):
        np.testing.assert_array_equal(got, want)


def test_world_defaults_and_explicit_options():
    assert {k: _settings()[k] for k in ("world", "size", "n_demos", "length")} == {"world": "grid", **unlabeled.WORLD_DEFAULTS["grid"]}
    s = _settings("--world", "objectworld", "--size", "6")
    assert (s["size"], s["n_demos"], s["length"]) == (6, *[unlabeled.WORLD_DEFAULTS["objectworld"][k] for k in ("n_demos", "length")])
    assert _settings("--quick", "--world", "objectworld", "--length", "7")["length"] == 7


def test_unknown_world_is_a_usage_error(capsys):
    with pytest.raises(SystemExit):
        bench.build_parser().parse_args(["unlabeled", "--world", "moon"])
    assert "--world" in capsys.readouterr().err
    args = bench.build_parser().parse_args(["unlabeled"])
    args.world = "moon"
    with pytest.raises(fo.exceptions.ValidationError, match="world must be one of 'grid', 'objectworld'; got 'moon'"):
        unlabeled.settings(args)


@pytest.mark.parametrize("argv, match", [(["--size", "1"], "--size: must be an integer >= 2"),
                                         (["--n-demos", "0"], "--n-demos: must be an integer >= 1"),
                                         (["--length", "0"], "--length: must be an integer >= 1"),
                                         (["--n-tasks", "3", "0"], "--n-tasks: must be an integer >= 1"),
                                         (["--n-test", "0"], "--n-test: must be an integer >= 1"),
                                         (["--n-primitives", "0"], "--n-primitives: must be an integer >= 1")])
@pytest.mark.parametrize("world", ["grid", "objectworld"])
def test_bad_counts_are_refused_before_any_fit(world, argv, match, capsys):
    with pytest.raises(SystemExit) as exc:  # by the parser
        bench.main(["unlabeled", "--quick", "--world", world, *argv])
    assert exc.value.code == 2 and f"error: argument {match}" in capsys.readouterr().err


def test_objectworld_with_more_colours_than_cells_is_refused(capsys):
    assert bench.main(["unlabeled", "--quick", "--world", "objectworld", "--size", "2", "--n-primitives", "5"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("python -m factirl_opt.lab.bench: error: ") and "n_inner" in err and err.count("\n") == 1


def test_oracle_labels_match_a_loop_over_steps():
    mdp = fo.GridWorld(4)
    tasks = fo.synthetic_tasks(mdp, 3, 4, 6, n_primitives=2, rng=1)
    R = np.asarray(tasks.rewards)
    episodes = [ep for demos in tasks.demos for ep in demos]
    pi = np.stack([fo.boltzmann_policy(fo.optimal_q(mdp, r)[0], 2.0) for r in R])
    want = [int(np.argmax([sum(np.log(pi[i, s, a]) for s, a in ep) for i in range(3)])) for ep in episodes]
    got = unlabeled.oracle_labels(mdp, R, episodes, 2.0)
    assert got.shape == (12,) and got.tolist() == want
    assert len(set(want)) > 1  # the reference tells the tasks apart: the check can fail


def test_rows_carry_the_oracle_ari(capsys):
    assert bench.main(["unlabeled", "--quick", "--em-max-iter", "1"]) == 0
    row = json.loads(capsys.readouterr().out)["rows"][0]
    assert -1.0 <= row["oracle_ari"] <= 1.0


def test_default_line_up_is_the_three_learners():
    assert _settings()["learners"] == ["labelled", "em_flat", "em_shared"]
    assert _settings("--learners", "em_flat", "labelled", "em_flat")["learners"] == ["em_flat", "labelled"]


def test_unknown_learner_is_a_usage_error(capsys):
    with pytest.raises(SystemExit):
        bench.build_parser().parse_args(["unlabeled", "--learners", "em_magic"])
    assert "--learners" in capsys.readouterr().err


@pytest.mark.parametrize("world", ["grid", "objectworld"])
def test_fixed_dictionary_learners_take_the_true_and_the_labelled_dictionaries(capsys, monkeypatch, world):
    seen = {}

    class Spy(fo.MultiIntentIRL):
        def fit(self, mdp, episodes):
            seen[len(seen)] = np.array(self.features, copy=True)
            return super().fit(mdp, episodes)

    fitted = []

    class LabSpy(fo.FactIRL):
        def fit(self, mdp, demos, *args, **kwargs):
            fitted.append(super().fit(mdp, demos, *args, **kwargs))
            return fitted[-1]

    monkeypatch.setattr(unlabeled, "MultiIntentIRL", Spy)
    monkeypatch.setattr(unlabeled, "FactIRL", LabSpy)
    argv = ["unlabeled", "--quick", "--world", world, "--learners", "em_true_dictionary", "em_labelled_dictionary"]
    assert bench.main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    s = _settings("--quick", "--world", world)
    draw = unlabeled.WORLDS[world](s, s["n_tasks"][0], 0)
    k = s["n_primitives"]
    np.testing.assert_array_equal(seen[0], draw.dictionary)
    assert seen[0].shape[1] == k and len(fitted) == 1  # the labelled fit is made (once) for its dictionary
    want = fitted[0].dictionary_ if draw.features is None else draw.features @ fitted[0].dictionary_
    np.testing.assert_allclose(seen[1], want, rtol=1e-12)
    learners = out["rows"][0]["learners"]
    assert list(learners) == ["em_true_dictionary", "em_labelled_dictionary"]  # labelled not reported
    for row in learners.values():
        assert -1.0 <= row["ari"] <= 1.0 and row["train_deviation"] >= 0 and row["transfer_deviation"] is None


def test_the_true_start_learner_starts_the_shared_em_from_the_true_labels(capsys, monkeypatch):
    inits = []

    class Spy(fo.MultiIntentIRL):
        def fit(self, mdp, episodes):
            inits.append((self.n_primitives, self.init if isinstance(self.init, str) else np.asarray(self.init).tolist()))
            return super().fit(mdp, episodes)

    monkeypatch.setattr(unlabeled, "MultiIntentIRL", Spy)
    assert bench.main(["unlabeled", "--quick", "--learners", "em_shared", "em_shared_true_start"]) == 0
    s = _settings("--quick")
    n, k = s["n_tasks"][0], s["n_primitives"]
    assert inits == [(k, "agreement"), (k, np.repeat(np.arange(n), s["n_demos"]).tolist())]
    learners = json.loads(capsys.readouterr().out)["rows"][0]["learners"]
    assert learners["em_shared_true_start"]["transfer_deviation"] is not None


@pytest.mark.filterwarnings("ignore::factirl_opt.exceptions.ConvergenceWarning")  # the tiny MCE fit may stall
def test_objective_reaches_every_learner(capsys, monkeypatch):
    seen = []

    def spy(cls):
        class Spy(cls):
            def fit(self, mdp, demos, *args, **kwargs):
                seen.append((cls.__name__, self.objective))
                return super().fit(mdp, demos, *args, **kwargs)
        return Spy

    monkeypatch.setattr(unlabeled, "FactIRL", spy(fo.FactIRL))
    monkeypatch.setattr(unlabeled, "MultiIntentIRL", spy(fo.MultiIntentIRL))
    assert bench.main(["unlabeled", "--quick", "--objective", "mce", "--em-max-iter", "1"]) == 0
    assert json.loads(capsys.readouterr().out)["settings"]["objective"] == "mce"
    assert seen == [("FactIRL", "mce"), ("MultiIntentIRL", "mce"), ("MultiIntentIRL", "mce")]
    with pytest.raises(SystemExit):
        bench.build_parser().parse_args(["unlabeled", "--objective", "maxent"])

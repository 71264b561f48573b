"""The experiment runner's machinery: presets, ground truth, resume, --jobs invariance, dask."""

import dataclasses
import json
import os

import numpy as np
import pytest

from factirl_opt import SolverSettings
from factirl_opt.exceptions import PersistenceError, UnknownSolverError, ValidationError
from factirl_opt.lab.experiments import (
    PRESETS, Preset, TEST_LEARNERS, TRAIN_LEARNERS, get_preset, make_ground_truth, plan_runs, read_csv, run_one,
    run_sweep, runner as runner_mod,
)
from factirl_opt.lab.experiments.figures import plot_all
from factirl_opt.lab.experiments.store import RejectedRunWarning

TABLES = ("results.csv", "summary.csv")


def _read(path):
    with open(path) as fh:
        return fh.read()


@pytest.fixture(scope="module")
def tiny_sweep(tmp_path_factory):
    """The tiny preset, run sequentially once for the module (about a second)."""
    out = tmp_path_factory.mktemp("tiny") / "seq"
    res = run_sweep("tiny", out, jobs=1, progress=False)
    return out, res


# --- presets -----------------------------------------------------------------------------


def test_paper_preset_is_the_papers_setting():
    p = PRESETS["paper"]
    assert (p.grid_size, p.n_primitives, p.demo_length) == (10, 5, 10)
    assert (p.default_tasks, p.default_demos, p.n_test_tasks) == (100, 10, 100)
    assert p.demos_sweep == (1, 2, 5, 10, 20) and p.tasks_sweep == (5, 10, 20, 50, 100)
    assert p.n_seeds >= 3 and p.n_features_from_examples == 15 and p.n_pca_components == 5
    # the default point is shared by both sweeps and planned once
    assert len(p.points()) == 9 and p.points().count((100, 10)) == 1


def test_plan_runs_sorted_and_complete():
    specs = plan_runs("tiny", [3, 4])
    assert specs == sorted(specs)
    assert len(specs) == len(PRESETS["tiny"].points()) * 2
    assert len({s.key(PRESETS["tiny"]) for s in specs}) == len(specs)


@pytest.mark.parametrize("bad, match", [
    (dict(grid_size=0), "grid_size"),
    (dict(demos_sweep=()), "demos_sweep"),
    (dict(tasks_sweep=(5, -1)), "tasks_sweep"),
    (dict(coefficient_kind="uniform"), "coefficient_kind"),
    (dict(n_seeds=1.5), "n_seeds"),
])
def test_preset_validation_names_the_field(bad, match):
    with pytest.raises(ValidationError, match=match):
        Preset(name="bad", **bad)


def test_preset_roundtrip_and_unknown_name():
    p = PRESETS["quick"]
    assert Preset.from_dict(json.loads(json.dumps(p.to_dict()))) == p
    with pytest.raises(ValidationError, match="unknown preset 'nope'"):
        get_preset("nope")


def test_plan_rejects_bad_seeds():
    with pytest.raises(ValidationError, match="seed"):
        plan_runs("tiny", [-1])
    with pytest.raises(ValidationError, match="distinct"):
        plan_runs("tiny", [1, 1])


# --- ground truth ------------------------------------------------------------------------


def test_ground_truth_streams_are_shared_across_points():
    p = PRESETS["tiny"]
    a = make_ground_truth(p, 4, 2, seed=7)
    b = make_ground_truth(p, 8, 5, seed=7)
    c = make_ground_truth(p, 4, 2, seed=8)
    np.testing.assert_array_equal(a.dictionary, b.dictionary)  # same dictionary for one seed
    np.testing.assert_array_equal(a.train_rewards, b.train_rewards[:4])  # nested training tasks
    np.testing.assert_array_equal(a.test_rewards, b.test_rewards)  # same test tasks and demos
    np.testing.assert_array_equal(np.stack(a.test_demos), np.stack(b.test_demos))
    assert a.train_demos[0].shape == (2, p.demo_length, 2) and b.train_demos[0].shape == (5, p.demo_length, 2)
    assert a.test_demos[0].shape == (1, p.demo_length, 2) and len(a.test_demos) == p.n_test_tasks
    assert not np.allclose(a.dictionary, c.dictionary)
    again = make_ground_truth(p, 4, 2, seed=7)
    np.testing.assert_array_equal(np.stack(a.train_demos), np.stack(again.train_demos))


def test_nonneg_ground_truth():
    p = Preset(name="nn", grid_size=3, coefficient_kind="nonneg", n_test_tasks=3)
    gt = make_ground_truth(p, 5, 1, seed=0)
    H = np.linalg.lstsq(gt.dictionary, gt.train_rewards.reshape(5, -1).T, rcond=None)[0]
    assert np.all(H >= -1e-9)


# --- one run -----------------------------------------------------------------------------


def test_run_one_scores_every_learner(tiny_sweep):
    p = PRESETS["tiny"]
    spec = plan_runs(p, [0])[-1]  # the default point: records figure 3
    assert (spec.n_tasks, spec.demos_per_task) == (p.default_tasks, p.default_demos)
    labels = []
    rec = run_one(p, spec, progress=labels.append)
    assert labels == [f"train: {x}" for x in TRAIN_LEARNERS] + [f"test: {x}" for x in TEST_LEARNERS]
    assert [(r["split"], r["learner"]) for r in rec["rows"]] == (
        [("train", x) for x in TRAIN_LEARNERS] + [("test", x) for x in TEST_LEARNERS])
    for r in rec["rows"]:
        assert r["deviation"] >= 0 and np.isfinite(r["deviation"]) and r["n_evaluations"] > 0
        assert r["n_scored_tasks"] == (spec.n_tasks if r["split"] == "train" else p.n_test_tasks)
    f3 = rec["figure3"]
    assert np.shape(f3["true"]) == (4, p.grid_size ** 2) == np.shape(f3["flat"]) == np.shape(f3["factorial"])
    # same run, same record, also when computed by the sweep
    out, _ = tiny_sweep
    with open(out / "runs" / f"{spec.key(p)}.json") as fh:
        assert json.load(fh)["rows"] == rec["rows"]


def test_sweep_with_a_gauss_newton_h_step(tmp_path):
    result = run_sweep("tiny", tmp_path, solvers=SolverSettings("gn-qp-clarabel"), seeds=1, progress=False)
    assert result["rows"] and all(row["h_solver"] == "gn-qp-clarabel" for row in result["rows"])
    learners = {row["learner"] for row in result["rows"]}
    assert {"factorial", "factorial, random init"} <= learners


def test_unknown_h_solver_is_rejected_before_running(tmp_path):
    with pytest.raises(UnknownSolverError, match="armijo"):
        run_sweep("tiny", tmp_path, solvers=SolverSettings("no-such-solver"), progress=False)
    with pytest.raises(ValidationError, match="solvers must be a SolverSettings"):
        run_sweep("tiny", tmp_path, solvers={"h_solver": "armijo"}, progress=False)
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("kw, match", [
    (dict(jobs=0), "jobs"), (dict(seeds=0), "seeds"), (dict(base_seed=-2), "base seed"),
    (dict(backend="threads"), "backend"), (dict(scheduler="tcp://x:1"), "scheduler"),
])
def test_run_sweep_validation(tmp_path, kw, match):
    with pytest.raises(ValidationError, match=match):
        run_sweep("tiny", tmp_path, progress=False, **kw)


def test_out_must_be_a_writable_directory(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(PersistenceError, match=f"output directory '{f}' exists and is not a directory"):
        run_sweep("tiny", f, progress=False)
    with pytest.raises(PersistenceError, match=f"cannot create the output directory '{f / 'sub'}': Not a directory"):
        run_sweep("tiny", f / "sub", progress=False)  # a file in the path: the directory cannot be made
    assert f.read_text() == "x"


# --- tables, resume, --jobs invariance --------------------------------------------------


def test_tables_are_tidy(tiny_sweep):
    out, res = tiny_sweep
    p = PRESETS["tiny"]
    rows = read_csv(out / "results.csv")
    assert res["n_runs"] == res["n_computed"] == len(p.points()) * p.n_seeds
    assert len(rows) == res["n_runs"] * (len(TRAIN_LEARNERS) + len(TEST_LEARNERS))
    for col in ("split", "learner", "n_tasks", "demos_per_task", "seed", "deviation", "h_solver"):
        assert col in rows[0]
    summary = read_csv(out / "summary.csv")
    assert all(r["n_seeds"] == p.n_seeds for r in summary)
    r0 = next(r for r in summary if r["split"] == "train" and r["learner"] == "flat" and r["n_tasks"] == 8 and r["demos_per_task"] == 5)
    devs = [r["deviation"] for r in rows if r["split"] == "train" and r["learner"] == "flat" and r["n_tasks"] == 8 and r["demos_per_task"] == 5]
    assert r0["deviation_mean"] == pytest.approx(np.mean(devs))
    manifest = json.loads(_read(out / "manifest.json"))
    assert manifest["seeds"] == [0, 1] and manifest["versions"]["numpy"] == np.__version__


def test_resume_computes_only_missing_runs(tiny_sweep, tmp_path):
    import shutil

    ref, _ = tiny_sweep
    out = tmp_path / "resumed"
    shutil.copytree(ref / "runs", out / "runs")
    files = sorted(os.listdir(out / "runs"))
    os.remove(out / "runs" / files[0])
    os.remove(out / "runs" / files[3])
    (out / "runs" / files[1]).write_text('{"key": "truncated')  # a run killed mid-write elsewhere
    computed = []
    original = runner_mod.run_one

    def spy(preset, spec, progress=None, reuse=None):
        computed.append(spec.key(preset))
        return original(preset, spec, progress, reuse=reuse)

    runner_mod.run_one = spy
    try:
        with pytest.warns(RejectedRunWarning, match=f"rejected 1 run record.*{files[1]}: truncated"):
            res = run_sweep("tiny", out, jobs=1, progress=False)
    finally:
        runner_mod.run_one = original
    assert sorted(computed) == sorted(f[:-5] for f in (files[0], files[1], files[3]))
    assert res["n_computed"] == 3
    for t in TABLES:
        assert _read(out / t) == _read(ref / t)
    res = run_sweep("tiny", out, jobs=1, progress=False)  # nothing left to do
    assert res["n_computed"] == 0


def test_interrupted_sweep_resumes_with_identical_tables(tiny_sweep, tmp_path, monkeypatch):
    ref, _ = tiny_sweep
    out = tmp_path / "interrupted"
    original = runner_mod.run_one
    calls = []

    def dies_on_third(preset, spec, progress=None, reuse=None):
        calls.append(spec)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return original(preset, spec, progress, reuse=reuse)

    monkeypatch.setattr(runner_mod, "run_one", dies_on_third)
    with pytest.raises(KeyboardInterrupt):
        run_sweep("tiny", out, jobs=1, progress=False)
    assert len(os.listdir(out / "runs")) == 2 and not (out / "results.csv").exists()
    monkeypatch.setattr(runner_mod, "run_one", original)
    res = run_sweep("tiny", out, jobs=1, progress=False)
    assert res["n_computed"] == res["n_runs"] - 2
    for t in TABLES:
        assert _read(out / t) == _read(ref / t)


def test_results_do_not_depend_on_jobs(tiny_sweep, tmp_path):
    ref, _ = tiny_sweep
    out = tmp_path / "jobs2"
    res = run_sweep("tiny", out, jobs=2, progress=False)
    assert res["n_computed"] == res["n_runs"]
    for t in TABLES:
        assert _read(out / t) == _read(ref / t)
    assert _read(out / "figure3.json") == _read(ref / "figure3.json")


def test_dask_backend_on_a_local_cluster(tiny_sweep, tmp_path):
    pytest.importorskip("dask")
    distributed = pytest.importorskip("distributed")
    ref, _ = tiny_sweep
    out = tmp_path / "dask"
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        res = run_sweep("tiny", out, jobs=2, backend="dask", scheduler=cluster.scheduler_address, progress=False)
    assert res["n_computed"] == res["n_runs"]
    for t in TABLES:
        assert _read(out / t) == _read(ref / t)


# --- figures -----------------------------------------------------------------------------


def test_plot_all_writes_png_and_svg(tiny_sweep):
    out, _ = tiny_sweep
    written = plot_all(out)
    names = sorted(os.path.basename(w) for w in written)
    assert names == sorted(f"figure{i}.{e}" for i in (1, 2, 3) for e in ("png", "svg"))  # figures only
    for w in written:
        assert os.path.getsize(w) > 5000
    with open(os.path.join(out, "figures", "figure1.svg")) as fh:
        svg = fh.read()
    for learner in TRAIN_LEARNERS:  # the legend uses the paper's names
        assert learner in svg


def test_plot_all_without_results(tmp_path):
    with pytest.raises(ValidationError, match="results.csv"):
        plot_all(tmp_path)


def test_claims_are_computed_from_the_rows(tiny_sweep):
    from factirl_opt.lab.experiments.claims import claims_markdown, evaluate_claims

    out, _ = tiny_sweep
    p = PRESETS["tiny"]
    rows = read_csv(out / "results.csv")
    claims = evaluate_claims(rows, p)
    first = claims[0]
    assert first["claim"] == "train: factorial beats flat" and first["point"] == "8 tasks, 5 demos"
    fact = [r["deviation"] for r in rows if r["split"] == "train" and r["learner"] == "factorial" and (r["n_tasks"], r["demos_per_task"]) == (8, 5)]
    flat = [r["deviation"] for r in rows if r["split"] == "train" and r["learner"] == "flat" and (r["n_tasks"], r["demos_per_task"]) == (8, 5)]
    assert first["holds"] == (np.mean(fact) < np.mean(flat))
    assert first["seeds"] == f"{sum(a < b for a, b in zip(fact, flat))}/2"
    # flip the data: the claim must flip too
    swapped = [dict(r, learner={"flat": "factorial", "factorial": "flat"}.get(r["learner"], r["learner"])) for r in rows]
    assert evaluate_claims(swapped, p)[0]["holds"] != first["holds"]
    table = claims_markdown(claims)
    assert table.count("\n") == len(claims) + 2 and "| train: factorial beats flat |" in table



def test_a_claim_that_does_not_hold_says_why():
    from factirl_opt.lab.experiments.claims import claims_markdown, paired_reason

    assert paired_reason("a", "b", [0.1, -0.2, 0.3], 1).startswith("a tie: a - b = +0.07 on average, within")
    assert paired_reason("a", "b", [2.0, 3.0, 2.5], 0) == (
        "reversed on every seed: a - b = +2.50 on average (paired s.d. 0.50)")
    assert paired_reason("a", "b", [2.0], 0) == "reversed on every seed: a - b = +2.00 on average (one seed)"
    assert paired_reason("a", "b", [-0.1, 3.0, 3.2], 1).startswith("mixed: lower on 1/3 seeds, a - b = +2.03")
    rows = [dict(split="test", learner=name, n_tasks=n, demos_per_task=10, seed=s, deviation=value)
            for s in range(3) for n in (5, 100)
            for name, value in (("factorial", (20.0 if n == 5 else 4.0) + s), ("flat", 14.0 + 0.1 * s))]
    preset = dataclasses.replace(PRESETS["tiny"], default_tasks=100, default_demos=10, tasks_sweep=(5, 100),
                                 demos_sweep=(10,))
    from factirl_opt.lab.experiments.claims import evaluate_claims
    claims = {(c["claim"], c["point"]): c for c in evaluate_claims(rows, preset)}
    holds = claims[("test: factorial beats flat from scratch", "100 tasks, 10 demos")]
    fails = claims[("test: factorial beats flat (tasks sweep)", "5 tasks, 10 demos")]
    assert holds["holds"] and holds["reason"] == ""
    assert not fails["holds"] and fails["reason"].startswith("reversed on every seed: factorial - flat = +6.90 on average (paired s.d. 0.90)")
    assert "less training data than at the default point (5 tasks x 10 demonstrations" in fails["reason"]
    table = claims_markdown(list(claims.values()))
    assert f"| **no** | 0/3 | {fails['reason']} |" in table and "| yes | 3/3 |  |" in table
    with pytest.raises(ValidationError, match="does not hold and gives no reason"):
        claims_markdown([dict(fails, reason="")])

# --- progress ------------------------------------------------------------------------------


def test_progress_is_weighted_by_run_cost(tmp_path, monkeypatch):
    """The bar advances by each run's estimated cost, so a cheap first run does not fool the ETA."""
    import tqdm.auto

    from factirl_opt.lab.experiments.runner import run_cost

    bars = []

    class Recorder:
        def __init__(self, total, initial, smoothing, **kw):
            self.total, self.n, self.smoothing, self.updates = total, initial, smoothing, []
            bars.append(self)

        def update(self, n):
            self.updates.append(n)
            self.n += n

        def set_postfix_str(self, *a, **kw):
            pass

        def close(self):
            pass

    monkeypatch.setattr(tqdm.auto, "tqdm", Recorder)
    p = PRESETS["tiny"]
    specs = plan_runs(p, [0])
    run_sweep("tiny", tmp_path, seeds=1, progress=True)
    (bar,) = bars
    costs = {s.key(p): run_cost(p, s) for s in specs}
    assert bar.total == pytest.approx(sum(costs.values())) and bar.n == pytest.approx(bar.total)
    assert sorted(bar.updates) == sorted(costs.values()) and bar.smoothing == 0  # average rate over the whole sweep
    assert bar.updates == sorted(bar.updates, reverse=True)  # one worker: the runs ran costliest first
    # a run with 100 training tasks weighs about 3 with 5 (paper preset; measured 2-3x)
    paper = PRESETS["paper"]
    big, small = (run_cost(paper, runner_mod.RunSpec(n, 10, 0)) for n in (100, 5))
    assert 2 < big / small < 4


# --- the paper's run keys; the other presets and line-ups at tiny scale --------------------


def test_the_papers_run_keys_are_those_of_the_committed_results():
    """The committed paper-scale run (results/runs) is what `reproduce --preset paper` plans."""
    runs = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "results", "runs")
    if not os.path.isdir(runs):
        pytest.skip("no committed results/ in this checkout")
    committed = sorted(f[:-5] for f in os.listdir(runs) if f.endswith(".json"))
    assert committed == sorted(s.key(PRESETS["paper"]) for s in plan_runs("paper", [0, 1, 2]))


@pytest.fixture(scope="module")
def objectworld_sweep(tmp_path_factory):
    """The objectworld-tiny preset, run once for the module (a few seconds)."""
    out = tmp_path_factory.mktemp("objectworld-tiny")
    res = run_sweep("objectworld-tiny", out, jobs=1, progress=False)
    return out, res


def test_objectworld_smoke_sweep_tables_figures_and_claims(objectworld_sweep):
    from factirl_opt.lab.experiments import LINEUPS
    from factirl_opt.lab.experiments.claims import evaluate_claims, write_claims

    out, res = objectworld_sweep
    p = PRESETS["objectworld-tiny"]
    assert res["n_runs"] == res["n_computed"] == len(p.points())
    rows = read_csv(out / "results.csv")
    lineup = LINEUPS["objectworld"]
    for split in ("train", "test"):
        assert {r["learner"] for r in rows if r["split"] == split} == set(lineup.names(split))
    assert {r["h_solver"] for r in rows} == {"gn-qp-clarabel | d: lbfgs"}
    data = json.loads(_read(out / "figure3.json"))
    assert {"objects", "n_inner", "n_outer", "moves", *lineup.value_maps} <= set(data)
    written = plot_all(out)
    assert sorted(os.path.basename(w) for w in written) == sorted(f"figure{i}.{e}" for i in (1, 2, 3) for e in ("png", "svg"))
    with open(out / "figures" / "figure1.svg") as fh:
        svg = fh.read()
    assert all(name in svg for name in lineup.names("train"))  # the legend names every learner
    claims = evaluate_claims(rows, p)
    names = [c["claim"] for c in claims]
    assert "test: factorial on features beats flat on features" in names
    assert "train: factorial on features beats flat tabular" in names
    assert "test: factorial on features improves with the number of training tasks" in names
    assert all(isinstance(c["holds"], bool) for c in claims)
    with open(write_claims(out, p)) as fh:
        assert fh.read().startswith("# Objectworld claims vs this run (H-step solver: gn-qp-clarabel | d: lbfgs)")


def test_a_single_sweep_draws_one_panel(objectworld_sweep, tiny_sweep, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from factirl_opt.lab.experiments.figures import plot_sweeps

    out, _ = objectworld_sweep
    rows = read_csv(out / "results.csv")
    created = []
    original = plt.subplots

    def spy(*args, **kwargs):
        fig, axes = original(*args, **kwargs)
        created.append(np.shape(axes))
        return fig, axes

    plt.subplots = spy
    try:
        plot_sweeps(rows, PRESETS["objectworld-tiny"], "test", str(tmp_path / "f2"))
        plot_sweeps(read_csv(tiny_sweep[0] / "results.csv"), PRESETS["tiny"], "test", str(tmp_path / "g2"))
    finally:
        plt.subplots = original
    assert created == [(1, 1), (1, 2)]  # the tasks sweep only; the paper's two sweeps


def test_paper_with_mce_smoke_sweep(tmp_path):
    import dataclasses

    from factirl_opt.lab.experiments.claims import evaluate_claims

    preset = dataclasses.replace(PRESETS["tiny"], lineup="paper+mce")
    run_sweep(preset, tmp_path, seeds=1, progress=False)
    rows = read_csv(tmp_path / "results.csv")
    assert {"flat MCE", "factorial MCE"} <= {r["learner"] for r in rows if r["split"] == "test"}
    claims = {c["claim"]: c for c in evaluate_claims(rows, preset)}
    assert "test: factorial MCE beats flat MCE" in claims and "test: factorial beats flat from scratch" in claims
    mce = {r["learner"]: r["deviation"] for r in rows if r["split"] == "test" and (r["n_tasks"], r["demos_per_task"]) == (8, 5)}
    assert claims["test: factorial MCE beats flat MCE"]["holds"] == (mce["factorial MCE"] < mce["flat MCE"])
    written = plot_all(tmp_path)
    with open(tmp_path / "figures" / "figure2.svg") as fh:
        svg = fh.read()
    assert "flat MCE" in svg and "factorial MCE" in svg and len(written) == 6
    assert set(json.loads(_read(tmp_path / "figure3.json"))) >= {"flat MCE", "factorial MCE", "deviation_factorial MCE"}


def test_claims_need_a_known_lineup():
    import dataclasses

    from factirl_opt.lab.experiments import claims as claims_mod

    preset = dataclasses.replace(PRESETS["tiny"], lineup="paper+mce")
    saved = claims_mod.CLAIMS.pop("paper+mce")
    try:
        with pytest.raises(ValidationError, match="no claims for the line-up 'paper\\+mce'"):
            claims_mod.evaluate_claims([], preset)
    finally:
        claims_mod.CLAIMS["paper+mce"] = saved


def test_value_maps_of_unknown_learners_are_refused(tiny_sweep, tmp_path):
    from factirl_opt.lab.experiments.figures import plot_value_functions

    out, _ = tiny_sweep
    data = json.loads(_read(out / "figure3.json"))
    with pytest.raises(ValidationError, match="no value maps of \\['factorial MCE'\\]"):
        plot_value_functions(data, str(tmp_path / "f3"), learners=("flat", "factorial MCE"))


# --- the plan, stale outputs, substitutions ----------------------------------------------


def test_the_experiment_path_stage_by_stage(tiny_sweep, tmp_path):
    from factirl_opt.lab.experiments import Execution, plan_sweep, run_plan

    ref, _ = tiny_sweep
    plan = plan_sweep("tiny", [0, 1])
    assert plan.keys == tuple(s.key(PRESETS["tiny"]) for s in plan.runs) and plan.seeds == (0, 1)
    assert plan.runs == tuple(plan_runs("tiny", [0, 1])) and plan.solvers == PRESETS["tiny"].solvers
    res = run_plan(plan, tmp_path, Execution(jobs=1), progress=False)
    assert res["n_computed"] == len(plan.runs) and res["substitutions"] == []
    for t in TABLES:
        assert _read(tmp_path / t) == _read(ref / t)
    assert Execution(-1).jobs == (os.cpu_count() or 1) and Execution(2, "loky").backend == "processes"


def test_a_sweep_removes_outputs_drawn_from_earlier_tables(objectworld_sweep, tmp_path):
    """Claims and figures of another preset's tables never stay beside new tables."""
    import shutil

    from factirl_opt.lab.experiments.claims import write_claims

    out = tmp_path / "out"
    shutil.copytree(objectworld_sweep[0], out)
    plot_all(out)
    write_claims(out, PRESETS["objectworld-tiny"])
    (out / "figures" / "notes.txt").write_text("mine")  # not ours: kept
    res = run_sweep("tiny", out, seeds=1, progress=False)
    assert not (out / "claims.md").exists() and sorted(os.listdir(out / "figures")) == ["notes.txt"]
    assert len(res["removed"]) == 7  # claims.md and the six figures
    assert json.loads(_read(out / "figure3.json"))["grid_size"] == PRESETS["tiny"].grid_size


def test_a_stale_figure3_json_is_removed_with_its_figure(tiny_sweep, tmp_path, monkeypatch):
    import dataclasses
    import shutil

    from factirl_opt.lab.experiments import LINEUPS, Learner, Lineup
    from factirl_opt.lab.experiments.learners import flat

    out = tmp_path / "out"
    shutil.copytree(tiny_sweep[0], out)
    plot_all(out)
    monkeypatch.setitem(LINEUPS, "short", Lineup("short", (Learner("train", "flat", flat),
                                                           Learner("test", "flat", flat, per_seed=True))))
    preset = dataclasses.replace(PRESETS["tiny"], lineup="short", flat_max_iter=2)  # no value maps
    run_sweep(preset, out, seeds=1, progress=False)
    assert not (out / "figure3.json").exists()
    written = plot_all(out)
    assert sorted(os.listdir(out / "figures")) == sorted(os.path.basename(w) for w in written)
    assert not any(os.path.basename(w).startswith("figure3") for w in written)


def test_substitutions_are_warned_and_recorded_in_the_manifest(tmp_path):
    import dataclasses

    from factirl_opt.lab.experiments.runner import SolverSubstitutionWarning

    preset = dataclasses.replace(PRESETS["tiny"], lineup="paper+mce", demos_sweep=(5,), tasks_sweep=(8,), n_seeds=1,
                                 fact_max_iter=1, flat_max_iter=2, transfer_max_iter=2)
    with pytest.warns(SolverSubstitutionWarning) as caught:
        res = run_sweep(preset, tmp_path, solvers=SolverSettings("gn-qp-clarabel"), progress=False)
    assert [str(w.message).split(" replaced")[0] for w in caught] == [
        "train: factorial MCE: H-step solver gn-qp-clarabel", "test: factorial MCE: H-step solver gn-qp-clarabel"]
    manifest = json.loads(_read(tmp_path / "manifest.json"))
    assert manifest["substitutions"] == res["substitutions"] == manifest["invocations"][-1]["substitutions"]
    assert len(res["substitutions"]) == 2  # train and test rows of factorial MCE

"""Learner line-ups as data, worlds by name, and the solver settings the runner passes to FactIRL."""

import dataclasses
import json

import numpy as np
import pytest

from factirl_opt import PAPER_SETTINGS, Execution, FactIRL, SolverSettings, Start
from factirl_opt.exceptions import UnknownSolverError, ValidationError
from factirl_opt.lab.experiments import (
    LINEUPS, Learner, Lineup, PRESETS, Preset, RunSpec, WORLDS, learners as learners_mod, plan_runs, run_one,
)
from factirl_opt.lab.experiments.learners import Fit, factorial_options, flat
from factirl_opt.lab.experiments.presets import LATER_FIELDS
from factirl_opt.lab.experiments.worlds import grid_world

TINY = PRESETS["tiny"]


def test_paper_lineup_is_the_papers():
    paper = LINEUPS["paper"]
    assert paper.names("train") == ("flat", "flat, ground truth", "flat, PCA features", "factorial", "factorial, random init")
    assert paper.names("test") == ("flat", "factorial", "flat, features from ex.", "flat, PCA features", "flat, ground truth")
    assert paper.value_maps == ("flat", "factorial")
    assert paper.fingerprint()[3] == ["train", "factorial", 1]


@pytest.mark.parametrize("learners, value_maps, match", [
    ((Learner("train", "a", flat), Learner("train", "a", flat)), (), "duplicate learner train: a"),
    ((Learner("test", "b", flat, needs=(("train", "a"),)),), (), r"needs \[\('train', 'a'\)\] earlier"),
    ((Learner("valid", "a", flat),), (), "split must be"),
    ((Learner("train", "a", flat),), ("a",), "value map of unknown test learner 'a'"),
    ((Learner("train", "a", flat, per_seed=True),), (), "train: a cannot be per_seed"),
    ((Learner("train", "a", flat), Learner("test", "b", flat, needs=(("train", "a"),), per_seed=True)), (),
     "test: b cannot be per_seed"),
])
def test_lineup_validation(learners, value_maps, match):
    with pytest.raises(ValidationError, match=match):
        Lineup("bad", learners, value_maps)


def _short_flat(gt, preset, ctx):
    from factirl_opt import GradIRL

    model = GradIRL(beta=preset.beta, max_iter=3).fit(gt.mdp, gt.demos(ctx.split))
    return Fit(model.rewards_, model.loss_, model.n_evaluations_)


def test_a_new_lineup_is_a_table_row(monkeypatch):
    lineup = Lineup("short", (Learner("train", "flat", flat), Learner("train", "flat, 3 iterations", _short_flat),
                              Learner("test", "flat, 3 iterations", _short_flat)))
    monkeypatch.setitem(LINEUPS, "short", lineup)
    preset = dataclasses.replace(TINY, lineup="short")
    assert preset.fingerprint() != TINY.fingerprint()  # a run's key follows its line-up
    rec = run_one(preset, RunSpec(4, 2, 0))
    assert [(r["split"], r["learner"]) for r in rec["rows"]] == [(lr.split, lr.name) for lr in lineup.learners]
    assert rec["rows"][1]["n_evaluations"] <= rec["rows"][0]["n_evaluations"]
    assert "figure3" not in rec  # no value maps in this line-up


def test_preset_names_its_world_and_lineup(monkeypatch):
    with pytest.raises(ValidationError, match="world must be one of grid, objectworld, objectworld-per-task(, [a-z-]+)*; got 'gridworld'"):
        Preset(name="x", world="gridworld")
    with pytest.raises(ValidationError, match="lineup must be one of paper, objectworld, paper\\+mce, objectworld\\+mce, objectworld-per-task"):
        Preset(name="x", lineup="mce")
    calls = []

    def small_grid(preset, n_tasks, demos_per_task, seed):
        calls.append((n_tasks, demos_per_task, seed))
        return grid_world(dataclasses.replace(preset, grid_size=3), n_tasks, demos_per_task, seed)

    monkeypatch.setitem(WORLDS, "grid3", small_grid)
    preset = dataclasses.replace(TINY, world="grid3", grid_size=3)
    rec = run_one(preset, RunSpec(4, 2, 1))
    assert calls == [(4, 2, 1)] and len(rec["rows"]) == 10
    # the paper's world and line-up do not enter the fingerprint: old run keys stay valid
    assert PRESETS["paper"].fingerprint() == "ea9fc43e51"


# --- solver settings ---------------------------------------------------------------------


def _named(kw):
    """The solver settings a FactIRL's or GradIRL's keyword arguments name (``solver``: a name or settings)."""
    return SolverSettings.of(kw["solver"])


class RecordingFactIRL(FactIRL):
    """A FactIRL that records its arguments, its solver settings as the flat names of before the groups
    (a D-step solver not named: ``""``)."""

    seen = []

    def __init__(self, **kw):
        super().__init__(**kw)
        s = _named(kw)
        RecordingFactIRL.seen.append(dict(kw, solver_options=s.h_options or None, d_solver=s.d_solver,
                                          d_solver_options=s.d_options or None))


def test_default_settings_build_the_same_factirl():
    spec = plan_runs(TINY, [0])[0]
    assert spec.solvers == SolverSettings() == SolverSettings("armijo", None, None, None)
    assert spec.solvers.fields() == dict(h_solver="armijo", h_solver_options="", d_solver="", d_solver_options="")
    assert spec.solver_label() == "armijo" and spec.key(TINY) == f"n004-m05-seed0-armijo-{TINY.fingerprint()}"
    assert factorial_options(TINY, spec.solvers) == dict(
        n_primitives=5, beta=5.0, max_iter=5, inner_steps=2, solver=SolverSettings("armijo", d_solver="armijo", flat_solver="armijo"),
        start=Start(flat_max_iter=10, pca_shrink=False, flat_stol=0.0), transfer_max_iter=10, objective="policy-matching",
        execution=Execution(planner="auto"), gtol=0.0, tol=1e-5, scheme="alternating", transfer_stol=0.0)
    import inspect

    assert inspect.signature(FactIRL).parameters["tol"].default == TINY.fact_tol  # FactIRL's own default


def test_h_solver_options_reach_factirl(monkeypatch):
    spec = plan_runs(TINY, [0], SolverSettings("armijo", {"initial_step": 0.5}))[0]
    assert spec.solvers.h_options == {"initial_step": 0.5} and spec.solver_label() == 'armijo {"initial_step":0.5}'
    assert spec.key(TINY) != plan_runs(TINY, [0])[0].key(TINY)
    RecordingFactIRL.seen = []
    monkeypatch.setattr(learners_mod, "FactIRL", RecordingFactIRL)
    rec = run_one(TINY, spec)
    assert [s["solver_options"] for s in RecordingFactIRL.seen] == [{"initial_step": 0.5}] * 2
    assert all(s["d_solver"] == "armijo" for s in RecordingFactIRL.seen)  # not named: the paper's, pinned
    assert {r["h_solver"] for r in rec["rows"]} == {'armijo {"initial_step":0.5}'}


def test_a_run_naming_no_d_or_flat_solver_pins_the_papers():
    """Whatever FactIRL's defaults, a preset's FactIRL takes the paper's D-step and flat-start solvers
    where the run names none (the committed tables were made with them), and the run's where it does."""
    assert factorial_options(TINY, plan_runs(TINY, [0])[0].solvers)["solver"] == SolverSettings(
        "armijo", d_solver=PAPER_SETTINGS["solver"].d_solver, flat_solver=PAPER_SETTINGS["solver"].flat_solver)
    named = factorial_options(TINY, SolverSettings("armijo", d_solver="lbfgs"))["solver"]
    assert (named.d_solver, named.flat_solver) == ("lbfgs", "armijo")
    assert SolverSettings().learner_kwargs() == {"solver": "armijo"}


def test_d_solver_and_its_options_reach_factirl(monkeypatch):
    monkeypatch.setattr(learners_mod, "FactIRL", RecordingFactIRL)
    spec = plan_runs(TINY, [0], SolverSettings(d_solver="armijo", d_solver_options={"initial_step": 0.25}))[0]
    assert spec.solver_label() == 'armijo | d: armijo {"initial_step":0.25}'
    RecordingFactIRL.seen = []
    run_one(TINY, spec)
    assert [(s["d_solver"], s["d_solver_options"]) for s in RecordingFactIRL.seen] == [("armijo", {"initial_step": 0.25})] * 2


def test_naming_the_default_d_solver_changes_only_the_label():
    default, named = plan_runs(TINY, [0])[-1], plan_runs(TINY, [0], SolverSettings(d_solver="armijo"))[-1]
    a, b = run_one(TINY, default), run_one(TINY, named)
    assert default.key(TINY) != named.key(TINY) and {r["h_solver"] for r in b["rows"]} == {"armijo | d: armijo"}
    strip = [{k: v for k, v in r.items() if k != "h_solver"} for r in a["rows"]]
    assert strip == [{k: v for k, v in r.items() if k != "h_solver"} for r in b["rows"]]


@pytest.mark.parametrize("kw, error, match", [
    (dict(h_solver="nope"), UnknownSolverError, "unknown solver 'nope'"),
    (dict(h_solver=""), ValidationError, "h_solver must be a registered solver name or a solvers.StepSolver; got ''"),
    (dict(h_solver_options={"bogus": 1}), ValidationError, "does not accept option"),
    (dict(h_solver_options=[("alpha", 1)]), ValidationError, "h_solver_options must be a dict"),
    (dict(h_solver_options="{oops"), ValidationError, "h_solver_options must be a dict or its JSON"),
    (dict(h_solver_options={"alpha": np.float32}), ValidationError, "plain values"),
    (dict(d_solver_options={"a": 1}), ValidationError, "d_solver_options given without d_solver"),
    (dict(d_solver=3), ValidationError, "d_solver must be a registered solver name or a solvers.StepSolver; got 3"),
    (dict(d_solver="nope"), UnknownSolverError, "unknown solver 'nope'"),
    (dict(d_solver="lbfgs", d_solver_options={"bogus": 1}), ValidationError, "does not accept option"),
])
def test_bad_solver_settings(kw, error, match):
    with pytest.raises(error, match=match):
        SolverSettings(**kw)


def test_solver_settings_are_one_canonical_value():
    a = SolverSettings("armijo", {"initial_step": 0.5, "c": 1e-4}, "lbfgs")
    b = SolverSettings("armijo", '{"c": 0.0001, "initial_step": 0.5}', "lbfgs", "")
    assert a == b and hash(a) == hash(b) and a.h_solver_options == '{"c":0.0001,"initial_step":0.5}'
    assert a.learner_kwargs() == dict(solver=a) and SolverSettings("lbfgs").learner_kwargs() == dict(solver="lbfgs")
    assert a.label() == 'armijo {"c":0.0001,"initial_step":0.5} | d: lbfgs'
    assert a.key_part().startswith("armijo-") and len(a.key_part()) == len("armijo-") + 8
    assert SolverSettings().key_part() == "armijo" and SolverSettings(d_solver="armijo").key_part() != "armijo"
    assert a.to_dict() == dict(h_solver="armijo", h_solver_options={"c": 1e-4, "initial_step": 0.5}, d_solver="lbfgs",
                               d_solver_options={})
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.h_solver = "lbfgs"
    assert sorted([SolverSettings("lbfgs"), SolverSettings()]) == [SolverSettings(), SolverSettings("lbfgs")]
    import factirl_opt

    assert factirl_opt.SolverSettings is SolverSettings and "SolverSettings" in factirl_opt.__all__


def test_a_spec_key_and_record_keep_the_flat_solver_fields():
    spec = RunSpec(4, 2, 0, SolverSettings("armijo", {"initial_step": 0.5}))
    assert spec.to_dict() == dict(n_tasks=4, demos_per_task=2, seed=0, h_solver="armijo",
                                  h_solver_options='{"initial_step":0.5}', d_solver="", d_solver_options="")
    extra = ('{"initial_step":0.5}', "", "")  # the key's hash of the non-default settings, as before
    import hashlib

    assert spec.key(TINY) == f"n004-m02-seed0-armijo-{hashlib.sha256(repr(extra).encode()).hexdigest()[:8]}-" \
        f"{TINY.fingerprint()}"


# --- planner -------------------------------------------------------------------------------


def test_planner_enters_the_fingerprint_only_when_not_auto():
    paper = PRESETS["paper"]
    assert paper.planner == "auto"
    assert dataclasses.replace(paper, planner="auto").fingerprint() == paper.fingerprint() == "ea9fc43e51"
    dense = dataclasses.replace(paper, planner="dense")
    assert dense.fingerprint() != paper.fingerprint()
    assert Preset.from_dict(dense.to_dict()) == dense
    assert RunSpec(100, 10, 0).key(dense) != RunSpec(100, 10, 0).key(paper)


def test_unknown_planner_is_rejected():
    with pytest.raises(ValidationError, match="preset 'x': planner must be one of auto, dense, sparse-lu; got 'gpu'"):
        Preset(name="x", planner="gpu")


def test_planner_reaches_every_learner_and_score(monkeypatch):
    from factirl_opt import GradIRL
    from factirl_opt.lab.experiments import runner as runner_mod

    seen = []

    class SpyGradIRL(GradIRL):
        def __init__(self, **kw):
            seen.append(("GradIRL", kw["execution"].planner))
            super().__init__(**kw)

    class SpyFactIRL(FactIRL):
        def __init__(self, **kw):
            seen.append(("FactIRL", kw["execution"].planner))
            super().__init__(**kw)

    original = runner_mod.deviation

    def spy_deviation(mdp, true, learnt, planner="auto"):
        seen.append(("deviation", planner))
        return original(mdp, true, learnt, planner=planner)

    monkeypatch.setattr(learners_mod, "GradIRL", SpyGradIRL)
    monkeypatch.setattr(learners_mod, "FactIRL", SpyFactIRL)
    monkeypatch.setattr(runner_mod, "deviation", spy_deviation)
    preset = dataclasses.replace(TINY, planner="sparse-lu")
    rec = run_one(preset, RunSpec(preset.default_tasks, preset.default_demos, 0))
    kinds = {k for k, _ in seen}
    assert kinds == {"GradIRL", "FactIRL", "deviation"} and {p for _, p in seen} == {"sparse-lu"}
    assert sum(k == "deviation" for k, _ in seen) == len(rec["rows"]) + len(LINEUPS["paper"].value_maps)


# --- solvers named by presets; the fast preset ---------------------------------------------


def test_fast_preset_is_the_paper_with_faster_solvers():
    from factirl_opt.lab.experiments.presets import FAST_SOLVERS, SOLVER_FIELDS

    paper, fast = PRESETS["paper"], PRESETS["fast"]
    assert {f: getattr(fast, f) for f in FAST_SOLVERS} == FAST_SOLVERS
    ignored = ("name", *FAST_SOLVERS, *SOLVER_FIELDS)
    same = {f: v for f, v in paper.to_dict().items() if f not in ignored}
    assert same == {f: v for f, v in fast.to_dict().items() if f not in ignored}
    assert paper.fact_gtol == 0.0 < fast.fact_gtol and fast.fingerprint() != paper.fingerprint()
    specs = plan_runs(fast, [0, 1, 2])
    assert len(specs) == 27 and {s.solvers for s in specs} == {fast.solvers}
    assert {s.key(fast) for s in specs}.isdisjoint(s.key(paper) for s in plan_runs(paper, [0, 1, 2]))


def test_a_sweep_overrides_the_presets_solvers():
    fast = PRESETS["fast"]
    solvers = fast.solvers.with_overrides(h_solver="armijo")
    (spec,) = plan_runs(dataclasses.replace(fast, demos_sweep=(10,), tasks_sweep=(100,)), [0], solvers)
    assert spec.solvers == SolverSettings("armijo", None, fast.solvers.d_solver)
    preset = dataclasses.replace(TINY, solvers=SolverSettings("armijo", {"initial_step": 0.5}))
    assert preset.solvers.h_solver_options == '{"initial_step":0.5}' and preset.solvers.h_options == {"initial_step": 0.5}
    assert Preset.from_dict(json.loads(json.dumps(preset.to_dict()))) == preset
    assert preset.to_dict()["h_solver_options"] == '{"initial_step":0.5}' and "solvers" not in preset.to_dict()
    assert plan_runs(preset, [0])[0].solvers.h_options == {"initial_step": 0.5}  # the preset's options with its solver
    over = preset.solvers.with_overrides(h_solver_options={"initial_step": 0.25})
    assert plan_runs(preset, [0], over)[0].solvers.h_options == {"initial_step": 0.25}
    named = preset.solvers.with_overrides(h_solver="armijo")
    assert plan_runs(preset, [0], named)[0].solvers.h_options == {}  # a named solver: its own options only
    with pytest.raises(ValidationError, match="d_solver_options given without d_solver"):
        preset.solvers.with_overrides(d_solver_options={"a": 1})
    with pytest.raises(ValidationError, match="solvers must be a SolverSettings; got 'armijo'"):
        plan_runs(preset, [0], "armijo")


@pytest.mark.parametrize("kw, error, match", [
    (dict(h_solver="nope"), UnknownSolverError, "preset 'x': unknown solver 'nope'"),
    (dict(h_solver_options="{oops"), ValidationError, "preset 'x': h_solver_options must be a dict or its JSON"),
    (dict(h_solver_options={"bogus": 1}), ValidationError, "preset 'x': .*does not accept option"),
    (dict(d_solver_options={"a": 1}), ValidationError, "preset 'x': d_solver_options given without d_solver"),
    (dict(x_solver="armijo"), ValidationError, "preset 'x': solvers: .*x_solver"),
])
def test_preset_solver_validation(kw, error, match):
    with pytest.raises(error, match=match):
        Preset(name="x", solvers=kw)  # a mapping of the four fields, as a manifest holds them
    with pytest.raises(error, match=match if "x_solver" not in kw else "not a preset"):
        Preset.from_dict(dict(name="x", **kw))


def test_preset_solvers_must_be_settings():
    with pytest.raises(ValidationError, match="preset 'x': solvers must be a SolverSettings; got 3"):
        Preset(name="x", solvers=3)


def test_fast_solvers_run_at_tiny_scale():
    from factirl_opt.lab.experiments.presets import FAST_SOLVERS

    preset = dataclasses.replace(TINY, name="tiny-fast", **FAST_SOLVERS)
    spec = plan_runs(preset, [0])[-1]
    rec = run_one(preset, spec)
    label = f"{FAST_SOLVERS['solvers'].h_solver} | d: {FAST_SOLVERS['solvers'].d_solver}"
    assert {r["h_solver"] for r in rec["rows"]} == {label}
    assert all(np.isfinite(r["deviation"]) and r["n_evaluations"] > 0 for r in rec["rows"])


@pytest.mark.parametrize("field", ["flat_solver", "flat_features_solver"])
@pytest.mark.parametrize("value, error, match", [
    ("nope", UnknownSolverError, "preset 'x': unknown solver 'nope'"),
    ("", ValidationError, "preset 'x': {field} must be a registered solver name; got ''"),
    (3, ValidationError, "preset 'x': {field} must be a registered solver name; got 3"),
])
def test_flat_solver_validation(field, value, error, match):
    with pytest.raises(error, match=match.format(field=field)):
        Preset(name="x", **{field: value})
    with pytest.raises(ValidationError, match="preset 'x': fact_tol must be"):
        Preset(name="x", fact_tol=-1.0)


@pytest.mark.parametrize("field, value", [("flat_solver", "lbfgs"), ("flat_features_solver", "lbfgs"), ("fact_tol", 1e-4),
                                          ("pca_shrink", True), ("flat_stol", 1e-5), ("fact_scheme", "joint")])
def test_later_solver_fields_enter_the_fingerprint_only_when_not_the_default(field, value):
    assert dataclasses.replace(TINY, **{field: LATER_FIELDS[field]}).fingerprint() == TINY.fingerprint()
    lbfgs = dataclasses.replace(TINY, **{field: value})
    assert lbfgs.fingerprint() != TINY.fingerprint()
    assert {s.key(lbfgs) for s in plan_runs(lbfgs, [0])}.isdisjoint(s.key(TINY) for s in plan_runs(TINY, [0]))


def test_flat_stopping_rules_reach_every_gradirl(monkeypatch):
    """The presets pin GradIRL's gradient and saturation rules (0: the committed protocol, where
    the library's defaults are on); a preset's values reach every flat fit of a run."""
    from factirl_opt import GradIRL

    seen = []

    class SpyGradIRL(GradIRL):
        def __init__(self, **kw):
            seen.append((kw["gtol"], kw["stol"]))
            super().__init__(**kw)

    monkeypatch.setattr(learners_mod, "GradIRL", SpyGradIRL)
    pinned = {name: p.flat_stol for name, p in PRESETS.items() if p.flat_gtol or p.flat_stol}
    assert pinned == {"objectworld": 1e-5, "objectworld-per-task": 1e-5}  # the full-size ELIRL protocol's
    preset = dataclasses.replace(TINY, flat_gtol=1e-4, flat_stol=1e-5)
    run_one(preset, RunSpec(preset.default_tasks, preset.default_demos, 0))
    assert len(seen) >= 2 and set(seen) == {(1e-4, 1e-5)}
    with pytest.raises(ValidationError, match="preset 'x': flat_stol must be"):
        Preset(name="x", flat_stol=-1.0)


def test_fact_scheme_reaches_the_factirl_fits_it_applies_to(monkeypatch):
    """The preset's outer scheme reaches every FactIRL fit whose solvers it applies to; the others
    alternate, and the substitution is announced (the train rows only: a transfer has no scheme)."""
    from factirl_opt.lab.experiments import plan_sweep
    from factirl_opt.lab.experiments.learner_solvers import factorial_scheme

    assert [name for name, p in PRESETS.items() if p.fact_scheme != "alternating"] == ["objectworld", "objectworld-per-task"]
    seen = []

    class SpyFactIRL(FactIRL):
        def __init__(self, **kw):
            seen.append(kw.get("scheme"))
            super().__init__(**kw)

    monkeypatch.setattr(learners_mod, "FactIRL", SpyFactIRL)
    preset = dataclasses.replace(PRESETS["objectworld-tiny"], fact_scheme="joint", fact_max_iter=2)
    rec = run_one(preset, plan_runs(preset, [0])[-1])
    assert len(seen) == 3 and set(seen) == {"joint"}  # factorial, on features, random init: the preset's L-BFGS D-steps
    assert all(np.isfinite(r["deviation"]) for r in rec["rows"])
    # a constrained H-step solver, or a D-step solver needing residuals: the alternation
    for settings in (SolverSettings("gn-qp-clarabel-nonneg", d_solver="lbfgs"), SolverSettings("armijo", d_solver="gn-cg")):
        assert factorial_options(preset, settings)["scheme"] == "alternating"  # pinned: FactIRL's default is "auto"
        assert factorial_scheme(preset, settings)[0] == "alternating"
    # ... except where the objective replaces it (MCE: gn-cg becomes L-BFGS)
    assert factorial_options(preset, SolverSettings("armijo", d_solver="gn-cg"), "mce")["scheme"] == "joint"
    plan = plan_sweep(preset, [0], SolverSettings("gn-qp-clarabel-nonneg", d_solver="lbfgs"))
    why = "scheme='joint' does not apply to the H-solver 'gn-qp-clarabel-nonneg' with constraint 'nonneg'"
    assert [s.split(": scheme")[0] for s in plan.substitutions] == [
        f"train: {n}" for n in ("factorial", "factorial, features", "factorial, features, random init")]
    assert all(f"scheme 'joint' replaced by 'alternating' ({why}" in s for s in plan.substitutions)
    assert factorial_options(TINY, SolverSettings())["scheme"] == "alternating"  # the paper's alternation, pinned
    # FactIRL's own flat start takes the preset's saturation rule where the preset sets one
    assert factorial_options(dataclasses.replace(preset, flat_stol=1e-5), SolverSettings())["start"].flat_stol == 1e-5
    assert factorial_options(TINY, SolverSettings())["start"].flat_stol == TINY.flat_stol == 0.0 != Start().flat_stol
    with pytest.raises(ValidationError, match="preset 'x': fact_scheme must be one of auto, alternating, joint; got 'both'"):
        Preset(name="x", fact_scheme="both")


def test_pca_shrink_reaches_every_factirl_and_is_validated():
    assert [name for name, p in PRESETS.items() if p.pca_shrink and not p.world.startswith("babyai")] == ["fast", "objectworld", "objectworld-quick",
                                                                      "objectworld-tiny", "objectworld-per-task",
                                                                      "objectworld-per-task-quick",
                                                                      "sharing-objectworld-quick",
                                                                      "sharing-objectworld-per-task-quick"]
    for preset in (TINY, PRESETS["fast"]):
        assert factorial_options(preset, plan_runs(preset, [0])[0].solvers)["start"].pca_shrink is preset.pca_shrink
    with pytest.raises(ValidationError, match="preset 'x': pca_shrink must be True or False; got 1"):
        Preset(name="x", pca_shrink=1)


def test_flat_solvers_reach_every_gradirl_and_fall_back_where_they_do_not_apply(monkeypatch):
    seen = []

    class SpyGradIRL(learners_mod.GradIRL):
        def __init__(self, **kw):
            seen.append((kw["objective"], kw["features"] is not None, kw["solver"]))
            super().__init__(**kw)

    monkeypatch.setattr(learners_mod, "GradIRL", SpyGradIRL)
    preset = dataclasses.replace(PRESETS["objectworld-tiny"], lineup="objectworld+mce", flat_solver="lbfgs",
                                 flat_features_solver="gn-qp-clarabel")
    rec = run_one(preset, plan_runs(preset, [0])[-1])
    assert sorted(set(seen)) == [("mce", True, "lbfgs"),  # flat MCE on features: no residuals for Gauss-Newton
                                 ("policy-matching", False, "lbfgs"), ("policy-matching", True, "gn-qp-clarabel")]
    assert len(seen) == 8 and all(np.isfinite(r["deviation"]) for r in rec["rows"])  # 4 flat rows, train and test
    default = {(r["split"], r["learner"]): r for r in run_one(TINY, plan_runs(TINY, [0])[-1])["rows"]}
    seen.clear()
    lbfgs = dataclasses.replace(TINY, flat_solver="lbfgs")
    rows = {(r["split"], r["learner"]): r for r in run_one(lbfgs, plan_runs(lbfgs, [0])[-1])["rows"]}
    assert sorted(set(seen)) == [("policy-matching", False, "lbfgs"), ("policy-matching", True, "armijo")]
    assert rows["train", "flat"]["n_evaluations"] != default["train", "flat"]["n_evaluations"]
    assert rows["train", "flat, ground truth"] == default["train", "flat, ground truth"]  # features: still Armijo


# --- Objectworld and MCE line-ups ---------------------------------------------------------


def test_objectworld_lineup():
    ow = LINEUPS["objectworld"]
    assert ow.names("train") == ("flat", "flat, features", "flat, ground truth", "factorial", "factorial, features",
                                 "factorial, features, random init")
    assert ow.names("test") == ("flat", "flat, features", "factorial", "factorial, features", "flat, ground truth")
    assert ow.value_maps == ("flat, features", "factorial, features") and ow.worlds == ("objectworld",)


def test_mce_lineups_extend_the_paper_and_objectworld_lineups():
    for base, suffix in (("paper", ""), ("objectworld", ", features")):
        ext, lineup = LINEUPS[base + "+mce"], LINEUPS[base]
        mce = (f"flat MCE{suffix}", f"factorial MCE{suffix}")
        for split in ("train", "test"):
            assert ext.names(split) == lineup.names(split) + mce
        assert ext.worlds == lineup.worlds and ext.value_maps == lineup.value_maps + mce
        # the line-up's own rows keep their builders and versions
        assert [r for r in ext.fingerprint() if r[1] not in mce] == lineup.fingerprint()


def test_mce_learners_fit_the_mce_objective_with_solvers_that_apply(monkeypatch):
    seen = []

    class SpyFactIRL(FactIRL):
        def __init__(self, **kw):
            seen.append((kw["objective"], _named(kw).h_solver, _named(kw).d_solver or "armijo"))
            super().__init__(**kw)

    monkeypatch.setattr(learners_mod, "FactIRL", SpyFactIRL)
    preset = dataclasses.replace(TINY, lineup="paper+mce")
    spec = plan_runs(preset, [0], SolverSettings("gn-qp-clarabel", d_solver="lbfgs"))[-1]
    rec = run_one(preset, spec)
    assert seen == [("policy-matching", "gn-qp-clarabel", "lbfgs")] * 2 + [("mce", "lbfgs", "lbfgs")]
    assert {r["h_solver"] for r in rec["rows"]} == {"gn-qp-clarabel | d: lbfgs"}
    mce = {(r["split"], r["learner"]): r for r in rec["rows"] if "MCE" in r["learner"]}
    assert set(mce) == {(s, n) for s in ("train", "test") for n in ("flat MCE", "factorial MCE")}
    assert all(np.isfinite(r["deviation"]) and r["n_evaluations"] > 0 for r in mce.values())


@pytest.mark.parametrize("objective, h, d, expected", [
    ("policy-matching", "gn-qp-clarabel", "gn-cg", ("gn-qp-clarabel", "gn-cg")),
    ("mce", "gn-qp-clarabel", "gn-cg", ("lbfgs", "lbfgs")),
    ("mce", "armijo", "lbfgs", ("armijo", "lbfgs")),
])
def test_factorial_options_use_solvers_that_apply_to_the_objective(objective, h, d, expected):
    spec = plan_runs(TINY, [0], SolverSettings(h, {"lam_max": 1e6} if h.startswith("gn") else None, d))[0]
    kw = factorial_options(TINY, spec.solvers, objective)
    assert (_named(kw).h_solver, _named(kw).d_solver, kw["objective"]) == (*expected, objective)
    assert bool(_named(kw).h_solver_options) == (expected[0] == h and h.startswith("gn"))


def test_the_papers_rows_do_not_depend_on_the_extra_learners():
    spec = plan_runs(TINY, [0])[0]  # 4 tasks < k = 5: the PCA completes its basis from the random stream
    paper, extended = run_one(TINY, spec), run_one(dataclasses.replace(TINY, lineup="paper+mce"), spec)
    rows = {(r["split"], r["learner"]): r for r in extended["rows"]}
    for r in paper["rows"]:
        assert rows[r["split"], r["learner"]] == r


# --- per-seed rows: fitted once per seed, scored at every point -----------------------------


def test_per_seed_rows_are_fitted_once_per_seed_with_the_same_records(monkeypatch):

    built = []
    real = [lr for lr in LINEUPS["paper"].learners]
    spy = tuple(dataclasses.replace(lr, build=(lambda b, lr=lr: lambda gt, p, ctx: built.append((ctx.spec.n_tasks, lr.split, lr.name))
                                                or b(gt, p, ctx))(lr.build)) for lr in real)
    monkeypatch.setitem(learners_mod.LINEUPS, "paper", Lineup("paper", spy, LINEUPS["paper"].value_maps))
    specs = plan_runs(TINY, [0])
    assert len({(s.n_tasks, s.demos_per_task) for s in specs}) == 3
    reuse = {}
    shared = [run_one(TINY, spec, reuse=reuse) for spec in specs]
    per_seed = {(lr.split, lr.name) for lr in real if lr.per_seed}
    assert per_seed == {("test", "flat"), ("test", "flat, ground truth")}
    counts = {name: sum(1 for b in built if (b[1], b[2]) == name) for name in {(b[1], b[2]) for b in built}}
    assert all(counts[name] == (1 if name in per_seed else 3) for name in counts)
    assert len(reuse) == 2
    built.clear()
    alone = [run_one(TINY, spec) for spec in specs]
    assert len(built) == 3 * len(real)  # without reuse: every row of every run
    for a, b in zip(shared, alone):
        assert a["rows"] == b["rows"] and a["key"] == b["key"]
    # another seed is another fit
    run_one(TINY, plan_runs(TINY, [1])[0], reuse=reuse)
    assert len(reuse) == 4


# --- solver substitutions, named before any run ---------------------------------------------


def test_substitutions_name_what_the_mce_learners_take_instead(monkeypatch):
    from factirl_opt.lab.experiments import plan_sweep
    from factirl_opt.lab.experiments.learners import substitutions

    preset = dataclasses.replace(TINY, lineup="paper+mce", flat_solver="gn-qp-clarabel", grid_size=3, fact_max_iter=1,
                                 flat_max_iter=2, transfer_max_iter=2, n_test_tasks=2)
    plan = plan_sweep(preset, [0], SolverSettings("gn-qp-clarabel", d_solver="gn-cg"))
    why = "(a Gauss-Newton solver needs residuals; the 'mce' objective has none)"
    assert plan.substitutions == (
        f"train: flat MCE: solver gn-qp-clarabel replaced by lbfgs {why}",
        f"train: factorial MCE: H-step solver gn-qp-clarabel replaced by lbfgs {why}",
        f"train: factorial MCE: D-step solver gn-cg replaced by lbfgs {why}",
        f"test: flat MCE: solver gn-qp-clarabel replaced by lbfgs {why}",
        f"test: factorial MCE: H-step solver gn-qp-clarabel replaced by lbfgs {why}",
        f"test: factorial MCE: D-step solver gn-cg replaced by lbfgs {why}",
    )
    # what the builders do is what was announced
    seen = []

    class SpyGradIRL(learners_mod.GradIRL):
        def __init__(self, **kw):
            seen.append(("GradIRL", kw["objective"], _named(kw).h_solver))
            super().__init__(**kw)

    class SpyFactIRL(FactIRL):
        def __init__(self, **kw):
            seen.append(("FactIRL", kw["objective"], _named(kw).h_solver, _named(kw).d_solver or "armijo"))
            super().__init__(**kw)

    monkeypatch.setattr(learners_mod, "GradIRL", SpyGradIRL)
    monkeypatch.setattr(learners_mod, "FactIRL", SpyFactIRL)
    run_one(preset, plan.runs[0])
    assert {s for s in seen if s[1] == "mce"} == {("GradIRL", "mce", "lbfgs"), ("FactIRL", "mce", "lbfgs", "lbfgs")}
    assert ("FactIRL", "policy-matching", "gn-qp-clarabel", "gn-cg") in seen
    # solvers that apply: nothing to say
    assert substitutions(LINEUPS["paper+mce"], TINY, SolverSettings("armijo", d_solver="lbfgs")) == []
    assert plan_sweep(TINY, [0], SolverSettings("gn-qp-clarabel")).substitutions == ()


def test_a_learner_names_a_known_solver_role():
    with pytest.raises(ValidationError, match="learner train: a: solvers must be one of flat, flat features, factorial"):
        Learner("train", "a", flat, solvers="gradient")


def test_learner_names_are_the_constants():
    from factirl_opt.lab.experiments import learner_names

    names = {getattr(learner_names, c) for c in learner_names.__all__}
    for lineup in LINEUPS.values():
        assert {lr.name for lr in lineup.learners} <= names


def test_runs_ignore_the_max_iter_warnings_of_their_fixed_budgets():
    """The presets' budgets stop the flat fits at max_iter (tiny: 10 iterations): no warning per fit;
    other convergence warnings are not silenced."""
    import warnings

    from factirl_opt.exceptions import MaxIterWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run_one(TINY, plan_runs(TINY, [0])[0])
    assert not [w for w in caught if issubclass(w.category, MaxIterWarning)]
    with pytest.warns(MaxIterWarning):  # the same fit outside a run warns
        from factirl_opt import GradIRL

        gt = grid_world(TINY, 4, 2, 0)
        GradIRL(max_iter=TINY.flat_max_iter).fit(gt.mdp, gt.demos("train"))


def test_the_paper_preset_pins_the_papers_setting():
    """The paper preset's FactIRL is fo.PAPER_SETTINGS (but for the preset's own start), whatever FactIRL's defaults."""
    kw = factorial_options(PRESETS["paper"], SolverSettings())
    for name in ("scheme", "inner_steps", "max_iter", "tol", "gtol", "transfer_stol", "solver"):
        assert kw[name] == PAPER_SETTINGS[name], name
    assert kw["start"].flat_stol == PAPER_SETTINGS["start"].flat_stol == 0.0
    assert all(kw[name] != FactIRL().get_params()[name] for name in ("scheme", "inner_steps", "transfer_stol", "solver"))

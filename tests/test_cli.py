"""The ``factirl-opt`` command line: help, reproduce, plot, bench, and clear errors."""

import json
import os
import subprocess
import sys

import pytest

from factirl_opt.lab.cli import main


REPRODUCE_OPTIONS = ("--preset", "--seed", "--seeds", "--jobs", "--out", "--h-solver", "--h-solver-options",
                     "--d-solver", "--d-solver-options", "--planner", "--lineup", "--flat-solver", "--backend",
                     "--scheduler")


def _reproduce_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["reproduce", "--help"])
    assert exc.value.code == 0
    return capsys.readouterr().out


def _option_blocks(text):
    """{option: its help text} from argparse's help output."""
    blocks, current = {}, None
    for line in text.split("options:", 1)[1].split("presets (", 1)[0].splitlines():
        stripped = line.strip()
        if line.startswith("  -"):  # an option (continuation lines are indented deeper)
            current = stripped.split()[0].rstrip(",")
            if current == "-h":
                current = "--help"
            blocks[current] = stripped
        elif current and stripped:
            blocks[current] += " " + stripped
    return blocks


def test_help_explains_every_reproduce_option(capsys):
    text = _reproduce_help(capsys)
    blocks = _option_blocks(text)
    for opt in REPRODUCE_OPTIONS:
        assert opt in blocks, opt
        assert blocks[opt].count("default") == 1, blocks[opt]  # each default printed once
    for opt in ("--no-plot", "--quiet", "--help"):
        assert "default" not in blocks[opt]
    assert "available_solvers" in text and "alpha=0.03" in text


def test_help_documents_every_preset(capsys):
    from factirl_opt.lab.experiments.presets import PRESET_DESCRIPTIONS, PRESETS

    text = " ".join(_reproduce_help(capsys).split())  # unwrapped
    assert set(PRESET_DESCRIPTIONS) == set(PRESETS)
    for name, description in PRESET_DESCRIPTIONS.items():
        assert f"{name} {len(PRESETS[name].points())} points x {PRESETS[name].n_seeds} seed(s): {description}" in text


def test_top_level_help(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    text = capsys.readouterr().out
    for cmd in ("reproduce", "plot", "bench"):
        assert cmd in text


def test_reproduce_then_plot(tmp_path, capsys):
    out = tmp_path / "tiny"
    assert main(["reproduce", "--preset", "tiny", "--seeds", "1", "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "3 runs (3 computed, 0 reused)" in printed and f"wrote: {out / 'claims.md'}" in printed
    for name in ("results.csv", "summary.csv", "timings.csv", "manifest.json", "figure3.json", "claims.md"):
        assert (out / name).exists()
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["command"] == f"factirl-opt reproduce --preset tiny --seeds 1 --out {out} --quiet"
    assert manifest["seeds"] == [0]
    assert sorted(os.listdir(out / "figures")) == sorted(f"figure{i}.{e}" for i in (1, 2, 3) for e in ("png", "svg"))
    # rerun: everything reused, the tables rewritten (and what was drawn from them removed); plot alone redraws
    assert main(["reproduce", "--preset", "tiny", "--seeds", "1", "--out", str(out), "--quiet", "--no-plot"]) == 0
    assert "3 runs (0 computed, 3 reused)" in capsys.readouterr().out
    assert not (out / "claims.md").exists() and os.listdir(out / "figures") == []
    assert main(["plot", str(out)]) == 0
    assert (out / "figures" / "figure2.png").exists() and (out / "claims.md").exists()
    # a truncated table: a clear error naming the file, not a traceback
    text = (out / "results.csv").read_text()
    (out / "results.csv").write_text(text[: len(text) - 40])
    assert main(["plot", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"factirl-opt: error: {out / 'results.csv'}, line ") and "not a table" in err
    assert err.count("\n") == 1
    (out / "results.csv").write_text("".join(text.splitlines(keepends=True)[:-3]))  # cut at a line boundary
    assert main(["plot", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{out / 'results.csv'} has 27 rows, but the manifest describes 3 runs x 10 learners = 30" in err


@pytest.mark.parametrize("argv, message", [
    (["reproduce", "--preset", "huge"], "invalid choice: 'huge'"),
    (["reproduce", "--jobs", "0"], "jobs must be an integer >= 1; got 0 (or -1: every core)"),
    (["reproduce", "--jobs", "x"], "jobs must be an integer (or -1: every core); got 'x'"),
    (["reproduce", "--seeds", "two"], "seeds must be an integer; got 'two'"),
    (["reproduce", "--seed", "-1"], "seed must be an integer >= 0; got -1"),
    (["reproduce", "--backend", "spark"], "invalid choice: 'spark'"),
    (["reproduce", "--planner", "gpu"], "invalid choice: 'gpu'"),
    (["reproduce", "--lineup", "mce"], "invalid choice: 'mce'"),
    (["reproduce", "--h-solver-options", "alpha"], "expected a JSON object or key=value pairs"),
    (["reproduce", "--h-solver-options", "{alpha: 1}"], "not a JSON object"),
    (["reproduce", "--h-solver-options", "a=1,a=2"], "distinct keys"),
    (["frobnicate"], "invalid choice: 'frobnicate'"),
])
def test_bad_options_are_usage_errors(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_library_errors_are_one_line_messages(tmp_path, capsys):
    code = main(["reproduce", "--preset", "tiny", "--out", str(tmp_path), "--h-solver", "no-such-solver", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("factirl-opt: error: unknown solver 'no-such-solver'") and "armijo" in err
    assert "Traceback" not in err and err.count("\n") == 1
    code = main(["reproduce", "--preset", "tiny", "--scheduler", "tcp://localhost:1", "--out", str(tmp_path), "--quiet"])
    assert code == 2 and "scheduler" in capsys.readouterr().err
    code = main(["plot", str(tmp_path / "missing")])
    assert code == 2 and "not a directory" in capsys.readouterr().err
    code = main(["plot", str(tmp_path)])
    assert code == 2 and "results.csv" in capsys.readouterr().err


def test_planner_option_overrides_the_presets(tmp_path, capsys):
    from factirl_opt.lab.experiments import PRESETS

    out = tmp_path / "dense"
    assert main(["reproduce", "--preset", "tiny", "--seeds", "1", "--planner", "dense", "--out", str(out), "--quiet",
                 "--no-plot"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["preset"]["name"] == "tiny" and manifest["preset"]["planner"] == "dense"
    runs = sorted(os.listdir(out / "runs"))
    assert len(runs) == 3 and not any(PRESETS["tiny"].fingerprint() in r for r in runs)  # other keys than auto's


def test_lineup_option_selects_the_mce_learners(tmp_path, capsys):
    out = tmp_path / "mce"
    assert main(["reproduce", "--preset", "tiny", "--seeds", "1", "--lineup", "paper+mce", "--out", str(out), "--quiet"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["preset"]["lineup"] == "paper+mce" and len(manifest["lineup"]) == 14
    claims = (out / "claims.md").read_text()
    assert claims.startswith("# Paper and MCE claims") and "| test: factorial MCE beats flat MCE |" in claims
    code = main(["reproduce", "--preset", "tiny", "--lineup", "objectworld", "--out", str(tmp_path / "x"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "the line-up 'objectworld' runs in the world(s) objectworld; got world 'grid'" in err
    assert err.count("\n") == 1


def test_flat_solver_option_overrides_the_presets(tmp_path, capsys):
    out = tmp_path / "lbfgs"
    assert main(["reproduce", "--preset", "tiny", "--seeds", "1", "--flat-solver", "lbfgs", "--out", str(out), "--quiet",
                 "--no-plot"]) == 0
    assert json.loads((out / "manifest.json").read_text())["preset"]["flat_solver"] == "lbfgs"
    code = main(["reproduce", "--preset", "tiny", "--flat-solver", "nope", "--out", str(tmp_path / "x"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("factirl-opt: error: preset 'tiny': unknown solver 'nope'") and "lbfgs" in err


def test_presets_print_their_solvers(capsys):
    text = " ".join(_reproduce_help(capsys).split())
    assert "[solvers: flat lbfgs/gn-qp-clarabel, H gn-qp-clarabel, D lbfgs]" in text and "objectworld-quick" in text
    from factirl_opt.lab.experiments.presets import PRESET_DESCRIPTIONS

    assert f"{PRESET_DESCRIPTIONS['paper']} [solvers" not in text  # the paper's Armijo steps are not listed


def test_solver_options_parse_json_or_pairs():
    from factirl_opt.lab.cli import parse_solver_options

    assert parse_solver_options('{"alpha": 0.03, "interface": "direct"}') == {"alpha": 0.03, "interface": "direct"}
    assert parse_solver_options("alpha=0.03, interface=direct,warm=true,n=3") == dict(
        alpha=0.03, interface="direct", warm=True, n=3)


def test_solver_options_are_validated_before_running(tmp_path, capsys):
    code = main(["reproduce", "--preset", "tiny", "--out", str(tmp_path), "--quiet", "--h-solver-options", "bogus=1"])
    err = capsys.readouterr().err
    assert code == 2 and "does not accept option(s) bogus" in err and err.count("\n") == 1
    assert not (tmp_path / "runs").exists()
    code = main(["reproduce", "--preset", "tiny", "--out", str(tmp_path), "--quiet", "--d-solver-options", "a=1"])
    assert code == 2 and "d_solver_options given without d_solver" in capsys.readouterr().err


def test_bench_forwards_to_the_benchmarks(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "--help"])
    assert exc.value.code == 0
    assert "BENCHMARK" in capsys.readouterr().out


def test_console_script_runs_as_a_module():
    res = subprocess.run([sys.executable, "-m", "factirl_opt.lab.cli", "plot", "/nonexistent/dir"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert "factirl-opt: error:" in res.stderr and "Traceback" not in res.stderr


# --- reliability: substitutions said, stale outputs removed, clear errors for --out -----------


def test_mce_learners_with_a_gauss_newton_solver_say_what_they_take_instead(tmp_path, capsys):
    out = tmp_path / "mce"
    code = main(["reproduce", "--preset", "tiny", "--seeds", "1", "--lineup", "paper+mce", "--h-solver", "gn-qp-clarabel",
                 "--d-solver", "gn-cg", "--out", str(out), "--quiet", "--no-plot"])
    err = capsys.readouterr().err
    assert code == 0
    lines = [line for line in err.splitlines() if line.startswith("factirl-opt: warning:")]
    assert lines[:2] == [
        "factirl-opt: warning: train: factorial MCE: H-step solver gn-qp-clarabel replaced by lbfgs (a Gauss-Newton "
        "solver needs residuals; the 'mce' objective has none)",
        "factirl-opt: warning: train: factorial MCE: D-step solver gn-cg replaced by lbfgs (a Gauss-Newton solver "
        "needs residuals; the 'mce' objective has none)"]
    assert len(lines) == 4 and "Traceback" not in err
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["substitutions"] == [line.split("warning: ", 1)[1] for line in lines]


def test_no_plot_into_another_presets_directory_removes_its_claims_and_figures(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["reproduce", "--preset", "tiny", "--seeds", "1", "--out", str(out), "--quiet"]) == 0
    assert (out / "claims.md").exists() and len(os.listdir(out / "figures")) == 6
    assert main(["reproduce", "--preset", "tiny", "--seeds", "1", "--lineup", "paper+mce", "--out", str(out), "--quiet",
                 "--no-plot"]) == 0
    assert not (out / "claims.md").exists() and os.listdir(out / "figures") == []
    assert main(["plot", str(out)]) == 0  # drawn again from the new tables
    assert (out / "claims.md").read_text().startswith("# Paper and MCE claims")


def test_an_out_that_is_a_file_or_cannot_be_made_is_a_clear_error(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("keep")
    for out, message in ((f, f"output directory '{f}' exists and is not a directory"),
                         (f / "sub", f"cannot create the output directory '{f / 'sub'}': Not a directory")):
        code = main(["reproduce", "--preset", "tiny", "--out", str(out), "--quiet", "--no-plot"])
        err = capsys.readouterr().err
        assert code == 2 and err == f"factirl-opt: error: {message}" + ("; choose another --out" if out == f else "") + "\n"
    assert f.read_text() == "keep"


def test_a_directory_that_cannot_be_written_is_a_clear_error(tmp_path, capsys, monkeypatch):
    """A read-only (or full) directory: the lock cannot be created; a PersistenceError names it."""
    import errno

    out = tmp_path / "ro"
    real_open = os.open

    def refuse(path, flags, *args, **kwargs):
        if str(path).startswith(str(out / ".lock")) and flags & os.O_CREAT:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", refuse)
    code = main(["reproduce", "--preset", "tiny", "--out", str(out), "--quiet", "--no-plot"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"factirl-opt: error: cannot create the lock '{out / '.lock'}': Permission denied")
    assert err.count("\n") == 1 and not (out / "results.csv").exists()


# ----------------------------------------------------------------------------- every option checked by its parser


def _value_actions(parser):
    """(subcommand path, action) of every option taking a value, through the sub-parsers."""
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                for path, act in _value_actions(sub):
                    yield (name,) + path, act
        elif action.option_strings and action.nargs != 0 and action.dest != "help":
            yield (), action


def _all_value_actions():
    from factirl_opt.lab.bench import build_parser as bench_parser
    from factirl_opt.lab.cli import build_parser

    yield from (((("reproduce",) + path), a) for path, a in _value_actions(build_parser()._subparsers._group_actions[0]
                                                                         .choices["reproduce"]))
    yield from ((("bench",) + path, a) for path, a in _value_actions(bench_parser()))


#: options whose value is free text checked where it is used (solver options: by the solver registry)
FREE_TEXT = {("reproduce", "--out"), ("reproduce", "--h-solver"), ("reproduce", "--d-solver"), ("reproduce", "--flat-solver")}


def test_every_option_has_a_checked_type_or_choices():
    from factirl_opt.lab.arguments import is_checked
    from factirl_opt.lab.cli import parse_solver_options

    unchecked = [(path, a.option_strings[-1]) for path, a in _all_value_actions()
                 if not (is_checked(a.type) or a.choices or a.type is parse_solver_options
                         or (path[0], a.option_strings[-1]) in FREE_TEXT)]
    assert unchecked == []


def test_negative_values_are_usage_errors_for_every_numeric_option(capsys):
    from factirl_opt.lab.arguments import is_checked
    from factirl_opt.lab.bench import main as bench_main

    checked = [(path, "/".join(a.option_strings)) for path, a in _all_value_actions()
               if path[0] == "bench" and is_checked(a.type) and a.type.__name__.startswith(("an integer", "a whole", "a finite"))]
    assert len(checked) > 60  # every benchmark's numbers
    for path, flag in checked:
        with pytest.raises(SystemExit) as exc:
            bench_main([path[1], flag.split("/")[-1], "-3"], prog="factirl-opt bench")
        err = capsys.readouterr().err
        assert exc.value.code == 2 and f"factirl-opt bench {path[1]}: error: argument {flag}" in err, (path, flag, err)


@pytest.mark.parametrize("argv, message", [
    (["bench", "environments", "--blas-threads", "-3"], "argument --blas-threads: must be an integer >= 0; got '-3'"),
    (["bench", "fit", "--h-solvers", "armijo", "nope"], "argument --h-solvers: unknown solver 'nope'; available: "),
    (["bench", "solvers", "--sparsity", "1"], "argument --sparsity: must be a finite number >= 0 and < 1; got '1'"),
    (["bench", "scale", "--jobs", "0"], "argument --jobs: must be an integer >= 1 (or -1: every core); got '0'"),
    (["bench", "robustness", "--extra", "1.5"], "argument --extra: must be a whole number >= 0 (1e5 accepted); got '1.5'"),
    (["bench", "gradient", "--beta", "nan"], "argument --beta: must be a finite number > 0; got 'nan'"),
    (["reproduce", "--scheduler", "not an address"], "argument --scheduler: must be a Dask scheduler address"),
    (["reproduce", "--scheduler", "tcp://localhost"], "([protocol://]host:port); got 'tcp://localhost'"),
])
def test_bad_values_are_refused_by_the_parsers(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.parametrize("preset, lineup", [("babyai-quick", "paper"), ("babyai-quick", "paper+mce"),
                                            ("objectworld-per-task-quick", "paper")])
def test_a_lineup_that_does_not_fit_the_presets_world_is_refused(tmp_path, capsys, preset, lineup):
    code = main(["reproduce", "--preset", preset, "--lineup", lineup, "--out", str(tmp_path / "x"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"factirl-opt: error: preset '{preset}': the line-up '{lineup}' plans every "
                                        "task on one MDP; the world ") and err.count("\n") == 1
    assert "has one MDP per task: choose a line-up of that world" in err
    assert not (tmp_path / "x").exists()


def test_library_errors_of_a_benchmark_are_one_line_messages(capsys, monkeypatch):
    from factirl_opt.lab.bench import main as bench_main
    from factirl_opt.lab.benchmarks import environments
    from factirl_opt.exceptions import ValidationError

    def refuse(args):
        raise ValidationError("this combination cannot run")

    monkeypatch.setattr(environments, "run", refuse)
    assert bench_main(["environments", "--quick"], prog="factirl-opt bench") == 2
    assert capsys.readouterr().err == "factirl-opt bench: error: this combination cannot run\n"

"""The ``factirl-opt`` command line: help, reproduce, plot, bench, and clear errors."""

import json
import os
import subprocess
import sys

import pytest

from factirl_opt.cli import main


def test_help_explains_every_reproduce_option(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["reproduce", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for opt in ("--preset", "--seed", "--seeds", "--jobs", "--out", "--h-solver", "--backend", "--scheduler"):
        assert opt in text
    assert "paper" in text and "quick" in text and "available_solvers" in text


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
    assert "3 runs (3 computed, 0 reused)" in printed
    for name in ("results.csv", "summary.csv", "timings.csv", "manifest.json", "figure3.json", "claims.md"):
        assert (out / name).exists()
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["command"] == f"factirl-opt reproduce --preset tiny --seeds 1 --out {out} --quiet"
    assert manifest["seeds"] == [0]
    assert sorted(os.listdir(out / "figures")) == sorted(f"figure{i}.{e}" for i in (1, 2, 3) for e in ("png", "svg"))
    # rerun: everything reused; plot alone redraws
    assert main(["reproduce", "--preset", "tiny", "--seeds", "1", "--out", str(out), "--quiet", "--no-plot"]) == 0
    assert "3 runs (0 computed, 3 reused)" in capsys.readouterr().out
    os.remove(out / "figures" / "figure2.png")
    assert main(["plot", str(out)]) == 0
    assert (out / "figures" / "figure2.png").exists()


@pytest.mark.parametrize("argv, message", [
    (["reproduce", "--preset", "huge"], "invalid choice: 'huge'"),
    (["reproduce", "--jobs", "0"], "expected a positive integer or -1"),
    (["reproduce", "--seeds", "two"], "expected an integer, got 'two'"),
    (["reproduce", "--seed", "-1"], "expected an integer >= 0"),
    (["reproduce", "--backend", "spark"], "invalid choice: 'spark'"),
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


def test_bench_forwards_to_the_benchmarks(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "--help"])
    assert exc.value.code == 0
    assert "BENCHMARK" in capsys.readouterr().out


def test_console_script_runs_as_a_module():
    res = subprocess.run([sys.executable, "-m", "factirl_opt.cli", "plot", "/nonexistent/dir"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert "factirl-opt: error:" in res.stderr and "Traceback" not in res.stderr

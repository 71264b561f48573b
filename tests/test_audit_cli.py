"""Audit: the command line's exit code after SIGTERM inside a fit, and an empty --out."""

import signal

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.lab import cli
from factirl_opt.lab.experiments import runner
from factirl_opt.lab.experiments.workers import Terminated


def terminated_fit(*args, **kwargs):
    """What ``run_plan`` does with --jobs 1 when SIGTERM arrives inside a fit of the main process."""
    mdp = fo.GridWorld(size=3)
    demos = fo.sample_demonstrations(mdp, np.random.default_rng(0).normal(size=(2, 9, 4)), 2, 4, rng=0)

    def sigterm(iteration, loss):
        raise Terminated(signal.SIGTERM)

    fo.GradIRL(max_iter=5, callback=sigterm).fit(mdp, demos)


def test_sigterm_inside_a_fit_exits_with_128_plus_sigterm(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(runner, "run_plan", terminated_fit)
    with pytest.warns(fo.exceptions.ConvergenceWarning, match="interrupted"):
        code = cli.main(["reproduce", "--preset", "tiny", "--out", str(tmp_path / "o"), "--quiet", "--no-plot"])
    assert code == 128 + signal.SIGTERM
    assert "interrupted; rerun the same command to resume" in capsys.readouterr().err


def test_a_plain_ctrl_c_still_exits_with_130(monkeypatch, tmp_path):
    def ctrl_c(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "run_plan", ctrl_c)
    assert cli.main(["reproduce", "--preset", "tiny", "--out", str(tmp_path / "o"), "--quiet", "--no-plot"]) == 130


def test_interrupt_signal_follows_causes_and_contexts_without_looping():
    inner = Terminated(signal.SIGTERM)
    outer = KeyboardInterrupt()
    outer.__cause__ = inner
    assert cli.interrupt_signal(outer) == signal.SIGTERM
    loop = KeyboardInterrupt()
    loop.__context__ = loop
    assert cli.interrupt_signal(loop) == signal.SIGINT


@pytest.mark.parametrize("out", ["", "  "])
def test_an_empty_out_is_refused(out, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code = cli.main(["reproduce", "--preset", "tiny", "--out", out, "--quiet", "--no-plot"])
    assert code == 2 and "--out is empty" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()

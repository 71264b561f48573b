"""Robustness to model error: learn on models estimated from logged data, score on the true one.

The paper's discussion calls the need for a known model of the dynamics "an important
limitation" and asks how robust IRL is to errors in a learnt model. This benchmark measures
it. For every seed, the world and its demonstrations are those of an experiment preset at one
point (:func:`factirl_opt.lab.experiments.make_ground_truth`): with ``--world grid`` the ``fast``
preset's (the paper's 10x10 grid, p_success 0.7, gamma 0.9, k = 5 primitives, beta 5, 100
training tasks x 10 demonstrations of 10 steps, 100 test tasks with one demonstration each,
its solvers and budgets); with ``--world objectworld`` the ``objectworld-quick`` preset's
(16x16, 20 training tasks x 16 demonstrations of 16 steps, 20 test tasks). The learners are
then fitted on the same demonstrations with

- the TRUE model (``M = "true"`` in the tables), and
- for every M in ``--extra`` (default 0, 10^3, 10^4, 10^5), the model
  :func:`factirl_opt.estimate_mdp` builds from the transitions of every demonstration (training
  and test: all the logged data) plus the first M of the seed's sequence of exploration
  transitions (:func:`exploration_sequence`: ``(s, a)`` uniform, ``s'`` drawn from the true
  model; nested, the same first M whatever the other values of ``--extra``), with ``--prior`` (default ``"self-loop"``) and ``--pseudo-count`` (default 1).

Learners (tabular rewards, the preset's solvers and budgets; docs/maths.md §5 and §8):
``flat`` (GradIRL) on the training tasks and, from scratch, on the test tasks; ``factorial``
(FactIRL from the PCA of the flat training rewards) on the training tasks, and its one-demo
``transfer`` to the test tasks. Every fit is scored on the TRUE model: the mean over tasks of
``deviation(true_mdp, true_rewards, learnt_rewards)`` (eq. 13; docs/maths.md §9).

Each estimated model is also scored on ``--n-heldout`` held-out exploration transitions
(:func:`factirl_opt.mdp.transition_log_likelihood`): the mean log-likelihood per transition
(``-inf`` when the model gives probability 0 to a held-out transition), the fraction of
held-out transitions given probability 0, the mean over the others, and the largest absolute
error of a transition probability against the true model. The true model's own held-out
log-likelihood is the ceiling.

Random streams: the demonstrations come from the preset's streams of the seed; the
exploration, held-out and learner streams are spawned from the seed's SeedSequence child
:data:`STREAM_KEY`, which the worlds never use, so they are independent of the demonstrations.
Every model (true or estimated) starts its learners from the same learner stream. A run is
deterministic in its seed and options.

``--out DIR`` writes ``robustness.csv`` (seed, M, learner, split, deviation),
``models.csv`` (the estimated models' scores), ``summary.csv`` (mean and std over seeds) and
``robustness.png`` (deviation vs M, one panel per learner and split, log x-axis with M = 0 a
decade below the smallest M > 0, the true model's level as a horizontal line).
``--quick`` is a tiny configuration for tests (options given explicitly keep their value).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import os
import time
from typing import Any

import numpy as np

from ...parallel import limit_blas_threads
from ...evaluation import deviation
from ...exceptions import ValidationError
from ..arguments import count, integer, real, text
from ..experiments.learners import factorial_options
from ..experiments.presets import get_preset
from ..experiments.worlds import make_ground_truth
from ...objectives.sharding import Execution
from ...learners.factirl import FactIRL
from ...learners.gradirl import GradIRL
from ...mdp.tabular import TabularMDP
from ...mdp.estimation import PRIORS, as_transitions, estimate_mdp, sample_transitions, transition_log_likelihood
from . import add_option, resolve_settings

__all__ = ["add_arguments", "run", "world_preset", "fit_and_score", "model_scores", "summarize", "write_outputs",
           "plot_summary", "exploration_sequence", "STREAM_KEY", "LEARNERS"]

DEFAULTS: dict[str, Any] = {"seeds": [0, 1, 2], "extra": [0, 1000, 10000, 100000], "world": "grid", "out": None,
                            "size": None, "n_tasks": None, "n_demos": None, "n_test_tasks": None, "n_heldout": 10000,
                            "prior": "self-loop", "pseudo_count": 1.0, "blas_threads": 1}
#: seconds: a 5x5 grid, 8 training tasks x 20 demonstrations (enough for the train deviations to
#: depend on the model more than on the optimiser's path), short budgets, 1 seed, M in {0, 10^6}
QUICK: dict[str, Any] = {"seeds": [0], "extra": [0, 1000000], "size": 5, "n_tasks": 8, "n_demos": 20, "n_test_tasks": 4,
                         "n_heldout": 2000}
#: world -> (base preset, overrides of its budgets under --quick)
WORLD_PRESETS = {"grid": "fast", "objectworld": "objectworld-quick"}
QUICK_BUDGETS = {"flat_max_iter": 30, "fact_max_iter": 10, "transfer_max_iter": 20}
#: the seed's SeedSequence child from which the exploration, held-out and learner streams are spawned
STREAM_KEY = 1000
#: (learner, split) pairs scored, in table order
LEARNERS = (("flat", "train"), ("factorial", "train"), ("flat", "test"), ("factorial", "test"))
TRUE = "true"
#: exploration transitions drawn at a time (:func:`exploration_sequence`)
EXPLORATION_BLOCK = 10_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    def opt(*flags: str, **kw: Any) -> None:
        add_option(parser, *flags, defaults=DEFAULTS, quick=QUICK, **kw)

    opt("--seeds", type=integer(0), nargs="+", metavar="SEED", help="seeds (one world and set of demonstrations each)")
    opt("--extra", type=count(0), nargs="+", metavar="M", help="exploration transitions added to the demonstrations' (1e5 accepted)")
    opt("--world", choices=sorted(WORLD_PRESETS), help="grid: the fast preset's; objectworld: objectworld-quick's")
    opt("--out", type=text("an output directory"), metavar="DIR", help="write the tables and the figure there")
    opt("--size", type=integer(2), help="grid side (default: the preset's)")
    opt("--n-tasks", type=integer(1), help="training tasks (default: the preset's)")
    opt("--n-demos", type=integer(1), help="demonstrations per training task (default: the preset's)")
    opt("--n-test-tasks", type=integer(1), help="test tasks, one demonstration each (default: the preset's)")
    opt("--n-heldout", type=count(1), help="held-out exploration transitions scoring each estimated model")
    opt("--prior", choices=PRIORS, help="prior of estimate_mdp")
    opt("--pseudo-count", type=real(0), help="pseudo-count of estimate_mdp")
    opt("--blas-threads", type=integer(0), help="OpenBLAS threads (0: leave as is)")
    parser.add_argument("--quick", action="store_true",
                        help="tiny configuration for tests: 5x5 grid, short budgets, 1 seed, M in {0, 1e6}")


def world_preset(s: dict) -> Any:
    """The experiment preset of the settings ``s``: the world's base preset with the given overrides."""
    preset = get_preset(WORLD_PRESETS[s["world"]])
    changes = {"grid_size": s["size"], "default_tasks": s["n_tasks"], "default_demos": s["n_demos"],
               "n_test_tasks": s["n_test_tasks"]}
    changes = {k: v for k, v in changes.items() if v is not None}
    if s.get("quick"):
        changes.update(QUICK_BUDGETS)
    return dataclasses.replace(preset, **changes)


def fit_and_score(gt: Any, mdp: TabularMDP, preset: Any, rng: np.random.SeedSequence) -> dict[tuple[str, str], float]:
    """Fit the learners of :data:`LEARNERS` on ``mdp`` and score them on the true model ``gt.mdp``.

    Parameters
    ----------
    gt : GroundTruth
        The true model, rewards and demonstrations (:func:`factirl_opt.lab.experiments.make_ground_truth`).
    mdp : TabularMDP
        The model the learners plan in (the true one or an estimate).
    preset : Preset
        Solvers and budgets.
    rng : SeedSequence
        The learner stream (FactIRL's PCA start).

    Returns
    -------
    dict
        ``(learner, split) -> mean deviation over the split's tasks`` on the true model (eq. 13).
    """
    flat_train = GradIRL(beta=preset.beta, max_iter=preset.flat_max_iter, gtol=preset.flat_gtol, solver=preset.flat_solver,
                         stol=preset.flat_stol, execution=Execution(planner=preset.planner)).fit(mdp, gt.train_demos)
    flat_test = GradIRL(beta=preset.beta, max_iter=preset.flat_max_iter, gtol=preset.flat_gtol, solver=preset.flat_solver,
                        stol=preset.flat_stol, execution=Execution(planner=preset.planner)).fit(mdp, gt.test_demos)
    fact = FactIRL(rng=np.random.default_rng(rng), **factorial_options(preset, preset.solvers))
    fact.fit(mdp, gt.train_demos, flat_rewards=flat_train.rewards_)
    fact.transfer(mdp, gt.test_demos)
    learnt = {("flat", "train"): flat_train.rewards_, ("factorial", "train"): fact.rewards_,
              ("flat", "test"): flat_test.rewards_, ("factorial", "test"): fact.transfer_rewards_}
    return {key: float(np.mean(deviation(gt.mdp, gt.rewards(key[1]), learnt[key], planner=preset.planner)))
            for key in LEARNERS}


def exploration_sequence(mdp: TabularMDP, n: int, rng: np.random.SeedSequence) -> np.ndarray:
    """The first ``n`` transitions of the seed's exploration sequence, an (n, 3) array.

    Drawn by :func:`factirl_opt.mdp.sample_transitions` in blocks of :data:`EXPLORATION_BLOCK` from one
    generator, so the first M transitions are the same whatever ``n >= M``: the models of a run
    are nested (each M's data extends the smaller M's), and an M gives the same model in a run
    with other values of ``--extra``.
    """
    gen = np.random.default_rng(rng)
    blocks = [sample_transitions(mdp, EXPLORATION_BLOCK, rng=gen) for _ in range(-(-n // EXPLORATION_BLOCK))]
    return np.concatenate(blocks)[:n] if blocks else np.zeros((0, 3), dtype=np.int64)


def model_scores(true_mdp: TabularMDP, mdp: TabularMDP, heldout: np.ndarray) -> dict[str, float]:
    """Held-out scores of a model: log-likelihood per transition and error against the true model.

    Returns
    -------
    dict
        ``heldout_loglik`` (mean per transition; ``-inf`` if a transition has probability 0),
        ``heldout_ruled_out`` (fraction of transitions given probability 0),
        ``heldout_loglik_possible`` (mean over the others) and ``max_abs_error`` (largest
        ``|P_hat(s' | s, a) - P(s' | s, a)|``).
    """
    logp = np.asarray(transition_log_likelihood(mdp, heldout, reduction="none"))
    possible = np.isfinite(logp)
    err = abs(mdp.csr() - true_mdp.csr())
    return {"heldout_loglik": float(np.mean(logp)), "heldout_ruled_out": float(1.0 - possible.mean()),
            "heldout_loglik_possible": float(np.mean(logp[possible])) if possible.any() else float("-inf"),
            "max_abs_error": float(err.max()) if err.nnz else 0.0}


def _models(gt: Any, s: dict, s_explore: np.random.SeedSequence):
    """``(M, model, n_transitions)`` for the true model (``M = "true"``) and each M of ``s["extra"]``."""
    mdp = gt.mdp
    yield TRUE, mdp, ""
    explore = exploration_sequence(mdp, max(s["extra"]), s_explore)
    demos = as_transitions(list(gt.train_demos) + list(gt.test_demos), mdp.n_states, mdp.n_actions)
    for M in sorted(set(s["extra"])):
        data = np.concatenate((demos, explore[:M]))
        yield M, estimate_mdp(data, mdp.n_states, mdp.n_actions, mdp.gamma, prior=s["prior"],
                              pseudo_count=s["pseudo_count"]), len(data)


def _run_seed(preset: Any, s: dict, seed: int) -> tuple[list[dict], list[dict], dict]:
    """The deviation rows, model rows and timings (s per model) of one seed (see the module docstring)."""
    gt = make_ground_truth(preset, preset.default_tasks, preset.default_demos, seed)
    s_explore, s_heldout, s_learn = np.random.SeedSequence(seed, spawn_key=(STREAM_KEY,)).spawn(3)
    heldout = sample_transitions(gt.mdp, s["n_heldout"], rng=s_heldout)
    rows, models, times = [], [], {}
    for M, model, n_transitions in _models(gt, s, s_explore):
        t0 = time.perf_counter()
        scores = fit_and_score(gt, model, preset, s_learn)
        times[str(M)] = time.perf_counter() - t0
        rows += [{"seed": seed, "M": M, "learner": lr, "split": sp, "deviation": dev} for (lr, sp), dev in scores.items()]
        quality = model_scores(gt.mdp, model, heldout) if len(heldout) else {}
        models.append({"seed": seed, "M": M, "n_transitions": n_transitions, **quality})
    return rows, models, times


def summarize(rows: list[dict]) -> list[dict]:
    """Mean and std (ddof=1; 0 for one seed) of the deviation over seeds, per (M, learner, split)."""
    groups: dict[tuple, list[float]] = {}
    for r in rows:
        groups.setdefault((r["M"], r["learner"], r["split"]), []).append(r["deviation"])
    order = {key: i for i, key in enumerate(LEARNERS)}
    keys = sorted(groups, key=lambda k: (order[k[1], k[2]], -1 if k[0] == TRUE else k[0]))
    return [{"M": M, "learner": lr, "split": sp, "n_seeds": len(groups[M, lr, sp]),
             "deviation_mean": float(np.mean(groups[M, lr, sp])),
             "deviation_std": float(np.std(groups[M, lr, sp], ddof=1)) if len(groups[M, lr, sp]) > 1 else 0.0}
            for M, lr, sp in keys]


def _write_csv(path: str, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows({k: repr(v) if isinstance(v, float) else v for k, v in r.items()} for r in rows)


def _x(M: int, zero_at: float) -> float:
    """Where M sits on the log x-axis (M = 0 at ``zero_at``)."""
    return float(M) if M > 0 else zero_at


def plot_summary(summary: list[dict], path: str) -> None:
    """Deviation vs M, one panel per learner and split (log x-axis, M = 0 drawn a decade below the
    smallest M > 0), mean and std over seeds; the true model's level as a dashed horizontal line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    positive = sorted({r["M"] for r in summary if r["M"] != TRUE and r["M"] > 0}) or [10]
    zero_at = positive[0] / 10
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharex=True)
    for ax, (learner, split) in zip(axes.T.ravel(), LEARNERS):
        colour = "tab:red" if learner == "factorial" else "tab:blue"
        pts = [r for r in summary if r["learner"] == learner and r["split"] == split]
        est = [r for r in pts if r["M"] != TRUE]
        ax.errorbar([_x(r["M"], zero_at) for r in est], [r["deviation_mean"] for r in est],
                    yerr=[r["deviation_std"] for r in est], marker="o", capsize=3, color=colour, label="estimated model")
        for r in pts:
            if r["M"] == TRUE:
                ax.axhline(r["deviation_mean"], color="k", linestyle="--", label="true model")
        ax.set_xscale("log")
        ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        ax.set_xticks([zero_at] + positive, ["0"] + [f"$10^{{{np.log10(m):g}}}$" if np.log10(m).is_integer() else str(m)
                                                     for m in positive])
        ax.set_title(f"{learner}, {split} tasks" + (" (transfer)" if (learner, split) == ("factorial", "test") else ""))
        ax.set_ylabel("deviation on the true model")
        ax.legend(fontsize=8)
    for ax in axes[1]:
        ax.set_xlabel("M, exploration transitions added to the demonstrations'")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_outputs(out: str, rows: list[dict], models: list[dict], summary: list[dict]) -> list[str]:
    """Write ``robustness.csv``, ``models.csv``, ``summary.csv`` and ``robustness.png`` in ``out``; returns the paths."""
    os.makedirs(out, exist_ok=True)
    paths = [os.path.join(out, name) for name in ("robustness.csv", "models.csv", "summary.csv", "robustness.png")]
    for path, table in zip(paths, (rows, models, summary)):
        _write_csv(path, table)
    plot_summary(summary, paths[3])
    return paths


def _check(s: dict) -> None:
    if not s["seeds"] or not s["extra"]:
        raise ValidationError("bench robustness: --seeds and --extra need at least one value each")
    if s["n_heldout"] < 0 or s["pseudo_count"] < 0:
        raise ValidationError(f"bench robustness: --n-heldout and --pseudo-count must be >= 0; got {s['n_heldout']}, {s['pseudo_count']}")


def run(args: argparse.Namespace) -> dict:
    s = resolve_settings(args, DEFAULTS, QUICK)
    _check(s)
    preset = world_preset(s)
    t0 = time.perf_counter()
    rows, models, times = [], [], {}
    with limit_blas_threads(s["blas_threads"]) as threads:
        for seed in s["seeds"]:
            seed_rows, seed_models, times[str(seed)] = _run_seed(preset, s, seed)
            rows += seed_rows
            models += seed_models
    summary = summarize(rows)
    files = write_outputs(s["out"], rows, models, summary) if s["out"] else []
    settings = {key: s[key] for key in DEFAULTS}
    settings.update(quick=bool(s["quick"]), blas_threads=threads, preset=preset.name, grid_size=preset.grid_size,
                    n_tasks=preset.default_tasks, n_demos=preset.default_demos, n_test_tasks=preset.n_test_tasks,
                    demo_length=preset.demo_length)
    return {"benchmark": "robustness", "total_s": time.perf_counter() - t0, "summary": summary, "models": models,
            "rows": rows, "fit_s": times, "files": files, "settings": settings}

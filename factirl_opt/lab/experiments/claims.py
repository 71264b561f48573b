"""The claims of a line-up (the paper's section 4; Objectworld's), checked against a reproduce directory's results.

Each claim compares two learners' mean deviations (over the run's tasks, then over seeds) at a
point of the sweeps, or one learner across a sweep. A claim *holds* when the means are ordered
as the claim says; the number of seeds in which the paired comparison holds (same ground truth,
same demonstrations) is reported next to it, so a reader sees how robust the ordering is.
:data:`CLAIMS` maps a line-up's name to its claims.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ...exceptions import ValidationError
from ...files import write_text_atomic
from .learner_names import (FACTORIAL, FACTORIAL_FEATURES, FACTORIAL_FEATURES_RANDOM_INIT, FACTORIAL_MCE,
                            FACTORIAL_MCE_FEATURES, FACTORIAL_MCE_FEATURES_RANDOM_INIT, FACTORIAL_RANDOM_INIT, FLAT, FLAT_FEATURES,
                            FLAT_FEATURES_FROM_EXAMPLES, FLAT_GROUND_TRUTH, FLAT_MCE, FLAT_MCE_FEATURES,
                            FLAT_PCA_FEATURES)
from .babyai import LINEUP as BABYAI_LINEUP, babyai_claims
from .tables import read_results

__all__ = ["CLAIMS_FILE", "CLAIMS", "evaluate_claims", "claims_markdown", "write_claims", "paper_claims", "objectworld_claims",
           "mce_claims", "per_task_claims"]


def _by_seed(rows, split, learner, n, m, column="deviation"):
    return {r["seed"]: r[column] for r in rows
            if r["split"] == split and r["learner"] == learner and r["n_tasks"] == n and r["demos_per_task"] == m}


def _fmt(values):
    v = np.array(list(values))
    return f"{v.mean():.2f} ± {v.std(ddof=1):.2f}" if v.size > 1 else f"{v.mean():.2f}"


def _less(rows, split, a, b, n, m, claim, source, column="deviation"):
    da, db = _by_seed(rows, split, a, n, m, column), _by_seed(rows, split, b, n, m, column)
    seeds = sorted(set(da) & set(db))
    if not seeds:
        return None
    wins = sum(da[s] < db[s] for s in seeds)
    ma, mb = np.mean([da[s] for s in seeds]), np.mean([db[s] for s in seeds])
    return dict(claim=claim, source=source, point=f"{n} tasks, {m} demos",
                measured=f"{a}: {_fmt(da[s] for s in seeds)}; {b}: {_fmt(db[s] for s in seeds)}",
                holds=bool(ma < mb), seeds=f"{wins}/{len(seeds)}")


def _decreasing(rows, split, learner, m, tasks, claim, source):
    means = []
    for n in tasks:
        d = _by_seed(rows, split, learner, n, m)
        if d:
            means.append((n, np.mean(list(d.values())), d))
    if len(means) < 2:
        return None
    (n0, m0, d0), (n1, m1, d1) = means[0], means[-1]
    seeds = sorted(set(d0) & set(d1))
    wins = sum(d1[s] < d0[s] for s in seeds)
    return dict(claim=claim, source=source, point=f"{m} demos, {n0} -> {n1} tasks",
                measured=", ".join(f"{n}: {v:.2f}" for n, v, _ in means), holds=bool(m1 < m0),
                seeds=f"{wins}/{len(seeds)}")


def _sweep_claims(rows, preset, split, a, b, claim, source, tasks_source=None):
    """``a`` beats ``b`` at every point of both sweeps but the default one (demos sweep first)."""
    n, m = preset.default_tasks, preset.default_demos
    out = [_less(rows, split, a, b, n, d, f"{claim} (demos sweep)", source) for d in sorted(preset.demos_sweep) if d != m]
    return out + [_less(rows, split, a, b, nn, m, f"{claim} (tasks sweep)", tasks_source or source)
                  for nn in sorted(preset.tasks_sweep) if nn != n]


def paper_claims(rows: Sequence[dict], preset: Any) -> list[dict | None]:
    """The claims of the paper's section 4 (line-up ``"paper"``)."""
    n, m = preset.default_tasks, preset.default_demos
    tasks = sorted(preset.tasks_sweep)
    out = [
        _less(rows, "train", FACTORIAL, FLAT, n, m, "train: factorial beats flat", "4.1, fig. 1"),
        _less(rows, "train", FACTORIAL, FLAT_PCA_FEATURES, n, m,
              "train: PCA features alone are not a good dictionary (factorial beats them)", "4.1, fn. 2, sec. 5"),
        _less(rows, "train", FACTORIAL, FACTORIAL_RANDOM_INIT, n, m,
              "train: PCA is an efficient initialisation (beats random init)", "fn. 2, fig. 1"),
        _less(rows, "train", FLAT_GROUND_TRUTH, FACTORIAL, n, m, "train: ground-truth features are the floor", "fig. 1"),
        _decreasing(rows, "train", FACTORIAL, m, tasks, "train: factorial improves with the number of tasks",
                    "4.1, fig. 1"),
    ]
    out += _sweep_claims(rows, preset, "train", FACTORIAL, FLAT, "train: factorial beats flat",
                         "fig. 1 caption: moderate demos per task", "fig. 1 caption: many tasks")
    out += [
        _less(rows, "test", FACTORIAL, FLAT, n, m, "test: factorial beats flat from scratch", "4.2, fig. 2"),
        _less(rows, "test", FACTORIAL, FLAT_PCA_FEATURES, n, m, "test: factorial beats flat, PCA features", "4.2"),
        _less(rows, "test", FACTORIAL, FLAT_FEATURES_FROM_EXAMPLES, n, m, "test: factorial beats flat, features from ex.",
              "4.2"),
        _less(rows, "test", FLAT_GROUND_TRUTH, FACTORIAL, n, m, "test: ground-truth features are the floor",
              "(our addition)"),
        _decreasing(rows, "test", FACTORIAL, m, tasks, "test: factorial improves with the number of training tasks",
                    "4.2, fig. 2"),
    ]
    return out + _sweep_claims(rows, preset, "test", FACTORIAL, FLAT, "test: factorial beats flat", "fig. 2")


#: the "where" column of the claims made by this project's line-ups rather than by the paper
OBJECTWORLD_SOURCE = "(Objectworld benchmark)"
MCE_SOURCE = "(MCE line-up)"


def objectworld_claims(rows: Sequence[dict], preset: Any) -> list[dict | None]:
    """The claims on the multi-task Objectworld (line-up ``"objectworld"``)."""
    n, m = preset.default_tasks, preset.default_demos
    tasks, source = sorted(preset.tasks_sweep), OBJECTWORLD_SOURCE
    out = []
    for split in ("train", "test"):
        out += [
            _less(rows, split, FACTORIAL_FEATURES, FLAT_FEATURES, n, m,
                  f"{split}: factorial on features beats flat on features", source),
            _less(rows, split, FACTORIAL_FEATURES, FLAT, n, m, f"{split}: factorial on features beats flat tabular",
                  source),
            _less(rows, split, FACTORIAL_FEATURES, FACTORIAL, n, m,
                  f"{split}: factorial on features beats factorial tabular", "(our addition)"),
            _less(rows, split, FLAT_GROUND_TRUTH, FACTORIAL_FEATURES, n, m,
                  f"{split}: the true primitives as features are the floor", "(our addition)"),
            _decreasing(rows, split, FACTORIAL_FEATURES, m, tasks,
                        f"{split}: factorial on features improves with the number of training tasks", source),
        ]
    out.insert(4, _less(rows, "train", FACTORIAL_FEATURES, FACTORIAL_FEATURES_RANDOM_INIT, n, m,
                        "train: PCA is an efficient initialisation on features (beats random init)", "(paper's fn. 2)"))
    return out + _sweep_claims(rows, preset, "test", FACTORIAL_FEATURES, FLAT_FEATURES,
                               "test: factorial on features beats flat on features", source)


def mce_claims(rows: Sequence[dict], preset: Any, flat: str = FLAT_MCE, fact: str = FACTORIAL_MCE) -> list[dict | None]:
    """The MCE claims: the factorial MCE learner ``fact`` beats the flat MCE learner ``flat``."""
    n, m = preset.default_tasks, preset.default_demos
    source = MCE_SOURCE
    out = [_less(rows, split, fact, flat, n, m, f"{split}: {fact} beats {flat}", source) for split in ("train", "test")]
    out.append(_decreasing(rows, "test", fact, m, sorted(preset.tasks_sweep),
                           f"test: {fact} improves with the number of training tasks", source))
    return out + _sweep_claims(rows, preset, "test", fact, flat, f"test: {fact} beats {flat}", source)


def per_task_claims(rows: Sequence[dict], preset: Any) -> list[dict | None]:
    """The claims on the world with a map per task (line-up ``"objectworld-per-task"``).

    Factorial on features beats flat on features, for policy matching and MCE, on the tasks'
    own maps (``deviation``) and on fresh maps (``new_maps_deviation``), at the default point
    (test tasks: also along the tasks sweep); PCA beats random starts; the true primitives are
    the floor.
    """
    n, m = preset.default_tasks, preset.default_demos
    source, out = "(map per task)", []
    for fact, flat, rand in ((FACTORIAL_FEATURES, FLAT_FEATURES, FACTORIAL_FEATURES_RANDOM_INIT),
                             (FACTORIAL_MCE_FEATURES, FLAT_MCE_FEATURES, FACTORIAL_MCE_FEATURES_RANDOM_INIT)):
        for column, where in (("deviation", "own maps"), ("new_maps_deviation", "new maps")):
            out += [_less(rows, split, fact, flat, n, m, f"{split}, {where}: {fact} beats {flat}", source, column)
                    for split in ("train", "test")]
            out.append(_less(rows, "train", fact, rand, n, m, f"train, {where}: PCA start beats random init ({fact})",
                             "(paper's fn. 2)", column))
            out += [_less(rows, "test", fact, flat, nn, m, f"test, {where}: {fact} beats {flat} (tasks sweep)", source,
                          column) for nn in sorted(preset.tasks_sweep) if nn != n]
    return out + [_less(rows, split, FLAT_GROUND_TRUTH, FACTORIAL_FEATURES, n, m,
                        f"{split}, own maps: the true primitives as features are the floor", source)
                  for split in ("train", "test")]


#: the claims' file in a reproduce directory
CLAIMS_FILE = "claims.md"

#: line-up name -> (what the claims are, the function evaluating them on result rows)
CLAIMS: dict[str, tuple[str, Callable[[Sequence[dict], Any], list]]] = {
    "paper": ("Paper claims", paper_claims),
    "objectworld": ("Objectworld claims", objectworld_claims),
    "paper+mce": ("Paper and MCE claims", lambda rows, preset: paper_claims(rows, preset) + mce_claims(rows, preset)),
    "objectworld+mce": ("Objectworld and MCE claims",
                        lambda rows, preset: objectworld_claims(rows, preset)
                        + mce_claims(rows, preset, FLAT_MCE_FEATURES, FACTORIAL_MCE_FEATURES)),
    "objectworld-per-task": ("Claims with a map per task", per_task_claims),
    BABYAI_LINEUP.name: ("BabyAI claims", babyai_claims),
}


def evaluate_claims(rows: Sequence[dict], preset: Any) -> list[dict]:
    """The claims of the preset's line-up (:data:`CLAIMS`) evaluated on result rows.

    Parameters
    ----------
    rows : list of dict
        Rows of results.csv (one h_solver).
    preset : Preset

    Returns
    -------
    list of dict
        ``claim``, ``source`` (where it is made), ``point``, ``measured`` (mean ± std over
        seeds), ``holds`` (bool) and ``seeds`` (paired wins / seeds); the claims whose learners
        or points are not in the rows are left out.
    """
    try:
        _, claims = CLAIMS[preset.lineup]
    except KeyError:
        raise ValidationError(f"no claims for the line-up {preset.lineup!r}; claims exist for {', '.join(CLAIMS)}") from None
    return [c for c in claims(rows, preset) if c is not None]


def claims_markdown(claims: Sequence[dict]) -> str:
    """A markdown table of :func:`evaluate_claims`'s output."""
    lines = ["| claim | where | point | ours: mean deviation ± std over seeds | holds | seeds |",
             "|---|---|---|---|---|---|"]
    for c in claims:
        lines.append(f"| {c['claim']} | {c['source']} | {c['point']} | {c['measured']} | "
                     f"{'yes' if c['holds'] else '**no**'} | {c['seeds']} |")
    return "\n".join(lines) + "\n"


def write_claims(out: str | os.PathLike, preset: Any) -> str:
    """Evaluate the claims on ``out/results.csv`` and write ``out/claims.md``; returns its path."""
    rows = read_results(out)
    solver = sorted({r["h_solver"] for r in rows})[0]
    rows = [r for r in rows if r["h_solver"] == solver]
    path = os.path.join(out, CLAIMS_FILE)
    title = CLAIMS.get(preset.lineup, ("Claims",))[0]
    write_text_atomic(path, f"# {title} vs this run (H-step solver: {solver})\n\n"
                 "Deviation from the optimal score (eq. 13), lower is better. *holds*: the means are ordered as "
                 "the claim says; *seeds*: seeds in which the paired comparison holds.\n\n"
                 + claims_markdown(evaluate_claims(rows, preset)))
    return path

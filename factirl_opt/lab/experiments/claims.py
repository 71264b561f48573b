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
from .learner_names import (ADAPTIVE, ADAPTIVE_FEATURES, FACTORIAL, FACTORIAL_FEATURES, FACTORIAL_FEATURES_RANDOM_INIT, FACTORIAL_MCE,
                            FACTORIAL_MCE_FEATURES, FACTORIAL_MCE_FEATURES_RANDOM_INIT, FACTORIAL_RANDOM_INIT, FLAT, FLAT_FEATURES,
                            FLAT_FEATURES_FROM_EXAMPLES, FLAT_GROUND_TRUTH, FLAT_MCE, FLAT_MCE_FEATURES,
                            FLAT_PCA_FEATURES)
from .babyai import LINEUP as BABYAI_LINEUP, SHARING_LINEUP as BABYAI_SHARING_LINEUP, babyai_claims
from .tables import read_results

__all__ = ["CLAIMS_FILE", "CLAIMS", "evaluate_claims", "claims_markdown", "paired_reason", "write_claims", "paper_claims", "objectworld_claims",
           "mce_claims", "per_task_claims", "sharing_claims", "SHARING_MARGINS", "sharing_verdicts"]


def _by_seed(rows, split, learner, n, m, column="deviation"):
    return {r["seed"]: r[column] for r in rows
            if r["split"] == split and r["learner"] == learner and r["n_tasks"] == n and r["demos_per_task"] == m}


def _fmt(values):
    v = np.array(list(values))
    return f"{v.mean():.2f} ± {v.std(ddof=1):.2f}" if v.size > 1 else f"{v.mean():.2f}"


def paired_reason(first: str, second: str, differences: Sequence[float], wins: int, better: str = "lower") -> str:
    """Why a claim that ``first`` is ``better`` than ``second`` does not hold, read off the seeds'
    paired differences (``first - second``, one per seed) and the seeds where it holds (``wins``).

    A *tie* when the mean difference is within the paired differences' standard deviation over
    seeds (a single seed: within 5% of the second's value is not known, so it is called
    *reversed*); *reversed* when it goes the other way on every seed; *mixed* otherwise.
    """
    d = np.asarray(differences, dtype=float)
    mean = float(d.mean())
    spread = float(d.std(ddof=1)) if d.size > 1 else 0.0
    if d.size > 1 and abs(mean) <= spread:
        return (f"a tie: {first} - {second} = {mean:+.2f} on average, within the seeds' paired s.d. "
                f"{spread:.2f}")
    if wins == 0:
        return (f"reversed on every seed: {first} - {second} = {mean:+.2f} on average"
                + (f" (paired s.d. {spread:.2f})" if d.size > 1 else " (one seed)"))
    return f"mixed: {better} on {wins}/{d.size} seeds, {first} - {second} = {mean:+.2f} on average (paired s.d. {spread:.2f})"


def _less(rows, split, a, b, n, m, claim, source, column="deviation", cause=None):
    """``a``'s mean is below ``b``'s; ``cause``: what is known to make it fail (added to the reason)."""
    da, db = _by_seed(rows, split, a, n, m, column), _by_seed(rows, split, b, n, m, column)
    seeds = sorted(set(da) & set(db))
    if not seeds:
        return None
    wins = sum(da[s] < db[s] for s in seeds)
    ma, mb = np.mean([da[s] for s in seeds]), np.mean([db[s] for s in seeds])
    return dict(claim=claim, source=source, point=f"{n} tasks, {m} demos",
                measured=f"{a}: {_fmt(da[s] for s in seeds)}; {b}: {_fmt(db[s] for s in seeds)}",
                holds=bool(ma < mb), seeds=f"{wins}/{len(seeds)}",
                paired=(a, b, [da[s] - db[s] for s in seeds], wins, "lower"), cause=cause)


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
                seeds=f"{wins}/{len(seeds)}", paired=(f"{n1} tasks", f"{n0} tasks", [d1[s] - d0[s] for s in seeds], wins))


def _scarce_data(preset, n, m):
    """The known cause of a factorial learner losing to the flat one at a sweep point with less data."""
    if n >= preset.default_tasks and m >= preset.default_demos:
        return None
    return (f"less training data than at the default point ({n} tasks x {m} demonstrations of {preset.demo_length} "
            f"steps for k = {preset.n_primitives} primitives): results/README.md, 'Where we differ from the paper'")


def _sweep_claims(rows, preset, split, a, b, claim, source, tasks_source=None):
    """``a`` beats ``b`` at every point of both sweeps but the default one (demos sweep first)."""
    n, m = preset.default_tasks, preset.default_demos
    out = [_less(rows, split, a, b, n, d, f"{claim} (demos sweep)", source, cause=_scarce_data(preset, n, d))
           for d in sorted(preset.demos_sweep) if d != m]
    return out + [_less(rows, split, a, b, nn, m, f"{claim} (tasks sweep)", tasks_source or source,
                        cause=_scarce_data(preset, nn, m))
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
SHARING_SOURCE = "(which-learner line-up)"


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


#: how far the adaptive learner may be from the better of flat and factorial and still count as
#: "no worse": 10% of the better deviation; 0.05 of success rate
SHARING_MARGINS = {"deviation": 0.10, "success_rate": 0.05}


def _sharing_learners(rows):
    """``(flat, factorial, adaptive)`` names of a "which learner when" run: tabular or on features."""
    names = {r["learner"] for r in rows}
    return (FLAT, FACTORIAL, ADAPTIVE) if ADAPTIVE in names else (FLAT_FEATURES, FACTORIAL_FEATURES, ADAPTIVE_FEATURES)


def sharing_verdicts(rows: Sequence[dict], split: str = "test", column: str = "deviation") -> list[dict]:
    """Per point and seed of a "which learner when" run: the three learners' ``column`` and how the
    adaptive learner compares with the better of flat and factorial.

    ``column="deviation"`` (lower is better): the adaptive learner is *no worse* when its deviation
    is at most ``(1 + SHARING_MARGINS["deviation"])`` times the better one; ``"success_rate"``
    (higher is better; BabyAI): when it is at least the better one minus
    ``SHARING_MARGINS["success_rate"]``. It *beats both* when it is strictly better than both.

    Returns
    -------
    list of dict
        ``n_tasks``, ``demos_per_task``, ``seed``, ``flat``, ``factorial``, ``adaptive`` (the
        values), ``best`` (the better of flat and factorial), ``no_worse``, ``beats_both``;
        points where one of the three is missing are left out.
    """
    flat, fact, auto = _sharing_learners(rows)
    lower = column != "success_rate"
    margin = SHARING_MARGINS["success_rate" if not lower else "deviation"]
    values: dict = {}
    for r in rows:
        if r["split"] == split and r["learner"] in (flat, fact, auto) and r.get(column) is not None:
            values.setdefault((r["n_tasks"], r["demos_per_task"], r["seed"]), {})[r["learner"]] = float(r[column])
    out = []
    for (n, m, seed), v in sorted(values.items()):
        if len(v) < 3:
            continue
        a, b, c = v[flat], v[fact], v[auto]
        best = min(a, b) if lower else max(a, b)
        no_worse = c <= (1 + margin) * best if lower else c >= best - margin
        beats = c < best if lower else c > best
        out.append(dict(n_tasks=n, demos_per_task=m, seed=seed, flat=a, factorial=b, adaptive=c, best=best,
                        no_worse=bool(no_worse), beats_both=bool(beats)))
    return out


def sharing_claims(rows: Sequence[dict], preset: Any) -> list[dict | None]:
    """The claims of a "which learner when" run (line-ups ``"sharing"``, ``"objectworld-sharing"``,
    ``"objectworld-per-task-sharing"``, ``"babyai-sharing"``), at every point of the sweeps, on the
    test tasks (one demonstration each): the adaptive learner is no worse than the better of flat
    and factorial (within :data:`SHARING_MARGINS`), and where it beats both. ``holds``: on every
    seed; ``seeds``: the seeds where it does. BabyAI runs are judged on the success rate in the
    environment, the others on the deviation."""
    column = "success_rate" if any(r.get("success_rate") is not None for r in rows) else "deviation"
    flat, fact, auto = _sharing_learners(rows)
    what = "success rate" if column == "success_rate" else "deviation"
    within = (f"{SHARING_MARGINS['success_rate']:.2f}" if column == "success_rate"
              else f"{SHARING_MARGINS['deviation']:.0%}")
    by_point: dict = {}
    for v in sharing_verdicts(rows, "test", column):
        by_point.setdefault((v["n_tasks"], v["demos_per_task"]), []).append(v)
    out: list[dict | None] = []
    for (n, m), vs in sorted(by_point.items()):
        measured = (f"{auto}: {_fmt(v['adaptive'] for v in vs)}; {flat}: {_fmt(v['flat'] for v in vs)}; "
                    f"{fact}: {_fmt(v['factorial'] for v in vs)} ({what})")
        for key, claim in (("no_worse", f"test: {auto} is within {within} of the better of {flat} and {fact}"),
                           ("beats_both", f"test: {auto} beats both {flat} and {fact}")):
            wins = sum(v[key] for v in vs)
            failed = [v for v in vs if not v[key]]
            reason = "; ".join(
                f"seed {v['seed']}: " + (f"the same {v['best']:.2f} as {name}" if v["adaptive"] == v["best"]
                                         else f"{auto} {v['adaptive']:.2f} against {name} {v['best']:.2f}")
                for v in failed for name in [flat if v["best"] == v["flat"] else fact])
            out.append(dict(claim=claim, source=SHARING_SOURCE, point=f"{n} tasks, {m} demos", measured=measured,
                            holds=bool(wins == len(vs)), seeds=f"{wins}/{len(vs)}", reason=reason))
    return out


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
    "sharing": ("Which learner when", sharing_claims),
    "objectworld-sharing": ("Which learner when", sharing_claims),
    "objectworld-per-task-sharing": ("Which learner when", sharing_claims),
    BABYAI_SHARING_LINEUP.name: ("Which learner when", sharing_claims),
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
        seeds), ``holds`` (bool), ``seeds`` (paired wins / seeds) and ``reason`` (empty when it
        holds; else how it fails, :func:`paired_reason`, and a known cause); the claims whose learners
        or points are not in the rows are left out.
    """
    try:
        _, claims = CLAIMS[preset.lineup]
    except KeyError:
        raise ValidationError(f"no claims for the line-up {preset.lineup!r}; claims exist for {', '.join(CLAIMS)}") from None
    out = [c for c in claims(rows, preset) if c is not None]
    for c in out:  # a claim gives its reason, or its paired comparison (and a known cause) to read it from
        paired, cause = c.pop("paired", None), c.pop("cause", None)
        if "reason" not in c:
            reason = "" if c["holds"] or paired is None else paired_reason(*paired)
            c["reason"] = reason + (f"; {cause}" if reason and cause else "")
    return out


def claims_markdown(claims: Sequence[dict]) -> str:
    """A markdown table of :func:`evaluate_claims`'s output."""
    """A markdown table of :func:`evaluate_claims`'s output; a claim that does not hold gives its reason
    (``reason``: how it fails on the seeds, and a known cause where the line-up names one)."""
    lines = ["| claim | where | point | ours: mean deviation ± std over seeds | holds | seeds | why not |",
             "|---|---|---|---|---|---|---|"]
    for c in claims:
        if not c["holds"] and not c.get("reason"):
            raise ValidationError(f"the claim {c['claim']!r} at {c['point']} does not hold and gives no reason")
        lines.append(f"| {c['claim']} | {c['source']} | {c['point']} | {c['measured']} | "
                     f"{'yes' if c['holds'] else '**no**'} | {c['seeds']} | {'' if c['holds'] else c['reason']} |")
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

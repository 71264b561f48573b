"""The result tables of a sweep: tidy CSV files written from run records, and read back.

::

    OUT/results.csv   one row per (run, split, learner); deterministic columns only
    OUT/summary.csv   mean and standard deviation over seeds per (split, learner, point, solver)

In a world with a map per task, results.csv and summary.csv have two more columns, the scores
on fresh maps (``new_maps_deviation``, ``new_maps_deviation_std``; summary: their mean and
standard deviation over seeds, ``new_maps_deviation_mean``, ``new_maps_deviation_std``).
    OUT/timings.csv   fit time of every learner in every run (varies from run to run)
    OUT/figure3.json  value functions of 4 test tasks (default point, first seed)

In a world scored in its environment (BabyAI, :mod:`.babyai`), results.csv has three more
columns, ``success_rate``, ``bot_success_rate`` and ``random_success_rate`` (:data:`ENVIRONMENT_COLUMNS`),
and summary.csv their mean and standard deviation over seeds (``success_rate_mean``, ...).

Rows are sorted (split, solver, n_tasks, demos_per_task, learner in line-up order, seed), so
the tables depend only on the set of run records, not on the order the runs finished in.
Every file is written atomically (:func:`factirl_opt.files.atomic_write`: a temporary file in
the same directory, fsynced, then renamed) with the usual permissions (``0o666`` minus the umask).
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from ...exceptions import ValidationError
from ...files import open_for_reading, os_error, write_text_atomic
from .per_task import NEW_MAP_COLUMNS
from .presets import Preset

__all__ = [
    "RESULT_COLUMNS",
    "SUMMARY_COLUMNS",
    "TIMING_COLUMNS",
    "NEW_MAP_RESULT_COLUMNS",
    "NEW_MAP_SUMMARY_COLUMNS",
    "write_tables",
    "read_csv",
    "read_results",
    "load_preset_from_manifest",
]

SPLITS = ("train", "test")
RESULT_COLUMNS = (
    "split", "learner", "n_tasks", "demos_per_task", "seed", "h_solver",
    "n_scored_tasks", "deviation", "deviation_std", "loss", "n_evaluations",
)
SUMMARY_COLUMNS = ("split", "learner", "n_tasks", "demos_per_task", "h_solver", "n_seeds", "deviation_mean", "deviation_std")
TIMING_COLUMNS = ("split", "learner", "n_tasks", "demos_per_task", "seed", "h_solver", "fit_time")
#: the columns added in a world with a map per task (:mod:`.per_task`): the scores on fresh maps
NEW_MAP_RESULT_COLUMNS = RESULT_COLUMNS + NEW_MAP_COLUMNS
NEW_MAP_SUMMARY_COLUMNS = SUMMARY_COLUMNS + ("new_maps_deviation_mean", "new_maps_deviation_std")
#: the columns of a world scored in its environment (BabyAI): success rates of the learnt, the bot's and a random policy
ENVIRONMENT_COLUMNS = ("success_rate", "bot_success_rate", "random_success_rate")
ENVIRONMENT_RESULT_COLUMNS = RESULT_COLUMNS + ENVIRONMENT_COLUMNS
ENVIRONMENT_SUMMARY_COLUMNS = SUMMARY_COLUMNS + tuple(f"{c}_{s}" for c in ENVIRONMENT_COLUMNS for s in ("mean", "std"))
INT_COLUMNS = ("n_tasks", "demos_per_task", "seed", "n_scored_tasks", "n_evaluations", "n_seeds")
FLOAT_COLUMNS = ("deviation", "deviation_std", "loss", "fit_time", "deviation_mean", *NEW_MAP_SUMMARY_COLUMNS[-2:],
                 *NEW_MAP_COLUMNS, *ENVIRONMENT_COLUMNS, *ENVIRONMENT_SUMMARY_COLUMNS[len(SUMMARY_COLUMNS):])


def _csv_text(rows, columns):
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(columns), lineterminator="\n", extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow({c: repr(r[c]) if isinstance(r[c], float) else r[c] for c in columns})
    return buf.getvalue()


def read_csv(path: str | os.PathLike) -> list[dict[str, Any]]:
    """Rows of a table written by :func:`write_tables`, with numbers parsed back.

    Raises
    ------
    ValidationError
        If the file is not such a table (a missing column or value, an unparsable number, a
        truncated last line), naming the file and the line.
    PersistenceError
        If the file cannot be opened (missing, a directory, no permission), naming it and the cause.
    """
    path = os.fspath(path)
    out = []
    with open_for_reading(path, binary=False, newline="") as fh:  # PersistenceError: missing, a directory, ...
        reader = csv.DictReader(fh)
        try:
            if tuple(reader.fieldnames or ()) not in (RESULT_COLUMNS, SUMMARY_COLUMNS, TIMING_COLUMNS,
                                                      NEW_MAP_RESULT_COLUMNS, NEW_MAP_SUMMARY_COLUMNS,
                                                      ENVIRONMENT_RESULT_COLUMNS, ENVIRONMENT_SUMMARY_COLUMNS):
                raise ValueError(f"unexpected header {reader.fieldnames}")
            for r in reader:
                out.append(_parse_row(r))
        except (TypeError, ValueError, csv.Error) as exc:
            raise ValidationError(f"{path}, line {reader.line_num}: not a table written by `factirl-opt reproduce` "
                                  f"({exc}); rerun the command to rewrite it") from None
    return out


def _parse_row(r):
    if None in r or None in r.values():
        raise ValueError(f"expected {len(r) - (None in r)} comma-separated values")
    for c, v in r.items():
        if c in INT_COLUMNS:
            r[c] = int(v)
        elif c in FLOAT_COLUMNS:
            r[c] = float(v)
    return r


def _order(learners):
    """Sort key of the rows, learners in line-up order (``{(split, name): position}``)."""

    def key(row):
        return (SPLITS.index(row["split"]), row["h_solver"], row["n_tasks"], row["demos_per_task"],
                learners[row["split"], row["learner"]], row.get("seed", 0))

    return key


def _mean_std(v):
    return float(np.mean(v)), float(np.std(v, ddof=1)) if len(v) > 1 else 0.0


def _summary(rows, new_maps=False):
    """Mean and std over seeds per (split, learner, point, solver); with ``new_maps``, of the fresh-map scores too."""
    groups = {}
    for r in rows:
        groups.setdefault((r["split"], r["learner"], r["n_tasks"], r["demos_per_task"], r["h_solver"]), []).append(r)
    out = []
    for (s, lr, n, m, h), g in groups.items():
        row = dict(split=s, learner=lr, n_tasks=n, demos_per_task=m, h_solver=h, n_seeds=len(g))
        row["deviation_mean"], row["deviation_std"] = _mean_std([r["deviation"] for r in g])
        if new_maps:
            row["new_maps_deviation_mean"], row["new_maps_deviation_std"] = _mean_std([r["new_maps_deviation"] for r in g])
        out.append(row)
    return out


def _environment_summary(rows, group):
    """Mean and standard deviation over seeds of the environment columns of a summary row's runs."""
    fields = ("split", "learner", "n_tasks", "demos_per_task", "h_solver")
    runs = [r for r in rows if all(r[f] == group[f] for f in fields)]
    out = {}
    for c in ENVIRONMENT_COLUMNS:
        v = [r[c] for r in runs]
        out[f"{c}_mean"], out[f"{c}_std"] = float(np.mean(v)), float(np.std(v, ddof=1)) if len(v) > 1 else 0.0
    return out


def write_tables(out: str | os.PathLike, records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Write results.csv, summary.csv, timings.csv (and figure3.json) from run records.

    A figure3.json of earlier records is removed when no record has value maps.

    Parameters
    ----------
    out : str or path
    records : list of dict
        Run records (:func:`.runner.run_one`); their rows give the learners' order.

    Returns
    -------
    list of dict
        The result rows, sorted.
    """
    out = os.fspath(out)
    learners: dict[tuple[str, str], int] = {}
    for rec in records:
        for r in rec["rows"]:
            learners.setdefault((r["split"], r["learner"]), len(learners))
    key = _order(learners)
    rows = sorted((r for rec in records for r in rec["rows"]), key=key)
    timings = sorted((r for rec in records for r in rec["timings"]), key=key)
    new_maps = any(NEW_MAP_COLUMNS[0] in r for r in rows)  # a world with a map per task: fresh-map scores
    summary = sorted(_summary(rows, new_maps), key=key)
    result_columns: tuple[str, ...] = NEW_MAP_RESULT_COLUMNS if new_maps else RESULT_COLUMNS
    summary_columns: tuple[str, ...] = NEW_MAP_SUMMARY_COLUMNS if new_maps else SUMMARY_COLUMNS
    if rows and ENVIRONMENT_COLUMNS[0] in rows[0]:  # a world scored in its environment
        summary = [dict(s, **_environment_summary(rows, s)) for s in summary]
        result_columns, summary_columns = ENVIRONMENT_RESULT_COLUMNS, ENVIRONMENT_SUMMARY_COLUMNS
    write_text_atomic(os.path.join(out, "results.csv"), _csv_text(rows, result_columns))
    write_text_atomic(os.path.join(out, "summary.csv"), _csv_text(summary, summary_columns))
    write_text_atomic(os.path.join(out, "timings.csv"), _csv_text(timings, TIMING_COLUMNS))
    fig3 = sorted((rec for rec in records if "figure3" in rec), key=lambda rec: (rec["spec"]["h_solver"], rec["spec"]["seed"]))
    path = os.path.join(out, "figure3.json")
    if fig3:
        write_text_atomic(path, json.dumps(fig3[0]["figure3"]))
    else:
        try:
            os.unlink(path)
        except FileNotFoundError:
            pass
        except OSError as exc:
            raise os_error(exc, "remove the stale output", path) from exc
    return rows


def read_results(out: str | os.PathLike) -> list[dict[str, Any]]:
    """The rows of ``out/results.csv``, checked against the runs ``out/manifest.json`` describes.

    Raises
    ------
    ValidationError
        If the table is not readable (:func:`read_csv`), or has fewer or more rows than the
        manifest's runs times the line-up's learners (a table cut at a line boundary).
    """
    out = os.fspath(out)
    path = os.path.join(out, "results.csv")
    if not os.path.exists(path):
        raise ValidationError(f"{path} not found; run `factirl-opt reproduce --out {out}` first")
    rows = read_csv(path)
    manifest = _read_manifest(out)
    runs, lineup = manifest.get("runs"), manifest.get("lineup")
    if isinstance(runs, list) and isinstance(lineup, list) and len(rows) != len(runs) * len(lineup):
        raise ValidationError(f"{path} has {len(rows)} rows, but the manifest describes {len(runs)} runs x "
                              f"{len(lineup)} learners = {len(runs) * len(lineup)}: truncated or from another sweep; "
                              f"rerun `factirl-opt reproduce --out {out}` to rewrite it")
    return rows


def _read_manifest(out):
    path = os.path.join(os.fspath(out), "manifest.json")
    try:
        with open(path) as fh:
            manifest = json.load(fh)
        if not isinstance(manifest, dict):
            raise ValueError("not a JSON object")
        return manifest
    except (OSError, ValueError) as exc:
        raise ValidationError(f"{path} is missing or unreadable ({exc}); run `factirl-opt reproduce --out DIR` first") from None


def load_preset_from_manifest(out: str | os.PathLike) -> Preset:
    """The :class:`Preset` recorded in ``out/manifest.json``."""
    manifest = _read_manifest(out)
    try:
        return Preset.from_dict(manifest["preset"])
    except (KeyError, TypeError, AttributeError) as exc:
        raise ValidationError(f"{os.path.join(os.fspath(out), 'manifest.json')} records no preset ({exc!r}); "
                              "run `factirl-opt reproduce --out DIR` first") from None

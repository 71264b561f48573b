"""The run store of a sweep directory: run records, their provenance and checksums, the lock, the manifest.

Run records (``OUT/runs/<key>.json``)
    One JSON file per finished run: the run's ``key``, ``spec``, ``preset``, result ``rows``,
    ``timings`` and optional ``figure3`` (:func:`.runner.run_one`), plus

    - ``provenance``: what determined the run beyond its spec: the record ``format``, the
      preset's ``fingerprint``, the learner ``lineup`` (``[split, name, builder version]``
      rows) and the ``code`` stamp (:func:`code_stamp`); and ``computed_by``, the id of the
      invocation that computed it (see the manifest);
    - ``checksum``: ``sha256`` of the canonical JSON of everything else in the record.

    A record is reused only if it parses, its checksum matches, its structure is that of a run
    record (rows and timings of every learner of the line-up, with numbers where numbers
    belong), and its key and provenance are those of the planned run. Any other record is
    *rejected*: reported (a :class:`RejectedRunWarning`, and the manifest's ``rejected``) and
    recomputed.

Code stamp
    ``factirl_opt.__version__``, the versions of numpy and scipy, and the sha256 of the source
    of every module of the ``factirl_opt`` and ``solvers`` packages except those that cannot
    change a run's numbers (:data:`STAMP_EXCLUDED`: the command line, the benchmarks, tables,
    claims, figures, this store, the worker pool, model persistence, the Gymnasium adapter).
    Any other edit of the source, a docstring included, makes the cached runs recomputed:
    conservative, never stale.

Lock (``OUT/.lock``)
    Created atomically (a complete temporary file hard-linked to the lock's name, which fails
    if the lock exists) and holding the writer's pid, host and process start time. A second sweep into the same directory is refused with a clear message while the
    holder lives; a lock left by a dead process (same host, pid gone or reused) is stale and
    replaced.

Manifest (``OUT/manifest.json``)
    The last invocation's settings (preset, seeds, solvers, jobs, command, versions, wall time)
    for compatibility, plus ``runs`` (every run of the tables with the invocation that computed
    it), ``invocations`` (the history of every invocation into the directory), ``substitutions``
    (solvers the line-up's learners take instead of those named), ``rejected`` and
    ``other_records`` (record files in ``runs/`` that are not part of these tables, e.g. other
    seeds).
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import importlib.metadata as md
import json
import os
import platform
import secrets
import socket
import time
import warnings
from collections.abc import Iterator
from typing import Any

from ...exceptions import PersistenceError, ValidationError
from ...files import FILE_MODE, os_error, write_text_atomic
from .tables import FLOAT_COLUMNS, INT_COLUMNS, RESULT_COLUMNS, TIMING_COLUMNS

__all__ = [
    "RECORD_FORMAT",
    "STAMP_EXCLUDED",
    "RejectedRunWarning",
    "OutputLockedError",
    "code_stamp",
    "expected_provenance",
    "seal",
    "check_record",
    "load_record",
    "load_records",
    "write_record",
    "locked",
    "new_invocation",
    "write_manifest",
]

#: version of the record layout
RECORD_FORMAT = 2
#: source files (relative to the repository root) that cannot change a run's numbers
STAMP_EXCLUDED = (
    "factirl_opt/lab/cli.py",
    "factirl_opt/lab/bench.py",
    "factirl_opt/lab/benchmarks/",
    "factirl_opt/lab/experiments/tables.py",
    "factirl_opt/lab/experiments/claims.py",
    "factirl_opt/lab/experiments/figures.py",
    "factirl_opt/lab/experiments/store.py",
    "factirl_opt/lab/experiments/workers.py",
    "factirl_opt/persistence/",
    "factirl_opt/adapters/gymnasium.py",
    "factirl_opt/_deprecation.py",
)
LOCK_NAME = ".lock"


class RejectedRunWarning(UserWarning):
    """A cached run record was rejected (and will be recomputed)."""


class OutputLockedError(ValidationError):
    """Another live sweep is writing to the output directory."""


# --- provenance ---------------------------------------------------------------------------


def _source_files():
    import factirl_opt
    import solvers

    root = os.path.dirname(os.path.dirname(os.path.abspath(factirl_opt.__file__)))
    for package in (factirl_opt, solvers):
        top = os.path.dirname(os.path.abspath(package.__file__))
        for d, dirs, files in os.walk(top):
            dirs[:] = sorted(x for x in dirs if x != "__pycache__")
            for f in sorted(files):
                if f.endswith(".py"):
                    rel = os.path.relpath(os.path.join(d, f), root).replace(os.sep, "/")
                    if not any(rel == x or (x.endswith("/") and rel.startswith(x)) for x in STAMP_EXCLUDED):
                        yield rel, os.path.join(d, f)


@functools.lru_cache(maxsize=1)
def code_stamp() -> dict[str, str]:
    """What identifies the code that computes runs (see the module docstring).

    Returns
    -------
    dict
        ``factirl_opt`` (version), ``numpy``, ``scipy`` (versions) and ``source_sha256``.
    """
    import numpy
    import scipy

    import factirl_opt

    h = hashlib.sha256()
    for rel, path in _source_files():
        with open(path, "rb") as fh:
            h.update(rel.encode() + b"\0" + fh.read() + b"\0")
    return dict(factirl_opt=factirl_opt.__version__, numpy=numpy.__version__, scipy=scipy.__version__,
                source_sha256=h.hexdigest())


def expected_provenance(preset: Any, lineup: Any) -> dict[str, Any]:
    """The provenance a reusable record of this preset and line-up must carry (``computed_by`` aside)."""
    return dict(format=RECORD_FORMAT, preset_fingerprint=preset.fingerprint(), lineup=lineup.fingerprint(),
                code=code_stamp())


def _checksum(record):
    body = {k: v for k, v in record.items() if k != "checksum"}
    return "sha256:" + hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def seal(record: dict[str, Any], provenance: dict[str, Any], invocation_id: str) -> dict[str, Any]:
    """The record with its provenance (computed by ``invocation_id``) and checksum added."""
    record = dict(record, provenance=dict(provenance, computed_by=invocation_id))
    record.pop("checksum", None)
    record["checksum"] = _checksum(record)
    return record


# --- checking records ---------------------------------------------------------------------


def _check_row(row, columns, where):
    if not isinstance(row, dict):
        raise ValueError(f"{where} is {type(row).__name__}, not an object")
    missing = [c for c in columns if c not in row]
    if missing:
        raise ValueError(f"{where} lacks {', '.join(missing)}")
    for c in columns:
        v = row[c]
        if c in INT_COLUMNS:
            ok = isinstance(v, int) and not isinstance(v, bool)
        elif c in FLOAT_COLUMNS:
            ok = isinstance(v, (int, float)) and not isinstance(v, bool)
        else:
            ok = isinstance(v, str)
        if not ok:
            raise ValueError(f"{where}[{c!r}] is {v!r}")


def check_record(record: Any, lineup: Any) -> None:
    """Raise ValueError naming the first structural defect of a run record (None if sound)."""
    if not isinstance(record, dict):
        raise ValueError(f"the record is {type(record).__name__}, not an object")
    for field, kind in (("key", str), ("spec", dict), ("preset", dict), ("rows", list), ("timings", list),
                        ("provenance", dict)):
        if not isinstance(record.get(field), kind):
            what = "missing" if field not in record else f"a {type(record[field]).__name__}"
            raise ValueError(f"'{field}' is {what}, not a {kind.__name__}")
    learners = [(lr.split, lr.name) for lr in lineup.learners]
    for field, columns in (("rows", RESULT_COLUMNS), ("timings", TIMING_COLUMNS)):
        for i, row in enumerate(record[field]):
            _check_row(row, columns, f"{field}[{i}]")
        found = [(r["split"], r["learner"]) for r in record[field]]
        if found != learners:
            raise ValueError(f"'{field}' has learners {found}, the line-up {lineup.name!r} has {learners}")
    fig = record.get("figure3")
    if fig is not None:
        needed = ("grid_size", "seed", "true", "demos", *lineup.value_maps)
        if not isinstance(fig, dict) or any(not isinstance(fig.get(k), (list, int)) for k in needed):
            raise ValueError(f"'figure3' is not a value-map record with {', '.join(needed)}")


def _provenance_mismatch(found, expected):
    if not isinstance(found, dict):
        return "no provenance"
    for field, what in (("format", "record format"), ("preset_fingerprint", "preset"), ("lineup", "learner line-up")):
        if found.get(field) != expected[field]:
            return f"another {what} ({found.get(field)!r}, expected {expected[field]!r})"
    code, want = found.get("code"), expected["code"]
    if code != want:
        diff = [k for k in want if not isinstance(code, dict) or code.get(k) != want[k]]
        return f"made by other code ({', '.join(diff) or 'stamp'} differ)"
    return None


def load_record(path: str, key: str, expected: dict[str, Any], lineup: Any) -> tuple[dict | None, str | None]:
    """Load a cached run record and check it.

    Returns
    -------
    (record, reason)
        ``(record, None)`` if it can be reused; ``(None, None)`` if there is no file;
        ``(None, reason)`` if it is rejected.
    """
    try:
        with open(path) as fh:
            text = fh.read()
    except FileNotFoundError:
        return None, None
    except OSError as exc:
        return None, f"unreadable ({exc.strerror})"
    try:
        rec = json.loads(text)
    except ValueError as exc:
        return None, f"truncated or not JSON ({exc})"
    if not isinstance(rec, dict) or "checksum" not in rec:
        return None, "no checksum (made by older code, or not a run record)"
    if rec["checksum"] != _checksum(rec):
        return None, "checksum mismatch (edited or corrupted)"
    try:
        check_record(rec, lineup)
    except ValueError as exc:
        return None, f"malformed: {exc}"
    if rec["key"] != key:
        return None, f"the record of another run ({rec['key']!r})"
    mismatch = _provenance_mismatch(rec["provenance"], expected)
    return (None, mismatch) if mismatch else (rec, None)


def write_record(runs_dir: str, record: dict[str, Any]) -> None:
    """Write a sealed record to ``runs_dir/<key>.json`` (atomically: :func:`factirl_opt.files.atomic_write`)."""
    write_text_atomic(os.path.join(runs_dir, record["key"] + ".json"), json.dumps(record))


def load_records(runs_dir: str, keys: list[str], expected: dict[str, Any],
                 lineup: Any) -> tuple[dict[str, dict], list[str], dict[str, str]]:
    """Load the reusable records of ``keys``; returns (records by key, keys to compute, rejected {file: reason})."""
    records, todo, rejected = {}, [], {}
    for key in keys:
        rec, reason = load_record(os.path.join(runs_dir, key + ".json"), key, expected, lineup)
        if rec is not None:
            records[key] = rec
        else:
            todo.append(key)
            if reason is not None:
                rejected[key + ".json"] = reason
    if rejected:
        lines = "; ".join(f"{name}: {why}" for name, why in sorted(rejected.items()))
        warnings.warn(f"rejected {len(rejected)} run record(s) in {runs_dir}, recomputing them: {lines}",
                      RejectedRunWarning, stacklevel=3)
    return records, todo, rejected


# --- the lock -----------------------------------------------------------------------------


def _process_start(pid):
    """Start time of a process (clock ticks since boot, Linux), or None if unknown."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return int(fh.read().rsplit(")", 1)[1].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def _holder_alive(holder):
    if holder.get("host") != socket.gethostname():
        return True  # cannot tell: assume it lives
    pid = holder.get("pid")
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    except (TypeError, OverflowError, ValueError):
        return False
    start = holder.get("start")
    return start is None or _process_start(pid) in (None, start)


def _read_holder(path):
    try:
        with open(path) as fh:
            holder = json.load(fh)
        return holder if isinstance(holder, dict) else {}
    except (OSError, ValueError):
        return {}


def _create_lock(path, content):
    """Create ``path`` holding ``content`` if it does not exist; returns False if it exists.

    The content goes to a temporary file beside the lock, fsynced, then hard-linked to the lock's
    name (``os.link`` fails if the name exists): the lock appears complete or not at all, so a
    reader never sees a half-written holder. On a file system without hard links the lock is
    created with ``O_CREAT | O_EXCL`` and then written.
    """
    tmp = f"{path}.{os.getpid()}-{secrets.token_hex(4)}.tmp"
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, FILE_MODE)
        with os.fdopen(fd, "w") as fh:
            fh.write(content)
            fh.flush()
            os.fsync(fh.fileno())
        try:
            os.link(tmp, path)
        except FileExistsError:
            return False
        except OSError as exc:
            if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV):
                raise
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, FILE_MODE)  # FileExistsError: held
            with os.fdopen(fd, "w") as fh:
                fh.write(content)
        return True
    except FileExistsError:
        return False
    except OSError as exc:
        raise os_error(exc, "create the lock", path) from exc
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)


def _try_lock(path):
    """Create the lock file; returns None, or the live holder's description."""
    me = dict(pid=os.getpid(), host=socket.gethostname(), start=_process_start(os.getpid()),
              since=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
    for _ in range(100):
        if _create_lock(path, json.dumps(me)):
            return None
        holder = _read_holder(path)
        young = time.time() - os.path.getmtime(path) < 10 if os.path.exists(path) else False
        if (holder and _holder_alive(holder)) or (not holder and young):
            return holder or {"pid": "?", "since": "just now"}
        try:
            os.unlink(path)  # stale: its holder is dead
        except FileNotFoundError:
            pass
        except OSError as exc:  # e.g. a directory named like the lock
            raise os_error(exc, "remove the stale lock", path) from exc
    raise PersistenceError(f"cannot create the lock {path!r}: it keeps reappearing")


@contextlib.contextmanager
def locked(out: str | os.PathLike) -> Iterator[None]:
    """Hold ``out/.lock`` for the duration of the block (see the module docstring).

    Raises
    ------
    OutputLockedError
        If another live process holds the lock.
    """
    path = os.path.join(os.fspath(out), LOCK_NAME)
    holder = _try_lock(path)
    if holder is not None:
        raise OutputLockedError(
            f"{out} is being written by another sweep (pid {holder.get('pid')} on {holder.get('host', 'this host')}, "
            f"since {holder.get('since')}); wait for it to finish or choose another --out "
            f"(if no such sweep runs, delete {path})")
    try:
        yield
    finally:
        with contextlib.suppress(OSError, ValueError):
            with open(path) as fh:
                mine = json.load(fh).get("pid") == os.getpid()
            if mine:
                os.unlink(path)


# --- the manifest -------------------------------------------------------------------------


def new_invocation(command: str | None, settings: dict[str, Any]) -> dict[str, Any]:
    """This invocation's entry of the manifest's history (completed by :func:`write_manifest`)."""
    now = time.gmtime()
    return dict(id=f"{time.strftime('%Y%m%dT%H%M%SZ', now)}-{os.getpid()}-{secrets.token_hex(3)}", command=command,
                started_utc=time.strftime("%Y-%m-%dT%H:%M:%SZ", now), **settings)


def _previous_invocations(path):
    try:
        with open(path) as fh:
            history = json.load(fh).get("invocations", [])
        return [h for h in history if isinstance(h, dict)] if isinstance(history, list) else []
    except (OSError, ValueError, AttributeError):
        return []


def _versions():
    from ... import __version__

    v = {"python": platform.python_version(), "git_commit": _git_commit()}
    for dist in ("numpy", "scipy", "cvxpy", "joblib", "matplotlib"):
        try:
            v[dist] = md.version(dist)
        except md.PackageNotFoundError:
            v[dist] = None
    v["factirl-opt"] = __version__
    return v


def _git_commit():
    """The source tree's git commit (``+dirty`` if modified), or None outside a git checkout."""
    import subprocess

    here = os.path.dirname(os.path.abspath(__file__))
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "../.."], cwd=here, capture_output=True,
                               text=True, timeout=10).stdout.strip()
        return head.stdout.strip() + ("+dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return None


def write_manifest(out: str, preset: Any, lineup: Any, records: list[dict], invocation: dict[str, Any],
                   rejected: dict[str, str]) -> dict[str, Any]:
    """Write ``out/manifest.json`` describing the tables' runs and every invocation (see the module docstring).

    Parameters
    ----------
    out : str
    preset : Preset
    lineup : Lineup
    records : list of dict
        The tables' run records, in plan order.
    invocation : dict
        This invocation (:func:`new_invocation`), with its results filled in.
    rejected : dict
        ``{file: reason}`` of the records rejected by this invocation.
    """
    path = os.path.join(out, "manifest.json")
    history = _previous_invocations(path) + [invocation]
    keys = {rec["key"] + ".json" for rec in records}
    runs = [dict(key=rec["key"], n_tasks=rec["spec"]["n_tasks"], demos_per_task=rec["spec"]["demos_per_task"],
                 seed=rec["spec"]["seed"], solver=rec["rows"][0]["h_solver"],
                 computed_by=rec["provenance"].get("computed_by")) for rec in records]
    others = sorted(f for f in os.listdir(os.path.join(out, "runs")) if f.endswith(".json") and f not in keys)
    manifest = dict(
        preset=preset.to_dict(), lineup=lineup.fingerprint(), seeds=sorted({r["seed"] for r in runs}),
        **{k: invocation.get(k) for k in ("h_solver", "h_solver_options", "d_solver", "d_solver_options", "jobs",
                                          "backend", "command", "n_runs", "n_computed", "wall_time_seconds",
                                          "substitutions")},
        cpu_count=os.cpu_count(), platform=platform.platform(), versions=_versions(), code=code_stamp(),
        finished_utc=invocation.get("finished_utc"), runs=runs, rejected=rejected, other_records=others,
        invocations=history,
    )
    write_text_atomic(path, json.dumps(manifest, indent=2) + "\n")
    return manifest

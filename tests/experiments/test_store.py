"""The run store: checked records (checksum, structure, key, provenance), the lock, the manifest, permissions."""

import json
import os
import shutil
import subprocess
import sys
import warnings

import pytest

from factirl_opt.lab.experiments import LINEUPS, PRESETS, run_sweep, runner as runner_mod, store
from factirl_opt.lab.experiments.learners import Learner, Lineup

TABLES = ("results.csv", "summary.csv")


def _read(path):
    with open(path) as fh:
        return fh.read()


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The tiny preset with one seed (3 runs), computed once."""
    out = tmp_path_factory.mktemp("store") / "ref"
    run_sweep("tiny", out, seeds=1, progress=False)
    return out


def _copy(reference, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(reference / "runs", out / "runs")
    return out, sorted(os.listdir(out / "runs"))


def _edit(path, change, reseal=False):
    rec = json.loads(_read(path))
    change(rec)
    if reseal:  # an adversary who also fixes the checksum
        rec = store.seal({k: v for k, v in rec.items() if k not in ("provenance", "checksum")},
                         {k: v for k, v in rec["provenance"].items() if k != "computed_by"},
                         rec["provenance"]["computed_by"])
    with open(path, "w") as fh:
        json.dump(rec, fh)


def _resume(out, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = run_sweep("tiny", out, seeds=1, progress=False, **kw)
    return res, [w for w in caught if issubclass(w.category, store.RejectedRunWarning)]


def _assert_recomputed(reference, out, res, caught, files, reason):
    assert res["n_computed"] == len(files)
    assert sorted(res["rejected"]) == sorted(files) and all(reason in r for r in res["rejected"].values())
    assert len(caught) == 1 and f"rejected {len(files)} run record(s)" in str(caught[0].message)
    assert json.loads(_read(out / "manifest.json"))["rejected"] == res["rejected"]
    for t in TABLES:
        assert _read(out / t) == _read(reference / t)


@pytest.mark.parametrize("change, reseal, reason", [
    (lambda r: r["rows"][0].update(deviation=0.0), False, "checksum mismatch"),
    (lambda r: r["rows"].pop(3), False, "checksum mismatch"),
    (lambda r: r["rows"].pop(3), True, "malformed: 'rows' has learners"),
    (lambda r: r.update(rows="not rows"), True, "malformed: 'rows' is a str"),
    (lambda r: r.pop("timings"), True, "malformed: 'timings' is missing"),
    (lambda r: r["rows"][1].update(deviation="0.1"), True, "malformed: rows[1]['deviation']"),
    (lambda r: r.pop("checksum"), False, "no checksum"),
    (lambda r: r["provenance"]["code"].update(source_sha256="0" * 64), True, "made by other code (source_sha256"),
    (lambda r: r["provenance"].update(lineup=[["train", "flat", 0]]), True, "another learner line-up"),
])
def test_bad_records_are_reported_and_recomputed(reference, tmp_path, change, reseal, reason):
    out, files = _copy(reference, tmp_path)
    _edit(out / "runs" / files[1], change, reseal)
    res, caught = _resume(out)
    _assert_recomputed(reference, out, res, caught, [files[1]], reason)


def test_truncated_and_foreign_records(reference, tmp_path):
    out, files = _copy(reference, tmp_path)
    text = _read(out / "runs" / files[0])
    (out / "runs" / files[0]).write_text(text[: len(text) // 2])
    shutil.copy(out / "runs" / files[2], out / "runs" / files[1])  # another run's record under this name
    res, caught = _resume(out)
    assert "truncated or not JSON" in res["rejected"][files[0]]
    assert "the record of another run" in res["rejected"][files[1]]
    assert res["n_computed"] == 2 and len(caught) == 1
    for t in TABLES:
        assert _read(out / t) == _read(reference / t)


def test_records_of_other_code_are_recomputed(reference, tmp_path, monkeypatch):
    out, files = _copy(reference, tmp_path)
    other = dict(store.code_stamp(), factirl_opt="9.9")
    monkeypatch.setattr(store, "code_stamp", lambda: other)
    res, caught = _resume(out)
    _assert_recomputed(reference, out, res, caught, files, "made by other code (factirl_opt differ)")


def test_a_new_builder_version_invalidates_the_cache(reference, tmp_path, monkeypatch):
    out, files = _copy(reference, tmp_path)
    paper = LINEUPS["paper"]
    bumped = tuple(Learner(lr.split, lr.name, lr.build, lr.version + (lr.name == "factorial"), lr.needs)
                   for lr in paper.learners)
    monkeypatch.setitem(LINEUPS, "paper", Lineup("paper", bumped, paper.value_maps))
    res, caught = _resume(out)
    _assert_recomputed(reference, out, res, caught, files, "another learner line-up")


def test_code_stamp_covers_the_result_code_only():
    files = dict(store._source_files())
    assert "factirl_opt/planning/engine.py" in files and "factirl_opt/learners/factirl.py" in files
    assert "factirl_opt/lab/experiments/learners.py" in files and "factirl_opt/lab/experiments/runner.py" in files
    assert "solvers/armijo.py" in files
    assert not any(f.startswith("factirl_opt/lab/benchmarks/") or f == "factirl_opt/lab/cli.py" for f in files)
    stamp = store.code_stamp()
    assert set(stamp) == {"factirl_opt", "numpy", "scipy", "source_sha256"} and len(stamp["source_sha256"]) == 64


def test_sealed_record_roundtrip(reference):
    path = next((reference / "runs").iterdir())
    rec = json.loads(_read(path))
    assert rec["checksum"].startswith("sha256:") and rec["provenance"]["computed_by"]
    p = PRESETS["tiny"]
    expected = store.expected_provenance(p, LINEUPS["paper"])
    again, reason = store.load_record(path, rec["key"], expected, LINEUPS["paper"])
    assert reason is None and again == rec
    assert store.load_record(path.parent / "absent.json", "absent", expected, LINEUPS["paper"]) == (None, None)


# --- manifest, permissions ---------------------------------------------------------------


def test_manifest_describes_every_invocation_and_run(reference, tmp_path):
    out, files = _copy(reference, tmp_path)
    os.remove(out / "runs" / files[0])
    res = run_sweep("tiny", out, seeds=1, progress=False, command="first")
    res = run_sweep("tiny", out, seeds=2, progress=False, command="second")
    assert res["n_computed"] == 3
    m = json.loads(_read(out / "manifest.json"))
    assert [i["command"] for i in m["invocations"]] == ["first", "second"]
    first, second = (i["id"] for i in m["invocations"])
    assert m["invocations"][0]["n_computed"] == 1 and m["invocations"][1]["n_computed"] == 3
    assert m["seeds"] == [0, 1] and len(m["runs"]) == 6 and m["other_records"] == []
    by_key = {r["key"]: r["computed_by"] for r in m["runs"]}
    assert by_key[files[0][:-5]] == first
    assert sum(v == second for v in by_key.values()) == 3
    # the copied records were computed by the reference's invocation
    ref_id = json.loads(_read(reference / "manifest.json"))["invocations"][0]["id"]
    assert sorted(v for v in by_key.values() if v not in (first, second)) == [ref_id, ref_id]
    run_sweep("tiny", out, seeds=1, progress=False, command="third")  # back to one seed
    m = json.loads(_read(out / "manifest.json"))
    assert len(m["runs"]) == 3 and len(m["other_records"]) == 3 and len(m["invocations"]) == 3


def test_tables_have_the_usual_permissions(reference):
    umask = os.umask(0)
    os.umask(umask)
    for name in ("results.csv", "summary.csv", "timings.csv", "manifest.json", "figure3.json"):
        assert os.stat(reference / name).st_mode & 0o777 == 0o666 & ~umask, name
    for f in (reference / "runs").iterdir():
        assert os.stat(f).st_mode & 0o777 == 0o666 & ~umask


# --- the lock ----------------------------------------------------------------------------


def _lock(out, pid, **extra):
    import socket

    (out / ".lock").write_text(json.dumps(dict(pid=pid, host=socket.gethostname(), since="then", **extra)))


def test_a_live_writer_locks_the_directory(reference, tmp_path):
    out, _ = _copy(reference, tmp_path)
    _lock(out, os.getpid(), start=store._process_start(os.getpid()))
    with pytest.raises(store.OutputLockedError, match=rf"being written by another sweep \(pid {os.getpid()}"):
        run_sweep("tiny", out, seeds=1, progress=False)
    assert (out / ".lock").exists()  # still the holder's
    assert not (out / "results.csv").exists()


def test_a_stale_lock_is_replaced(reference, tmp_path):
    out, _ = _copy(reference, tmp_path)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    _lock(out, int(dead.stdout))
    res = run_sweep("tiny", out, seeds=1, progress=False)
    assert res["n_computed"] == 0 and not (out / ".lock").exists()
    _lock(out, os.getpid(), start=-1)  # our pid, but another process start: a reused pid
    run_sweep("tiny", out, seeds=1, progress=False)
    assert not (out / ".lock").exists()


def test_lock_released_after_an_interruption(tmp_path, monkeypatch):
    def interrupted(preset, spec, progress=None, reuse=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner_mod, "run_one", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_sweep("tiny", tmp_path, seeds=1, progress=False)
    assert not (tmp_path / ".lock").exists()


def test_cli_refuses_a_second_writer(reference, tmp_path, capsys):
    from factirl_opt.lab.cli import main

    out, _ = _copy(reference, tmp_path)
    _lock(out, os.getpid(), start=store._process_start(os.getpid()))
    assert main(["reproduce", "--preset", "tiny", "--seeds", "1", "--out", str(out), "--quiet", "--no-plot"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("factirl-opt: error: ") and "being written by another sweep" in err and err.count("\n") == 1


@pytest.mark.parametrize("links", [True, False])
def test_the_lock_appears_complete_and_leaves_no_temporary_file(tmp_path, monkeypatch, links):
    import errno

    if not links:  # a file system without hard links: O_CREAT | O_EXCL, then written
        def no_link(src, dst):
            raise OSError(errno.EPERM, "Operation not permitted")

        monkeypatch.setattr(os, "link", no_link)
    seen = []
    with store.locked(tmp_path):
        holder = json.loads(_read(tmp_path / ".lock"))
        seen = sorted(os.listdir(tmp_path))
        with pytest.raises(store.OutputLockedError):
            with store.locked(tmp_path):
                pass
    assert holder["pid"] == os.getpid() and seen == [".lock"] and os.listdir(tmp_path) == []


def test_a_failed_write_keeps_the_previous_record_and_leaves_no_partial_file(reference, tmp_path, monkeypatch):
    """A full disk while a record or table is rewritten: a PersistenceError naming it, the old file intact."""
    import errno

    from factirl_opt.exceptions import PersistenceError

    out, files = _copy(reference, tmp_path)
    rec = json.loads(_read(out / "runs" / files[0]))
    before = _read(out / "runs" / files[0])

    real_fsync = os.fsync

    def full(fd):  # the disk fills up while a run record or results.csv is written
        if os.readlink(f"/proc/self/fd/{fd}").endswith((".json", "results.csv")) and "lock" not in os.readlink(
                f"/proc/self/fd/{fd}"):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(PersistenceError, match=f"cannot write '{out / 'runs' / files[0]}': No space left on device"):
        store.write_record(str(out / "runs"), dict(rec, rows=[]))
    assert _read(out / "runs" / files[0]) == before and sorted(os.listdir(out / "runs")) == files
    with pytest.raises(PersistenceError, match="results.csv': No space left on device"):
        run_sweep("tiny", out, seeds=1, progress=False)
    assert sorted(os.listdir(out)) == ["runs"]  # no table, no partial file, no lock left
    assert sorted(os.listdir(out / "runs")) == files


def test_tables_has_no_writer_of_its_own():
    from factirl_opt.lab.experiments import tables

    assert not hasattr(tables, "write_atomic")  # one home: factirl_opt.files

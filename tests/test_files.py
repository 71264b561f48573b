"""Atomic writes: a failure leaves the old file intact and nothing beside it."""

import errno
import os

import pytest

from factirl_opt.exceptions import PersistenceError
from factirl_opt.files import atomic_write, open_for_reading, write_text_atomic


def _listing(d):
    return sorted(os.listdir(d))


def test_write_and_replace(tmp_path):
    p = tmp_path / "a.txt"
    write_text_atomic(p, "one")
    write_text_atomic(p, "two")
    assert p.read_text() == "two"
    assert _listing(tmp_path) == ["a.txt"]


def test_mode_follows_umask(tmp_path):
    old = os.umask(0o027)
    try:
        write_text_atomic(tmp_path / "m.txt", "x")
    finally:
        os.umask(old)
    assert (os.stat(tmp_path / "m.txt").st_mode & 0o777) == 0o640


def test_exception_inside_block_keeps_old_file(tmp_path):
    p = tmp_path / "a.bin"
    p.write_bytes(b"good")
    with pytest.raises(KeyboardInterrupt):
        with atomic_write(p, binary=True) as fh:
            fh.write(b"partial")
            raise KeyboardInterrupt
    assert p.read_bytes() == b"good"
    assert _listing(tmp_path) == ["a.bin"]


def test_full_disk_keeps_old_file(tmp_path, monkeypatch):
    p = tmp_path / "a.bin"
    p.write_bytes(b"good")

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(PersistenceError, match="disk is full") as info:
        with atomic_write(p, binary=True) as fh:
            fh.write(b"new")
    assert isinstance(info.value.__cause__, OSError)
    assert str(p) in str(info.value)
    assert p.read_bytes() == b"good"
    assert _listing(tmp_path) == ["a.bin"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores directory permissions")
def test_read_only_directory(tmp_path):
    d = tmp_path / "ro"
    d.mkdir()
    (d / "a.txt").write_text("good")
    d.chmod(0o500)
    try:
        with pytest.raises(PersistenceError, match="a.txt"):
            write_text_atomic(d / "a.txt", "new")
        assert (d / "a.txt").read_text() == "good"
    finally:
        d.chmod(0o700)


def test_missing_directory_and_directory_path(tmp_path):
    with pytest.raises(PersistenceError, match="No such file or directory"):
        write_text_atomic(tmp_path / "missing" / "a.txt", "x")
    with pytest.raises(PersistenceError, match=r"does not exist") as info:
        write_text_atomic(tmp_path / "missing" / "a.txt", "x")
    assert isinstance(info.value.__cause__, FileNotFoundError)
    with pytest.raises(PersistenceError, match="Is a directory") as info:
        write_text_atomic(tmp_path, "x")
    assert isinstance(info.value.__cause__, IsADirectoryError)
    assert _listing(tmp_path) == []


def test_open_for_reading_errors(tmp_path):
    with pytest.raises(PersistenceError, match="missing.bin") as info:
        open_for_reading(tmp_path / "missing.bin")
    assert isinstance(info.value.__cause__, FileNotFoundError)
    with pytest.raises(PersistenceError):
        open_for_reading(tmp_path)


def test_permission_denied_directory_monkeypatched(tmp_path, monkeypatch):
    """A directory we may not write into. Root ignores permission bits, so os.open is made to
    raise EACCES here (the real read-only file system is tested on a tmpfs in
    tests/persistence/test_writes.py)."""
    p = tmp_path / "a.txt"
    p.write_text("good")
    real_open = os.open

    def denied(path, flags, *args, **kwargs):
        if flags & os.O_CREAT:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), path)
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", denied)
    with pytest.raises(PersistenceError, match=r"cannot write .*a\.txt.*Permission denied") as info:
        write_text_atomic(p, "new")
    assert isinstance(info.value.__cause__, PermissionError)
    monkeypatch.undo()
    assert p.read_text() == "good"
    assert _listing(tmp_path) == ["a.txt"]


@pytest.mark.parametrize("where", ["fsync", "replace"])
@pytest.mark.parametrize("error", [KeyboardInterrupt(), OSError(errno.EIO, os.strerror(errno.EIO))])
def test_failure_after_writing_keeps_old_file(tmp_path, monkeypatch, where, error):
    p = tmp_path / "a.txt"
    p.write_text("good")

    def fail(*args):
        raise error

    monkeypatch.setattr(os, where, fail)
    with pytest.raises(KeyboardInterrupt if isinstance(error, KeyboardInterrupt) else PersistenceError) as info:
        write_text_atomic(p, "new")
    monkeypatch.undo()
    if isinstance(error, OSError):
        assert info.value.__cause__ is error and "Input/output error" in str(info.value)
    assert p.read_text() == "good"
    assert _listing(tmp_path) == ["a.txt"]


def test_text_mode_keeps_newlines(tmp_path):
    write_text_atomic(tmp_path / "t.txt", "a\r\nb\n")
    assert (tmp_path / "t.txt").read_bytes() == b"a\r\nb\n"


def test_open_for_reading_reads_and_names_a_directory(tmp_path):
    (tmp_path / "a.bin").write_bytes(b"xy")
    with open_for_reading(tmp_path / "a.bin") as fh:
        assert fh.read() == b"xy"
    with open_for_reading(tmp_path / "a.bin", binary=False) as fh:
        assert fh.read() == "xy"
    with pytest.raises(PersistenceError, match="Is a directory") as info:
        open_for_reading(tmp_path)
    assert isinstance(info.value.__cause__, IsADirectoryError)


def test_long_names_are_written(tmp_path):
    p = tmp_path / ("n" * 250)
    write_text_atomic(p, "x")
    assert p.read_text() == "x"
    assert _listing(tmp_path) == ["n" * 250]

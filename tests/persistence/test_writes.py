"""Atomic saves and operating-system errors: a failed save never harms the previous file."""

import errno
import io
import os
import signal
import time

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import PersistenceError

ENOSPC = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _listing(directory):
    return sorted(os.listdir(directory))


def _same_model(a, b):
    assert type(a) is type(b)
    for key, value in vars(a).items():
        if key.endswith("_"):
            np.testing.assert_array_equal(getattr(b, key), value, err_msg=key)


class _FailingFile:
    """A file whose ``write`` raises ``error`` once ``budget`` bytes have been written."""

    def __init__(self, fh, budget, error):
        self._fh, self._budget, self._error = fh, budget, error

    def write(self, data):
        if len(data) > self._budget:
            self._fh.write(bytes(data[: self._budget]))
            raise self._error
        self._budget -= len(data)
        return self._fh.write(data)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._fh.close()

    def __getattr__(self, name):
        return getattr(self._fh, name)


def _fail_at(monkeypatch, where, error):
    """Make the next save fail at ``where``: after some bytes of the archive, at fsync or at rename."""
    if where.startswith("write"):
        budget = int(where.split("@")[1])
        real = os.fdopen
        monkeypatch.setattr(os, "fdopen", lambda fd, *a, **k: _FailingFile(real(fd, *a, **k), budget, error))
    else:
        def fail(*args):
            raise error

        monkeypatch.setattr(os, where, fail)


OLD_DEMOS = [np.ones((1, 4, 2), dtype=np.int64)]


def _same_demos(path):
    loaded = fo.load_demonstrations(path)
    assert len(loaded) == 1
    np.testing.assert_array_equal(loaded[0], OLD_DEMOS[0])


SAVES = {
    "model": (lambda models, path: fo.save_model(models["gradirl-features"], path),
              lambda models, path: _same_model(models["factirl-transfer"], fo.load_model(path))),
    "demonstrations": (lambda models, path: fo.save_demonstrations([np.zeros((2, 3, 2), dtype=int)], path),
                       lambda models, path: _same_demos(path)),
}


def _write_old(kind, models, path):
    if kind == "model":
        fo.save_model(models["factirl-transfer"], path)
    else:
        fo.save_demonstrations(OLD_DEMOS, path)


@pytest.mark.parametrize("kind", list(SAVES))
@pytest.mark.parametrize("where", ["write@0", "write@40", "write@700", "fsync", "replace"])
@pytest.mark.parametrize("error", [KeyboardInterrupt(), ENOSPC], ids=["ctrl-c", "disk-full"])
def test_interrupted_or_failed_save_keeps_the_old_file(fitted_models, tmp_path, monkeypatch, kind, where, error):
    save, check_old = SAVES[kind]
    path = tmp_path / "file.npz"
    _write_old(kind, fitted_models, path)
    _fail_at(monkeypatch, where, error)
    expected = KeyboardInterrupt if isinstance(error, KeyboardInterrupt) else PersistenceError
    with pytest.raises(expected) as info:
        save(fitted_models, path)
    monkeypatch.undo()
    if expected is PersistenceError:
        assert str(path) in str(info.value) and "disk is full" in str(info.value)
        assert info.value.__cause__ is error
    check_old(fitted_models, path)
    assert _listing(tmp_path) == ["file.npz"]


def test_save_writes_completely_when_nothing_fails(fitted_models, tmp_path):
    path = tmp_path / "file.npz"
    _write_old("model", fitted_models, path)
    fo.save_model(fitted_models["gradirl-features"], path)
    _same_model(fitted_models["gradirl-features"], fo.load_model(path))
    assert _listing(tmp_path) == ["file.npz"]


def test_file_objects_are_written_as_they_are(fitted_models):
    buffer = io.BytesIO()
    assert fo.save_model(fitted_models["factirl-features"], buffer) is buffer
    buffer.seek(0)
    _same_model(fitted_models["factirl-features"], fo.load_model(buffer))


# ----------------------------------------------------------------------------- OS errors


@pytest.mark.parametrize("save", [lambda p: fo.save_model(fo.GradIRL(), p), lambda p: fo.save_demonstrations([[[[0, 1]]]], p)],
                         ids=["model", "demonstrations"])
def test_missing_directory_and_directory_path(tmp_path, save):
    with pytest.raises(PersistenceError, match=r"cannot write .*missing.*No such file or directory \(the directory") as info:
        save(tmp_path / "missing" / "m.npz")
    assert isinstance(info.value.__cause__, FileNotFoundError)
    (tmp_path / "dir.npz").mkdir()
    with pytest.raises(PersistenceError, match=r"cannot write .*dir\.npz.*Is a directory") as info:
        save(tmp_path / "dir.npz")
    assert isinstance(info.value.__cause__, IsADirectoryError)
    assert _listing(tmp_path) == ["dir.npz"]


@pytest.mark.parametrize("load", [fo.load_model, fo.load_demonstrations])
def test_loading_a_missing_file_or_a_directory(tmp_path, load):
    with pytest.raises(PersistenceError, match=r"cannot read .*nope\.npz.*No such file or directory") as info:
        load(tmp_path / "nope.npz")
    assert isinstance(info.value.__cause__, FileNotFoundError)
    with pytest.raises(PersistenceError, match=r"cannot read .*Is a directory") as info:
        load(tmp_path)
    assert isinstance(info.value.__cause__, IsADirectoryError)


def test_unreadable_file_monkeypatched(tmp_path, monkeypatch):
    """Permission bits do not stop root, so open() is made to raise EACCES here."""
    path = fo.save_model(fo.GradIRL(), tmp_path / "m.npz")

    def denied(*args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))

    monkeypatch.setattr("builtins.open", denied)
    with pytest.raises(PersistenceError, match=r"cannot read .*m\.npz.*Permission denied") as info:
        fo.load_model(path)
    assert isinstance(info.value.__cause__, PermissionError)


def test_full_disk_on_a_real_tmpfs(fitted_models, tmpfs):
    directory = tmpfs.mount("small", size="64k")
    path = directory / "model.npz"
    fo.save_model(fitted_models["factirl-transfer"], path)
    with pytest.raises(OSError) as filled:  # fill the file system
        with open(directory / "filler", "wb") as fh:
            while True:
                fh.write(b"\0" * 4096)
                fh.flush()
    assert filled.value.errno == errno.ENOSPC
    for save in (lambda p: fo.save_model(fitted_models["factirl-features-transfer"], p),
                 lambda p: fo.save_demonstrations([np.zeros((50, 50, 2), dtype=int)], p)):
        with pytest.raises(PersistenceError, match=r"model\.npz.*disk is full") as info:
            save(path)
        assert info.value.__cause__.errno == errno.ENOSPC
        _same_model(fitted_models["factirl-transfer"], fo.load_model(path))
        assert _listing(directory) == ["filler", "model.npz"]


def test_read_only_directory_on_a_real_tmpfs(fitted_models, tmpfs):
    directory = tmpfs.mount("ro")
    path = directory / "model.npz"
    fo.save_model(fitted_models["factirl-transfer"], path)
    tmpfs.read_only(directory)
    for save in (lambda p: fo.save_model(fitted_models["gradirl-tabular"], p),
                 lambda p: fo.save_demonstrations([np.zeros((2, 3, 2), dtype=int)], p)):
        with pytest.raises(PersistenceError, match=r"cannot write .*model\.npz.*Read-only file system") as info:
            save(path)
        assert info.value.__cause__.errno == errno.EROFS
    _same_model(fitted_models["factirl-transfer"], fo.load_model(path))
    assert _listing(directory) == ["model.npz"]


def test_a_path_of_another_type_is_refused(tmp_path):
    with pytest.raises(fo.exceptions.ValidationError, match="path must be a str, an os.PathLike or a writable binary file; got int"):
        fo.save_model(fo.GradIRL(), 3)
    with pytest.raises(fo.exceptions.ValidationError, match="path must be a str, an os.PathLike or a readable binary file; got NoneType"):
        fo.load_demonstrations(None)
    assert _listing(tmp_path) == []


def test_ctrl_c_at_any_byte_of_the_archive(fitted_models, tmp_path, monkeypatch):
    path = tmp_path / "file.npz"
    _write_old("model", fitted_models, path)
    size = os.path.getsize(path)
    for budget in range(0, size + 200, max(1, size // 25)):
        _fail_at(monkeypatch, f"write@{budget}", KeyboardInterrupt())
        try:
            fo.save_model(fitted_models["factirl-features-transfer"], path)
        except KeyboardInterrupt:
            pass
        monkeypatch.undo()
        _same_model(fitted_models["factirl-transfer"], fo.load_model(path))
        assert _listing(tmp_path) == ["file.npz"]


# A ZipFile interrupted inside its own closing cannot be closed again: its __del__ reports that
# ("Exception ignored in ZipFile.__del__"); the file on disk is not affected.
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_real_interrupts_at_random_times_leave_a_readable_file(tmp_path):
    """SIGALRM raising KeyboardInterrupt (as Ctrl-C does) at random times during repeated saves:
    the interrupt propagates as itself and the file always loads, as the old model or the new one."""
    mdp = fo.GridWorld(size=8)
    rng = np.random.default_rng(0)
    demos = fo.sample_demonstrations(mdp, rng.standard_normal((20, mdp.n_states, mdp.n_actions)), 2, 5, rng=0)
    old, new = fo.GradIRL(max_iter=1).fit(mdp, demos), fo.GradIRL(max_iter=2).fit(mdp, demos)
    path = tmp_path / "model.npz"
    fo.save_model(old, path)
    started = time.perf_counter()
    fo.save_model(old, tmp_path / "timing.npz")
    duration = time.perf_counter() - started
    os.unlink(tmp_path / "timing.npz")

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGALRM, interrupt)
    interrupted = 0
    try:
        for _ in range(30):
            signal.setitimer(signal.ITIMER_REAL, float(rng.uniform(1e-5, 1.2 * duration)))
            try:
                fo.save_model(new, path)
                signal.setitimer(signal.ITIMER_REAL, 0)
            except KeyboardInterrupt:
                interrupted += 1
            loaded = fo.load_model(path)
            assert any(np.array_equal(loaded.weights_, m.weights_) for m in (old, new))
            fo.save_model(old, path)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    assert interrupted > 0


@pytest.mark.parametrize("error", [KeyboardInterrupt(), ENOSPC], ids=["ctrl-c", "disk-full"])
def test_an_error_zipfile_masks_is_raised_as_itself(tmp_path, monkeypatch, error):
    """zipfile turns an error raised inside a member's write into its own ValueError on closing."""
    path = tmp_path / "file.npz"
    fo.save_demonstrations(OLD_DEMOS, path)

    def masked(fh, **members):
        try:
            raise error
        finally:
            raise ValueError("Can't close the ZIP file while there is an open writing handle on it.")

    monkeypatch.setattr(np, "savez_compressed", masked)
    with pytest.raises(KeyboardInterrupt if isinstance(error, KeyboardInterrupt) else PersistenceError) as info:
        fo.save_demonstrations([np.zeros((2, 3, 2), dtype=int)], path)
    monkeypatch.undo()
    assert info.value is error or info.value.__cause__ is error
    _same_demos(path)
    assert _listing(tmp_path) == ["file.npz"]

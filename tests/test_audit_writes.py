"""Audit: every writer is atomic and never replaces what the path names by something else.

Variants not covered by tests/test_files.py: a path through a symbolic link (the link must
survive and the file it points to be replaced), a path naming a FIFO (a special file must not
be replaced by a regular one), the scale benchmark's figure, and the figures' and tables'
readers on paths that cannot be opened.
"""

import os
import stat

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.lab.benchmarks import scale
from factirl_opt.exceptions import PersistenceError
from factirl_opt.lab.experiments import figures, tables
from factirl_opt.files import atomic_write


@pytest.fixture
def model(rng, grid3):
    demos = fo.sample_demonstrations(grid3, rng.normal(size=(2, 9, 4)), 2, 3, rng)
    return fo.GradIRL(max_iter=2).fit(grid3, demos), demos


@pytest.mark.parametrize("writer", ["model", "demonstrations"])
def test_saving_through_a_symlink_keeps_the_link_and_replaces_its_target(model, tmp_path, writer):
    fitted, demos = model
    target = tmp_path / "store" / "v3.npz"
    target.parent.mkdir()
    target.write_bytes(b"old")
    link = tmp_path / "current.npz"
    link.symlink_to(target)
    if writer == "model":
        fo.save_model(fitted, link)
        loaded = fo.load_model(target)
        np.testing.assert_array_equal(loaded.rewards_, fitted.rewards_)
    else:
        fo.save_demonstrations(demos, link)
        np.testing.assert_array_equal(fo.load_demonstrations(target)[0], demos[0])
    assert link.is_symlink() and os.path.samefile(link, target)
    assert sorted(os.listdir(target.parent)) == ["v3.npz"]  # no temporary file left beside it


def test_a_dangling_symlink_is_written_through(tmp_path):
    link = tmp_path / "link.txt"
    link.symlink_to(tmp_path / "new.txt")
    with atomic_write(link) as fh:
        fh.write("x")
    assert link.is_symlink() and (tmp_path / "new.txt").read_text() == "x"


@pytest.mark.parametrize("writer", ["model", "demonstrations", "text"])
def test_a_fifo_is_refused_and_left_in_place(model, tmp_path, writer):
    fitted, demos = model
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    write = {"model": lambda: fo.save_model(fitted, fifo), "demonstrations": lambda: fo.save_demonstrations(demos, fifo),
             "text": lambda: atomic_write(fifo).__enter__()}[writer]
    with pytest.raises(PersistenceError, match="not a regular file") as info:
        write()
    assert str(fifo) in str(info.value)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert os.listdir(tmp_path) == ["pipe"]


def test_scale_benchmark_figure_is_written_atomically(tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    per_size = {"3x3": {"n_states": 9, "demonstrations_s": 0.1, "score_s": 0.1, "build_s": 0.1,
                        "planners": {"dense": {"warm_s": 0.1}, "sparse-lu": {"warm_s": 0.1}}}}
    path = tmp_path / "scale.png"
    path.write_bytes(b"old figure")
    import matplotlib.figure

    def interrupted(fig, target, **kwargs):  # Ctrl-C half-way through writing the figure
        if isinstance(target, (str, os.PathLike)):
            with open(target, "wb") as fh:
                fh.write(b"partial")
        else:
            target.write(b"partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", interrupted)
    with pytest.raises(KeyboardInterrupt):
        scale._plot(per_size, str(path), 1)
    assert path.read_bytes() == b"old figure" and os.listdir(tmp_path) == ["scale.png"]
    monkeypatch.undo()
    scale._plot(per_size, str(path), 1)
    assert path.read_bytes().startswith(b"\x89PNG")


@pytest.mark.parametrize("make", ["missing", "directory"])
def test_read_csv_names_a_path_it_cannot_open(tmp_path, make):
    path = tmp_path / "results.csv"
    if make == "directory":
        path.mkdir()
    with pytest.raises(PersistenceError, match="cannot read") as info:
        tables.read_csv(path)
    assert str(path) in str(info.value) and isinstance(info.value.__cause__, OSError)


def test_read_results_with_a_directory_as_its_table(tmp_path):
    (tmp_path / "results.csv").mkdir()
    with pytest.raises(PersistenceError, match="results.csv"):
        tables.read_results(tmp_path)


def test_plot_all_names_a_figure3_it_cannot_read(tmp_path, monkeypatch):
    monkeypatch.setattr(figures, "read_results", lambda out: [])
    monkeypatch.setattr(figures, "load_preset_from_manifest", lambda out: None)
    monkeypatch.setattr(figures, "plot_sweeps", lambda *a, **k: [])
    (tmp_path / "figure3.json").mkdir()
    with pytest.raises(PersistenceError, match="figure3.json"):
        figures.plot_all(tmp_path)


def test_plot_all_names_a_stale_figure_it_cannot_remove(tmp_path, monkeypatch):
    monkeypatch.setattr(figures, "read_results", lambda out: [])
    monkeypatch.setattr(figures, "load_preset_from_manifest", lambda out: None)
    monkeypatch.setattr(figures, "plot_sweeps", lambda *a, **k: [])
    stale = tmp_path / "figures" / f"{figures.FIGURES[2][0]}.{figures.FIGURES[2][1][0]}"
    stale.mkdir(parents=True)  # a directory where the stale figure should be: unlink fails
    with pytest.raises(PersistenceError, match="stale figure"):
        figures.plot_all(tmp_path)


def test_a_directory_in_place_of_the_lock_is_named(tmp_path):
    from factirl_opt.lab.experiments import store

    lock = tmp_path / store.LOCK_NAME
    lock.mkdir()
    os.utime(lock, (0, 0))  # old: taken for a stale lock
    with pytest.raises(PersistenceError, match="cannot remove the stale lock") as info:
        with store.locked(tmp_path):
            pass
    assert str(lock) in str(info.value) and lock.is_dir()


@pytest.mark.parametrize("mode", [0o600, 0o640, 0o444])
def test_replacing_a_file_keeps_its_permissions(model, tmp_path, mode):
    fitted, _ = model
    path = tmp_path / "private.npz"
    path.write_bytes(b"old")
    os.chmod(path, mode)
    fo.save_model(fitted, path)
    assert stat.S_IMODE(os.stat(path).st_mode) == mode
    np.testing.assert_array_equal(fo.load_model(path).rewards_, fitted.rewards_)


@pytest.mark.parametrize("reader", ["model", "demonstrations", "table"])
def test_reading_a_fifo_is_refused_instead_of_waiting_for_a_writer(tmp_path, reader):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    read = {"model": fo.load_model, "demonstrations": fo.load_demonstrations, "table": tables.read_csv}[reader]
    with pytest.raises(PersistenceError, match="not a regular file"):
        read(fifo)

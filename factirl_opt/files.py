"""Files the library writes: atomically, or not at all.

Every file the library writes (models, demonstrations, run records, tables, manifests,
figures) goes through :func:`atomic_write`: the bytes go to a temporary file in the target's
directory, which is flushed and ``fsync``-ed, then renamed over the target (``os.replace``,
atomic on POSIX within one file system). A failure at any point (a full disk, a read-only
directory, Ctrl-C) leaves the previous file intact and no temporary file behind.

Operating-system errors (a missing or read-only directory, a path that is a directory, a full
disk) are raised as :class:`~factirl_opt.exceptions.PersistenceError`, naming the path and the
cause; the original ``OSError`` is chained as ``__cause__``.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
from collections.abc import Iterator
from typing import IO

from .exceptions import PersistenceError

__all__ = ["atomic_write", "write_text_atomic", "os_error", "open_for_reading"]

#: permissions of a new file before the umask is applied (as ``open`` gives)
FILE_MODE = 0o666


def os_error(exc: OSError, action: str, path: str | os.PathLike) -> PersistenceError:
    """The library's error for an ``OSError`` raised while ``action``-ing ``path``.

    The message names the path and the cause (``strerror``, e.g. "No space left on device");
    raise it ``from exc`` so the original stays chained.
    """
    cause = exc.strerror or type(exc).__name__
    if exc.errno == errno.ENOSPC:
        cause += " (the disk is full)"
    elif exc.errno == errno.ENOENT and action == "write":
        cause += f" (the directory {os.path.dirname(os.path.abspath(path))!r} does not exist)"
    return PersistenceError(f"cannot {action} {os.fspath(path)!r}: {cause}")


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, binary: bool = False) -> Iterator[IO]:
    """Open a temporary file beside ``path``; on a clean exit make it ``path`` atomically.

    Parameters
    ----------
    path : str or path-like
        The file to create or replace. Its directory must exist.
    binary : bool
        Open the temporary file in binary mode (text mode, ``newline=""`` otherwise).

    Yields
    ------
    file object
        Write the whole content into it. On an exception inside the block (or a failure to
        flush, sync or rename) the temporary file is removed, ``path`` is left as it was and
        the exception propagates (an ``OSError`` as :class:`PersistenceError`).

    Notes
    -----
    A new file gets mode ``0o666`` minus the umask, like a file made by ``open``; a replaced
    file keeps its permissions (a private ``0o600`` model stays private). The
    directory is synced after the rename where the platform allows it. A symbolic link is
    followed: the file it points to is replaced and the link kept. A path that exists but is
    not a regular file (a device such as ``/dev/full``, a FIFO) is refused.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        exc = IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), path)
        raise os_error(exc, "write", path) from exc
    if os.path.exists(path) and not os.path.isfile(path):
        # a device, FIFO or socket: renaming over it would replace the special file itself
        raise PersistenceError(f"cannot write {path!r}: not a regular file (a device, FIFO or socket); "
                               "give the path of a file")
    # through a symbolic link, replace the file it points to (beside it), not the link
    directory, base = os.path.split(os.path.realpath(path))
    # a unique name (O_EXCL) of bounded length beside the target, created inside the try so
    # that an interrupt right after its creation still removes it
    tmp = os.path.join(directory, f".tmp-{os.getpid()}-{secrets.token_hex(8)}-{base[:100]}")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, FILE_MODE)  # the kernel applies the umask
        _keep_mode(fd, os.path.join(directory, base))
        fh: IO = os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", newline="")
        with fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, os.path.join(directory, base))
    except OSError as exc:
        _remove_quietly(tmp)
        raise os_error(exc, "write", path) from exc
    except BaseException:
        _remove_quietly(tmp)
        raise
    _sync_directory(directory)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` through :func:`atomic_write`."""
    with atomic_write(path) as fh:
        fh.write(text)


def open_for_reading(path: str | os.PathLike, binary: bool = True, newline: str | None = None) -> IO:
    """``open(path)`` for reading, with ``OSError`` raised as :class:`PersistenceError`.

    A missing file, a directory or a file without read permission is named with its cause.
    A FIFO or socket is refused (reading it would wait for a writer, possibly forever).
    ``newline`` is passed to ``open`` in text mode (``""`` for CSV files).
    """
    path = os.fspath(path)
    try:
        mode = os.stat(path).st_mode
        if stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode):
            raise PersistenceError(f"cannot read {path!r}: not a regular file (a FIFO or socket); give the path of a file")
        return open(path, "rb") if binary else open(path, "r", newline=newline)
    except OSError as exc:
        raise os_error(exc, "read", path) from exc


def _keep_mode(fd: int, target: str) -> None:
    """Give the new file the permissions of the file it replaces (a private 0o600 file stays private)."""
    try:
        mode = os.stat(target).st_mode
    except OSError:
        return  # no previous file: 0o666 minus the umask
    if hasattr(os, "fchmod"):  # POSIX
        os.fchmod(fd, stat.S_IMODE(mode))


def _remove_quietly(path: str) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path)


def _sync_directory(directory: str) -> None:
    """Make the rename durable (best effort: not every platform can open a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)

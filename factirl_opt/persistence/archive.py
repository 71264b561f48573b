"""The container of every factirl-opt file: an ``.npz`` archive with a JSON header.

Writing goes through :func:`factirl_opt.files.atomic_write` (temporary file in the same
directory, flushed, fsynced, renamed), so a failure leaves the previous file intact; reading
opens the file with :func:`factirl_opt.files.open_for_reading`. Operating-system errors are
raised as :class:`~factirl_opt.exceptions.PersistenceError` naming the path and the cause,
the ``OSError`` chained.
"""

from __future__ import annotations

import json
import os
from typing import IO, Any

import numpy as np

from ..exceptions import PersistenceError, ValidationError
from ..files import atomic_write, open_for_reading, os_error

__all__ = ["FORMAT_VERSION", "FORMAT", "HEADER", "write_archive", "read_archive", "require", "check_array", "to_json",
           "json_default", "library_version", "label_of"]

#: Version of the file format written by this library; files with a larger one are refused.
#: 2: models carry ``mdp_signature_``; demonstration tasks are "array" or "list".
FORMAT_VERSION = 2
FORMAT = "factirl-opt"
HEADER = "__header__"

#: Where a file is written or read: a path, or an open binary file object.
Target = str | os.PathLike | IO[bytes]


def library_version() -> str:
    from .._version import __version__

    return __version__


def json_default(obj: Any) -> Any:
    """``json.dumps`` hook: numpy scalars as Python numbers, numpy arrays as lists (``FactIRL.cv_results_``)."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray) and not obj.dtype.hasobject:
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def to_json(value: Any, what: str) -> Any:
    """``value`` as plain JSON data (numpy scalars converted); PersistenceError naming ``what``."""
    try:
        return json.loads(json.dumps(value, default=json_default))
    except (TypeError, ValueError) as exc:
        raise PersistenceError(f"cannot save {what}: {exc}") from None


def label_of(target: Target) -> str:
    """How messages name a file: its path, or the type of a file object."""
    return os.fspath(target) if isinstance(target, (str, os.PathLike)) else type(target).__name__


def write_archive(target: Target, header: dict, arrays: dict[str, np.ndarray]) -> str | IO[bytes]:
    """Write ``header`` (plus the format entries) and ``arrays`` as an ``.npz`` archive.

    A path is written atomically (:func:`~factirl_opt.files.atomic_write`): on any failure,
    Ctrl-C included, the previous file is left as it was and no partial file remains. A file
    object (anything with ``write``) is written into as it is. No ``.npz`` suffix is appended.
    Returns the path as a string, or the file object.
    """
    header = {"format": FORMAT, "format_version": FORMAT_VERSION, "library_version": library_version(),
              "numpy_version": np.__version__, **header}
    members: dict[str, Any] = {HEADER: np.array(json.dumps(header, default=json_default)), **arrays}
    if not isinstance(target, (str, os.PathLike)):
        if not hasattr(target, "write"):
            raise ValidationError(f"path must be a str, an os.PathLike or a writable binary file; got {type(target).__name__}")
        np.savez_compressed(target, **members)
        return target
    path = os.fspath(target)
    with atomic_write(path, binary=True) as fh:
        _savez(fh, members)
    return path


def _savez(fh: IO[bytes], members: dict[str, Any]) -> None:
    """``np.savez_compressed`` into ``fh``, raising the interrupt or OS error that stopped it.

    ``zipfile`` replaces an exception raised while a member is being written (Ctrl-C, a full
    disk) by its own ``ValueError`` ("Can't close the ZIP file while there is an open writing
    handle"); the original, found in the ``__context__`` chain, is raised instead.
    """
    try:
        np.savez_compressed(fh, **members)
    except (KeyboardInterrupt, OSError):
        raise
    except BaseException as exc:
        original = exc.__context__
        while original is not None and not isinstance(original, (KeyboardInterrupt, OSError)):
            original = original.__context__
        if original is None:
            raise
        raise original from None


def _members(source: Target, label: str) -> dict[str, np.ndarray]:
    """Every member of the archive, each read (and decompressed) on its own.

    numpy's .npz/.npy readers raise many types on damaged bytes (zipfile.BadZipFile,
    zlib.error, EOFError, NotImplementedError for a flipped compression method, RuntimeError
    for a flipped encryption flag, SyntaxError or tokenize.TokenError from the .npy header
    parser, MemoryError for a huge declared shape, ...): every one of them means the file is
    damaged, so both reading steps catch them all and name the file (and the member). An
    ``OSError`` while reading is the operating system's, reported as such.
    """
    unreadable = f"{label} is not a readable factirl-opt file"
    try:
        loaded = np.load(source, allow_pickle=False)
    except OSError as exc:
        raise os_error(exc, "read", label) from exc
    except Exception as exc:  # damaged bytes, see the docstring
        raise PersistenceError(f"{unreadable} (corrupt or not an .npz archive): {type(exc).__name__}: {exc}") from None
    if not isinstance(loaded, np.lib.npyio.NpzFile):
        raise PersistenceError(f"{label} is not a factirl-opt file: it holds a single .npy array, not an .npz archive")
    contents = {}
    with loaded as npz:
        for name in npz.files:
            try:
                contents[name] = npz[name]
            except OSError as exc:
                raise os_error(exc, "read", label) from exc
            except Exception as exc:  # damaged bytes, see the docstring
                raise PersistenceError(
                    f"{unreadable}: member {name!r} is corrupt or unreadable ({type(exc).__name__}: {exc})"
                ) from None
    return contents


def _header(contents: dict[str, np.ndarray], label: str) -> dict:
    if HEADER not in contents:
        raise PersistenceError(f"{label} is an .npz archive but not a factirl-opt file: it has no {HEADER} member")
    raw = contents.pop(HEADER)
    try:
        header = json.loads(str(raw[()]))
    except (ValueError, IndexError, TypeError, RecursionError) as exc:
        raise PersistenceError(f"{label}: the {HEADER} member is not valid JSON: {exc}") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise PersistenceError(f"{label} is not a factirl-opt file: its header does not say format {FORMAT!r}")
    version = header.get("format_version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise PersistenceError(f"{label}: the header's format_version is missing or not an integer >= 1: {version!r}")
    if version > FORMAT_VERSION:
        raise PersistenceError(
            f"{label} has format version {version}, written by factirl-opt {header.get('library_version', '?')}; "
            f"this is factirl-opt {library_version()}, which reads versions up to {FORMAT_VERSION}: upgrade factirl-opt"
        )
    return header


def read_archive(source: Target, kind: str) -> tuple[dict, dict[str, np.ndarray], str]:
    """The header, the arrays and the label of a factirl-opt file of the given ``kind``.

    ``kind`` is ``"model"`` or ``"demonstrations"``; a file of the other kind, a damaged file
    or an unreadable path raises :class:`PersistenceError` naming the file.
    """
    label = label_of(source)
    if not isinstance(source, (str, os.PathLike)):
        if not hasattr(source, "read"):
            raise ValidationError(f"path must be a str, an os.PathLike or a readable binary file; got {type(source).__name__}")
        contents = _members(source, label)
    else:
        with open_for_reading(source) as fh:
            contents = _members(fh, label)
    header = _header(contents, label)
    found = header.get("kind")
    if found != kind:
        loader = {"model": "load_model", "demonstrations": "load_demonstrations"}.get(str(found))
        hint = f"; use {loader}" if loader else ""
        raise PersistenceError(f"{label} holds {found!r:.40} data, not {kind!r}{hint}")
    return header, contents, label


def require(mapping: dict, key: str, label: str, where: str, kind: type | None = None) -> Any:
    """``mapping[key]``, of type ``kind`` if given; PersistenceError naming what is missing."""
    if key not in mapping:
        raise PersistenceError(f"{label} is incomplete: {where} lacks {key!r}")
    value = mapping[key]
    if kind is not None and not isinstance(value, kind):
        raise PersistenceError(f"{label} is malformed: {key!r} in {where} must be a {kind.__name__}; got {type(value).__name__}")
    return value


def check_array(arr: np.ndarray, what: str, context: str, ndim: int | None = None, kinds: str = "biuf") -> np.ndarray:
    """A stored array: numeric of the given dtype kinds and ndim, and finite; PersistenceError otherwise."""
    if not isinstance(arr, np.ndarray) or arr.dtype.kind not in kinds or (ndim is not None and arr.ndim != ndim):
        rule = f"{ndim}-d " if ndim is not None else ""
        rule += "float" if kinds == "f" else "integer" if kinds == "iu" else "numeric"
        got = f"{arr.dtype} of shape {arr.shape}" if isinstance(arr, np.ndarray) else f"{type(arr).__name__} {arr!r:.60}"
        raise PersistenceError(f"{context}: {what} must be a {rule} array; got {got}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise PersistenceError(f"{context}: {what} must be finite; found {arr[bad].item()!r} at index {bad}")
    return arr

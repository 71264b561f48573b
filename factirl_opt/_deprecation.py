"""Deprecated aliases of names and modules that moved when the package was cut into layers.

Three kinds, all kept for one release and all warning once (a
:class:`~factirl_opt.exceptions.DeprecatedNameWarning`, a :class:`FutureWarning` shown to users
by default):

- a renamed estimator parameter (:mod:`factirl_opt.learners.estimator`);

- a former top-level name (``fo.ObjectWorld``) resolves to the object in its new namespace
  (:func:`moved_attribute`, called by the package's ``__getattr__``);
- a former module path (``factirl_opt.learners.gradirl``) imports the module at its new path
  (:func:`install_module_aliases`: a finder on :data:`sys.meta_path` that hands the import
  system the module itself, so both paths name one module object and its state is shared);
  ``python -m`` on a former path (``python -m factirl_opt.bench``) runs the new one. A name
  the former module held that now lives in another module (``factirl_opt.successors.to_successors``,
  now beside ``TabularMDP``) still resolves through the former path, with its own warning
  (``former_names`` of :func:`install_module_aliases`).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import threading
import warnings
from collections.abc import Mapping, Sequence
from types import FrameType, ModuleType
from typing import Any

from .exceptions import DeprecatedNameWarning

__all__ = ["moved_attribute", "install_module_aliases", "moved_names", "warn_once"]

_warned: set[str] = set()
_lock = threading.Lock()
#: former module path -> the user's line (file, line number) whose import of it warned
_module_warned_at: dict[str, tuple[str, int]] = {}


def warn_once(key: str, message: str, stacklevel: int | None = 3) -> None:
    """Emit ``message`` as a :class:`~factirl_opt.exceptions.DeprecatedNameWarning` (a
    :class:`FutureWarning`) the first time ``key`` is seen in this process.

    ``stacklevel=None``: the warning points at the user's line, the first frame outside the
    import system and the aliases' machinery (:func:`_user_frame`), however deep the access went.
    """
    with _lock:
        if key in _warned:
            return
        _warned.add(key)
    if stacklevel is not None:
        warnings.warn(message, DeprecatedNameWarning, stacklevel=stacklevel)
        return
    frame = _user_frame()
    if frame is None:
        warnings.warn(message, DeprecatedNameWarning, stacklevel=2)
        return
    module_globals = frame.f_globals
    registry = module_globals.setdefault("__warningregistry__", {})
    warnings.warn_explicit(message, DeprecatedNameWarning, frame.f_code.co_filename, frame.f_lineno,
                           module=module_globals.get("__name__", "<string>"), registry=registry)


_PACKAGE_DIR = __file__.rsplit("/", 1)[0] if "/" in __file__ else ""


def _internal(code: Any) -> bool:
    """Whether a frame running ``code`` belongs to the machinery between a user's access and its warning:
    the import system, this module, or a module ``__getattr__`` of the package."""
    name = code.co_filename
    return (name == __file__ or "importlib" in name
            or (code.co_name == "__getattr__" and name.startswith(_PACKAGE_DIR)))


def _user_frame() -> Any:
    """The innermost frame outside the import system and the aliases' machinery (None if none)."""
    frame: FrameType | None = sys._getframe(1)
    while frame is not None and _internal(frame.f_code):
        frame = frame.f_back
    return frame


def _user_line() -> tuple[str, int] | None:
    """The file and line number of the user's line making the access in progress (None if none)."""
    frame = _user_frame()
    return None if frame is None else (frame.f_code.co_filename, frame.f_lineno)


def _requested_module(name: str) -> str:
    """The module an import in progress asked for, when ``name`` is being imported as its parent
    package (``import a.b.c`` imports ``a.b`` first): the longest dotted path extending ``name``
    among the import system's frames that are loading it, else ``name``."""
    requested = name
    frame: FrameType | None = sys._getframe(1)
    while frame is not None:
        if frame.f_code.co_name == "_find_and_load" and "importlib" in frame.f_code.co_filename:
            outer = frame.f_locals.get("name")
            if isinstance(outer, str) and outer.startswith(requested + "."):
                requested = outer
            elif outer != requested:
                break
        frame = frame.f_back
    return requested


def moved_attribute(name: str, module: str, namespace: str, new_name: str | None = None) -> Any:
    """The object ``name`` of ``module``, with a one-time warning that it now lives in ``namespace``
    (as ``new_name`` when it was renamed too: the object of that name, not the module's own deprecated alias).

    The warning points at the user's line, whether the name was read as an attribute or imported
    (``from factirl_opt import name`` reads it twice: one warning).
    """
    new = new_name or name
    value = getattr(importlib.import_module(module), new)
    what = f"moved to {namespace}.{name}" if new == name else f"was renamed {namespace}.{new}"
    warn_once(f"name:{name}", f"factirl_opt.{name} {what}; the top-level alias will be removed in the next release",
              stacklevel=None)
    return value


class _FormerNames:
    """A module's ``__getattr__`` (PEP 562) resolving the names its former path held that moved
    elsewhere: ``names`` maps a name to ``(former module path, module holding it now)``."""

    def __init__(self, module: str, fallback: Any) -> None:
        self.module = module
        self.fallback = fallback  # the module's own __getattr__, if it had one
        self.names: dict[str, tuple[str, str]] = {}

    def __call__(self, name: str) -> Any:
        if name in self.names:
            former, home = self.names[name]
            value = getattr(importlib.import_module(home), name)
            if _module_warned_at.get(former) == _user_line():  # one access (``from former import name``):
                with _lock:                                    # the module's warning named it already
                    _warned.add(f"name:{former}.{name}")
                return value
            warn_once(f"name:{former}.{name}", f"{former}.{name} moved to {home}.{name}; the old path will be removed "
                                               "in the next release", stacklevel=None)
            return value
        if self.fallback is not None:
            return self.fallback(name)
        raise AttributeError(f"module {self.module!r} has no attribute {name!r}")


def _add_former_names(module: ModuleType, former: str, names: Mapping[str, str]) -> None:
    """Let ``module`` (imported under its former path ``former``) resolve ``names`` (name -> module holding it now)."""
    with _lock:
        getter = module.__dict__.get("__getattr__")
        if not isinstance(getter, _FormerNames):
            getter = _FormerNames(module.__name__, getter)
            module.__getattr__ = getter  # type: ignore[method-assign]
        for name, home in names.items():
            getter.names.setdefault(name, (former, home))


def moved_names(module: str, names: Mapping[str, str]) -> None:
    """Let the imported ``module`` still resolve ``names`` that left it (name -> module holding it now), each with a one-time warning."""
    _add_former_names(sys.modules[module], module, names)


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, target: str, former_names: Mapping[str, str] | None = None) -> None:
        self.target = target
        self.former_names = former_names or {}

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        if _requested_module(spec.name) == spec.name:  # a former package imported for its former child: the child warns
            left: dict[str, list[str]] = {}
            for name, home in self.former_names.items():
                left.setdefault(home, []).append(name)
            elsewhere = "".join(f" ({', '.join(names)}: now in {home})" for home, names in left.items())
            warn_once(f"module:{spec.name}", f"the module {spec.name} moved to {self.target}{elsewhere}; the old path "
                                             "will be removed in the next release", stacklevel=None)
            line = _user_line()
            if line is not None:
                _module_warned_at[spec.name] = line
        module = importlib.import_module(self.target)
        if self.former_names:
            _add_former_names(module, spec.name, self.former_names)
        return module

    def exec_module(self, module: ModuleType) -> None:  # already executed under its new name
        pass

    def get_code(self, fullname: str) -> Any:
        """``python -m <old path>``: code that runs the module at its new path as ``__main__``
        (with its own package, so that its relative imports resolve), after the one-time warning."""
        warn_once(f"module:{fullname}", f"the module {fullname} moved to {self.target}; the old path will be removed "
                                        f"in the next release (run python -m {self.target})", stacklevel=3)
        return compile(f"import runpy\nrunpy.run_module({self.target!r}, run_name='__main__', alter_sys=True)\n",
                       f"<{fullname}, moved to {self.target}>", "exec")


class _AliasFinder(importlib.abc.MetaPathFinder):
    def __init__(self, package: str, moves: Mapping[str, str],
                 former_names: Mapping[str, Mapping[str, str]] | None = None) -> None:
        self.package = package
        self.moves = dict(moves)
        self.former_names = {old: dict(names) for old, names in (former_names or {}).items()}

    def target(self, fullname: str) -> str | None:
        """The new path of a former module path (a moved package maps its children), or None."""
        prefix = self.package + "."
        if not fullname.startswith(prefix):
            return None
        parts = fullname[len(prefix):].split(".")
        for i in range(len(parts), 0, -1):
            head = ".".join(parts[:i])
            if head in self.moves:
                return ".".join([self.package, self.moves[head], *parts[i:]])
        return None

    def find_spec(self, fullname: str, path: Sequence[str] | None = None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        new = self.target(fullname)
        if new is None or new == fullname:
            return None
        former = self.former_names.get(fullname[len(self.package) + 1:], {})
        return importlib.machinery.ModuleSpec(fullname, _AliasLoader(new, {
            name: f"{self.package}.{home}" for name, home in former.items()}))


def install_module_aliases(package: str, moves: Mapping[str, str],
                           former_names: Mapping[str, Mapping[str, str]] | None = None) -> None:
    """Let the former module paths ``package.<old>`` import ``package.<new>`` (``moves``: old -> new).

    Installed once per process, first on :data:`sys.meta_path` (so that the children of a
    moved package resolve through it too); it answers only for the former paths in ``moves``,
    none of which exists any more.

    ``former_names`` maps a former path (``"successors"``, or a child of a moved package:
    ``"experiments.babyai"``) to the names it held that now live in another module (name ->
    that module, relative to ``package``). Imported under its former path, the module resolves
    them (a module ``__getattr__``), each with a one-time warning naming where it is now.
    """
    if not any(isinstance(f, _AliasFinder) and f.package == package for f in sys.meta_path):
        sys.meta_path.insert(0, _AliasFinder(package, moves, former_names))

"""Cross-references to the package's public names, by the names the docstrings use.

The docstrings name objects the way a reader of the code does: ``TabularMDP``,
``fo.FactIRL``, ``mdp.TabularMDP``, ``FactIRL.transfer``, or a module path such as
``factirl_opt.learners.factirl.FactIRL``. The API reference documents each public object once,
under its public name (``factirl_opt.FactIRL``). This extension resolves a reference that Sphinx
could not resolve to the one documented object whose dotted name ends with the reference's last
components (``fo.`` read as ``factirl_opt.``). What still does not resolve stays a warning, and
the build (``-W``) fails: a docstring naming something the reference does not document.
"""

from __future__ import annotations

from typing import Any

from docutils import nodes
from sphinx.addnodes import pending_xref
from sphinx.application import Sphinx
from sphinx.environment import BuildEnvironment
from sphinx.util.nodes import make_refnode

PREFIXES = {"fo": "factirl_opt", "factirl_opt": "factirl_opt", "solvers": "solvers"}


def _candidates(env: BuildEnvironment, target: str) -> list[tuple[str, Any]]:
    objects = env.get_domain("py").objects  # full name -> ObjectEntry
    parts = target.lstrip("~.").split(".")
    if parts and parts[0] in PREFIXES:
        parts[0] = PREFIXES[parts[0]]
    found = []
    for n in range(len(parts), 0, -1):
        suffix = ".".join(parts[-n:])
        hits = [(name, entry) for name, entry in objects.items() if name == suffix or name.endswith("." + suffix)]
        if hits:
            # with more components given, the first that matches at all decides
            found = hits
            break
    return found


PACKAGES = ("factirl_opt", "solvers")


def _lookup(path: str) -> bool:
    """Whether a dotted path names a module of the package or an attribute inside one."""
    import importlib

    parts = path.split(".")
    if parts[0] not in PACKAGES:
        return False
    for i in range(len(parts), 0, -1):
        try:
            obj: Any = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        if obj.__name__ != ".".join(parts[:i]):  # a deprecated alias of a moved module: stale
            return False
        for j, attr in enumerate(parts[i:], start=i):
            if hasattr(obj, attr):
                obj = getattr(obj, attr)
            elif isinstance(obj, type) and j == len(parts) - 1 and attr in (obj.__doc__ or ""):
                return True  # an instance attribute the class documents (numpydoc Attributes)
            else:
                return False
        return True
    return False


def _exists(target: str, module: str | None, cls: str | None) -> bool:
    """Whether ``target`` names something of the package: as written (``fo.`` read as
    ``factirl_opt.``), relative to the referring module or class, or as an attribute path in one
    of the package's loaded modules (a docstring naming a helper of a sibling module)."""
    import sys
    import warnings

    parts = target.split(".")
    if parts[0] in PREFIXES:
        parts[0] = PREFIXES[parts[0]]
    target = ".".join(parts)
    tries = [target]
    if module:
        tries += [f"{module}.{cls}.{target}" if cls else "", f"{module}.{target}"]
        pieces = module.split(".")
        tries += [".".join(pieces[:i] + [target]) for i in range(len(pieces) - 1, 0, -1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # deprecated module aliases
        if any(t and _lookup(t) for t in tries):
            return True
        first = parts[0]
        for name, mod in list(sys.modules.items()):
            if name.split(".")[0] in PACKAGES and mod is not None and mod.__name__ == name:
                if hasattr(mod, first) and _lookup(f"{name}.{target}"):
                    return True
    return False


def resolve(app: Sphinx, env: BuildEnvironment, node: pending_xref, contnode: nodes.Element) -> Any:
    if node.get("refdomain") != "py":
        return None
    target = node.get("reftarget", "")
    if not target or target.lstrip("~.").split(".")[0] in ("np", "numpy", "scipy", "sp"):
        return None
    hits = _candidates(env, target)
    if not hits:
        # an internal name of the package (a module, a private helper, a constant): it exists
        # but has no page, so it is shown as code, unlinked; a name that does not exist (a typo,
        # a name since removed) stays unresolved and fails the build
        if _exists(target.lstrip("~."), node.get("py:module"), node.get("py:class")):
            return contnode
        return None
    if len(hits) > 1:
        # the same object documented once: several hits are several objects; prefer the
        # package of the referring module, then the shortest (public) name
        module = node.get("py:module") or ""
        top = module.split(".")[0]
        same = [h for h in hits if h[0].split(".")[0] == top] or hits
        same.sort(key=lambda h: (h[0].count("."), h[0]))
        hits = same
    name, entry = hits[0]
    return make_refnode(app.builder, node["refdoc"], entry.docname, entry.node_id, contnode, name)


def constant_docs(app: Sphinx, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    """A constant's page shows its ``#:`` comment from the module that defines it, not the
    docstring of its type (a namespace re-exports constants its submodules define)."""
    if what != "data":
        return
    import sys

    from sphinx.pycode import ModuleAnalyzer

    short = name.rsplit(".", 1)[-1]
    top = name.split(".")[0]
    for module_name, module in sorted(sys.modules.items()):
        if not module_name.startswith(top) or getattr(module, short, None) is not obj:
            continue
        try:
            docs = ModuleAnalyzer.for_module(module_name).find_attr_docs()
        except Exception:  # a module without source: look further
            continue
        if ("", short) in docs:
            lines[:] = list(docs[("", short)])
            return
    if lines and type(obj).__doc__ and lines[0].strip() == type(obj).__doc__.strip().splitlines()[0].strip():
        lines[:] = []


def setup(app: Sphinx) -> dict[str, Any]:
    app.connect("missing-reference", resolve, priority=900)
    app.connect("autodoc-process-docstring", constant_docs)
    return {"parallel_read_safe": True, "parallel_write_safe": True}

"""Public names only: the notebooks, the guide and the README use no private module or name,
nothing from the benchmarks and no top-level alias that moved to a namespace; the analysis
scripts (results/) and the harness (factirl_opt/lab) import no private name of the library and
assign into none of its modules (read from their AST)."""

import ast
import importlib
import json
import pathlib
import re

import pytest

import factirl_opt as fo

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCUMENTS = [*sorted((ROOT / "notebooks").glob("*.ipynb")), ROOT / "docs" / "guide.md", ROOT / "README.md"]


def _code(path):
    if path.suffix == ".ipynb":
        return "\n".join("".join(c["source"]) for c in json.loads(path.read_text())["cells"] if c["cell_type"] == "code")
    return "\n".join(re.findall(r"```python\n(.*?)```", path.read_text(), re.S))


def _imports(code):
    for module, names in re.findall(r"^\s*from (factirl_opt[\w.]*) import \(?([^)\n]*(?:\n[^)\n]*)*?)\)?$", code, re.M):
        for name in re.split(r"[,\s]+", names.strip()):
            if name and name != "as":
                yield module, name.split(" as ")[0]
    for module in re.findall(r"^\s*import (factirl_opt[\w.]*)", code, re.M):
        yield module, None


def _public(module, name):
    if any(part.startswith("_") for part in module.split(".")) or ".lab.benchmarks" in module or module.endswith(".lab.bench"):
        return False
    mod = importlib.import_module(module)
    if name is None:
        return True
    if name.startswith("_"):
        return False
    exported = getattr(mod, "__all__", None)
    if exported is not None and name in exported:
        return True
    return hasattr(mod, name) and importlib.util.find_spec(f"{module}.{name}") is not None  # a public submodule


@pytest.mark.parametrize("path", DOCUMENTS, ids=lambda p: p.name)
def test_documents_import_public_names_only(path):
    code = _code(path)
    wrong = [f"from {m} import {n}" for m, n in _imports(code) if not _public(m, n)]
    assert not wrong, f"{path.name} uses non-public names: {wrong}"


@pytest.mark.parametrize("path", DOCUMENTS, ids=lambda p: p.name)
def test_documents_use_no_moved_top_level_name(path):
    used = set(re.findall(r"\bfo\.(\w+)", _code(path)))
    moved = sorted(used & set(fo._MOVED_NAMES))
    assert not moved, f"{path.name} uses former top-level names (deprecated aliases): {moved}"
    unknown = sorted(n for n in used if not hasattr(fo, n))
    assert not unknown, f"{path.name} uses names factirl_opt does not have: {unknown}"


# -- the analysis scripts (results/) and the harness (factirl_opt/lab) ------------------------------
LIBRARY = ("factirl_opt", "solvers")
HARNESS = "factirl_opt.lab"
#: scripts not scanned (none now: every analysis script uses the library through public names)
EXCLUDED: tuple[str, ...] = ()


def _private(name):
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _absolute(module, level, path):
    """The absolute module of ``from <level dots><module> import ...`` in the file ``path``."""
    if not level:
        return module or ""
    parts = list(pathlib.PurePosixPath(path).with_suffix("").parts)
    parts = parts[:-1] if parts[-1] == "__init__" else parts
    return ".".join(parts[: len(parts) - level] + ([module] if module else []))


def _root(node):
    """The name an assignment target or attribute chain starts from (None for anything else)."""
    while isinstance(node, (ast.Attribute, ast.Subscript, ast.Starred)):
        node = node.value
    return node.id if isinstance(node, ast.Name) else None


def library_misuse(source, path):
    """What a script does with the library that only the library may do, as ``"line: what"``.

    ``path`` is the file's path from the repository root (``factirl_opt/lab/...`` or
    ``results/...``). Flagged: importing a private name or a private module of ``factirl_opt``
    or ``solvers`` (``from factirl_opt.learners.adaptive import _subset``,
    ``factirl_opt._validation``); reading a private attribute of an imported library name
    (``adaptive._run_folds``); assigning or deleting into one (``adaptive.N_FOLDS = 3``,
    ``setattr(adaptive, ...)``, ``fo.FactIRL.x = ...``). The harness's own modules are not the
    library here: a harness module may import another's private helpers.
    """
    tree = ast.parse(source)
    in_harness = path.startswith("factirl_opt/lab/")
    library = {}  # local name -> the library object it is bound to
    found = []

    def owned(full):
        return full.split(".")[0] in LIBRARY and not (in_harness and (full + ".").startswith(HARNESS + "."))

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if owned(alias.name):
                    library[(alias.asname or alias.name).split(".")[0]] = alias.name
                    if any(_private(p) for p in alias.name.split(".")):
                        found.append(f"{node.lineno}: import {alias.name}")
        elif isinstance(node, ast.ImportFrom):
            module = _absolute(node.module, node.level, path)
            if not owned(module):
                continue
            for alias in node.names:
                library[alias.asname or alias.name] = f"{module}.{alias.name}"
                if any(_private(p) for p in module.split(".")) or _private(alias.name):
                    found.append(f"{node.lineno}: from {module} import {alias.name}")
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, (ast.Assign, ast.Delete)):
            targets = node.targets
        elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
            targets = [node.target]
        while targets:
            target = targets.pop()
            if isinstance(target, (ast.Tuple, ast.List)):
                targets.extend(target.elts)
            elif isinstance(target, (ast.Attribute, ast.Subscript, ast.Starred)) and _root(target) in library:
                found.append(f"{node.lineno}: assigns {ast.unparse(target)} ({library[_root(target)]})")
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("setattr", "delattr"):
            if node.args and _root(node.args[0]) in library:
                found.append(f"{node.lineno}: {node.func.id}({ast.unparse(node.args[0])}, ...)")
        if isinstance(node, ast.Attribute) and _private(node.attr) and _root(node.value) in library:
            found.append(f"{node.lineno}: uses {ast.unparse(node)}")
    return sorted(set(found), key=lambda s: int(s.split(":")[0]))


SCRIPTS = sorted(
    str(p.relative_to(ROOT))
    for folder in ("results", "factirl_opt/lab")
    for p in (ROOT / folder).rglob("*.py")
    if not str(p.relative_to(ROOT)).startswith(EXCLUDED)
)


def test_there_are_scripts_to_scan():
    assert any(s.startswith("results/") for s in SCRIPTS) and any(s.startswith("factirl_opt/lab/") for s in SCRIPTS)


@pytest.mark.parametrize("path", SCRIPTS)
def test_scripts_use_the_library_through_public_names_only(path):
    wrong = library_misuse((ROOT / path).read_text(), path)
    assert not wrong, f"{path} reaches into the library: {wrong}"


def test_the_scan_finds_private_names_and_assignments():
    source = "\n".join([
        "import factirl_opt as fo",
        "import factirl_opt._threads",
        "from factirl_opt.learners import adaptive",
        "from factirl_opt.learners.adaptive import _subset, choose_sharing",
        "from solvers.gauss_newton import GaussNewtonSolver as G",
        "from ...learners import fitting",
        "import numpy as np",
        "adaptive.N_FOLDS = 3",
        "adaptive._run_folds(1)",
        "fo.FactIRL.max_iter += 1",
        "G.name, x = 'a', 1",
        "setattr(fitting, 'x', 1)",
        "np.x = 1",
        "rows = {}",
        "rows[fo.score] = 1",
        "model = fo.FactIRL()",
        "model.max_iter = 3",
        "from ._helpers import _private_helper",
    ])
    found = library_misuse(source, "factirl_opt/lab/benchmarks/x.py")
    assert found == [
        "2: import factirl_opt._threads",
        "4: from factirl_opt.learners.adaptive import _subset",
        "8: assigns adaptive.N_FOLDS (factirl_opt.learners.adaptive)",
        "9: uses adaptive._run_folds",
        "10: assigns fo.FactIRL.max_iter (factirl_opt)",
        "11: assigns G.name (solvers.gauss_newton.GaussNewtonSolver)",
        "12: setattr(fitting, ...)",
    ], found
    # a results/ script may not use the harness's private helpers either
    assert library_misuse("from factirl_opt.lab.benchmarks.mce import _fit", "results/x/y.py") == [
        "1: from factirl_opt.lab.benchmarks.mce import _fit"]

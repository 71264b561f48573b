"""The notebooks, the guide and the README use public names only: no private module or name, nothing
from the benchmarks, no top-level alias that moved to a namespace."""

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

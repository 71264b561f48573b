"""The package's layers: imports point down only, no import cycle, the harness stays above the library.

Read from the AST, imports inside functions counted (``if TYPE_CHECKING:`` blocks aside), as
``../shared/checks/import_cycles.py`` reads them.
"""

import ast
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]

#: layer -> rank; a module may import its own layer and the layers of lower rank only
LAYERS = {
    "base": 0,  # exceptions, interruption, _validation, _params, validation, _threads, _progress, _deprecation, files
    "mdp": 1,
    "planning": 2,
    "parallel": 3,
    "tasks": 4,
    "objectives": 5,
    "evaluation": 6,
    "learners": 7,
    "adapters": 8,
    "datasets": 9,
    "persistence": 10,
    "factirl_opt": 11,  # the package root: the public surface
    "lab": 12,  # the experiment harness and the command line
}
BASE = {"exceptions", "interruption", "_validation", "_params", "validation", "_threads", "_progress", "_deprecation", "_version", "_batched",
        "files"}


def _modules(package):
    out = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = {**_modules("factirl_opt"), **_modules("solvers")}


def _is_type_checking(node):
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def imported_modules(name, path):
    """Every module of the two packages that ``name`` imports, anywhere in its body."""
    pkg = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()

    def visit(node):
        if isinstance(node, ast.If) and _is_type_checking(node):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            found.add(mod)
            found.update(f"{mod}.{a.name}" for a in node.names)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(path.read_text()))
    deps = set()
    for f in found:
        while f and f not in MODULES:
            f = f.rsplit(".", 1)[0] if "." in f else ""
        if f and f != name:
            deps.add(f)
    return deps


def layer(module):
    parts = module.split(".")
    if parts[0] == "solvers":
        return "solvers"
    if len(parts) == 1:
        return "factirl_opt"
    return "base" if parts[1] in BASE else parts[1]


def test_every_module_has_a_layer():
    unknown = sorted(m for m in MODULES if layer(m) not in LAYERS and layer(m) != "solvers")
    assert not unknown, f"modules outside every layer (add them to LAYERS or move them): {unknown}"


def test_imports_point_down_only():
    wrong = []
    for name, path in MODULES.items():
        own = layer(name)
        for dep in imported_modules(name, path):
            if own == "solvers":
                if not dep.startswith("solvers"):
                    wrong.append(f"{name} (the solvers leaf) imports {dep}")
                continue
            if layer(dep) == "solvers":
                continue
            if own == "factirl_opt" and dep.startswith("factirl_opt.") and name == "factirl_opt" and layer(dep) != "lab":
                continue  # the root re-exports every layer but the harness
            if LAYERS[layer(dep)] > LAYERS[own]:
                wrong.append(f"{name} ({own}) imports {dep} ({layer(dep)})")
    assert not wrong, "imports pointing up the layers:\n" + "\n".join(sorted(wrong))


def _cycles(graph):
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            strong(v)
    return out


def test_no_import_cycle():
    graph = {}
    for name, path in MODULES.items():
        deps = imported_modules(name, path)
        if path.name == "__init__.py":  # a package re-exporting its children is not a cycle with them
            deps = {d for d in deps if not d.startswith(name + ".")}
        graph[name] = deps
    assert _cycles(graph) == []


def test_the_layer_check_sees_imports_inside_functions(tmp_path):
    path = tmp_path / "probe.py"
    path.write_text("def f():\n    from ..learners.gradirl import GradIRL\n")
    assert "factirl_opt.learners.gradirl" in imported_modules("factirl_opt.mdp.probe", path)


def test_no_module_mutates_another_at_import():
    """A module's top level never assigns into, or updates, a name it imported (registration by import)."""
    wrong = []
    for name, path in MODULES.items():
        tree = ast.parse(path.read_text())
        imported = {a.asname or a.name.split(".")[0] for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))
                    for a in n.names}
        for node in tree.body:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AugAssign) else []
            for t in targets:
                if isinstance(t, (ast.Subscript, ast.Attribute)) and isinstance(t.value, ast.Name) and t.value.id in imported:
                    wrong.append(f"{name}:{node.lineno} assigns into {t.value.id}")
            if isinstance(node, ast.Expr) and isinstance(node.value, ast.Call) and isinstance(node.value.func, ast.Attribute):
                owner = node.value.func.value
                if isinstance(owner, ast.Name) and owner.id in imported and node.value.func.attr in ("update", "setdefault", "append"):
                    wrong.append(f"{name}:{node.lineno} updates {owner.id}")
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("package", ["factirl_opt"])
def test_importing_the_library_loads_no_harness(package):
    code = ("import sys, factirl_opt; harness = sorted(m for m in sys.modules if m.startswith('factirl_opt.lab')); "
            "print(','.join(harness))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == ""

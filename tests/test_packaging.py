"""The distribution: version from the metadata, the files a release carries, and (slow) the wheel
installed in a fresh virtualenv running the quick reproduction."""

import os
import pathlib
import re
import subprocess
import sys
import venv

import pytest

import factirl_opt as fo

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _pyproject_version():
    match = re.search(r'^version = "([^"]+)"', (ROOT / "pyproject.toml").read_text(), flags=re.M)
    assert match, "pyproject.toml has no version"
    return match.group(1)


def test_version_is_a_string_from_the_metadata():
    assert isinstance(fo.__version__, str) and fo.__version__
    # an installed checkout reports pyproject's version; a never-installed tree says so
    assert fo.__version__ in (_pyproject_version(), "0+unknown")


def test_changelog_has_the_released_version_and_an_unreleased_section():
    text = (ROOT / "CHANGELOG.md").read_text()
    assert "## [Unreleased]" in text
    assert f"## [{_pyproject_version()}]" in text


def test_citation_file_names_the_software_and_the_paper():
    text = (ROOT / "CITATION.cff").read_text()
    assert "cff-version: 1.2.0" in text
    assert f"version: {_pyproject_version()}" in text
    assert "Feature learning for multi-task inverse reinforcement learning" in text
    assert "Mangin" in text and "Oudeyer" in text


def test_docs_extra_lists_the_site_tools():
    text = (ROOT / "pyproject.toml").read_text()
    docs = re.search(r"^docs = \[(.*?)\]", text, flags=re.S | re.M)
    assert docs, "pyproject.toml has no docs extra"
    for tool in ("sphinx", "pydata-sphinx-theme", "numpydoc", "sphinx-gallery", "myst-parser"):
        assert f'"{tool}>=' in docs.group(1)


def _run(cmd, **kwargs):
    result = subprocess.run(cmd, capture_output=True, text=True, **kwargs)
    assert result.returncode == 0, f"{' '.join(map(str, cmd))} failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    return result


@pytest.mark.slow
def test_wheel_installs_in_a_fresh_virtualenv_and_runs_the_quick_reproduction(tmp_path):
    """``python -m build`` gives an sdist and a wheel that ``twine check`` accepts; the wheel
    (not editable) installs in a fresh virtualenv, and its command runs the quick preset."""
    pytest.importorskip("build")
    pytest.importorskip("twine")
    dist = tmp_path / "dist"
    _run([sys.executable, "-m", "build", "--outdir", str(dist), str(ROOT)])
    wheels, sdists = sorted(dist.glob("*.whl")), sorted(dist.glob("*.tar.gz"))
    assert len(wheels) == 1 and len(sdists) == 1
    _run([sys.executable, "-m", "twine", "check", "--strict", *map(str, wheels + sdists)])

    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True, clear=True).create(env_dir)
    python = env_dir / "bin" / "python"
    # nothing of this checkout on the path: pip would take its build metadata for an installed copy
    clean = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    _run([str(python), "-m", "pip", "install", "--quiet", str(wheels[0])], cwd=tmp_path, env=clean)
    # imported from the virtualenv's site-packages, not from this checkout
    out = _run([str(python), "-c", "import factirl_opt as fo; print(fo.__file__); print(fo.__version__)"],
               cwd=tmp_path, env=clean).stdout.split()
    assert str(env_dir) in out[0] and str(ROOT) not in out[0]
    assert out[1] == _pyproject_version()

    runs = tmp_path / "runs" / "quick"
    _run([str(env_dir / "bin" / "factirl-opt"), "reproduce", "--preset", "quick", "--out", str(runs), "--quiet"],
         cwd=tmp_path, env=clean, timeout=1800)
    assert (runs / "manifest.json").is_file()
    assert any(runs.glob("*.csv")) and any(runs.rglob("*.png"))


# Modules the tests import only behind ``pytest.importorskip`` or ``except ImportError``, and that
# the test extra leaves out on purpose, with the reason. Every other third-party import of the
# tests (and of the docs code they load) must come with ``pip install -e ".[test]"``.
OPTIONAL_TEST_IMPORTS = {
    "minari": "needs Python >= 3.11 and, to record datasets, jax (minari's 'create' extra): the minari extra",
    "jax": "minari.DataCollector's own need, several hundred MB; the Minari recording tests skip without it",
    "pandas": "only shows cv_results_ as a table in one test; the table itself is plain arrays",
}


def _imports_of(path):
    """(top-level module, guarded) for each import in ``path``: ``guarded`` when the import is a
    ``pytest.importorskip``, sits in a ``try`` that catches ImportError, or is of a module that
    its function already took through ``importorskip``."""
    import ast

    tree = ast.parse(path.read_text())
    guarded_nodes = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            skipped = {call.args[0].value.split(".")[0] for call in ast.walk(node)
                       if isinstance(call, ast.Call) and getattr(call.func, "attr", None) == "importorskip"
                       and call.args and isinstance(call.args[0], ast.Constant)}
            guarded_nodes.update(id(n) for n in ast.walk(node) if isinstance(n, (ast.Import, ast.ImportFrom))
                                 and any((a.name if isinstance(n, ast.Import) else n.module or "").split(".")[0]
                                         in skipped for a in n.names))
        if isinstance(node, ast.Try) and any(
                "ImportError" in ast.dump(h.type) or "ModuleNotFoundError" in ast.dump(h.type)
                for h in node.handlers if h.type is not None):
            for inner in node.body:
                guarded_nodes.update(id(n) for n in ast.walk(inner))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "importorskip"
              and node.args and isinstance(node.args[0], ast.Constant)):
            found.append((node.args[0].value.split(".")[0], True))
            continue
        else:
            continue
        found.extend((name.split(".")[0], id(node) in guarded_nodes) for name in names)
    return found


def _installed_closure(requirements, extras_of=()):
    """Canonical names of the distributions that installing ``requirements`` brings, following the
    installed metadata's own requirements (with their extras' markers)."""
    from importlib import metadata

    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    closure, missing = set(), []
    todo = [Requirement(r) for r in requirements]
    while todo:
        req = todo.pop()
        name = canonicalize_name(req.name)
        key = (name, frozenset(req.extras))
        if key in closure:
            continue
        closure.add(key)
        try:
            dist_requires = metadata.requires(req.name) or []
        except metadata.PackageNotFoundError:
            missing.append(req.name)
            continue
        for text in dist_requires:
            sub = Requirement(text)
            if sub.marker is None or any(sub.marker.evaluate({"extra": e}) for e in ("", *req.extras)):
                todo.append(sub)
    return {name for name, _ in closure}, missing


def test_every_third_party_import_of_the_tests_comes_with_the_test_extra():
    """``pip install -e ".[test]" && python -m pytest`` (the README's test command, run by .ci/run
    on a fresh machine) must not need a module that only another extra or a hand install brings:
    each import of tests/ and of the docs code the tests load or run is the standard library, this
    project's own, or a distribution the core dependencies and the test extra install."""
    tomllib = pytest.importorskip("tomllib", reason="Python < 3.11 has no tomllib")
    from importlib import metadata

    from packaging.utils import canonicalize_name

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    closure, missing = _installed_closure([*project["dependencies"], *project["optional-dependencies"]["test"]])
    assert not missing, f"the test extra is not installed here (run pip install -e '.[test]'): {missing}"
    module_dists = metadata.packages_distributions()
    own = {"factirl_opt", "solvers", "conftest"}
    files = [*(ROOT / "tests").rglob("*.py"), *(ROOT / "docs").rglob("*.py")]
    local = {p.stem for p in files} | {p.parent.name for p in files}
    wrong = []
    for path in files:
        if "_build" in path.parts:
            continue
        for module, guarded in _imports_of(path):
            if module in sys.stdlib_module_names or module in own or module in local:
                continue
            dists = {canonicalize_name(d) for d in module_dists.get(module, [])}
            if dists & closure or (guarded and module in OPTIONAL_TEST_IMPORTS):
                continue
            wrong.append(f"{path.relative_to(ROOT)} imports {module} ({', '.join(sorted(dists)) or 'not installed'})")
    assert not wrong, "not brought by the core dependencies + test extra:\n" + "\n".join(sorted(set(wrong)))


def test_the_check_of_the_test_imports_sees_a_missing_extra(tmp_path):
    """The check above finds a guarded and an unguarded import, and a requirement not installed."""
    sample = tmp_path / "sample.py"
    sample.write_text("import os\nimport sphinx\ntry:\n    import pandas\nexcept ImportError:\n    pass\n"
                      "def f(pytest):\n    pytest.importorskip('jax')\n    from jax import numpy\n    import minari\n")
    assert sorted(_imports_of(sample)) == [("jax", True), ("jax", True), ("minari", False), ("os", False),
                                           ("pandas", True), ("sphinx", False)]
    closure, missing = _installed_closure(["numpy", "no-such-distribution-here"])
    assert "numpy" in closure and missing == ["no-such-distribution-here"]

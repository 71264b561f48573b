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

"""Names and modules that moved when the package was cut into layers stay importable for one release."""

import subprocess
import sys
import warnings

import pytest

import factirl_opt as fo
from factirl_opt import _deprecation


@pytest.fixture(autouse=True)
def fresh_warnings(monkeypatch):
    monkeypatch.setattr(_deprecation, "_warned", set())


@pytest.mark.parametrize("name, namespace", [("ObjectWorld", "objectworld"), ("objectworld_maps", "objectworld"),
                                             ("ValidationError", "exceptions"), ("read_minari", "adapters"),
                                             ("from_successors", "mdp"), ("residual_jacobian", "objectives"),
                                             ("TaskFeatures", "tasks")])
def test_a_former_top_level_name_is_the_object_in_its_namespace_and_warns_once(name, namespace):
    with pytest.warns(FutureWarning, match=rf"factirl_opt\.{name} moved to fo\.{namespace}\.{name}"):
        value = getattr(fo, name)
    assert value is getattr(getattr(fo, namespace), name)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert getattr(fo, name) is value  # once per name


def test_the_top_level_is_the_core_and_every_public_name_resolves():
    assert len(fo.__all__) <= 45
    for name in fo.__all__:
        assert getattr(fo, name) is not None
    assert "ObjectWorld" not in fo.__all__ and "ObjectWorld" in dir(fo)
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        fo.nonsense


def test_namespaces_load_on_first_access():
    assert fo.objectworld.ObjectWorld.__module__ == "factirl_opt.datasets.objectworld.world"
    assert fo.datasets.synthetic_tasks is fo.synthetic_tasks


@pytest.mark.parametrize("old, new", [("factirl_opt.gradirl", "factirl_opt.learners.gradirl"),
                                      ("factirl_opt.objectworld.world", "factirl_opt.datasets.objectworld.world"),
                                      ("factirl_opt.experiments.presets", "factirl_opt.lab.experiments.presets")])
def test_a_former_module_path_imports_the_module_itself(old, new):
    code = (f"import importlib, warnings\nwarnings.simplefilter('always')\n"
            f"with warnings.catch_warnings(record=True) as w:\n"
            f"    a = importlib.import_module({old!r})\n"
            f"b = importlib.import_module({new!r})\n"
            f"assert a is b, (a, b)\n"
            f"assert any('moved to {new}' in str(x.message) and issubclass(x.category, FutureWarning) for x in w), [str(x.message) for x in w]\n")
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("old, new, argv, expected", [
    ("factirl_opt.bench", "factirl_opt.lab.bench", ["--help"], "usage: python -m factirl_opt.lab.bench"),
    ("factirl_opt.cli", "factirl_opt.lab.cli", ["reproduce", "--help"], "--preset"),
])
def test_python_m_on_a_former_module_path_runs_the_new_one(old, new, argv, expected):
    """``python -m factirl_opt.bench ...`` (the commands of older READMEs) runs ``factirl_opt.lab.bench``
    with the same arguments and warns; it used to fail inside runpy (the alias loader had no code)."""
    res = subprocess.run([sys.executable, "-W", "always", "-m", old, *argv], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert expected in res.stdout
    assert f"moved to {new}" in res.stderr and "DeprecatedNameWarning" in res.stderr

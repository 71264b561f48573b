"""Names and modules that moved when the package was cut into layers stay importable for one release."""

import importlib
import json
import pathlib
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


def test_every_former_top_level_name_resolves_with_a_warning():
    """All of the package's former top-level names (two of them, the multi-environment objective
    and its constructor, pointed at a namespace that does not hold them)."""
    assert len(fo._MOVED_NAMES) >= 45
    for name, (module, namespace) in fo._MOVED_NAMES.items():
        new = fo._RENAMED_NAMES.get(name, name)  # renamed too: the warning names the current name
        what = f"moved to {namespace}\\.{name}" if new == name else f"was renamed {namespace}\\.{new}"
        with pytest.warns(FutureWarning, match=rf"factirl_opt\.{name} {what}; "):
            value = getattr(fo, name)
        assert value is getattr(sys.modules[module], new), name
        assert value is eval(namespace + "." + new, {"fo": fo}), name  # the namespace the warning names holds it


#: the public names each former module path held at the commit before the move (3825363^), written
#: by the script in this file's ``former_module_contents`` docstring
FORMER_CONTENTS = pathlib.Path(__file__).parent / "data" / "former_module_contents.json"
#: names removed since, on purpose (a former path cannot resolve a name that exists nowhere)
REMOVED = {
    "factirl_opt.em": {"POLICY_OBJECTIVES"},  # 014dad2: EM scores episodes through Objective.log_policy
    "factirl_opt.experiments.babyai": {"BabyAIGroundTruth", "ENV_IDS"},  # 3825363: datasets.babyai.BabyAITasks
    "factirl_opt.fitting": {"Environments", "environments_setup"},  # 25a26e5: tasks.task_set builds a TaskSet
    "factirl_opt.task_environments": {"environments",  # 50e3cfd: check_environments is the one home
                                      "task_rewards"},  # 25a26e5: TaskSet.rewards (tasks.features.task_rewards is D h)
    "factirl_opt.transfer": {"environments_transfer_setup"},  # 68946e2: transfer_tasks builds the new tasks' TaskSet
}


def former_module_contents():
    """The former contents, as written by (from the repository root, with git history)::

        git ls-tree -r --name-only 3825363^ factirl_opt  # each module under a former path of fo._MOVED_MODULES:
        # its top-level def, class and assigned names without a leading underscore, and its __all__
        # (learners.adaptive and learners.evidence: as at 991e151, before the selection package)
    """
    return json.loads(FORMER_CONTENTS.read_text())


def test_every_former_module_path_resolves_what_it_held():
    contents = former_module_contents()
    heads = {next((m for m in fo._MOVED_MODULES if f"{old}.".startswith(f"factirl_opt.{m}.")), old) for old in contents}
    assert heads == set(fo._MOVED_MODULES)  # every former path, children too
    missing = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        for old, names in contents.items():
            module = importlib.import_module(old)
            gone = {name for name in names if not hasattr(module, name)}
            if gone:
                missing[old] = gone
    assert missing == REMOVED


@pytest.mark.parametrize("old, name, home", [
    (old, name, home) for old, names in fo._MOVED_MODULE_NAMES.items() for name, home in names.items()])
def test_a_name_that_left_a_former_module_resolves_through_it_with_a_warning(old, name, home):
    module = importlib.import_module(f"factirl_opt.{old}")
    with pytest.warns(FutureWarning, match=rf"factirl_opt\.{old}\.{name} moved to factirl_opt\.{home}\.{name}; "):
        value = getattr(module, name)
    assert value is getattr(importlib.import_module(f"factirl_opt.{home}"), name)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert getattr(module, name) is value  # once per name
    with pytest.raises(AttributeError, match=rf"has no attribute 'nonsense'"):
        module.nonsense


def test_to_successors_through_its_former_path_in_a_fresh_process():
    code = ("import warnings\nwarnings.simplefilter('error')\n"
            "try:\n    import factirl_opt.successors\nexcept FutureWarning as w:\n    print(w)\n"
            "warnings.simplefilter('ignore')\nimport factirl_opt.successors\nwarnings.simplefilter('error')\n"
            "try:\n    from factirl_opt.successors import to_successors\nexcept FutureWarning as w:\n    print(w)\n"
            "warnings.simplefilter('ignore')\n"
            "from factirl_opt.successors import to_successors\nimport factirl_opt as fo\n"
            "sa_s, sa_p = to_successors(fo.GridWorld(size=2))\nprint(sa_s.shape, to_successors is fo.mdp.to_successors)\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines() == [
        "the module factirl_opt.successors moved to factirl_opt.mdp.successors (from_successors, to_successors: now "
        "in factirl_opt.mdp.tabular); the old path will be removed in the next release",
        "factirl_opt.successors.to_successors moved to factirl_opt.mdp.tabular.to_successors; the old path will be "
        "removed in the next release",
        "(4, 4, 2) True"]


@pytest.mark.parametrize("access", [
    "fo.MissingSolverBackendError",  # renamed too: one warning naming the current name, not its deprecated alias
    "from factirl_opt import MissingSolverBackendError",  # the import statement reads the name twice
    "from factirl_opt import ObjectWorld",
    "fo.ObjectWorld",
    "import factirl_opt.objectworld.world",  # a former package's child: the package is imported first
    "from factirl_opt.experiments.presets import PRESETS",
    "importlib.import_module('factirl_opt.gradirl')",
    "from factirl_opt.successors import from_successors",  # a former module and a name that left it: one access
])
def test_one_warning_per_deprecated_access_at_the_users_line(tmp_path, access):
    """A fresh process: the access warns once, at the line of the user's script that made it, and the
    warning names where the object is now (never another deprecated name)."""
    script = tmp_path / "user_script.py"
    script.write_text("import importlib, json, warnings\nimport factirl_opt as fo\n"
                      "with warnings.catch_warnings(record=True) as caught:\n"
                      "    warnings.simplefilter('always')\n"
                      f"    {access}\n"
                      "print(json.dumps([[w.category.__name__, w.filename, w.lineno, str(w.message)] for w in caught]))\n")
    res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=pathlib.Path(fo.__file__).parents[1])
    assert res.returncode == 0, res.stderr
    caught = json.loads(res.stdout)
    assert len(caught) == 1, caught
    category, filename, lineno, message = caught[0]
    assert (category, filename, lineno) == ("DeprecatedNameWarning", str(script), 5), caught
    if "from_successors" in access:
        assert "from_successors, to_successors: now in factirl_opt.mdp.tabular" in message, message
    if "MissingSolverBackendError" in access:
        assert "renamed fo.exceptions.MissingSolverDependencyError" in message, message

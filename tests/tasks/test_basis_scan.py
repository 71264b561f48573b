"""No branch on the kind of reward features below the estimators (read from the AST).

The kind of features (tabular, state, one shared matrix, one per task) lives in
:mod:`factirl_opt.tasks` (:class:`~factirl_opt.tasks.basis.RewardBasis`): elsewhere no
``isinstance(..., TaskFeatures | StateBroadcast)``, and in the learners, objectives,
evaluation, parallel and planning layers no ``features is None`` / ``Phi is None`` test
(persistence and the harness may still read the public ``features=None`` parameter).
"""

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "factirl_opt"

#: the classes that name a kind of features
KIND_CLASSES = {"TaskFeatures", "StateBroadcast"}
#: the names whose None-ness would be a test of the kind of features
FEATURE_NAMES = {"features", "Phi", "base_features", "F"}
#: where no None test of the features may stand
NO_NONE_TESTS = ["learners", "objectives", "evaluation.py", "parallel", "planning"]
#: files the scans skip (none: the validation search works on the task set's row subsets)
EXCLUDED: set[str] = set()


def _files(*parts):
    for part in parts:
        path = PACKAGE / part
        for f in sorted([path] if path.is_file() else path.rglob("*.py")):
            if str(f.relative_to(PACKAGE)) not in EXCLUDED:
                yield f


def _names(node):
    """The class names in an isinstance's second argument (a name, an attribute or a tuple/union of them)."""
    if isinstance(node, ast.Name):
        return {node.id}
    if isinstance(node, ast.Attribute):
        return {node.attr}
    if isinstance(node, ast.Tuple):
        return set().union(*map(_names, node.elts)) if node.elts else set()
    if isinstance(node, ast.BinOp):
        return _names(node.left) | _names(node.right)
    return set()


def kind_branches(path):
    """``(line, text)`` of every ``isinstance(x, <a kind of features>)`` in ``path``."""
    tree = ast.parse(path.read_text())
    return [(n.lineno, ast.unparse(n)) for n in ast.walk(tree)
            if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == "isinstance"
            and len(n.args) == 2 and _names(n.args[1]) & KIND_CLASSES]


def _feature_name(node):
    return (isinstance(node, ast.Name) and node.id in FEATURE_NAMES) or \
        (isinstance(node, ast.Attribute) and node.attr in FEATURE_NAMES)


def none_tests(path):
    """``(line, text)`` of every ``<features> is None`` / ``is not None`` in ``path``."""
    tree = ast.parse(path.read_text())
    out = []
    for n in ast.walk(tree):
        if isinstance(n, ast.Compare) and any(isinstance(op, (ast.Is, ast.IsNot)) for op in n.ops):
            operands = [n.left, *n.comparators]
            if any(isinstance(o, ast.Constant) and o.value is None for o in operands) and any(map(_feature_name, operands)):
                out.append((n.lineno, ast.unparse(n)))
    return out


def test_no_feature_kind_branch_outside_tasks():
    found = [f"{f.relative_to(ROOT)}:{line}: {text}" for f in _files(".") if "tasks" not in f.relative_to(PACKAGE).parts
             for line, text in kind_branches(f)]
    assert found == []


def test_no_features_none_test_below_the_estimators():
    found = [f"{f.relative_to(ROOT)}:{line}: {text}" for f in _files(*NO_NONE_TESTS) for line, text in none_tests(f)]
    assert found == []


@pytest.mark.parametrize("source, n_branches, n_none", [
    ("if isinstance(F, TaskFeatures): pass", 1, 0),
    ("x = isinstance(F, (np.ndarray, StateBroadcast))", 1, 0),
    ("x = isinstance(F, features.TaskFeatures | int)", 1, 0),
    ("x = F if Phi is None else 0", 0, 1),
    ("x = model.features is not None", 0, 1),
    ("x = isinstance(F, np.ndarray) and other is None", 0, 0),
])
def test_the_scan_sees_what_it_looks_for(tmp_path, source, n_branches, n_none):
    path = tmp_path / "m.py"
    path.write_text(source + "\n")
    assert (len(kind_branches(path)), len(none_tests(path))) == (n_branches, n_none)

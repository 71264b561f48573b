"""The scripts of results/which-learner use the library's public names only and never assign into a library module."""

import ast
import pathlib

import pytest

SCRIPTS = sorted((pathlib.Path(__file__).resolve().parents[2] / "results" / "which-learner").glob("*.py"))


def _library_names(tree):
    """The names a script binds to factirl_opt modules or objects (``import factirl_opt as fo``,
    ``from factirl_opt.learners import adaptive``, ...)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update((a.asname or a.name).split(".")[0] for a in node.names if a.name.startswith("factirl_opt"))
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("factirl_opt"):
            names.update(a.asname or a.name for a in node.names)
    return names


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_a_script_uses_public_names_and_leaves_the_library_alone(script):
    tree = ast.parse(script.read_text())
    library = _library_names(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("factirl_opt"):
            private = [part for part in node.module.split(".") + [a.name for a in node.names] if part.startswith("_")]
            assert not private, f"{script.name}:{node.lineno} imports the private {private[0]}"
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in library:
            assert not node.attr.startswith("_"), f"{script.name}:{node.lineno} uses the private {node.value.id}.{node.attr}"
        if isinstance(node, (ast.Assign, ast.AugAssign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                base = target
                while isinstance(base, (ast.Attribute, ast.Subscript)):
                    base = base.value
                assert not (target is not base and isinstance(base, ast.Name) and base.id in library), \
                    f"{script.name}:{node.lineno} assigns into the library ({ast.unparse(target)})"


def test_there_are_scripts():
    assert any(p.name == "_point.py" for p in SCRIPTS)

"""The type checker passes on both packages (``factirl_opt`` and ``solvers``) under the
repository's mypy configuration (``[tool.mypy]`` in pyproject.toml; mypy is in the test extra),
and the estimators' public signatures say what each parameter takes (no ``Any``)."""

import collections.abc
import inspect
import pathlib
import subprocess
import sys
import types
import typing

import pytest

import factirl_opt as fo

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_mypy_passes_on_the_packages():
    out = subprocess.run(
        [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml")],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Success: no issues found" in out.stdout


#: the generic containers whose arguments are part of what a parameter takes (a third-party
#: generic such as numpy's ``dtype[Any]`` inside ``ArrayLike`` is that library's own business)
_CONTAINERS = (typing.Union, types.UnionType, tuple, list, dict, type, collections.abc.Sequence, collections.abc.Mapping)


def _annotations_naming_any(hint):
    """Whether a resolved type hint is ``Any`` or holds ``Any`` (in a union, a tuple, a type[...])."""
    if hint is typing.Any:
        return True
    if typing.get_origin(hint) not in _CONTAINERS:
        return False
    return any(_annotations_naming_any(arg) for arg in typing.get_args(hint) if arg is not Ellipsis)


@pytest.mark.parametrize("name", ["GradIRL", "FactIRL", "MultiIntentIRL"])
def test_estimator_parameters_say_what_they_take(name):
    """Every parameter of the three estimators is annotated, resolvable, and nowhere ``Any``."""
    cls = getattr(fo, name)
    hints = typing.get_type_hints(cls.__init__)
    params = [p for p in inspect.signature(cls).parameters]
    assert params, name
    missing = [p for p in params if p not in hints]
    assert not missing, f"{name}: parameters without an annotation: {missing}"
    vague = {p: hints[p] for p in params if _annotations_naming_any(hints[p])}
    assert not vague, f"{name}: parameters annotated with Any: {vague}"


def test_the_any_detector_looks_inside_unions_and_tuples():
    assert _annotations_naming_any(typing.Any)
    assert _annotations_naming_any(typing.Optional[typing.Any])
    assert _annotations_naming_any(tuple[int, typing.Any])
    assert _annotations_naming_any(dict[str, typing.Any])
    assert not _annotations_naming_any(typing.Union[int, typing.Literal["auto"]])
    assert not _annotations_naming_any(tuple[int, ...])
    assert _annotations_naming_any(collections.abc.Sequence[typing.Any] | None)

    def former(features: typing.Any = None, solver: str | typing.Any = "armijo") -> None:  # the signatures before
        pass

    assert all(_annotations_naming_any(h) for h in typing.get_type_hints(former).values() if h is not type(None))


#: the namespaces whose ``__all__`` is public (``fo.<name>``), besides the top level
NAMESPACES = ("datasets", "adapters", "exceptions", "mdp", "tasks", "objectives", "parallel", "planning", "learners",
              "persistence", "validation", "evaluation", "interruption", "files")


def _public_callables():
    """``(label, callable)`` for every function and class in ``fo.__all__`` and the namespaces'
    ``__all__``, and every public method, class method and property getter of those classes."""
    seen = set()
    for prefix, module in [("fo", fo)] + [(f"fo.{n}", getattr(fo, n)) for n in NAMESPACES]:
        for name in module.__all__:
            obj = getattr(module, name)
            if id(obj) in seen or isinstance(obj, types.ModuleType) or not callable(obj):
                continue
            seen.add(id(obj))
            yield f"{prefix}.{name}", obj
            if inspect.isclass(obj):
                for attr, member in vars(obj).items():
                    if attr.startswith("_") and attr != "__init__":
                        continue
                    fn = member.fget if isinstance(member, property) else getattr(member, "__func__", member)
                    if inspect.isfunction(fn):
                        yield f"{prefix}.{name}.{attr}", fn


def test_type_hints_of_every_public_callable_resolve_without_localns():
    """``typing.get_type_hints`` works on every public callable as it stands: no annotation names a
    type imported under ``TYPE_CHECKING`` only (``Client``, ``TabularMDP``)."""
    callables = list(_public_callables())
    assert len(callables) > 300
    failed = {}
    for label, obj in callables:
        try:
            typing.get_type_hints(obj)
        except Exception as exc:  # noqa: BLE001 - every failure is reported
            failed[label] = f"{type(exc).__name__}: {exc}"
    assert not failed, failed


def test_the_client_annotation_is_dask_client_without_importing_distributed():
    """The execution group's ``client`` hint is ``distributed.Client`` for ``isinstance`` and in the docs, and
    resolving it imports nothing (a fresh process: ``distributed`` costs a second to import)."""
    code = ("import sys, typing, factirl_opt as fo; h = typing.get_type_hints(fo.Execution)['client']; "
            "print(typing.get_args(h)[0].__module__, typing.get_args(h)[0].__qualname__, 'distributed' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["distributed", "Client", "False"], out.stdout + out.stderr
    distributed = pytest.importorskip("distributed")
    client_hint = typing.get_args(typing.get_type_hints(fo.Execution)["client"])[0]
    assert not isinstance(object(), client_hint)
    assert issubclass(distributed.Client, client_hint)

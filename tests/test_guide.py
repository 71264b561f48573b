"""The user guide's code runs as written: every python block of docs/guide.md, in order."""

import pathlib
import re

import pytest

GUIDE = pathlib.Path(__file__).resolve().parents[1] / "docs" / "guide.md"


def with_includes(path):
    """The text of a page of the docs with its ``{include}`` directives replaced by what they include
    (``:start-after:`` / ``:end-before:`` honoured), as the site shows it."""
    def include(match):
        target, options = (path.parent / match.group(1)).resolve(), dict(re.findall(r':([\w-]+): "(.*?)"', match.group(2)))
        text = target.read_text()
        if "start-after" in options:
            text = text.split(options["start-after"], 1)[1]
        if "end-before" in options:
            text = text.split(options["end-before"], 1)[0]
        return text
    return re.sub(r"```\{include\} (\S+)\n((?::[\w-]+: .*\n)*)```", include, path.read_text())


def test_guide_code_blocks_run_in_order(capsys):
    pytest.importorskip("gymnasium")
    blocks = re.findall(r"```python\n(.*?)```", with_includes(GUIDE), flags=re.S)
    assert len(blocks) >= 6, "the guide lost its examples"
    namespace = {}
    for i, block in enumerate(blocks):
        exec(compile(block, f"docs/guide.md (python block {i})", "exec"), namespace)
    out = capsys.readouterr().out
    assert "FrozenLake 8x8 train deviation" in out
    flat_dev, fact_dev = map(float, re.search(r"train tasks: flat ([\d.]+), factorial ([\d.]+)", out).groups())
    assert fact_dev < flat_dev  # the guide's first example shows the factorial learner winning
    lake = namespace["lake"]
    assert (lake.n_states, lake.n_actions) == (64, 4)
    assert namespace["fact_lake"].dictionary_.shape == (256, 3)
    assert namespace["h_new"].shape == (10, 5)
    # demonstrations from other libraries: the rollouts read back exactly, in the library's layout
    assert "is a single episode" in out and "pass [demos_per_task] (1 task of 2 episodes)" in out
    demos_task0, rollouts = namespace["demos_task0"], namespace["rollouts"]
    assert len(demos_task0) == 1 and len(demos_task0[0]) == len(rollouts)
    for ep, rec in zip(demos_task0[0], rollouts):
        assert ep.dtype.kind == "i" and ep[:, 0].tolist() == rec["obs"][:-1] and ep[:, 1].tolist() == rec["acts"]
    assert namespace["h_rollouts"].shape == (1, 3)

"""The README's library example runs as written (so the README cannot rot)."""

import pathlib
import re

import numpy as np

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_example_runs(capsys):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks, "README.md has no python example"
    namespace = {}
    exec(compile(blocks[0], "README.md", "exec"), namespace)
    flat_dev, fact_dev = map(float, capsys.readouterr().out.split())
    assert fact_dev < flat_dev  # the README's point: the factorial learner beats the flat one
    assert namespace["h_new"].shape == (10, 5)
    assert np.all(np.isfinite(namespace["h_new"]))


def test_readme_gives_the_two_setup_commands():
    text = README.read_text()
    assert "pip install -e . && factirl-opt reproduce --preset quick" in text
    assert 'pip install -e ".[test]" && python -m pytest' in text
    ci = (README.parent / ".ci" / "run").read_text()
    assert 'pip install -e ".[test]" && python -m pytest' in ci


def test_readme_many_environments_example_runs(capsys):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    example = next(b for b in blocks if "objectworld_maps" in b)
    namespace = {}
    exec(compile(example, "README.md", "exec"), namespace)
    dev = float(capsys.readouterr().out.split()[-1])
    assert np.isfinite(dev) and dev >= 0.0
    assert namespace["h"].shape == (5, 3)
    assert namespace["fact"].dictionary_.shape == (namespace["feats"][0].shape[1], 3)
    assert [np.shape(r) for r in namespace["R_new"]] == [(m.n_states, m.n_actions) for m in namespace["new_mdps"]]

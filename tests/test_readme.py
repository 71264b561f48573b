"""The README's library example runs as written (so the README cannot rot)."""

import pathlib
import re
import warnings

import numpy as np

from factirl_opt.exceptions import MaxIterWarning

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_example_runs(capsys):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks, "README.md has no python example"
    namespace = {}
    with warnings.catch_warnings():
        warnings.simplefilter("error", MaxIterWarning)  # every task of the example converges
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


def test_readme_fits_on_a_screen_and_its_links_exist():
    text = README.read_text()
    assert len(text.splitlines()) <= 200
    for target in re.findall(r"\]\(([^)#]+)\)", text):
        if not target.startswith("http"):
            assert (README.parent / target).exists(), f"README links to {target}, which does not exist"


def test_readme_gives_the_docs_build_command_and_ci_runs_it():
    command = 'pip install -e ".[docs]" && python -m sphinx -W -b html docs docs/_build/html'
    assert command in README.read_text()
    assert command in (README.parent / ".ci" / "run").read_text()


def test_readme_headline_table_is_included_by_the_results_page():
    """One truth per number: the headline table lives in the README, the site includes it."""
    text = README.read_text()
    assert text.count("<!-- headline: start -->") == 1 and text.count("<!-- headline: end -->") == 1
    results = (README.parent / "docs" / "results.md").read_text()
    assert '"<!-- headline: start -->"' in results and "| train tasks | 4.08" not in results

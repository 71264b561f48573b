"""The README's library example runs as written (so the README cannot rot)."""

import pathlib
import re
import warnings

import numpy as np


README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def ten_lines():
    """The README's ten lines (the one example the guide and the getting-started page include) and the
    output the README shows for them."""
    text = README.read_text()
    section = text[text.index("<!-- ten-lines: start -->"):text.index("<!-- ten-lines: end -->")]
    (code,) = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    (shown,) = re.findall(r"```text\n(.*?)```", section, flags=re.S)
    return code, shown


def same_up_to_rounding(printed, shown, rtol=0.05):
    """The same lines with the same words, each number within ``rtol`` (other machines' BLAS kernels
    move the last digits of a fit)."""
    number = r"-?\d+\.\d+"
    if re.sub(number, "#", printed).split() != re.sub(number, "#", shown).split():
        return False
    return np.allclose([float(x) for x in re.findall(number, printed)], [float(x) for x in re.findall(number, shown)],
                       rtol=rtol, atol=0.05)


def test_the_ten_lines_run_without_a_warning_and_print_what_the_readme_shows(capsys):
    code, shown = ten_lines()
    namespace = {}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning at all: every transfer stops by its own rule
        exec(compile(code, "README.md (the ten lines)", "exec"), namespace)
    printed = capsys.readouterr().out
    assert same_up_to_rounding(printed, shown), (printed, shown)
    flat_dev, fact_dev, flat_new, fact_new = map(float, re.findall(r"\d+\.\d+", printed))
    assert fact_dev < flat_dev and fact_new < flat_new  # the README's point: sharing wins, on both task sets
    assert namespace["h_new"].shape == (10, 5)
    assert np.all(np.isfinite(namespace["h_new"]))


def test_the_comparison_of_printed_and_shown_output_can_fail():
    shown = "train tasks: flat 3.65, factorial 1.61\n"
    assert same_up_to_rounding("train tasks: flat 3.66, factorial 1.60\n", shown)
    assert not same_up_to_rounding("train tasks: flat 3.65, factorial 1.91\n", shown)
    assert not same_up_to_rounding("train tasks: flat 3.65, fact 1.61\n", shown)


def test_the_guide_includes_the_ten_lines_from_the_readme():
    guide = (README.parent / "docs" / "guide.md").read_text()
    section = guide[guide.index("## The library in ten lines"):]
    section = section[:section.index("\n## ", 1)]
    assert '```{include} ../README.md\n:start-after: "<!-- ten-lines: start -->"\n:end-before: "<!-- ten-lines: end -->"' \
        in section
    assert "```python" not in section  # one example, not two


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

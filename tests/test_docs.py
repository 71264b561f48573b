"""The documentation site (docs/): its API pages (written at build time) cover every public name, its guide pages cut
docs/guide.md at headings that exist, and every gallery example runs and draws a plot.

The site itself is built by CI's second command (``python -m sphinx -W -b html docs OUT``,
see docs/development.md); the slow test at the end builds it and opens it in headless Chromium.
"""

import importlib.util
import os
import pathlib
import re
import shutil
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
EXAMPLES = sorted((DOCS / "examples").glob("plot_*.py"))


def _load(path, name):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def api():
    sys.path.insert(0, str(DOCS / "api"))
    try:
        yield _load(DOCS / "api" / "generate.py", "docs_api_generate"), _load(DOCS / "api" / "_sections.py", "docs_api_sections")
    finally:
        sys.path.remove(str(DOCS / "api"))


def test_every_public_name_has_one_page(api):
    """Each name of the top level's and each namespace's __all__ is listed on exactly one
    autosummary (its page), or links to the page of the same object."""
    generate, sections = api
    pages = generate.render()  # what docs/conf.py writes at every build
    listed = {}
    for page, _namespace, module_name, *_ in sections.SECTIONS:
        text = pages[page]
        table = text.split(":toctree: generated/", 1)[1].split("\n\n", 2)[1]
        for name in table.split():
            full = f"{module_name}.{name}"
            assert full not in listed, f"{full} listed twice"
            listed[full] = page
    where = sections.documented_where()
    for (namespace, name), full in where.items():
        assert full in listed, f"{namespace}.{name} ({full}) has no page"
    import factirl_opt as fo

    namespaces = {s[1] for s in sections.SECTIONS}
    for ns in ("fo", "fo.objectworld", "fo.minigrid", "fo.adapters", "fo.datasets", "fo.exceptions", "fo.mdp",
               "fo.tasks", "fo.objectives", "fo.learners", "fo.planning"):
        assert ns in namespaces, f"the API reference has no section for {ns}"
    assert {name for (ns, name) in where if ns == "fo"} == set(fo.__all__)


@pytest.fixture(scope="module")
def maths_links():
    return _load(DOCS / "_ext" / "maths_links.py", "docs_maths_links")


@pytest.mark.parametrize("text, linked", [
    ("(docs/maths.md §5).", "(:ref:`docs/maths.md §5 <maths-5>`)."),
    ("docs/maths.md §7, §8 and", ":ref:`docs/maths.md §7 <maths-7>`, :ref:`§8 <maths-8>` and"),
    ("docs/maths.md §2 and §4;", ":ref:`docs/maths.md §2 <maths-2>` and :ref:`§4 <maths-4>`;"),
    ("docs/maths.md §5-6", ":ref:`docs/maths.md §5 <maths-5>`-:ref:`6 <maths-6>`"),
    ("docs/maths.md §8a,", ":ref:`docs/maths.md §8a <maths-8a>`,"),
    ("the docs/maths.md page", "the :doc:`docs/maths.md </maths>` page"),
    ("``docs/maths.md §8`` stays", "``docs/maths.md §8`` stays"),
    ("no citation", "no citation"),
])
def test_docstring_citations_of_the_maths_link_its_sections(maths_links, text, linked):
    assert maths_links.link_line(text) == linked


def test_every_cited_maths_section_has_its_label(maths_links):
    """Each section the docstrings cite (docs/maths.md §N) is a label of docs/maths.md, so the link resolves."""
    labels = set(re.findall(r"^\((maths-[0-9]+[a-z]?)\)=$", (DOCS / "maths.md").read_text(), re.M))
    cited = set()
    for path in [*(ROOT / "factirl_opt").rglob("*.py"), *(ROOT / "solvers").rglob("*.py")]:
        for line in path.read_text().splitlines():
            cited.update(re.findall(r"<(maths-[0-9]+[a-z]?)>", maths_links.link_line(line)))
    assert {"maths-5", "maths-8"} <= cited
    assert cited <= labels, sorted(cited - labels)


def test_deprecated_aliases_are_kept_off_the_api_pages(maths_links):
    import factirl_opt as fo
    import solvers

    assert maths_links.skip_deprecated(None, "class", "h_solver", fo.FactIRL.__dict__["h_solver"], False, None)
    assert maths_links.skip_deprecated(None, "class", "backend", solvers.GaussNewtonSolver.__dict__["backend"], False, None)
    assert maths_links.skip_deprecated(None, "class", "h_options", fo.SolverSettings.__dict__["h_options"], False, None) is None
    assert maths_links.skip_deprecated(None, "class", "fit", fo.FactIRL.fit, False, None) is None


def test_guide_pages_cut_the_guide_at_its_headings():
    guide = (DOCS / "guide.md").read_text()
    pages = sorted((DOCS / "guide").glob("*.md")) + [DOCS / "getting-started.md"]
    markers = []
    for page in pages:
        for key, value in re.findall(r'^:(start-after|end-before): "(.*)"$', page.read_text(), flags=re.M):
            assert value in guide, f"{page.name}: {key} {value!r} is not in docs/guide.md"
            markers.append(value)
    # every top-level section of the guide is on some page
    for heading in re.findall(r"^## .*$", guide, flags=re.M):
        starts = [m for m in markers if m == heading]
        assert starts or heading in ("## Install", "## The quick reproduction", "## The library in ten lines",
                                     "## Transfer: a new task from one demonstration"), f"{heading!r} is on no page"


def test_the_gallery_has_at_least_eight_examples():
    assert len(EXAMPLES) >= 8
    for path in EXAMPLES:
        text = path.read_text()
        assert text.startswith('"""\n'), f"{path.name}: sphinx-gallery needs a docstring title first"
        assert "plt.show()" in text, f"{path.name} draws no plot"


def test_gallery_examples_import_public_names_only():
    """What a reader copies from the gallery uses the public API: names in a module's ``__all__``,
    no private module, nothing from the harness's benchmarks."""
    import importlib

    for path in EXAMPLES:
        code = path.read_text()
        for module, names in re.findall(r"^from (factirl_opt[\w.]*) import ([\w, ]+)$", code, flags=re.M):
            assert not any(part.startswith("_") for part in module.split(".")), f"{path.name}: {module}"
            assert ".lab." not in module, f"{path.name} imports from the harness: {module}"
            exported = importlib.import_module(module).__all__
            for name in names.replace(" ", "").split(","):
                assert name in exported, f"{path.name}: {name} is not in {module}.__all__"


RUN_EXAMPLE = """
import runpy, sys
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
plt.show = lambda *args, **kwargs: None
runpy.run_path(sys.argv[1], run_name="__main__")
figures = plt.get_fignums()
assert figures, "the example made no figure"
for number in figures:
    plt.figure(number).savefig(sys.argv[2] + f"-{number}.png")
"""


@pytest.mark.parametrize("example", EXAMPLES, ids=lambda p: p.stem)
def test_gallery_example_runs_and_plots(example, tmp_path):
    if "babyai" in example.name:
        pytest.importorskip("minigrid")
    if "dask" in example.name:
        pytest.importorskip("distributed")
    env = {**os.environ, "MPLBACKEND": "Agg", "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    result = subprocess.run([sys.executable, "-c", RUN_EXAMPLE, str(example), str(tmp_path / example.stem)],
                            cwd=example.parent, env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, f"{example.name} failed:\n{result.stdout[-2000:]}\n{result.stderr[-4000:]}"
    assert sorted(tmp_path.glob("*.png")), f"{example.name} saved no figure"


def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if shutil.which(name):
            return shutil.which(name)
    return None


@pytest.mark.slow
def test_built_site_renders_in_headless_chromium(tmp_path):
    """Build the site with -W, then open the home page, an API page, a gallery page and the
    search page in headless Chromium; each renders (a screenshot is taken, the DOM holds the
    page's content). Screenshots are kept in a temporary directory whose paths are printed."""
    pytest.importorskip("sphinx")
    chromium = _chromium()
    if chromium is None:
        pytest.skip("no Chromium: apt-get install -y chromium")
    site = pathlib.Path(os.environ.get("FACTIRL_SITE", "")) if os.environ.get("FACTIRL_SITE") else None
    local_mathjax = pathlib.Path("/usr/share/javascript/mathjax/MathJax.js")  # Debian's libjs-mathjax
    if site is None or not (site / "index.html").is_file():
        site = tmp_path / "html"
        env = dict(os.environ)
        if local_mathjax.is_file():  # equations render without the CDN
            env["FACTIRL_MATHJAX_PATH"] = local_mathjax.as_uri()
        build = subprocess.run([sys.executable, "-m", "sphinx", "-W", "-q", "-b", "html", str(DOCS), str(site)],
                               cwd=ROOT, env=env, capture_output=True, text=True, timeout=3600)
        assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-6000:]
    shots = pathlib.Path(os.environ.get("FACTIRL_SCREENSHOTS", tmp_path / "screenshots"))
    shots.mkdir(parents=True, exist_ok=True)
    pages = {
        "home": ("index.html", ["factirl-opt", "Getting started"]),
        "api": ("api/generated/factirl_opt.FactIRL.html", ["FactIRL", "n_primitives", "transfer"]),
        "gallery": ("auto_examples/plot_paper_figures.html", ["figure 1", "sphx-glr-single-img"]),
        "search": ("search.html?q=transfer", ["search", "transfer"]),
    }
    if local_mathjax.is_file() and local_mathjax.as_uri() in (site / "maths.html").read_text():
        pages["maths"] = ("maths.html", ["§2 Planning", "MathJax-Element-"])  # equations typeset
    for name, (page, expected) in pages.items():
        url = (site / page.split("?")[0]).as_uri() + ("?" + page.split("?")[1] if "?" in page else "")
        common = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                  "--window-size=1280,1600", "--virtual-time-budget=10000"]
        png = shots / f"{name}.png"
        shot = subprocess.run(common + [f"--screenshot={png}", url], capture_output=True, text=True, timeout=120)
        assert shot.returncode == 0 and png.is_file() and png.stat().st_size > 10_000, shot.stderr[-2000:]
        dom = subprocess.run(common + ["--dump-dom", url], capture_output=True, text=True, timeout=120).stdout
        for text in expected:
            assert text in dom, f"{page}: {text!r} not in the rendered page"
        if name == "gallery":  # the plot is an image that loaded from the built site
            image = re.search(r'<img[^>]+src="([^"]*sphx_glr_plot_paper_figures_001[^"]*)"', dom)
            assert image, "the gallery page shows no plot"
            assert (site / "auto_examples" / image.group(1)).resolve().is_file()
        if name == "search":  # the search ran in the page's JavaScript and listed results
            found = re.search(r"Search finished, found (\d+) page", dom)
            assert found and int(found.group(1)) > 0, "the search page lists no result"
            assert re.search(r'<ul[^>]*class="search"[^>]*>\s*<li', dom)
            assert 'href="api/generated/factirl_opt.FactIRL.html#factirl_opt.FactIRL.transfer"' in dom
        print(f"screenshot {name}: {png}")

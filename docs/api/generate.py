"""Write the API reference's section pages (``docs/api/<page>.rst``) from the ``__all__`` lists.

``docs/conf.py`` runs it at every build (the pages are not committed); run it by hand with
``python docs/api/generate.py``. A page is rewritten only when its text changes.
"""

import pathlib
import sys

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))
sys.path.insert(0, str(HERE))

from _sections import SECTIONS, documented_where, public_names  # noqa: E402


def render():
    """Page name -> text of every section page."""
    where = documented_where()
    pages = {}
    for page, namespace, module_name, title, summary in SECTIONS:
        own, elsewhere = [], []
        for name in public_names(module_name):
            full = where[(namespace, name)]
            (own if full == f"{module_name}.{name}" else elsewhere).append((name, full))
        lines = [f".. _api-{page}:", "", title, "=" * len(title), "", summary, ""]
        if module_name != namespace.replace("fo", "factirl_opt", 1):
            lines += [f"The names live in ``{module_name}``; use them as ``{namespace}.NAME``.", ""]
        lines += [f".. currentmodule:: {module_name}", "", ".. autosummary::", "   :toctree: generated/", ""]
        lines += [f"   {name}" for name, _full in own]
        if elsewhere:
            lines += ["", "Also in this namespace, documented where they are listed first:", ""]
            lines += [f"- :py:obj:`{namespace}.{name} <{full}>`" for name, full in elsewhere]
        pages[page] = "\n".join(lines) + "\n"
    return pages


def main():
    for page, text in render().items():
        path = HERE / f"{page}.rst"
        if not path.is_file() or path.read_text() != text:
            path.write_text(text)


if __name__ == "__main__":
    main()

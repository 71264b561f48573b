"""Links from the docstrings to the sections of the maths page, and deprecated aliases off the API pages.

Docstrings cite the derivations as plain text, ``docs/maths.md §8`` (readable in ``help()`` and
in the source). On the site each such citation becomes a link to the section: every section
heading of ``docs/maths.md`` carries the label ``maths-<number>`` (``(maths-8a)=`` in MyST), and
:func:`link_sections` rewrites the citations of every docstring into ``:ref:`` roles to those
labels (``docs/maths.md §7, §8`` links both sections, ``§5-6`` both ends). A citation of the page
without a section links the page. Citations inside inline literals (double backquotes) are
left as they are.

Deprecated aliases (a property whose docstring starts with "Deprecated name of", e.g. FactIRL's
``h_solver``) still work but are not part of the API: :func:`skip_deprecated` keeps them out of
the class pages and of their tables of contents.
"""

from __future__ import annotations

import re
from typing import Any

from sphinx.application import Sphinx

#: "docs/maths.md", then optionally its sections: "§7", "§7, §8", "§2 and §4", "§5-6", "§2-§4"
CITATION = re.compile(r"docs/maths\.md(?P<sections>(?: §\d+[a-z]?)(?:(?:, | and |-)§?\d+[a-z]?)*)?")
SECTION = re.compile(r"(?P<sign>§?)(?P<number>\d+[a-z]?)")
#: the label of a section of docs/maths.md
LABEL = "maths-{}"
DEPRECATED_PREFIX = "Deprecated name of"


def _link(match: re.Match) -> str:
    sections = match.group("sections")
    if not sections:
        return ":doc:`docs/maths.md </maths>`"
    out, first, pos = [], True, 0
    for m in SECTION.finditer(sections):
        out.append(sections[pos:m.start()].lstrip() if first else sections[pos:m.start()])
        text = ("docs/maths.md " if first else "") + m.group("sign") + m.group("number")
        out.append(f":ref:`{text} <{LABEL.format(m.group('number'))}>`")
        first, pos = False, m.end()
    return "".join(out) + sections[pos:]


def _outside_literals(line: str) -> list[tuple[int, int]]:
    """The spans of ``line`` that are not inside an inline literal (````...````)."""
    spans, pos, inside = [], 0, False
    for m in re.finditer(r"``", line):
        if not inside:
            spans.append((pos, m.start()))
        inside, pos = not inside, m.end()
    if not inside:
        spans.append((pos, len(line)))
    return spans


def link_line(line: str) -> str:
    """``line`` with its citations of docs/maths.md turned into links (see the module docstring)."""
    if "docs/maths.md" not in line:
        return line
    out, pos = [], 0
    for start, end in _outside_literals(line):
        out.append(line[pos:start])
        out.append(CITATION.sub(_link, line[start:end]))
        pos = end
    return "".join(out) + line[pos:]


def link_sections(app: Sphinx, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    """``autodoc-process-docstring``: link the docstring's citations of the maths page."""
    lines[:] = [link_line(line) for line in lines]


def skip_deprecated(app: Sphinx, what: str, name: str, obj: Any, skip: bool, options: Any) -> bool | None:
    """``autodoc-skip-member``: skip a deprecated alias (a property documented "Deprecated name of ...")."""
    if isinstance(obj, property) and (obj.__doc__ or "").startswith(DEPRECATED_PREFIX):
        return True
    return None


def setup(app: Sphinx) -> dict[str, Any]:
    app.connect("autodoc-process-docstring", link_sections)
    app.connect("autodoc-skip-member", skip_deprecated)
    return {"parallel_read_safe": True, "parallel_write_safe": True}

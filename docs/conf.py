"""Sphinx configuration of the taichi_anim user guide: Markdown pages (MyST) and an API reference built
from the docstrings (autodoc). Builds offline with the built-in theme:
`python -m sphinx -b html docs docs/_build`."""

import os
import re
import sys

# Document the source tree this folder belongs to, not some other installed copy.
sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

project = "taichi_anim"
author = "taichi_anim authors"
copyright = "taichi_anim authors"

extensions = ["myst_parser", "sphinx.ext.autodoc"]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build"]
html_theme = "alabaster"

# Links to section titles inside and between pages: [text](state.md#pins).
myst_heading_anchors = 3

autodoc_default_options = {"members": True, "undoc-members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
# `name` in a docstring is code.
default_role = "code"


# The docstrings are plain text with hard-wrapped lines, |x| for norms, a*b, indented continuation lines
# and lists: read as reStructuredText they would be substitutions, emphasis and "unexpected
# indentation". Escape the markup characters outside `code`, and separate lines of different
# indentation by a blank line (an indented run becomes a quoted block or a list item's second paragraph).
_CODE = re.compile(r"(``.*?``|`[^`]*`)")
_TRAILING_UNDERSCORES = re.compile(r"(?<=\w)(_+)(?=\W|$)")


def _escape(text: str) -> str:
    parts = _CODE.split(text)
    for k in range(0, len(parts), 2):  # even parts lie outside code spans
        p = parts[k].replace("\\", "\\\\").replace("|", "\\|").replace("*", "\\*")
        parts[k] = _TRAILING_UNDERSCORES.sub(lambda m: "\\_" * len(m.group(1)), p)
    for k in range(1, len(parts), 2):  # `x` -> ``x``, joined to adjacent letters (`update()`s)
        code = parts[k] if parts[k].startswith("``") else "``" + parts[k][1:-1] + "``"
        before = "\\ " if parts[k - 1][-1:].isalnum() else ""
        after = "\\ " if parts[k + 1][:1].isalnum() else ""
        parts[k] = before + code + after
    return "".join(parts)


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


def plain_docstring(app, what, name, obj, options, lines) -> None:
    out: list[str] = []
    for line in lines:
        if out and out[-1].strip() and line.strip() and _indent(out[-1]) != _indent(line):
            out.append("")
        out.append(_escape(line))
    lines[:] = out


def setup(app):
    app.connect("autodoc-process-docstring", plain_docstring)

"""The docstrings write their equations in plain text, where |x| is a norm and not a
reStructuredText substitution: escape the bars (outside ``literal`` spans and table rows)
before autodoc and autosummary parse a docstring."""

import re

_LITERAL = re.compile(r"(``.*?``)")


def _escape(line: str) -> str:
    row = line.strip()
    if (row.startswith("|") and row.endswith("|") and len(row) > 1) or row.startswith("+-"):
        return line  # a table row
    parts = _LITERAL.split(line)
    return "".join(p if p.startswith("``") else p.replace("|", r"\|") for p in parts)


def escape_bars(app, what, name, obj, options, lines):
    lines[:] = [_escape(line) for line in lines]


def setup(app):
    app.connect("autodoc-process-docstring", escape_bars)
    return {"parallel_read_safe": True}

"""The Markdown the package and its docs write: tables, per-joint "A / B" pairs, inline code,
code blocks and pages.  One implementation for the benchmark's report
(tendon2r_gym.app.report) and the docs generator (scripts/gen_docs.py).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from typing import Any

from tendon2r_gym.formatting import MISSING, pair

__all__ = ["MISSING", "code", "code_block", "indented", "page", "pair", "rows_of", "table"]


def code(text: Any) -> str:
    """Returns ``text`` as inline code."""
    return f"`{text}`"


def table(head: Sequence[Any], rows: Iterable[Sequence[Any]]) -> list[str]:
    """Returns the lines of a Markdown table: its head, then one line per row."""
    lines = ["| " + " | ".join(str(c) for c in head) + " |", "|" + "---|" * len(head)]
    return lines + ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]


def code_block(lines: Iterable[str], language: str = "") -> list[str]:
    """Returns the lines of a fenced code block."""
    return [f"```{language}", *lines, "```"]


def indented(lines: Iterable[str], by: int = 4) -> list[str]:
    """Returns ``lines`` indented by ``by`` spaces (blank lines stay empty): the body of an
    admonition or a list item."""
    return [" " * by + line if line.strip() else "" for line in lines]


def page(lines: Iterable[str]) -> str:
    """Returns a page's text: its lines, runs of blank lines collapsed, one final newline."""
    text = "\n".join(lines)
    return re.sub(r"\n{3,}", "\n\n", text).strip("\n") + "\n"


def rows_of(text: str) -> list[list[str]]:
    """Returns the body rows of every Markdown table in ``text``, as lists of cells (heads and
    separator lines left out): what a test compares with the data a table was written from."""
    out: list[list[str]] = []
    in_body = False
    for line in text.splitlines():
        if SEPARATOR.fullmatch(line):
            in_body = True
        elif in_body and line.startswith("|"):
            out.append([c.strip() for c in line.strip().strip("|").split(" | ")])
        else:
            in_body = False
    return out


#: A table's separator line: ``|---|---|``.
SEPARATOR = re.compile(r"\|(\s*:?-+:?\s*\|)+")

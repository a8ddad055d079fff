"""A rendered page read back into data, for the tests that compare a page with the data it
was written from rather than with its wording: its tables' rows (tendon2r_gym.app.markdown's
rows_of), the row of one name, its list items, the figures of a line, and a line's form with
its figures left out."""

from __future__ import annotations

import re

from tendon2r_gym.app.markdown import rows_of

__all__ = ["bullets", "figures", "form", "row", "rows_by_name", "rows_of"]

#: A figure as the pages print it: 12, -0.5, 1,024, 3.2e-09 (not the digit of a name: R2, v1).
NUMBER = re.compile(r"(?<![\w.])-?\d+(?:,\d{3})*(?:\.\d+)?(?:e[-+]?\d+)?")


def figures(text: str) -> list[float]:
    """Returns the figures in ``text``, in order."""
    return [float(m.replace(",", "")) for m in NUMBER.findall(text)]


def form(text: str) -> str:
    """Returns ``text`` with each figure replaced by ``#``: two cells of the same verdict read
    the same apart from their figures."""
    return NUMBER.sub("#", text)


def rows_by_name(text: str) -> dict[str, list[str]]:
    """Returns the body rows of the tables in ``text`` by their first cell."""
    return {r[0]: r for r in rows_of(text)}


def row(text: str, name: str) -> list[str]:
    """Returns the one table row of ``text`` whose first cell is ``name``."""
    (found,) = [r for r in rows_of(text) if r[0] == name]
    return found


def bullets(text: str) -> list[str]:
    """Returns the top-level list items of ``text``, without their ``- ``."""
    return [line[2:] for line in text.splitlines() if line.startswith("- ")]

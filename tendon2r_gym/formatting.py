"""How figures are written as text, shared by every layer: per-joint (or per-tendon) pairs
"A / B".  The Markdown toolkit (tendon2r_gym.app.markdown), training's log lines and the
research studies' pages all write pairs through `pair`."""

from __future__ import annotations

from collections.abc import Iterable

#: What a missing figure shows.
MISSING = "-"


def pair(values: Iterable[float | None] | None, spec: str = ".4f") -> str:
    """Returns per-joint (or per-tendon) figures as "A / B" in the format ``spec`` ("-" for
    none, and for a missing entry): ``pair([0.1, 0.25], ".2f")`` is "0.10 / 0.25"."""
    if values is None:
        return MISSING
    return " / ".join(MISSING if v is None else f"{v:{spec}}" for v in values)

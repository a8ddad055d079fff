"""Studies and benchmarks behind the research results: speed, time step, actuation map,
learnability, the arm sweep, sensitivity, the realism ablation and the generalists.

Each module has a ``main(argv)``: ``python -m research.studies.<name> --help`` from the
repository's root.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any


def joints(values: Sequence[float], digits: int = 3) -> str:
    """Returns per-joint (or per-tendon) figures as the tables show them: ``A / B``."""
    return " / ".join(f"{x:.{digits}f}" for x in values)


def one_or_more(flag: str, values: list[Any], allowed: str) -> list[Any]:
    """Returns a list flag's values, refusing none (a flag given without values)."""
    if not values:
        from tendon2r_gym.validation import invalid

        raise invalid(flag, values, allowed)
    return values


def save_json(out: Path, name: str, result: dict[str, Any]) -> None:
    """Creates ``out`` and writes ``result`` to ``out/<name>.json``."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(result, indent=1))

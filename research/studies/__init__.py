"""Studies and benchmarks behind the research results: speed, time step, actuation map,
learnability, the arm sweep, sensitivity, the realism ablation and the generalists.

Each module has a ``main(argv)``: ``python -m research.studies.<name> --help`` from the
repository's root.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any


def joints(values: Sequence[float], digits: int = 3) -> str:
    """Returns per-joint (or per-tendon) figures as the tables show them: ``A / B``."""
    from tendon2r_gym.formatting import pair

    return pair(values, f".{digits}f")


def one_or_more(flag: str, values: list[Any], allowed: str) -> list[Any]:
    """Returns a list flag's values, refusing none (a flag given without values)."""
    if not values:
        from tendon2r_gym.validation import invalid

        raise invalid(flag, values, allowed)
    return values


def seeds_flag(flag: str, seeds: list[Any]) -> list[int]:
    """Returns a study's training seeds, refusing none, one outside [0, 2**32 - 1] and a
    repeated one (a ValueError naming ``flag``)."""
    from tendon2r_gym.validation import integer, invalid

    for seed in one_or_more(flag, seeds, "one or more seeds"):
        integer(flag, seed, 0, 2**32 - 1)
    if len(set(seeds)) != len(seeds):
        raise invalid(flag, seeds, "distinct seeds")
    return seeds


def save_json(out: Path, name: str, result: dict[str, Any]) -> None:
    """Creates ``out`` and writes ``result`` to ``out/<name>.json``."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(result, indent=1))


def computed_or_read(out: Path, name: str, only_report: bool,
                     compute: Callable[[], dict[str, Any]]) -> dict[str, Any]:  # fmt: skip
    """Returns ``compute()`` saved to ``out/<name>.json``, or with ``only_report`` that file
    as it was saved (a study's ``--only-report``: its page rewritten from its results)."""
    if only_report:
        return json.loads((out / f"{name}.json").read_text())
    result = compute()
    save_json(out, name, result)
    return result

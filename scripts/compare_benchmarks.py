"""Compares two benchmark records row by row, within each row's reproducibility.

    python scripts/compare_benchmarks.py results/benchmark.json runs/benchmark-check/benchmark.json

Exit 0 when every row of one is in the other and every RMS error agrees within the larger of
the two rows' ``reproducible to`` (tendon2r_gym.app.report.differences); else 1, naming each
row that differs.  ``make benchmark-check`` reruns the benchmark and runs it.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

import tyro

from tendon2r_gym.app.report import differences


@dataclass
class Args:
    """Two benchmark.json files: the committed one, then the rerun."""

    ours: tyro.conf.Positional[Path]
    theirs: tyro.conf.Positional[Path]


def main(argv: list[str] | None = None) -> int:
    args = tyro.cli(Args, args=argv)
    records = []
    for path in (args.ours, args.theirs):
        try:
            records.append(json.loads(path.read_text()))
        except (OSError, ValueError) as e:
            print(f"error: {path} is not a benchmark record ({e}); rerun tendon2r-benchmark",
                  file=sys.stderr)  # fmt: skip
            return 2
    found = differences(*records)
    for line in found:
        print(line)
    rows = len(records[0].get("rows", [])) + len(records[0].get("held_out", []))
    print(
        f"{rows - len(found)} of {rows} rows reproduce" if found else f"all {rows} rows reproduce"
    )
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())

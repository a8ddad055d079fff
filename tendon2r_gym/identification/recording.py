"""The recording format: what a tendon arm did, one row per control step, as a CSV file.

Columns (a header row names them; their order is free):

- ``time``: seconds, uniform at the arm's control period ``ctrl_dt``, increasing;
- ``command_<i>`` for each tendon i = 1..n: the tension command sent to motor i (N, pulling
  positive), as it was sent: before any motor delay;
- ``q_A``, ``q_B``: the measured joint angles (rad, the project's joint conventions: the
  mechanism page);
- optional: ``tension_<i>`` (measured cable tension, N), ``dq_A``, ``dq_B`` (rad/s).

Row k holds the angles measured at ``time[k]`` and the command sent right after them: the
command of row k acts from ``time[k]`` to ``time[k + 1]`` (plus the arm's delays).

`load` checks a file against the arm it was recorded on and raises a ValueError naming
the file, the column and the row (the data row, 1 = the first after the header) of the first
problem: a missing or unknown column, a value that is not a finite number, time that does
not increase or is not uniform at ``ctrl_dt`` (or drifts from it), a command beyond the arm's
force limit (or a push on a pull-only arm), a recording too short for what is asked of it.
Comment lines (``#``) and blank lines are skipped.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

JOINT_COLUMNS = ("q_A", "q_B")
SPEED_COLUMNS = ("dq_A", "dq_B")
#: Relative tolerance of time's uniformity: a step may differ from ctrl_dt by this fraction
#: (at 1 kHz, 10 us: a clock printed with 6 decimals is within it); over the whole recording,
#: time may drift from uniform steps by half a step.
TIME_TOLERANCE = 1e-2
#: Commands may exceed the force limit by this fraction (rounding of the printed values).
FORCE_TOLERANCE = 1e-6


def command_columns(n_tendons: int) -> list[str]:
    return [f"command_{i + 1}" for i in range(n_tendons)]


def tension_columns(n_tendons: int) -> list[str]:
    return [f"tension_{i + 1}" for i in range(n_tendons)]


@dataclass
class Recording:
    """One recording of one arm: arrays of one row per control step."""

    time: np.ndarray  # (T,) s
    command: np.ndarray  # (T, n) N, pulling positive, as sent
    q: np.ndarray  # (T, 2) rad, as measured
    tension: np.ndarray | None = None  # (T, n) N
    dq: np.ndarray | None = None  # (T, 2) rad/s
    #: Where it was read from (error messages), or a label.
    source: str = "recording"
    #: Anything the writer wants beside the columns: written as ``# key: value`` lines above
    #: the header (the recorder writes the arm it simulated); reading skips them.
    notes: dict[str, str] = field(default_factory=dict)

    @property
    def n_tendons(self) -> int:
        return self.command.shape[1]

    @property
    def duration(self) -> float:
        """Seconds from the first row to the last."""
        return float(self.time[-1] - self.time[0])

    def columns(self) -> dict[str, np.ndarray]:
        """Returns the columns in the file's order."""
        n = self.n_tendons
        out = {"time": self.time}
        out.update(zip(command_columns(n), self.command.T, strict=True))
        out.update(zip(JOINT_COLUMNS, self.q.T, strict=True))
        if self.tension is not None:
            out.update(zip(tension_columns(n), self.tension.T, strict=True))
        if self.dq is not None:
            out.update(zip(SPEED_COLUMNS, self.dq.T, strict=True))
        return out

    def save(self, path: str | os.PathLike) -> Path:
        """Writes the CSV (numbers with 17 significant digits: they read back exactly)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        cols = self.columns()
        with path.open("w", newline="") as f:
            for key, value in self.notes.items():
                f.write(f"# {key}: {value}\n")
            writer = csv.writer(f)
            writer.writerow(cols)
            writer.writerows(
                [f"{v:.17g}" for v in row] for row in np.column_stack(list(cols.values()))
            )
        return path


def _fail(source: str, column: str | None, row: int | None, problem: str) -> ValueError:
    where = ", ".join(
        p
        for p in (f"column {column!r}" if column is not None else "", f"row {row}" if row else "")
        if p
    )
    return ValueError(
        f"recording {source}{': ' + where if where else ''}: {problem}. "
        "The format is on the docs' 'Identify your arm' page."
    )


def load(
    path: str | os.PathLike,
    n_tendons: int,
    ctrl_dt: float,
    force_limit: float,
    pull_only: bool,
    min_duration: float = 0.0,
) -> Recording:
    """Reads and checks a recording of an arm with ``n_tendons`` tendons, control period
    ``ctrl_dt`` (s) and force limit ``force_limit`` (N); ``min_duration``: what the caller
    needs of it (s).  Raises a ValueError naming the file, column and row of a problem."""
    source = str(path)
    rows = _read_rows(path, source)
    header = _check_header(rows, n_tendons, source)
    col = _parse_columns(rows[1:], header, source)
    _check_time(col["time"], ctrl_dt, source)
    _check_commands(col, n_tendons, force_limit, pull_only, source)
    _check_duration(col["time"], ctrl_dt, min_duration, source)
    return Recording(
        time=col["time"],
        command=np.column_stack([col[k] for k in command_columns(n_tendons)]),
        q=np.column_stack([col[k] for k in JOINT_COLUMNS]),
        tension=_block(col, tension_columns(n_tendons), source),
        dq=_block(col, list(SPEED_COLUMNS), source),
        source=source,
    )


def _read_rows(path: str | os.PathLike, source: str) -> list[list[str]]:
    """Returns the file's rows of cells, without comment lines and blank rows."""
    try:  # utf-8-sig: a spreadsheet's byte-order mark is not part of the first column's name
        with open(path, newline="", encoding="utf-8-sig") as f:
            lines = [line for line in f if not line.lstrip().startswith("#")]
    except OSError as e:
        raise ValueError(f"recording {source}: cannot be read ({e.strerror})") from None
    except UnicodeDecodeError as e:
        raise ValueError(
            f"recording {source}: not a UTF-8 text file (byte {e.start}); save it as CSV "
            "(UTF-8) with the columns of the recording format"
        ) from None
    return [row for row in csv.reader(lines) if any(cell.strip() for cell in row)]


def _check_header(rows: list[list[str]], n_tendons: int, source: str) -> list[str]:
    """Returns the header's column names: each known, none twice, every required one."""
    if not rows or not any(rows[0]):
        raise _fail(source, None, None, "it is empty; a header row names the columns")
    header = [h.strip() for h in rows[0]]
    required = ["time", *command_columns(n_tendons), *JOINT_COLUMNS]
    optional = [*tension_columns(n_tendons), *SPEED_COLUMNS]
    for name in header:
        if name not in required and name not in optional:
            raise _fail(
                source,
                name,
                None,
                f"unknown column; allowed: {required + optional} (this arm has {n_tendons} "
                "tendons)",
            )
    if len(set(header)) != len(header):
        twice = next(h for h in header if header.count(h) > 1)
        raise _fail(source, twice, None, "the column appears twice")
    for name in required:
        if name not in header:
            raise _fail(source, name, None, f"missing; required: {required}")
    return header


def _parse_columns(data: list[list[str]], header: list[str], source: str) -> dict[str, np.ndarray]:
    """Returns each column's values: finite numbers, a full row each, at least two rows."""
    values = np.empty((len(data), len(header)))
    for r, row in enumerate(data, start=1):
        if len(row) != len(header):
            raise _fail(source, None, r, f"{len(row)} values for {len(header)} columns")
        for c, text in enumerate(row):
            try:
                x = float(text)
            except ValueError:
                x = math.nan
            if not math.isfinite(x):
                raise _fail(source, header[c], r, f"{text!r} is not a finite number")
            values[r - 1, c] = x
    if len(data) < 2:
        raise _fail(source, None, None, f"{len(data)} data rows; it needs at least 2")
    return {name: values[:, i] for i, name in enumerate(header)}


def _check_time(time: np.ndarray, ctrl_dt: float, source: str) -> None:
    """Raises if time does not step by ``ctrl_dt`` (TIME_TOLERANCE) or drifts from it."""
    steps = np.diff(time)
    bad = np.flatnonzero(np.abs(steps - ctrl_dt) > TIME_TOLERANCE * ctrl_dt)
    if bad.size:
        r = int(bad[0]) + 2  # the row whose time is off
        what = "does not increase" if steps[bad[0]] <= 0 else "is not uniform"
        raise _fail(
            source,
            "time",
            r,
            f"time {what}: {float(time[r - 2])!r} s then {float(time[r - 1])!r}"
            f" s; allowed: steps of ctrl_dt = {ctrl_dt} s (to {TIME_TOLERANCE:g} of it)",
        )
    n = len(time)
    span = float(time[-1] - time[0])
    drift = span - (n - 1) * ctrl_dt
    if abs(drift) > 0.5 * ctrl_dt:
        raise _fail(
            source,
            "time",
            n,
            f"the clock drifts: {n} rows span {span!r}"
            f" s, {drift:+.3g} s off {n - 1} steps of ctrl_dt = {ctrl_dt} s",
        )


def _check_commands(
    col: dict[str, np.ndarray], n_tendons: int, force_limit: float, pull_only: bool, source: str
) -> None:
    """Raises if a command is beyond the force limit (FORCE_TOLERANCE) or pushes a pull-only
    motor."""
    lo, hi = (0.0 if pull_only else -force_limit), force_limit
    slack = FORCE_TOLERANCE * force_limit
    for name in command_columns(n_tendons):
        out = np.flatnonzero((col[name] < lo - slack) | (col[name] > hi + slack))
        if out.size:
            r = int(out[0]) + 1
            raise _fail(
                source,
                name,
                r,
                f"command {float(col[name][r - 1])!r} N is beyond the arm's force limit; allowed: "
                f"[{lo:g}, {hi:g}] N ({'pull-only' if pull_only else 'push-pull'} motors, "
                "max_tendon_force of the experiment file)",
            )


def _check_duration(time: np.ndarray, ctrl_dt: float, min_duration: float, source: str) -> None:
    """Raises if the recording is shorter than ``min_duration`` (s, to half a step)."""
    duration = float(time[-1] - time[0])
    if duration < min_duration - 0.5 * ctrl_dt:
        raise _fail(
            source,
            None,
            None,
            f"it lasts {duration:g} s; what is asked of it needs at least {min_duration:g} s",
        )


def _block(col: dict[str, np.ndarray], names: list[str], source: str) -> np.ndarray | None:
    """Returns an optional block of columns (all of ``names``), or None if none is given."""
    present = [k in col for k in names]
    if any(present) and not all(present):
        missing = names[present.index(False)]
        raise _fail(source, missing, None, f"missing; give all of {names} or none")
    return np.column_stack([col[k] for k in names]) if all(present) else None

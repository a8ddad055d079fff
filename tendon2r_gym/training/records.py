"""A run folder's records of its own progress: each command's segment and the summary of all
of them (written at every checkpoint, so that a killed segment counts up to its last one), the
summary over seeds, and the one-line error of a folder that cannot be written."""

from __future__ import annotations

import contextlib
import errno
import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tendon2r_gym.artifacts.runs import (
    BEST_METRICS,
    EVALUATIONS,
    SUMMARY,
    RunFolder,
    saved_steps,
)


@contextlib.contextmanager
def training_lock(runs: Sequence[RunFolder]) -> Iterator[None]:
    """Holds each run folder (made if missing) for one process while it trains: a second
    command on a folder in training (a --resume, a benchmark run again) is a ValueError naming
    it, before anything is written, instead of two trainings writing the same records.  An
    advisory lock on the folder itself (flock), released when the process ends, however it
    ends; none where the OS or the file system has no flock."""
    try:
        import fcntl
    except ImportError:  # not POSIX
        yield
        return
    with contextlib.ExitStack() as stack:
        for run in runs:
            run.path.mkdir(parents=True, exist_ok=True)
            fd = os.open(run.path, os.O_RDONLY)
            stack.callback(os.close, fd)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                from tendon2r_gym.validation import invalid

                raise invalid(
                    "run_dir",
                    str(run.path),
                    "a run folder that no other process is training (one is: wait for it to "
                    "finish, or stop it with Ctrl-C, which saves it, then --resume)",
                ) from None
            except OSError:  # a file system without locks (some network mounts): unheld
                pass
        yield


class RunWriteError(ValueError):
    """Writing to a run folder failed (read-only, or a full disk): the command's one-line error
    (a ValueError, as the console commands print them) names the folder, the OS error and the
    saved state a --resume continues from."""


def attempt_write(write: Callable[[], Any]) -> list[OSError]:
    """Runs ``write``; returns its OSError (a read-only folder, a full disk) in a list, or []."""
    try:
        write()
    except OSError as e:
        return [e]
    return []


#: The errors of a folder that cannot be written (a failed write may not name its file).
WRITE_ERRNOS = frozenset({errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT,
                          errno.EFBIG})  # fmt: skip


def is_write_error(error: BaseException, run: RunFolder) -> bool:
    """Returns whether ``error`` is a failure to write to the run folder: an OSError of
    ``WRITE_ERRNOS``, or of a file in the folder."""
    if not isinstance(error, OSError):
        return False
    if error.errno in WRITE_ERRNOS:
        return True
    if not isinstance(error.filename, (str, bytes, os.PathLike)):
        return False
    return Path(os.fsdecode(error.filename)).resolve().is_relative_to(run.path.resolve())


def write_failure(run: RunFolder, steps: int, failed: list[OSError]) -> str:
    """Returns the one-line error of a run whose folder could not be written: the folder, the
    first OS error, and the saved state a --resume continues from."""
    saved = []
    with contextlib.suppress(OSError):  # a folder that cannot be read either
        saved = run.checkpoint_candidates()
    if not saved:
        then = "run the command again (nothing was saved to continue from)"
    else:
        then = (
            f"--resume continues from {saved[0][0].relative_to(run.path)} "
            f"({saved_steps(saved[0][0])} steps)"
        )
    return (
        f"writing to the run folder {run.path} failed at {steps} steps ({failed[0]}); training "
        f"stopped; once the folder is writable and has room again, {then}"
    )


@dataclass
class Segment:
    """This command's segment of a run: summary.json adds it to the earlier ones, at each
    checkpoint (as if the run were killed then, so that a SIGKILL loses only the time since)
    and at the end."""

    run: RunFolder
    seed: int
    command: str
    previous: dict[str, Any] | None
    start_steps: int
    start: float = field(default_factory=time.perf_counter)

    @property
    def wall_offset_s(self) -> float:
        """The wall time of the earlier segments."""
        return float(self.previous["wall_time_s"]) if self.previous else 0.0

    def checkpoint(self, steps: int) -> None:
        """Records the segment so far, as interrupted at ``steps``."""
        write_summary(self.run, self.seed, self._segments(steps, True))

    def end(self, steps: int, interrupted: bool) -> dict[str, Any]:
        """Records the segment's end; returns the summary."""
        return write_summary(self.run, self.seed, self._segments(steps, interrupted))

    def _segments(self, steps: int, interrupted: bool) -> list[dict[str, Any]]:
        segment = {
            "command": self.command,
            "start_timesteps": self.start_steps,
            "end_timesteps": int(steps),
            "wall_time_s": round(time.perf_counter() - self.start, 1),
            "interrupted": interrupted,
        }
        return [*(self.previous or {}).get("segments", []), segment]


def first_beat_pd(run: RunFolder) -> dict[str, Any] | None:
    """Returns the first evaluation of a run that beat PD on both joints, or None."""
    for row in run.read_json(EVALUATIONS) or []:
        if row["beats_pd"]:
            return {"timesteps": row["timesteps"], "wall_time_s": row["wall_time_s"]}
    return None


def write_summary(run: RunFolder, seed: int, segments: list[dict[str, Any]]) -> dict[str, Any]:
    """Writes summary.json: steps and wall time summed over ``segments`` (the last one this
    command's), and the best evaluation so far; returns it."""
    last = segments[-1]
    total_wall = round(sum(s["wall_time_s"] for s in segments), 1)
    best = run.read_json(BEST_METRICS) or {}
    summary = {
        "seed": seed,
        "timesteps": last["end_timesteps"],
        "wall_time_s": total_wall,
        "steps_per_s": round(
            sum(s["end_timesteps"] - s["start_timesteps"] for s in segments)
            / max(total_wall, 1e-9),
            1,
        ),
        "interrupted": last["interrupted"],
        "best_rms_deg": best.get("rms_deg"),
        "best_timesteps": best.get("timesteps"),
        "best_tension_rate_N_per_s": best.get("rms_tension_rate_N_per_s"),
        "pd_eval_rms_deg": run.pd_eval_rms(),
        "first_beat_pd": first_beat_pd(run),
        "segments": segments,
    }
    run.write_json(SUMMARY, summary)
    return summary


def seeds_summary(seeds: list[int], results: list[dict[str, Any]]) -> dict[str, Any]:
    """Returns mean +- std (ddof 0) of the finished runs' best RMS."""
    done = [r for r in results if r.get("best_rms_deg") is not None]
    out: dict[str, Any] = {"seeds": seeds, "finished": [r["seed"] for r in done], "runs": results}
    if done:
        rms = np.array([r["best_rms_deg"] for r in done], dtype=float)
        out.update(
            rms_deg_mean=rms.mean(0).tolist(),
            rms_deg_std=rms.std(0).tolist(),
            wall_time_s_mean=float(np.mean([r["wall_time_s"] for r in done])),
        )
    return out

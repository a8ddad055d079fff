"""The run folder: the one module that knows its file names (like rl_zoo3's ExperimentManager).

A training run writes, in ``runs/<name>/seed_<n>/``::

    run.json                     env config (the exact env kwargs), residual scale, seed
    config.yaml                  the resolved hyperparameters
    command.txt                  the original command, then one line per resume
    best_model.zip               best evaluation on the eval seeds: the lowest tracking RMS
                                 among those <= PD within the smoothness limits, else overall
    best_model_vecnormalize.pkl  its VecNormalize statistics
    best_metrics.json            its tracking metrics
    evaluations.json             every evaluation: steps, wall time, RMS, smoothness x PD
    pd_eval.json                 PD's tracking metrics on the eval seeds (and on_reference:
                                 on them started on the reference, where smoothness is judged)
    last_model.zip (+ pkl)       the state at the end, or at Ctrl-C
    checkpoints/                 periodic checkpoints (by steps and by time)
    summary.json                 steps and wall time summed over all segments
    tb/                          TensorBoard logs

A bundle (tendon2r_gym.bundle) copies the small files of a run: :data:`BUNDLE_FILES`.
"""

from __future__ import annotations

import json
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

RUN_META = "run.json"
CONFIG = "config.yaml"
COMMAND = "command.txt"
BEST = "best_model"
BEST_METRICS = "best_metrics.json"
EVALUATIONS = "evaluations.json"
PD_EVAL = "pd_eval.json"
SUMMARY = "summary.json"
LAST = "last_model"
CHECKPOINTS = "checkpoints"
CHECKPOINT_PREFIX = "rl_model"
TENSORBOARD = "tb"
#: Beside the seed folders of a multi-seed command.
SEEDS_SUMMARY = "seeds_summary.json"
#: The small files a bundle keeps (no checkpoints, no TensorBoard logs).
BUNDLE_FILES = (
    f"{BEST}.zip",
    f"{BEST}_vecnormalize.pkl",
    RUN_META,
    BEST_METRICS,
    EVALUATIONS,
    SUMMARY,
    CONFIG,
    COMMAND,
)


def seed_dir(base: str | Path, seed: int) -> Path:
    """Returns the run folder of one seed of a multi-seed command: ``base/seed_<n>``."""
    return Path(base) / f"seed_{seed}"


def seed_dirs(base: str | Path) -> list[Path]:
    """Returns the seed run folders under ``base`` that hold a recorded config, by seed."""
    found = [p for p in Path(base).glob("seed_*") if (p / CONFIG).is_file()]
    return sorted(found, key=lambda p: int(p.name.removeprefix("seed_")))


def model_files(stem: Path) -> tuple[Path, Path]:
    """Returns (model zip, VecNormalize pkl) of a saved model ``stem`` (a path without .zip)."""
    return stem.with_name(stem.name + ".zip"), stem.with_name(stem.name + "_vecnormalize.pkl")


def stem_of(model_path: str | Path) -> Path:
    """Returns the stem of a model path given with or without .zip."""
    path = Path(model_path)
    return path.with_suffix("") if path.suffix == ".zip" else path


def training_summary(model_path: str | Path) -> dict[str, Any] | None:
    """Returns the summary.json (timesteps, wall time, ...) beside a saved model (``<name>``
    or ``<name>.zip`` in a run folder or bundle), or None if there is none."""
    return RunFolder(stem_of(model_path).parent).read_json(SUMMARY)


def training_record(model_path: str | Path) -> dict[str, Any] | None:
    """Returns the run.json beside a saved model: the env kwargs and the resolved env config
    it trained on, or None if there is none."""
    return RunFolder(stem_of(model_path).parent).read_json(RUN_META)


def command_line(argv: list[str] | None = None, program: str | None = None) -> str:
    """Returns ``program`` (default: this process's script name) and ``argv`` (default: this
    process's arguments), quoted as a shell command."""
    args = sys.argv[1:] if argv is None else argv
    return " ".join([program or Path(sys.argv[0]).name, shlex.join(args)]).strip()


@dataclass(frozen=True)
class RunFolder:
    """One training run's folder and the names of everything in it."""

    path: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))

    # -- names ---------------------------------------------------------------------------------
    @property
    def best(self) -> Path:
        return self.path / BEST

    @property
    def last(self) -> Path:
        return self.path / LAST

    @property
    def checkpoints(self) -> Path:
        return self.path / CHECKPOINTS

    @property
    def tensorboard(self) -> Path:
        return self.path / TENSORBOARD

    @property
    def seed(self) -> int | None:
        """Returns the seed of a ``seed_<n>`` folder (None for another name)."""
        name = self.path.name
        return int(name.removeprefix("seed_")) if name.startswith("seed_") else None

    def file(self, name: str) -> Path:
        return self.path / name

    # -- records -------------------------------------------------------------------------------
    def read_json(self, name: str) -> Any:
        path = self.file(name)
        return json.loads(path.read_text()) if path.is_file() else None

    def write_json(self, name: str, data: Any) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        tmp = self.file(name + ".tmp")
        tmp.write_text(json.dumps(data, indent=1) + "\n")
        tmp.replace(self.file(name))  # atomic: a crash never leaves half a file

    def write_config(self, cfg: dict[str, Any]) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        self.file(CONFIG).write_text(yaml.safe_dump(cfg, sort_keys=False))

    def read_config(self) -> dict[str, Any] | None:
        """Returns the recorded hyperparameters (config.yaml), or None."""
        path = self.file(CONFIG)
        return yaml.safe_load(path.read_text()) if path.is_file() else None

    def record_command(self, command: str, resume: bool) -> None:
        """Starts command.txt with the original command; a resume appends its own line."""
        self.path.mkdir(parents=True, exist_ok=True)
        path = self.file(COMMAND)
        if resume and path.is_file():
            with open(path, "a") as f:
                f.write(f"# resumed: {command}\n")
        else:
            path.write_text(f"{command}\n")

    def train_command(self) -> str:
        """Returns the command that started the run (the first line of command.txt)."""
        return self.file(COMMAND).read_text().splitlines()[0]

    def pd_eval_rms(self) -> list[float] | None:
        """PD's RMS error (deg) on the eval seeds: pd_eval.json holds PD's tracking metrics
        (in older runs, its RMS error alone)."""
        pd = self.read_json(PD_EVAL)
        return pd["rms_deg"] if isinstance(pd, dict) else pd

    def best_evaluation(self) -> dict[str, Any] | None:
        """Returns the evaluations.json row of the best model (the last row at its steps), or
        None: no best model yet, or one saved before evaluations.json recorded it."""
        best = self.read_json(BEST_METRICS)
        if best is None:
            return None
        rows = [r for r in self.read_json(EVALUATIONS) or [] if r["timesteps"] == best["timesteps"]]
        return rows[-1] if rows else None

    def append_evaluation(self, row: dict[str, Any]) -> None:
        rows = self.read_json(EVALUATIONS) or []
        self.write_json(EVALUATIONS, [*rows, row])

    def checkpoint_candidates(self) -> list[tuple[Path, Path]]:
        """Returns every saved (zip, pkl) pair of the run, the most trained first (by the steps
        each one recorded, last_model first among equals, not by file times, which a copy of
        the run folder may reset): last_model (written on Ctrl-C and at the end) and the
        checkpoints."""
        last = model_files(self.last)
        pairs = [(*last, saved_steps(last[0]))]
        for zip_path in self.checkpoints.glob(f"{CHECKPOINT_PREFIX}_*_steps.zip"):
            steps = zip_path.stem.removeprefix(f"{CHECKPOINT_PREFIX}_").removesuffix("_steps")
            if not steps.isdigit():
                continue
            stats = zip_path.with_name(f"{CHECKPOINT_PREFIX}_vecnormalize_{steps}_steps.pkl")
            pairs.append((zip_path, stats, int(steps)))
        pairs = [p for p in pairs if p[0].is_file() and p[1].is_file()]
        ordered = sorted(enumerate(pairs), key=lambda ip: (-ip[1][2], ip[0]))
        return [(zip_path, stats) for _, (zip_path, stats, _) in ordered]


def saved_steps(zip_path: Path) -> int:
    """Returns the training steps an SB3 model zip recorded (``num_timesteps`` in its
    ``data``), or -1 if it is missing or unreadable."""
    import zipfile

    try:
        with zipfile.ZipFile(zip_path) as z:
            return int(json.loads(z.read("data"))["num_timesteps"])
    except (OSError, KeyError, ValueError, TypeError, zipfile.BadZipFile):
        return -1

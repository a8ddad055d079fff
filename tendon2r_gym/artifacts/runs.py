"""The run folder: the one module that knows its file names (like rl_zoo3's ExperimentManager).

A training run writes, in ``runs/<name>/seed_<n>/``::

    run.json                     env config (the exact env kwargs), residual scale, seed
    config.yaml                  the resolved hyperparameters
    command.txt                  the original command, then one line per resume
    best_model.zip               best evaluation on the eval seeds: the lowest tracking RMS
                                 among those <= PD within the smoothness limits, else overall
    best_model_vecnormalize.npz  its VecNormalize statistics, as plain arrays (and SB3's
                                 pickle of them, .pkl, which is read only when trusted)
    best_metrics.json            its tracking metrics
    evaluations.json             every evaluation: steps, wall time, RMS, smoothness x PD
    pd_eval.json                 PD's tracking metrics on the eval seeds (and on_reference:
                                 on them started on the reference, where smoothness is judged)
    last_model.zip (+ npz, pkl)  the state at the end, or at Ctrl-C
    checkpoints/                 periodic checkpoints (by steps and by time)
    summary.json                 steps and wall time summed over all segments (also written at
                                 each checkpoint, as if the run were interrupted there)
    tb/                          TensorBoard logs

A bundle (tendon2r_gym.artifacts.bundle) copies the small files of a run: `BUNDLE_FILES`
(no pickle: a bundle's statistics are the npz).  Each
record is checked when it is read (`read_record`): a corrupt one is a ValueError naming
the file, what is wrong with it and how to recover.  A training option this version no longer
has (`REMOVED`) is dropped from a record that holds it off, and refused in one that
holds it on.
"""

from __future__ import annotations

import json
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from tendon2r_gym.artifacts.files import corrupt
from tendon2r_gym.validation import invalid

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
#: A model's statistics beside ``<name>.zip``: plain arrays (tendon2r_gym.artifacts.files), and
#: the pickle that earlier versions wrote (and SB3's own VecNormalize.save writes).
STATS = "_vecnormalize.npz"
LEGACY_STATS = "_vecnormalize.pkl"
#: Beside the seed folders of a multi-seed command.
SEEDS_SUMMARY = "seeds_summary.json"
#: config.yaml opens with CONFIG_HEAD and ends with CONFIG_END, so that one cut short is told
#: from a whole one (YAML cut at a line end still parses; JSON cut short does not).  One
#: without CONFIG_HEAD was written by an earlier version, and is read as it is.
CONFIG_HEAD = "# tendon2r_gym: the hyperparameters of this run, whole if its last line is:"
CONFIG_END = "# end of config.yaml"
#: The small files a bundle keeps (no checkpoints, no TensorBoard logs).
BUNDLE_FILES = (
    f"{BEST}.zip",
    f"{BEST}{STATS}",
    RUN_META,
    BEST_METRICS,
    EVALUATIONS,
    SUMMARY,
    CONFIG,
    COMMAND,
)


#: What each record holds, checked when it is read: a mapping of keys to what their values
#: are (``{}`` a mapping, ``[...]`` a list of such rows, ``list`` a list, ``float`` a number,
#: ``None`` anything); a file not named here is only parsed.
_SEGMENT = {"start_timesteps": float, "end_timesteps": float, "wall_time_s": float}
SHAPES: dict[str, Any] = {
    RUN_META: {"seed": float, "env_kwargs": {}, "env_config": {}},
    CONFIG: {},
    SUMMARY: {"timesteps": float, "wall_time_s": float, "segments": [_SEGMENT]},
    EVALUATIONS: [{"timesteps": float, "wall_time_s": float, "rms_deg": list, "beats_pd": None}],
    BEST_METRICS: {"timesteps": float, "rms_deg": list},
    SEEDS_SUMMARY: {"seeds": list, "runs": list},
}
_AGAIN = "delete the seed folder and train it again"
#: How to recover from a corrupt record.
RECOVERY = {
    RUN_META: f"restore it from a copy (a bundle keeps one), or {_AGAIN}",
    CONFIG: f"restore it from a copy (a bundle keeps one), or {_AGAIN}",
    COMMAND: "restore it from a copy (a bundle keeps one), or write the command on its first line",
    SUMMARY: "restore it from a copy (a bundle keeps one), or delete it: a --resume then counts "
    "the totals from its own segment on",
    EVALUATIONS: "restore it from a copy (a bundle keeps one), or delete it: the evaluations "
    "start anew (best_metrics.json keeps the best model's RMS)",
    BEST_METRICS: "restore it from a copy (a bundle keeps one), or delete it with best_model.zip "
    "and its best_model_vecnormalize files: the next evaluation saves a new best model",
    PD_EVAL: "delete it: the next training measures PD again",
    SEEDS_SUMMARY: "delete it: the next train command writes it again",
}


#: The training options this version no longer has (only ablations that lost used them; the
#: ablations' results stay in research/results/), each with the value a run records while it
#: is off; a mapping is off when it holds these values (its other keys unused while off).
#: Records of runs (config.yaml, run.json) hold them: `without_removed`.
REMOVED: dict[str, Any] = {
    "zero_obs": [],
    "hide_from_critic": [],
    "smoothing": {"temporal": 0.0, "spatial": 0.0},
    "residual_relative_to": "range",
}


def without_removed(data: dict[str, Any], path: Path) -> dict[str, Any]:
    """Returns a run record's ``data`` without the options of `REMOVED`, each recorded
    off (the run trained without it, as this version trains); raises naming the file, the key
    and the value if one is recorded on."""
    out = dict(data)
    for key, off in REMOVED.items():
        if key in out and not _is_off(value := out.pop(key), off):
            raise invalid(
                f"{path}: {key}",
                value,
                f"{off!r} (off): this version no longer has the option {key} (tendon2r_gym 0.2 "
                "has it; the results of the ablations that used it stay in research/results/)",
            )
    return out


def _is_off(value: Any, off: Any) -> bool:
    if isinstance(off, dict):
        return isinstance(value, dict) and all(value.get(k) == v for k, v in off.items())
    return value == off


def corrupt_record(path: Path, what: str) -> ValueError:
    """Returns the error of a corrupt run file (files.corrupt): ``<path> is corrupt: <what>;
    to recover: <how>``, how as `RECOVERY` says."""
    how = RECOVERY.get(path.name, f"restore it from a copy, or {_AGAIN}")
    return corrupt(path, f"corrupt: {what}", how)


def read_record(path: Path) -> Any:
    """Returns the data of a run record (JSON, or YAML for config.yaml), or None if there is
    no such file; raises `corrupt_record` if it is empty, does not parse, or is not shaped as
    `SHAPES` says.  The hyperparameters and run.json come `without_removed`."""
    if not path.is_file():
        return None
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise corrupt_record(path, "it is not UTF-8 text") from None
    if not text.strip():
        raise corrupt_record(path, "it is empty")
    if path.name == CONFIG and text.startswith(CONFIG_HEAD):
        if text.rstrip().splitlines()[-1] != CONFIG_END:
            raise corrupt_record(path, f"it is cut short (its last line is not {CONFIG_END!r})")
    yaml_file = path.suffix == ".yaml"
    try:
        data = yaml.safe_load(text) if yaml_file else json.loads(text)
    except (yaml.YAMLError, json.JSONDecodeError) as e:
        kind = "YAML" if yaml_file else "JSON"
        raise corrupt_record(path, f"it is not valid {kind} ({e})") from None
    if (problem := _mismatch(data, SHAPES.get(path.name))) is not None:
        raise corrupt_record(path, problem)
    return without_removed(data, path) if path.name in (CONFIG, RUN_META) else data


def _mismatch(data: Any, shape: Any, where: str = "") -> str | None:
    """Returns what about ``data`` (the value at ``where``) does not match ``shape`` (see
    `SHAPES`), or None."""
    name = where or "its top level"
    if shape is None:
        return None
    if shape is float:
        number = isinstance(data, (int, float)) and not isinstance(data, bool)
        return None if number else f"{name} = {data!r} is not a number"
    if shape is list or isinstance(shape, list):
        if not isinstance(data, list):
            return f"{name} is a {type(data).__name__}, not a list"
        rows = enumerate(data if isinstance(shape, list) else [])
        found = (_mismatch(r, shape[0], f"{where}[{i}]" if where else f"row {i}") for i, r in rows)
        return next((problem for problem in found if problem is not None), None)
    if not isinstance(data, dict):
        return f"{name} is a {type(data).__name__}, not a mapping"
    for key, value in shape.items():
        if key not in data:
            return f"{where or 'it'} lacks {key!r}"
        inner = f"{where}'s {key}" if where.startswith("row") else f"{where}.{key}".lstrip(".")
        if (problem := _mismatch(data[key], value, inner)) is not None:
            return problem
    return None


def seed_dir(base: str | Path, seed: int) -> Path:
    """Returns the run folder of one seed of a multi-seed command: ``base/seed_<n>``."""
    return Path(base) / f"seed_{seed}"


def seed_dirs(base: str | Path) -> list[Path]:
    """Returns the seed run folders under ``base`` that hold a recorded config, by seed."""
    found = [
        p
        for p in Path(base).glob("seed_*")
        if p.name.removeprefix("seed_").isdigit() and (p / CONFIG).is_file()
    ]
    return sorted(found, key=lambda p: int(p.name.removeprefix("seed_")))


def model_files(stem: Path) -> tuple[Path, Path]:
    """Returns (model zip, statistics) of a saved model ``stem`` (a path without .zip): the
    statistics' npz, or an earlier version's pkl where only that one is there."""
    npz, pkl = stats_files(stem)
    stats = pkl if pkl.is_file() and not npz.is_file() else npz
    return stem.with_name(stem.name + ".zip"), stats


def stats_files(stem: Path) -> tuple[Path, Path]:
    """Returns (npz, pkl): the names of a saved model's statistics (`STATS`,
    `LEGACY_STATS`)."""
    return stem.with_name(stem.name + STATS), stem.with_name(stem.name + LEGACY_STATS)


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
        """Returns a JSON record of the run, or None if there is none; raises a ValueError
        naming the file if it is corrupt (`read_record`)."""
        return read_record(self.file(name))

    def write_json(self, name: str, data: Any) -> None:
        self._write(name, json.dumps(data, indent=1) + "\n")

    def write_config(self, cfg: dict[str, Any]) -> None:
        text = yaml.safe_dump(cfg, sort_keys=False)
        self._write(CONFIG, f"{CONFIG_HEAD}\n{text}{CONFIG_END}\n")

    def _write(self, name: str, text: str) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        tmp = self.file(name + ".tmp")
        tmp.write_text(text)
        tmp.replace(self.file(name))  # atomic: a crash never leaves half a file

    def read_config(self) -> dict[str, Any] | None:
        """Returns the recorded hyperparameters (config.yaml), or None; raises a ValueError
        naming the file if it is corrupt (`read_record`)."""
        return read_record(self.file(CONFIG))

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
        path = self.file(COMMAND)
        lines = path.read_text().splitlines()
        if not lines or not lines[0].strip():
            what = "it is empty (its first line is the command that started the run)"
            raise corrupt_record(path, what)
        return lines[0]

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
        """Returns every saved (zip, statistics) pair of the run (the statistics' npz, or an
        earlier version's pkl: `model_files`), the most trained first (by the steps
        each one recorded, last_model first among equals, not by file times, which a copy of
        the run folder may reset): last_model (written on Ctrl-C and at the end) and the
        checkpoints."""
        last = model_files(self.last)
        pairs = [(*last, saved_steps(last[0]))]
        for zip_path in self.checkpoints.glob(f"{CHECKPOINT_PREFIX}_*_steps.zip"):
            steps = zip_path.stem.removeprefix(f"{CHECKPOINT_PREFIX}_").removesuffix("_steps")
            if not steps.isdigit():
                continue
            stats = checkpoint_stats(zip_path.parent, steps)
            pairs.append((zip_path, stats, int(steps)))
        pairs = [p for p in pairs if p[0].is_file() and p[1].is_file()]
        ordered = sorted(enumerate(pairs), key=lambda ip: (-ip[1][2], ip[0]))
        return [(zip_path, stats) for _, (zip_path, stats, _) in ordered]


def checkpoint_stats(folder: Path, steps: int | str) -> Path:
    """Returns the statistics of the checkpoint at ``steps`` (SB3's CheckpointCallback names):
    its npz, or an earlier version's pkl where only that one is there."""
    stem = folder / f"{CHECKPOINT_PREFIX}_vecnormalize_{steps}_steps"
    npz, pkl = stem.with_name(stem.name + ".npz"), stem.with_name(stem.name + ".pkl")
    return pkl if pkl.is_file() and not npz.is_file() else npz


def saved_steps(zip_path: Path) -> int:
    """Returns the training steps an SB3 model zip recorded (``num_timesteps`` in its
    ``data``), or -1 if it is missing or unreadable."""
    import zipfile

    try:
        with zipfile.ZipFile(zip_path) as z:
            return int(json.loads(z.read("data"))["num_timesteps"])
    except (OSError, KeyError, ValueError, TypeError, zipfile.BadZipFile):
        return -1

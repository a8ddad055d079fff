"""The bundled PPO models in models/<preset>/: what is copied from a training run, and lookup.

Layout (small files only: no checkpoints, no TensorBoard logs)::

    models/<preset>/bundle.json          seeds, primary seed, the training and bundling commands
    models/<preset>/seed_<n>/            best_model.zip, best_model_vecnormalize.pkl,
                                         policy.json, best_metrics.json, summary.json,
                                         config.yaml, command.txt

The primary seed (the first one trained, chosen before training, not the best one) is the model
that ``evaluate.py --policy ppo`` uses; the others give the spread over training seeds.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

BUNDLED_DIR = Path(__file__).resolve().parent.parent / "models"
BUNDLE_META = "bundle.json"
RUN_FILES = (
    "best_model.zip",
    "best_model_vecnormalize.pkl",
    "policy.json",
    "best_metrics.json",
    "summary.json",
    "config.yaml",
    "command.txt",
)


def bundle_runs(run_dirs: list[Path], preset: str, command: str, root: Path = BUNDLED_DIR) -> Path:
    """Copies the small files of each training run into root/<preset>/seed_<n>/ (replacing an
    earlier bundle) and writes bundle.json.  Returns the preset's bundle folder."""
    runs = [Path(r) for r in run_dirs]
    if not runs:
        raise ValueError("bundle_runs: no run folders given; allowed: one or more")
    summaries = []
    for run in runs:
        missing = [f for f in RUN_FILES if not (run / f).is_file()]
        if missing:
            raise FileNotFoundError(f"run folder {run} lacks {missing}; was training finished?")
        summaries.append(json.loads((run / "summary.json").read_text()))
    dest = root / preset
    if dest.exists():
        shutil.rmtree(dest)
    for run, summary in zip(runs, summaries, strict=True):
        seed_dir = dest / f"seed_{summary['seed']}"
        seed_dir.mkdir(parents=True)
        for name in RUN_FILES:
            shutil.copy2(run / name, seed_dir / name)
    meta = {
        "preset": preset,
        "seeds": [s["seed"] for s in summaries],
        "primary_seed": summaries[0]["seed"],
        "train_command": (runs[0] / "command.txt").read_text().splitlines()[0],
        "command": command,
    }
    (dest / BUNDLE_META).write_text(json.dumps(meta, indent=1) + "\n")
    return dest


def bundle_meta(preset: str, root: Path = BUNDLED_DIR) -> dict[str, Any] | None:
    """Returns the preset's bundle.json, or None if nothing is bundled for it."""
    path = root / preset / BUNDLE_META
    return json.loads(path.read_text()) if path.is_file() else None


def bundled_model(preset: str, seed: int | None = None, root: Path = BUNDLED_DIR) -> Path:
    """Returns the bundled best_model.zip for a preset (its primary seed unless ``seed``)."""
    meta = bundle_meta(preset, root)
    if meta is None:
        available = sorted(p.name for p in root.glob("*") if (p / BUNDLE_META).is_file())
        raise FileNotFoundError(
            f"no bundled PPO model for preset {preset!r} (bundled: {available}); "
            "pass --model PATH or train one with scripts/train_ppo.py --bundle"
        )
    seed = meta["primary_seed"] if seed is None else seed
    if seed not in meta["seeds"]:
        raise ValueError(f"seed = {seed!r} is not bundled for {preset!r}; allowed: {meta['seeds']}")
    return root / preset / f"seed_{seed}" / "best_model.zip"


def training_summary(model_path: Path) -> dict[str, Any]:
    """Returns the summary.json (timesteps, wall time, ...) beside a bundled model."""
    return json.loads((Path(model_path).parent / "summary.json").read_text())

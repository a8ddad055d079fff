"""The bundled PPO models (package data, ``tendon2r_gym/data/models/<name>/``): copy and look up.

Layout (the small files of each run, tendon2r_gym.runs.BUNDLE_FILES)::

    <name>/bundle.json        seeds, primary seed, the training and bundling commands
    <name>/seed_<n>/          best_model.zip, best_model_vecnormalize.pkl, run.json, ...

The primary seed (the first one trained, chosen before training, not the best one) is the model
that ``tendon2r-evaluate --policy ppo`` uses; the others give the spread over training seeds.
Each run.json records the env config the model was trained with.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from tendon2r_gym.files import corrupt, read_json
from tendon2r_gym.presets import MODELS_DIR
from tendon2r_gym.runs import BEST, BUNDLE_FILES, SUMMARY, RunFolder, seed_dir
from tendon2r_gym.validation import invalid

BUNDLE_META = "bundle.json"
#: The keys of bundle.json that are read (it also records the bundle's name).
META_KEYS = ("seeds", "primary_seed", "train_command", "command")


def bundle_runs(run_dirs: list[Path], name: str, command: str, root: Path = MODELS_DIR) -> Path:
    """Copies the small files of each training run into root/<name>/seed_<n>/ (replacing an
    earlier bundle) and writes bundle.json.  Returns the bundle folder."""
    runs = [RunFolder(r) for r in run_dirs]
    if not runs:
        raise invalid("runs", run_dirs, "one or more run folders")
    summaries = []
    for run in runs:
        missing = [f for f in BUNDLE_FILES if not run.file(f).is_file()]
        if missing:
            raise FileNotFoundError(f"run folder {run.path} lacks {missing}; was it finished?")
        summaries.append(run.read_json(SUMMARY))
    dest = root / name
    if dest.exists():
        shutil.rmtree(dest)
    for run, summary in zip(runs, summaries, strict=True):
        folder = seed_dir(dest, summary["seed"])
        folder.mkdir(parents=True)
        for f in BUNDLE_FILES:
            shutil.copy2(run.file(f), folder / f)
    meta = {
        "name": name,
        "seeds": [s["seed"] for s in summaries],
        "primary_seed": summaries[0]["seed"],
        "train_command": runs[0].train_command(),
        "command": command,
    }
    (dest / BUNDLE_META).write_text(json.dumps(meta, indent=1) + "\n")
    return dest


def bundle_names(root: Path = MODELS_DIR) -> list[str]:
    """Returns the names of the bundles under root."""
    return sorted(p.name for p in root.glob("*") if (p / BUNDLE_META).is_file())


def bundle_meta(name: str, root: Path = MODELS_DIR) -> dict[str, Any] | None:
    """Returns the bundle's bundle.json, or None if nothing is bundled under that name; a
    corrupt one is a ValueError naming it."""
    path = Path(root) / name / BUNDLE_META
    if not path.is_file():
        return None
    recover = (
        f"re-bundle it: tendon2r-bundle --name {name} --replace --runs <its run folders> "
        "(the command it recorded, if readable, names them)"
    )
    meta = read_json(path, META_KEYS, recover)
    seeds = meta["seeds"]
    if not isinstance(seeds, list) or not seeds or not all(type(s) is int for s in seeds):
        raise corrupt(path, f"invalid: seeds = {seeds!r} is not a list of seeds", recover)
    if meta["primary_seed"] not in seeds:
        primary = meta["primary_seed"]
        raise corrupt(path, f"invalid: primary_seed = {primary!r} is not among {seeds}", recover)
    return meta


def bundled_model(name: str, seed: int | None = None, root: Path = MODELS_DIR) -> Path:
    """Returns the bundled best_model.zip of a bundle (its primary seed unless ``seed``)."""
    meta = bundle_meta(name, root)
    if meta is None:
        raise invalid(
            "bundle",
            name,
            f"one of {bundle_names(root)} (or pass --model PATH, or train one "
            "with tendon2r-train --bundle NAME)",
        )
    seed = meta["primary_seed"] if seed is None else seed
    if seed not in meta["seeds"]:
        raise invalid(f"seed of bundle {name!r}", seed, f"one of {meta['seeds']}")
    return seed_dir(root / name, seed) / f"{BEST}.zip"


def model_path(name_or_path: str | Path) -> Path:
    """Returns the model a name stands for: a bundle's primary best_model.zip, or the path."""
    name = str(name_or_path)
    return bundled_model(name) if name in bundle_names() else Path(name)

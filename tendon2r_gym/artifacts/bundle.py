"""The bundled PPO models (package data, ``tendon2r_gym/data/models/<name>/``): copy and look up.

Layout (the small files of each run, tendon2r_gym.artifacts.runs.BUNDLE_FILES)::

    <name>/bundle.json        seeds, primary seed, the training and bundling commands
    <name>/seed_<n>/          best_model.zip, best_model_vecnormalize.npz, run.json, ...

The primary seed (the first one trained, chosen before training, not the best one) is the model
that ``tendon2r-evaluate --policy ppo`` uses; the others give the spread over training seeds.
Each run.json records the env config the model was trained with.  A bundle holds no pickle:
its statistics are plain arrays (npz), and its model zip is read without unpickling
(tendon2r_gym.artifacts.files); bundling a run of an earlier version, whose statistics are a
pickle, converts them, and only with the trust option.

A bundle's name is one plain folder name under the models root (`check_name`), and
bundling writes nothing else: the new bundle is written into a temporary folder beside it
(``.<name>.new-*``) and renamed into place once complete; an existing bundle is replaced only
when asked (``replace``), and only after the new one is complete.
"""

from __future__ import annotations

import json
import re
import shutil
import uuid
from pathlib import Path
from typing import Any

from tendon2r_gym.artifacts.files import corrupt, load_policy, read_json, read_stats
from tendon2r_gym.artifacts.runs import (
    BEST,
    BUNDLE_FILES,
    STATS,
    SUMMARY,
    RunFolder,
    model_files,
    seed_dir,
)
from tendon2r_gym.presets import MODELS_DIR
from tendon2r_gym.validation import invalid

BUNDLE_META = "bundle.json"
#: The keys of bundle.json that are read (it also records the bundle's name).
META_KEYS = ("seeds", "primary_seed", "train_command", "command")
#: A bundle name: a plain folder name (no separator, not hidden, no '..').
NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")
NAME_ALLOWED = (
    "a plain bundle name: letters, digits, '_', '.' and '-', starting with a letter, digit or "
    "'_', without '..' (one folder under the models root)"
)


def check_name(name: Any, field: str = "name") -> str:
    """Returns ``name`` if it is a plain bundle name (`NAME`), else raises naming
    ``field``."""
    if not _plain(name):
        raise invalid(field, name, NAME_ALLOWED)
    return name


def _plain(name: Any) -> bool:
    return isinstance(name, str) and bool(NAME.fullmatch(name)) and ".." not in name


def check_destination(
    name: Any,
    replace: bool = False,
    root: Path = MODELS_DIR,
    field: str = "name",
    flag: str = "replace=True",
) -> Path:
    """Returns root/<name>, the folder a bundle ``name`` is written to, after checking the name
    (naming ``field``) and that no bundle is there unless ``replace`` (``flag`` is what asks
    for it); a folder there that is not a bundle is never replaced."""
    dest = Path(root) / check_name(name, field)
    if dest.exists() or dest.is_symlink():
        if not (dest / BUNDLE_META).is_file() or dest.is_symlink():
            raise invalid(field, name, f"a name not taken by {dest}, which is not a bundle folder")
        if not replace:
            raise invalid(field, name, f"a new bundle name, or {flag} to replace the bundle {dest}")
    return dest


def bundle_runs(
    run_dirs: list[Path],
    name: str,
    command: str,
    root: Path = MODELS_DIR,
    replace: bool = False,
    trust_pickle: bool | None = None,
) -> Path:
    """Copies the small files of each training run into root/<name>/seed_<n>/ and writes
    bundle.json (an existing bundle of that name only with ``replace``, and only once the new
    one is complete: module docstring).  A run of an earlier version (its statistics a pickle)
    is bundled only with ``trust_pickle`` (or inside files.trusting_pickle), its statistics
    written as the npz.  Returns the bundle folder."""
    dest = check_destination(name, replace, root)
    runs = [RunFolder(r) for r in run_dirs]
    if not runs:
        raise invalid("runs", run_dirs, "one or more run folders")
    summaries, stats = [], []
    for run in runs:
        stats.append(model_files(run.best)[1])  # the npz, or an earlier version's pkl
        needed = [f for f in BUNDLE_FILES if f != f"{BEST}{STATS}"]
        missing = [f for f in needed if not run.file(f).is_file()]
        missing += [] if stats[-1].is_file() else [f"{BEST}{STATS}"]
        if missing:
            raise FileNotFoundError(f"run folder {run.path} lacks {missing}; was it finished?")
        load_policy(run.file(f"{BEST}.zip"))  # a corrupt model is not bundled
        read_stats(stats[-1], trust_pickle)  # nor a pickle unless trusted
        summaries.append(run.read_json(SUMMARY))
    seeds = [s["seed"] for s in summaries]
    if len(set(seeds)) != len(seeds):
        raise invalid("runs", [str(r) for r in run_dirs], f"runs of different seeds (not {seeds})")
    meta = {
        "name": name,
        "seeds": seeds,
        "primary_seed": seeds[0],
        "train_command": runs[0].train_command(),
        "command": command,
    }
    Path(root).mkdir(parents=True, exist_ok=True)
    new = _beside(dest, "new")
    new.mkdir()
    try:
        for run, seed, saved in zip(runs, seeds, stats, strict=True):
            folder = seed_dir(new, seed)
            folder.mkdir()
            for f in BUNDLE_FILES:
                if f == f"{BEST}{STATS}" and saved.suffix != ".npz":  # an earlier version's
                    read_stats(saved, trust_pickle).save(folder / f)
                else:
                    shutil.copy2(run.file(f), folder / f)
        (new / BUNDLE_META).write_text(json.dumps(meta, indent=1) + "\n")
        _swap_in(new, dest)
    finally:
        shutil.rmtree(new, ignore_errors=True)  # gone already once renamed into place
    return dest


def _swap_in(new: Path, dest: Path) -> None:
    """Renames the complete bundle ``new`` to ``dest``; an old bundle there is moved aside
    first and deleted only after, or moved back if the rename fails."""
    if not dest.exists():
        new.rename(dest)
        return
    old = _beside(dest, "old")
    dest.rename(old)
    try:
        new.rename(dest)
    except BaseException:
        old.rename(dest)
        raise
    shutil.rmtree(old)


def _beside(dest: Path, kind: str) -> Path:
    """Returns a free hidden name beside ``dest`` (never a bundle name: `NAME`)."""
    return dest.with_name(f".{dest.name}.{kind}-{uuid.uuid4().hex[:8]}")


def bundle_names(root: Path = MODELS_DIR) -> list[str]:
    """Returns the names of the bundles under root."""
    found = Path(root).glob("*")
    return sorted(p.name for p in found if _plain(p.name) and (p / BUNDLE_META).is_file())


def bundle_meta(name: str, root: Path = MODELS_DIR) -> dict[str, Any] | None:
    """Returns the bundle's bundle.json, or None if nothing is bundled under that name; a
    corrupt one is a ValueError naming it."""
    path = Path(root) / str(name) / BUNDLE_META
    if not _plain(name) or not path.is_file():
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
    return seed_dir(Path(root) / name, seed) / f"{BEST}.zip"


def model_path(name_or_path: str | Path) -> Path:
    """Returns the model a name stands for: a bundle's primary best_model.zip, or the path."""
    name = str(name_or_path)
    return bundled_model(name) if name in bundle_names() else Path(name)

"""Presets: YAML files in ``configs/env/`` whose keys are the Python fields.

A preset has up to three sections: ``mechanism`` (Mechanism fields), ``reference`` (Reference
fields) and ``reference_ranges`` (ReferenceRanges fields: a random reference every episode).
Files are read with ``yaml.safe_load``; the same format serves ``evaluate.py --env-config``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

#: The repository's configs/ folder (override with TENDON2R_CONFIG_DIR).
CONFIG_DIR = Path(
    os.environ.get("TENDON2R_CONFIG_DIR", Path(__file__).resolve().parent.parent / "configs")
)
PRESET_DIR = CONFIG_DIR / "env"
PRESET_SECTIONS = ("mechanism", "reference", "reference_ranges")


def list_presets() -> list[str]:
    """Returns the names of the presets in configs/env/."""
    return sorted(p.stem for p in PRESET_DIR.glob("*.yaml"))


def preset_path(preset: str | os.PathLike) -> Path:
    """Returns the file of a preset name or a YAML path."""
    path = Path(preset)
    if path.suffix in (".yaml", ".yml"):
        if not path.is_file():
            raise ValueError(f"preset file {str(path)!r} does not exist")
        return path
    path = PRESET_DIR / f"{preset}.yaml"
    if not path.is_file():
        raise ValueError(
            f"unknown preset {str(preset)!r}; allowed: {list_presets()} or a .yaml path"
        )
    return path


def load_yaml(path: str | os.PathLike) -> dict[str, Any]:
    """Reads a YAML mapping (safe_load: plain data, never code)."""
    with open(path) as f:
        data = yaml.safe_load(f) or {}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping at the top level, got {type(data).__name__}")
    return data


def load_preset(preset: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """Returns the sections of a preset, each a dict (empty when the file omits it)."""
    path = preset_path(preset)
    data = load_yaml(path)
    unknown = set(data) - set(PRESET_SECTIONS)
    if unknown:
        raise ValueError(f"{path}: unknown sections {sorted(unknown)}; allowed: {PRESET_SECTIONS}")
    return {k: dict(data.get(k) or {}) for k in PRESET_SECTIONS}

"""Package data and experiment files: where things live, how YAML is read, how presets merge.

An *experiment file* (an env YAML) holds any keyword argument of the Tendon2R env at its top level:
the sections ``mechanism`` (Mechanism fields), ``reference`` (Reference fields) and
``reference_ranges`` (ReferenceRanges fields), and the scalar arguments such as ``ctrl_dt``,
``episode_duration``, ``fit_to_workspace`` or ``reward_scales``.  The bundled presets are such
files, shipped inside the package (``tendon2r_gym/data/presets/``); a user's own file is passed
by path, ``gym.make("Tendon2R-v1", preset="my_arm.yaml")``.  Keyword arguments given to
``gym.make`` override the file: a ``mechanism`` or ``reference`` dict overrides only the fields
it names (`merge_env_kwargs`).

Everything the library reads at run time lives under `DATA_DIR`, so a non-editable
install works from any folder.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import yaml

from tendon2r_gym.validation import check_keys, invalid, mapping

#: Package data: presets, PD gains, PPO hyperparameters and bundled models.
DATA_DIR = Path(__file__).resolve().parent / "data"
PRESET_DIR = DATA_DIR / "presets"
PD_CONFIG = DATA_DIR / "pd.yaml"
#: The PPO hyperparameters (``configs/ppo.yaml`` in the repository links here).
PPO_CONFIG = DATA_DIR / "ppo.yaml"
#: Bundled PPO models, one folder per bundle name (see tendon2r_gym.artifacts.bundle).
MODELS_DIR = DATA_DIR / "models"

#: Sections of an experiment file that hold a mapping of fields.
SECTIONS = ("mechanism", "reference", "reference_ranges", "pd_gains")


class _Loader(yaml.SafeLoader):
    """safe_load with YAML 1.2 floats: ``1e-3`` and ``1.0e-3`` are numbers, not strings."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


def load_yaml(path: str | os.PathLike) -> dict[str, Any]:
    """Reads a YAML mapping (plain data, never code; ``1e-3`` is a float).  An empty file is
    an empty mapping."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"YAML file {str(path)!r} is invalid; allowed: an existing file")
    with open(path) as f:
        try:
            data = yaml.load(f, Loader=_Loader)  # noqa: S506 (a SafeLoader subclass)
        except yaml.YAMLError as e:
            raise ValueError(f"{path}: not valid YAML ({e})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ValueError(
            f"{path}: top level = {type(data).__name__} is invalid; allowed: a mapping"
        )
    return data


def list_presets() -> list[str]:
    """Returns the names of the bundled presets."""
    return sorted(p.stem for p in PRESET_DIR.glob("*.yaml"))


def preset_path(preset: str | os.PathLike) -> Path:
    """Returns the file of a bundled preset name or of a YAML path."""
    if not isinstance(preset, (str, os.PathLike)):
        raise invalid("preset", preset, f"one of {list_presets()} or a .yaml path")
    path = Path(preset)
    if path.suffix in (".yaml", ".yml"):
        if not path.is_file():
            raise invalid("preset", str(preset), "an existing .yaml file or a bundled preset")
        return path
    path = PRESET_DIR / f"{preset}.yaml"
    if not path.is_file():
        raise ValueError(
            f"unknown preset {str(preset)!r}; allowed: {list_presets()} or a .yaml path"
        )
    return path


def load_preset(preset: str | os.PathLike, allowed: Iterable[str]) -> dict[str, Any]:
    """Returns the env keyword arguments of a preset or experiment file, with each section a
    dict.  Unknown keys raise, naming the closest of ``allowed``."""
    path = preset_path(preset)
    data = load_yaml(path)
    check_keys(str(path), data, allowed)
    # A section is a mapping, or a name that EnvConfig reads (reference_ranges: course).
    section = lambda k, v: k in SECTIONS and not isinstance(v, str)  # noqa: E731
    return {k: (mapping(f"{path}: {k}", v) if section(k, v) else v) for k, v in data.items()}


def merge_reference(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """Returns ``base`` with ``override``'s fields; naming one of freq_hz / omega_rad_s drops
    the other (a reference has exactly one of the two)."""
    out = dict(base)
    if {"freq_hz", "omega_rad_s"} & set(override):
        out.pop("freq_hz", None)
        out.pop("omega_rad_s", None)
    return {**out, **override}


def merge_env_kwargs(base: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """Returns env keyword arguments ``base`` (a preset's) with ``overrides`` applied: dicts for
    ``mechanism``, ``reference`` and ``pd_gains`` override only the fields they name, anything
    else (a Mechanism or Reference object, a scalar, ``reference_ranges``) replaces the base
    value."""
    out = dict(base)
    for key, value in overrides.items():
        if key in ("mechanism", "pd_gains") and isinstance(value, Mapping):
            out[key] = {**_fields(key, out.get(key) or {}), **value}
        elif key == "reference" and isinstance(value, Mapping):
            out[key] = merge_reference(_fields(key, out.get(key)), value)
        else:
            out[key] = value
    return out


def _fields(name: str, value: Any) -> dict[str, Any]:
    """Returns a section as a dict of fields (a Mechanism or Reference object gives its own)."""
    to_dict = getattr(value, "to_dict", None)
    return to_dict() if callable(to_dict) else mapping(name, value)

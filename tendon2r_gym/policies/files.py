"""Reading the model-side files of a run or bundle: the SB3 model zip, its VecNormalize pkl and a
bundle's bundle.json.  Whatever is wrong with one of them (truncated, not that kind of file,
missing a key, made for another observation size) is one ValueError that names the file, says
what is wrong and how to recover (:func:`corrupt`, :func:`mismatch`)."""

from __future__ import annotations

import json
import pickle
import struct
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from tendon2r_gym.llvm import load_triton

#: How to get a good model file back.
RECOVER_MODEL = (
    "re-bundle it with tendon2r-bundle --replace from its run folder (a bundled model), resume "
    "its run from the last good checkpoint with tendon2r-train --resume, or re-train it"
)
#: SB3's first entry of a model zip: a file that starts with it and has lost it is truncated.
_MODEL_DATA = "data"


def corrupt(path: str | Path, what: str, recover: str = RECOVER_MODEL) -> ValueError:
    """Returns the project's error for a corrupt file: ``<path> is <what>; to recover: ...``."""
    return ValueError(f"{path} is {what}; to recover: {recover}")


def mismatch(path: str | Path, what: str, theirs: Any, ours: Any, env: str) -> ValueError:
    """Returns the error for a readable model file made for another env: ``what`` (e.g.
    observation shape) is ``theirs`` in the file, ``ours`` in ``env``."""
    return ValueError(
        f"{path} does not match {env}: {what} {theirs} in the file, {ours} in the env; "
        f"to recover: {RECOVER_MODEL}"
    )


# -- model zip ---------------------------------------------------------------------------------
def model_data(path: str | Path) -> dict[str, Any]:
    """Returns the SB3 ``data`` of a model zip (its spaces and settings) after reading the whole
    file as ``PPO.load`` does (SB3's load_from_zip_file: data and weights)."""
    load_triton()  # before torch: tendon2r_gym.llvm
    from stable_baselines3.common.save_util import load_from_zip_file

    path = Path(path)
    _exists(path)
    try:
        data, params, _ = load_from_zip_file(path, device="cpu")
    except Exception as e:  # noqa: BLE001 (anything SB3 cannot read is a corrupt file)
        raise corrupt(path, f"{_zip_state(path)} ({type(e).__name__}: {e})") from None
    if data is None or not params:
        raise corrupt(path, _zip_state(path))
    return data


def load_model(path: str | Path, cls: Any = None, **kwargs: Any) -> Any:
    """Returns ``cls.load(path, **kwargs)`` (default: SB3's PPO); a file SB3 cannot read is a
    ValueError naming it."""
    if cls is None:
        load_triton()  # before torch: tendon2r_gym.llvm
        from stable_baselines3 import PPO

        cls = PPO
    path = Path(path)
    _exists(path)
    try:
        return cls.load(path, **kwargs)
    except Exception as e:  # noqa: BLE001 (anything SB3 cannot load is one error naming it)
        model_data(path)  # raises if the file itself is unreadable
        raise ValueError(
            f"{path} does not load ({type(e).__name__}: {e}); to recover: {RECOVER_MODEL}"
        ) from None


def check_model_spaces(
    path: str | Path,
    data: dict[str, Any],
    obs_shape: tuple[int, ...],
    action_shape: tuple[int, ...],
    env: str,
) -> None:
    """Raises if the model zip's observation or action space (``data``: :func:`model_data`)
    differs in shape from what ``env`` gives it."""
    for what, key, ours in (
        ("observation shape", "observation_space", tuple(obs_shape)),
        ("action shape", "action_space", tuple(action_shape)),
    ):
        space = data.get(key)
        theirs = getattr(space, "shape", None)
        if theirs is None:
            raise corrupt(path, f"not a model zip of this env's kind ({key}: {space!r})")
        if tuple(theirs) != ours:
            raise mismatch(path, what, tuple(theirs), ours, env)


def _zip_state(path: Path) -> str:
    """Returns what is wrong with a zip SB3 found no model in: truncated (it starts as an SB3
    model zip does, with its ``data`` entry), or not a model zip at all."""
    with path.open("rb") as f:
        head = f.read(30 + len(_MODEL_DATA))  # a zip's first local header and name
    if len(head) >= 30 and head[:4] == b"PK\x03\x04":
        size = struct.unpack("<H", head[26:28])[0]
        if head[30 : 30 + size] == _MODEL_DATA.encode():
            return "truncated (an SB3 model zip whose end is missing or damaged)"
    return "not an SB3 model zip (no readable 'data' entry and weights)"


# -- VecNormalize pkl --------------------------------------------------------------------------
def vecnormalize(path: str | Path) -> Any:
    """Returns the VecNormalize a pkl holds, without its VecEnv (the first half of SB3's
    VecNormalize.load)."""
    load_triton()  # before torch: tendon2r_gym.llvm
    from stable_baselines3.common.vec_env import VecNormalize

    path = Path(path)
    _exists(path)
    try:
        with path.open("rb") as f:
            stats = pickle.load(f)  # noqa: S301 (as VecNormalize.load: the run's own file)
    except Exception as e:  # noqa: BLE001 (anything pickle cannot read is a corrupt file)
        what = "truncated" if isinstance(e, EOFError) or "truncated" in str(e) else "unreadable"
        raise corrupt(path, f"{what} (not a whole VecNormalize pickle: {e})") from None
    if not isinstance(stats, VecNormalize):
        raise corrupt(path, f"not a VecNormalize pickle (it holds a {type(stats).__name__})")
    return stats


def load_vecnormalize(path: str | Path, venv: Any, env: str = "the env") -> Any:
    """Returns the VecNormalize of a pkl wrapping ``venv`` (SB3's VecNormalize.load), after
    checking that it normalizes observations of venv's shape."""
    stats = vecnormalize(path)
    check_stats_shape(path, stats, venv.observation_space.shape, env)
    stats.set_venv(venv)
    return stats


def check_stats_shape(path: str | Path, stats: Any, obs_shape: tuple[int, ...], env: str) -> None:
    """Raises if the VecNormalize ``stats`` normalize observations of another shape."""
    theirs = tuple(stats.observation_space.shape)
    if theirs != tuple(obs_shape):
        raise mismatch(path, "observation shape", theirs, tuple(obs_shape), env)


# -- JSON records ------------------------------------------------------------------------------
def read_json(path: str | Path, keys: Iterable[str], recover: str) -> dict[str, Any]:
    """Returns the JSON object in ``path`` after checking that it has every key of ``keys``."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except UnicodeDecodeError as e:
        raise corrupt(path, f"not JSON text ({e})", recover) from None
    except json.JSONDecodeError as e:
        raise corrupt(path, f"not JSON ({e})", recover) from None
    if not isinstance(data, dict):
        raise corrupt(path, f"not a JSON object (it holds a {type(data).__name__})", recover)
    missing = [k for k in keys if k not in data]
    if missing:
        raise corrupt(path, f"missing key {missing[0]!r}", recover)
    return data


def _exists(path: Path) -> None:
    if not path.is_file():
        raise corrupt(path, "missing")

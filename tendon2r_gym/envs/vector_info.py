"""Gymnasium's vector-env conventions, for the native vector env: the autoreset modes it
supports, SAME_STEP's final observations and infos of the arms that finished, and no mask that
no arm sets."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode

from tendon2r_gym.validation import invalid

#: The autoreset modes of the native vector env (SB3's adapter uses SAME_STEP).
MODES = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)


def autoreset(mode: AutoresetMode | str) -> AutoresetMode:
    """Returns ``mode`` (one of MODES, or its value) as an AutoresetMode, or raises."""
    if mode not in MODES + tuple(m.value for m in MODES):
        allowed = " or ".join(f"AutoresetMode.{m.name} ({m.value!r})" for m in MODES)
        raise invalid("autoreset_mode", mode, allowed)
    return AutoresetMode(mode)


def with_final(obs: np.ndarray, info: dict[str, Any], done: np.ndarray) -> dict[str, Any]:
    """Returns ``info`` of a SAME_STEP step, as SyncVectorEnv gives it: the arms ``done`` report
    their last observation in ``final_obs`` and their step info in ``final_info`` (each key
    with its mask), and their own masks cleared (their reset info comes next)."""
    final = {k: v.copy() for k, v in info.items() if not k.startswith("_")}
    final.update({f"_{k}": done.copy() for k in list(final)})
    for key in list(info):
        if key.startswith("_"):
            info[key] = info[key] & ~done
    info["final_obs"] = np.full(len(done), None, dtype=object)
    for i in np.flatnonzero(done):
        info["final_obs"][i] = obs[i].copy()
    info["_final_obs"] = done.copy()
    info["final_info"], info["_final_info"] = final, done.copy()
    return info


def without_empty(info: dict[str, Any]) -> dict[str, Any]:
    """Returns info without the keys that no arm has (all-False masks), as Gymnasium's vector
    envs never create them."""
    empty = {k[1:] for k, v in info.items() if k.startswith("_") and not np.any(v)}
    return {k: v for k, v in info.items() if k not in empty and k.removeprefix("_") not in empty}

"""How the ids are made: the registered entry point (the env under its TimeLimit) and the
library's own factory, which makes envs of exactly the kwargs it is given."""

from __future__ import annotations

import os
from typing import Any

import gymnasium as gym

from tendon2r_gym.envs.env import RENDER_ARGS, Tendon2REnv
from tendon2r_gym.envs.env_config import EnvConfig, resolve


def make_env(preset: EnvConfig | str | os.PathLike = "default", **kwargs: Any) -> gym.Env:
    """The registered entry point: Tendon2REnv under a TimeLimit of episode_duration / ctrl_dt
    steps, so ``gym.make(..., episode_duration=X, ctrl_dt=Y)`` gives X / Y steps (the TimeLimit
    is the one source of truth for truncation, and ``env.spec.max_episode_steps`` reports it).
    The experiment is resolved here, once (or given resolved: an EnvConfig as ``preset``), and
    passed down."""
    config, render = resolved(preset, kwargs)
    env = Tendon2REnv(config, **render)
    return gym.wrappers.TimeLimit(env, env.timing.max_episode_steps)


def resolved(
    preset: EnvConfig | str | os.PathLike, kwargs: dict[str, Any]
) -> tuple[EnvConfig, dict[str, Any]]:
    """Returns the EnvConfig of an entry point's ``preset`` (an EnvConfig if resolved already)
    and ``kwargs``, and the rendering arguments among them (RENDER_ARGS)."""
    render = {k: kwargs.pop(k) for k in RENDER_ARGS if k in kwargs}
    return resolve(preset, **kwargs), render


#: The id the library's own tools make envs with: Tendon2R-v0 adds no defaults over a preset,
#: so the env is exactly what the given kwargs (a model's recorded settings) say.
BASE_ID = "Tendon2R-v0"


def make(**kwargs: Any) -> gym.Env:
    """``gym.make`` of BASE_ID, through its spec: the same env, wrappers and TimeLimit, without
    Gymnasium's notice that a newer version exists (it is meant for users' own ids)."""
    return gym.make(gym.spec(BASE_ID), **kwargs)

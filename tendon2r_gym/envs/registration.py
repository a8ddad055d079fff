"""How the ids are made: the registered entry point (the env under its TimeLimit) and the
library's own factory, which makes envs of exactly the kwargs it is given."""

from __future__ import annotations

import os
from typing import Any

import gymnasium as gym

from tendon2r_gym.envs.env import Tendon2REnv


def make_env(preset: str | os.PathLike = "default", **kwargs: Any) -> gym.Env:
    """The registered entry point: Tendon2REnv under a TimeLimit of episode_duration / ctrl_dt
    steps, so ``gym.make(..., episode_duration=X, ctrl_dt=Y)`` gives X / Y steps (the TimeLimit
    is the one source of truth for truncation, and ``env.spec.max_episode_steps`` reports it)."""
    env = Tendon2REnv(preset, **kwargs)
    return gym.wrappers.TimeLimit(env, env.config.max_episode_steps)


#: The id the library's own tools make envs with: Tendon2R-v0 adds no defaults over a preset,
#: so the env is exactly what the given kwargs (a model's recorded settings) say.
BASE_ID = "Tendon2R-v0"


def make(**kwargs: Any) -> gym.Env:
    """``gym.make`` of BASE_ID, through its spec: the same env, wrappers and TimeLimit, without
    Gymnasium's notice that a newer version exists (it is meant for users' own ids)."""
    return gym.make(gym.spec(BASE_ID), **kwargs)

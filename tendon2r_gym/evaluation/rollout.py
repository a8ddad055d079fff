"""Rollouts: run any policy with ``predict(obs) -> (action, state)`` on seeded episodes."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from tendon2r_gym.envs.env_config import EnvConfig, resolve


class Policy(Protocol):
    """SB3's ``predict``.  A policy may also have ``reset(info)``: the rollouts call it with
    each reset's info (computed torque reads the episode's reference there)."""

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]: ...


@dataclass
class Trace:
    """One episode, one row per control step (after the step)."""

    seed: int
    time: np.ndarray  # (T,) s
    q: np.ndarray  # (T, 2) rad
    q_des: np.ndarray  # (T, 2) rad
    error_deg: np.ndarray  # (T, 2) q_des - q, deg
    tendon_tension: np.ndarray  # (T, n_tendons) N, positive pulling
    action: np.ndarray  # (T, n_tendons) normalized command (clipped)
    effector_pos: np.ndarray  # (T, 2) m
    reward: np.ndarray  # (T,)
    diverged: bool
    frames: list[np.ndarray] | None = None


def rollout(
    policy: Policy,
    env: gym.Env,
    seed: int,
    options: dict[str, Any] | None = None,
    render: bool = False,
) -> Trace:
    """Runs one deterministic episode of ``policy`` on ``env`` from ``reset(seed=seed)``."""
    obs, info = env.reset(seed=seed, options=options)
    _start_episode(policy, info)
    rows: dict[str, list] = {k: [] for k in _FIELDS}
    frames = [env.render()] if render else None
    done, diverged = False, False
    while not done:
        action, _ = policy.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = env.step(action)
        done = terminated or truncated
        diverged = diverged or bool(info["diverged"])
        _record(rows, info, action, reward)
        if render:
            frames.append(env.render())
    return Trace(
        seed=seed,
        diverged=diverged,
        frames=frames,
        **{k: np.asarray(v, dtype=float) for k, v in rows.items()},
    )


def rollouts(
    policy: Policy,
    env: EnvConfig | Mapping[str, Any],
    seeds: Sequence[int],
    options: dict[str, Any] | None = None,
) -> list[Trace]:
    """Runs one deterministic episode per seed, all at once on the native vector env (one arm
    per seed, the policy called on the batch of observations) of ``env`` (an EnvConfig, or
    env kwargs: resolved once).  Each episode equals ``rollout`` on
    ``tendon2r_gym.envs.registration.make(preset=config)`` with that seed, bit for bit."""
    from tendon2r_gym.envs.vector_env import Tendon2RVectorEnv

    n = len(seeds)
    envs = Tendon2RVectorEnv(n, resolve(env))
    try:
        obs, info = envs.reset(seed=list(seeds), options=options)
        _start_episode(policy, info)
        rows: dict[str, list] = {k: [] for k in _FIELDS}
        live = np.ones(n, dtype=bool)  # the arm's episode is still running
        length = np.zeros(n, dtype=int)
        diverged = np.zeros(n, dtype=bool)
        while live.any():
            action, _ = policy.predict(obs, deterministic=True)
            action = np.asarray(action, dtype=np.float64).reshape(n, -1)
            obs, reward, terminated, truncated, info = envs.step(action)
            _record(rows, info, action, reward)
            diverged |= live & info["diverged"]
            length += live
            live &= ~(terminated | truncated)
    finally:
        envs.close()
    stacked = {k: np.asarray(v, dtype=float) for k, v in rows.items()}
    return [
        Trace(
            seed=s, diverged=bool(diverged[i]), **{k: v[: length[i], i] for k, v in stacked.items()}
        )
        for i, s in enumerate(seeds)
    ]


def _start_episode(policy: Policy, info: dict[str, Any]) -> None:
    reset = getattr(policy, "reset", None)
    if callable(reset):
        reset(info)


#: Trace fields read from a step's info (the same keys in the single and the vector env).
_FROM_INFO = {
    "time": "time",
    "q": "q",
    "q_des": "q_des",
    "error_deg": "tracking_error_deg",
    "tendon_tension": "tendon_tension",
    "effector_pos": "effector_pos",
}
_FIELDS = (*_FROM_INFO, "action", "reward")


def _record(rows: dict[str, list], info: dict[str, Any], action: Any, reward: Any) -> None:
    """Appends one step (of one env, or of every arm) to the trace rows."""
    for field, key in _FROM_INFO.items():
        rows[field].append(info[key])
    rows["action"].append(np.clip(action, -1, 1))
    rows["reward"].append(reward)

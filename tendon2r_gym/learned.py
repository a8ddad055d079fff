"""Learned policies: residual RL on top of the PD baseline, and loading trained PPO runs.

With ``residual_scale > 0`` the agent's action a in [-1, 1] is added to the PD command:
command = clip(PD(obs) + residual_scale * a, -1, 1).  The agent starts at PD's performance
(SB3 initializes the policy mean near zero) and learns what PD lacks, such as acceleration
feed-forward.  With ``residual_scale = 0`` the agent drives the motors directly.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from tendon2r_gym.policies import PDPolicy

RUN_META = "policy.json"  # written beside a saved model: how to rebuild the policy


class ResidualPDWrapper(gym.Wrapper):
    """The agent's action is a residual on the PD command (see module docstring)."""

    def __init__(self, env: gym.Env, residual_scale: float) -> None:
        super().__init__(env)
        if not 0 < residual_scale <= 2:
            raise ValueError(f"residual_scale = {residual_scale!r} is invalid; allowed: (0, 2]")
        self.residual_scale = residual_scale
        self.pd = PDPolicy.from_env(env)
        self._obs: np.ndarray | None = None

    def reset(self, **kwargs: Any):
        self._obs, info = self.env.reset(**kwargs)
        return self._obs, info

    def step(self, action: np.ndarray):
        base, _ = self.pd.predict(self._obs)
        command = residual_command(base, _checked_action(action), self.residual_scale)
        self._obs, reward, terminated, truncated, info = self.env.step(command)
        return self._obs, reward, terminated, truncated, info


def residual_command(base: np.ndarray, action: np.ndarray, scale: float) -> np.ndarray:
    """Returns clip(base + scale * clip(action, -1, 1), -1, 1) for one observation: the PD
    command ``base`` plus the agent's residual.  Scalar math, as it runs on every training step;
    training (ResidualPDWrapper) and deployment (PPOPolicy) share it."""
    (b1, b2), (a1, a2) = base.tolist(), action.tolist()
    return np.array(
        (_clip1(b1 + scale * _clip1(a1)), _clip1(b2 + scale * _clip1(a2))), dtype=np.float64
    )


def _clip1(x: float) -> float:
    return min(max(x, -1.0), 1.0)


def _checked_action(action: np.ndarray) -> np.ndarray:
    """Returns the action as a float64 array; raises on a wrong shape or non-finite values."""
    arr = np.asarray(action, dtype=np.float64)
    if arr.shape != (2,) or not (math.isfinite(arr[0]) and math.isfinite(arr[1])):
        raise ValueError(f"action = {action!r} is invalid; allowed: 2 finite values in [-1, 1]")
    return arr


def make_training_env(env_kwargs: dict[str, Any], residual_scale: float) -> gym.Env:
    """Returns Tendon2R-v0 with the given kwargs, wrapped for residual learning if asked."""
    env = gym.make("Tendon2R-v0", **env_kwargs)
    return ResidualPDWrapper(env, residual_scale) if residual_scale > 0 else env


class PPOPolicy:
    """A trained PPO (+ VecNormalize statistics) behind the SB3 ``predict`` interface, acting on
    raw observations of the unwrapped env: normalizes them, and adds PD if it was residual."""

    def __init__(
        self,
        model: Any,
        obs_rms: Any,
        clip_obs: float,
        epsilon: float,
        residual_scale: float,
        env: gym.Env | None = None,
    ) -> None:
        self.model = model
        self.obs_rms = obs_rms
        self.clip_obs, self.epsilon = clip_obs, epsilon
        self.residual_scale = residual_scale
        self.pd = PDPolicy.from_env(env) if residual_scale > 0 and env is not None else None

    @classmethod
    def load(cls, model_path: str | Path, env: gym.Env) -> PPOPolicy:
        """Loads ``<name>.zip`` with ``<name>_vecnormalize.pkl`` and the run's policy.json."""
        import pickle

        from stable_baselines3 import PPO

        model_path = Path(model_path)
        model = PPO.load(model_path, device="cpu")
        stats = model_path.with_name(model_path.stem + "_vecnormalize.pkl")
        if not stats.is_file():
            raise FileNotFoundError(
                f"VecNormalize statistics {stats} not found beside {model_path}"
            )
        with open(stats, "rb") as f:
            vecnorm = pickle.load(f)
        meta = json.loads((model_path.parent / RUN_META).read_text())
        return cls(
            model,
            vecnorm.obs_rms if vecnorm.norm_obs else None,
            vecnorm.clip_obs,
            vecnorm.epsilon,
            float(meta["residual_scale"]),
            env,
        )

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        if self.obs_rms is None:
            return obs
        z = (obs - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + self.epsilon)
        return np.clip(z, -self.clip_obs, self.clip_obs).astype(np.float32)

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        obs = np.asarray(observation, dtype=np.float64)
        action, state = self.model.predict(self.normalize(obs), state, episode_start, deterministic)
        if self.pd is None:
            return np.clip(action, -1.0, 1.0).astype(np.float32), state
        base, _ = self.pd.predict(obs)
        if obs.ndim == 1:
            action = residual_command(base, action, self.residual_scale)
        else:
            action = np.stack(
                [
                    residual_command(b, a, self.residual_scale)
                    for b, a in zip(base, action, strict=True)
                ]
            )
        return action.astype(np.float32), state

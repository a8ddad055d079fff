"""The stacked observations training sees: SB3's VecFrameStack, or `StridedFrameStack` when
the frames are ``frame_stride`` control steps apart (tendon2r_gym.policies.history, whose
`FrameHistory` buffer the deployed policy stacks through as well)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import VecEnvWrapper, VecFrameStack

from tendon2r_gym.policies.history import FrameHistory


class StridedFrameStack(VecEnvWrapper):
    """SB3's VecFrameStack for vector observations, with frames ``stride`` steps apart;
    ``infos[i]["terminal_observation"]`` is stacked too, as VecFrameStack does."""

    def __init__(self, venv: Any, n_stack: int, stride: int) -> None:
        space = venv.observation_space
        box = gym.spaces.Box(
            np.tile(space.low, n_stack), np.tile(space.high, n_stack), dtype=space.dtype
        )
        super().__init__(venv, observation_space=box)
        self.history = FrameHistory(n_stack, stride)

    def reset(self) -> np.ndarray:
        self.history.clear()
        return self.history.push(self.venv.reset())

    def step_wait(self) -> Any:
        obs, rewards, dones, infos = self.venv.step_wait()
        for i, done in enumerate(dones):
            if done and "terminal_observation" in infos[i]:
                infos[i]["terminal_observation"] = self.history.peek(
                    i, infos[i]["terminal_observation"]
                )
        return self.history.push(obs, dones), rewards, dones, infos


def stacked(vecnorm: Any, frame_stack: int, frame_stride: int = 1) -> Any:
    """Returns what the policy trains on: ``vecnorm``; with frame_stack > 1 SB3's VecFrameStack
    of it (rl_zoo3's order: normalize, then stack), or `StridedFrameStack` with a
    stride."""
    if frame_stack == 1:
        return vecnorm
    if frame_stride == 1:
        return VecFrameStack(vecnorm, frame_stack)
    return StridedFrameStack(vecnorm, frame_stack, frame_stride)

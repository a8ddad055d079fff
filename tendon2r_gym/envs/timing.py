"""Timing: an env's clock and sensors in control steps, derived once from its EnvConfig.

EnvConfig is the record of an experiment (seconds, as a user writes them); the envs step in
whole control and physics steps.  `Timing.of(config)` turns the one into the other: the
physics steps per control step, the episode's length, each delay in control steps, the
largest delays that any episode of drawn arms holds (the buffers' sizes), and whether the
observation is a measurement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from tendon2r_gym.task.arms import SENSING, drawn_high

if TYPE_CHECKING:
    from tendon2r_gym.envs.env_config import EnvConfig


@dataclass(frozen=True)
class Timing:
    """An env's (or one drawn arm's) counts of control steps and its sensing (`Timing.of`)."""

    #: The physics steps per control step: ctrl_dt / mechanism.sim_dt.
    n_substeps: int
    #: The control steps per episode: episode_duration / ctrl_dt.
    max_episode_steps: int
    #: The control steps each motor command is held back (mechanism.motor_delay).
    delay_steps: int
    #: The control steps each measurement is late (observation_delay).
    observation_delay_steps: int
    #: The most control steps any episode holds a command back (0: no delay); with
    #: mechanism_ranges, the top of a drawn motor_delay's range.
    delay_capacity: int
    #: The most control steps any episode's measurements are late.
    observation_delay_capacity: int
    #: Whether any episode's measurements can carry noise.
    noisy: bool
    #: The weight of a new action in the applied command, 1 - exp(-ctrl_dt / tau) (1: no
    #: filter; `low_pass_alpha` of action_filter_tau).
    action_filter_alpha: float

    @classmethod
    def of(cls, config: EnvConfig) -> Timing:
        """Returns the timing of ``config`` (its ranges' largest delays and noise included)."""
        dt = config.ctrl_dt
        steps = lambda seconds: round(seconds / dt)  # noqa: E731
        motor_delay = config.mechanism.motor_delay
        noise = zip(SENSING[1:], config.observation_noise, strict=True)
        return cls(
            n_substeps=round(dt / config.mechanism.sim_dt),
            max_episode_steps=steps(config.episode_duration),
            delay_steps=steps(motor_delay),
            observation_delay_steps=steps(config.observation_delay),
            delay_capacity=steps(drawn_high(config, "motor_delay", motor_delay)),
            observation_delay_capacity=steps(
                drawn_high(config, "observation_delay", config.observation_delay)
            ),
            noisy=any(drawn_high(config, k, v) > 0 for k, v in noise),
            action_filter_alpha=low_pass_alpha(config.action_filter_tau, dt),
        )

    @property
    def sensed(self) -> bool:
        """Returns whether the observation is (or in some episode may be) a measurement, noisy
        or late, not the state."""
        return self.observation_delay_capacity > 0 or self.noisy


def low_pass_alpha(tau: float, dt: float) -> float:
    """Returns the weight of a new input to a first-order low-pass of time constant ``tau``
    sampled every ``dt``, y <- y + alpha (x - y): alpha = 1 - exp(-dt / tau), 1 for ``tau =
    0`` (no filter).  The env's action filter and a residual's filter
    (tendon2r_gym.policies.residual.ResidualFilter) both use it."""
    return 1.0 if tau == 0.0 else -math.expm1(-dt / tau)

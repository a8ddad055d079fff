"""Residual RL on top of the PD baseline.

With ``residual_scale > 0`` the agent's action a in [-1, 1] is added to the PD command:
command = clip(PD(obs) + residual_scale * a, -1, 1).  The agent starts at PD's performance
(SB3 initializes the policy mean near zero) and learns what PD lacks, such as acceleration
feed-forward.  With ``residual_scale = 0`` the agent drives the motors directly ("from
scratch").  With ``residual_filter_tau > 0`` the residual passes a first-order low-pass
(``ResidualFilter``) before it is added, and PD's own command does not: a filter on the
whole command would put its lag inside PD's loop.  ``residual_scale`` is a fraction of each
command's whole range (a tendon's in tension mode, a joint's in joint-torque mode), the same on
every arm.  With ``residual_units="need"`` (joint-torque mode) it is instead a multiple of
each joint's peak torque need on the episode's arm and reference (EnvConfig.needs.torque_need):
a residual of 1 can add the whole torque the reference needs, on the joint that needs little as
on the one that needs much (``Tendon2RResidual-v2``).
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import gymnasium as gym
import numpy as np

from tendon2r_gym.envs.env import Tendon2REnv
from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.envs.registration import resolved
from tendon2r_gym.envs.timing import low_pass_alpha
from tendon2r_gym.policies.baselines import PDPolicy
from tendon2r_gym.validation import invalid, number, real_array

#: The largest residual_scale (a fraction of the command range).
MAX_RESIDUAL_SCALE = 2.0


#: The largest residual_filter_tau (s).
MAX_RESIDUAL_FILTER_TAU = 1.0
#: What residual_scale multiplies: "command", each command's whole range (the same on every
#: joint and arm); "need", each joint's peak torque need (joint-torque mode only).
RESIDUAL_UNITS = ("command", "need")


@dataclasses.dataclass(frozen=True)
class Residual:
    """How a policy's action joins PD's command (module docstring): ``scale`` (0: no PD, the
    action is the command; > 0: a residual on PD) and the residual's low-pass ``filter_tau``
    (s).  An entry, a run record and a deployed policy carry these two as ``residual_scale``
    and ``residual_filter_tau`` (``to_record``, ``from_record``); errors name those."""

    scale: float = 0.0
    filter_tau: float = 0.0

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        set_("scale", number("residual_scale", self.scale, 0.0, MAX_RESIDUAL_SCALE))
        tau = number("residual_filter_tau", self.filter_tau, 0.0, MAX_RESIDUAL_FILTER_TAU)
        if tau > 0 and self.scale == 0:
            raise invalid("residual_filter_tau", tau, "0 without a residual (residual_scale 0)")
        set_("filter_tau", tau)

    @property
    def active(self) -> bool:
        """Whether the action is a residual on PD (scale > 0)."""
        return self.scale > 0

    def to_record(self) -> dict[str, Any]:
        """Returns the fields under the names an entry and a run record give them."""
        return {"residual_scale": self.scale, "residual_filter_tau": self.filter_tau}

    @classmethod
    def from_record(cls, record: dict[str, Any] | None) -> Residual:
        """Returns the residual an entry or a model's run record (run.json, as
        tendon2r_gym.artifacts.runs reads it) gives; a field recorded before it existed, or no
        record, takes its default (no filter)."""
        record = record or {}
        return cls(
            float(record.get("residual_scale", 0.0)), float(record.get("residual_filter_tau", 0.0))
        )


#: No residual: the policy's action is the command (plain PPO).
NO_RESIDUAL = Residual()


class ResidualPDWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """The agent's action is a residual on the PD command (see module docstring)."""

    def __init__(
        self,
        env: gym.Env,
        residual_scale: float,
        residual_filter_tau: float = 0.0,
        residual_units: str = "command",
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self,
            residual_scale=residual_scale,
            residual_filter_tau=residual_filter_tau,
            residual_units=residual_units,
        )
        super().__init__(env)
        number("residual_scale", residual_scale, 0.0, MAX_RESIDUAL_SCALE, lo_open=True)
        if residual_units not in RESIDUAL_UNITS:
            raise invalid("residual_units", residual_units, f"one of {RESIDUAL_UNITS}")
        mode = env.unwrapped.config.action_mode
        if residual_units == "need" and mode != "joint_torque":
            raise invalid(
                "residual_units", residual_units, f"'command' in action_mode {mode!r} ('need' "
                "scales joint torques: action_mode 'joint_torque')",
            )  # fmt: skip
        self.residual = Residual(residual_scale, residual_filter_tau)
        self.residual_units = residual_units
        self.pd = PDPolicy.from_env(env)
        self.filter = ResidualFilter(residual_filter_tau, env.unwrapped.config.ctrl_dt)
        self._scale: float | np.ndarray = self.residual.scale
        self._obs: np.ndarray | None = None

    def reset(self, **kwargs: Any):
        self._obs, info = self.env.reset(**kwargs)
        self.pd.reset(info)  # follows the episode's arm, if the env draws arms
        self.filter.clear()
        if self.residual_units == "need":  # this episode's need, over the action's torque
            max_torque = self.pd.actuation.max_torque
            need = np.asarray(info["torque_need_Nm"], dtype=float)
            self._scale = self.residual.scale * need / np.where(max_torque > 0, max_torque, 1.0)
        return self._obs, info

    def step(self, action: np.ndarray):
        base, _ = self.pd.predict(self._obs)
        command = residual_command(base, action, self._scale, self.filter)
        self._obs, reward, terminated, truncated, info = self.env.step(command)
        return self._obs, reward, terminated, truncated, info


class ResidualFilter:
    """A first-order low-pass on the residual of one env or a batch of them: y <- y + alpha
    (r - y), alpha = 1 - exp(-ctrl_dt / tau), y = 0 where an episode starts (the policy starts
    at PD's command); ``tau = 0``: none (y = r).  Its state is not observed: the env observes
    the command it applied, PD's plus y."""

    def __init__(self, tau: float, ctrl_dt: float) -> None:
        tau = number("residual_filter_tau", tau, 0.0, MAX_RESIDUAL_FILTER_TAU)
        self.alpha = low_pass_alpha(tau, ctrl_dt)
        self._y: np.ndarray | None = None

    def clear(self) -> None:
        """Starts every episode anew (the next residual is the first of its episode)."""
        self._y = None

    def __call__(self, residual: np.ndarray, start: Any = None) -> np.ndarray:
        """Returns the filtered ``residual`` (shape (*batch, n)); where ``start`` (a bool per
        batch row, as SB3's ``episode_start``) the filter restarts from 0 first."""
        if self.alpha == 1.0:
            return residual
        if self._y is None or self._y.shape != np.shape(residual):
            self._y = np.zeros(np.shape(residual))
        elif start is not None:
            self._y[np.broadcast_to(np.asarray(start, dtype=bool), self._y.shape[:-1])] = 0.0
        self._y = self._y + self.alpha * (residual - self._y)
        return self._y.copy()


def residual_command(
    base: np.ndarray,
    action: np.ndarray,
    scale: float | np.ndarray,
    filter_: ResidualFilter | None = None,
    start: Any = None,
) -> np.ndarray:
    """Returns clip(base + r, -1, 1) with r = scale * clip(action, -1, 1) (``scale``: one
    number, or one per action dimension; through ``filter_``
    if given; ``start`` as ``ResidualFilter.__call__`` takes it): the PD command ``base``
    plus the agent's residual.  Training (ResidualPDWrapper, the native vector env) and
    deployment (PPOPolicy) share it, and it refuses an action of the wrong shape or a
    non-finite one."""
    shape = np.shape(base)
    a = real_array("action", action, shape, f"finite real numbers of shape {shape} in [-1, 1]")
    residual = scale * np.clip(a, -1.0, 1.0)
    if filter_ is not None:
        residual = filter_(residual, start)
    return np.clip(base + residual, -1.0, 1.0)


def make_residual_env(
    preset: EnvConfig | str | os.PathLike = "default",
    residual_scale: float = 1.0,
    residual_units: str = "need",
    residual_filter_tau: float = 0.0,
    **kwargs: Any,
) -> gym.Env:
    """The entry point of ``Tendon2RResidual-v2`` and later: Tendon2REnv (``preset`` and
    ``kwargs``) with PD inside (``ResidualPDWrapper``), under a TimeLimit of
    episode_duration / ctrl_dt steps.  ``gym.make`` gives what the name says: the action is a
    correction to PD's command, by default in multiples of each joint's torque need."""
    config, render = resolved(preset, kwargs)  # once, passed down
    env = Tendon2REnv(config, **render)
    wrapped = ResidualPDWrapper(env, residual_scale, residual_filter_tau, residual_units)
    return gym.wrappers.TimeLimit(wrapped, env.timing.max_episode_steps)

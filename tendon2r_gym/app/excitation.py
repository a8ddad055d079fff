"""Recordings from the simulator, and the excitation a user plays on a physical arm.

`record` runs any policy on any arm (a preset, an experiment file, with any realism,
noise and delay) and writes what a physical arm's logger would: the commands as sent, the
angles as measured (recording format: tendon2r_gym.identification.recording).

`design` chooses the excitation: PD tracking a multi-sine reference about the experiment
file's bias, each joint a sum of sines over ``MultiSine.freq_hz`` with Schroeder phases (a flat
spectrum with a low peak), its amplitude the largest (at most the file's) for which PD keeps
every command within `FORCE_MARGIN` of the force limit and the joints
`RANGE_MARGIN_DEG` inside their range on the nominal arm.  Low frequencies move the links'
mass and damping; the high ones make the cables stretch and the motors lag; every reversal of a
joint makes the cables' friction change sign.  To fit the force limit, the slow sines shrink
first (down to MIN_SLOW of the reference's amplitudes), then the fast ones with them.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from tendon2r_gym.envs.env_config import EnvConfig, resolve
from tendon2r_gym.evaluation.rollout import Policy
from tendon2r_gym.identification.recording import Recording
from tendon2r_gym.task.observation import DQ, DQ_DES, Q_DES, Q
from tendon2r_gym.validation import invalid, number

#: PD's commands stay below this fraction of the force limit on the nominal arm.
FORCE_MARGIN = 0.8
#: The joints stay this far inside their range (deg) on the nominal arm.
RANGE_MARGIN_DEG = 5.0
#: The slow sines shrink alone (to fit the force limit) down to this fraction of the
#: reference's amplitudes; below it, the fast ones shrink with them.
MIN_SLOW = 0.25


@dataclass(frozen=True)
class MultiSine:
    """q_des(t) = bias + sum_k amp_j / sqrt(K) sin(2 pi f_k t + phi_jk) over the K slow sines,
    plus dither_rad sin(2 pi f t + phi) for each fast one, per joint j; the phases are
    Schroeder's over all the sines, joint B's shifted by pi k / 2 for the k-th (so that the
    joints do not move in step)."""

    amp_rad: tuple[float, float]
    bias_rad: tuple[float, float]
    freq_hz: tuple[float, ...] = (0.4, 0.7, 1.1, 1.6, 2.3, 3.1, 4.2, 5.5)
    ramp_s: float = 0.5
    #: Small fast sines on top (Hz, and rad each): the arm follows them only partly, but PD's
    #: commands carry them, and the joints' response shows the motors' lag apart from their
    #: delay (which the slow sines alone cannot tell apart) and the cables' stretch.
    dither_hz: tuple[float, ...] = (11.0, 17.0, 26.0, 40.0, 60.0)
    dither_rad: float = 0.003
    #: The bandwidth of the PD that tracks it (pd_gains.bandwidth_hz): soft, so that an arm
    #: lagging twice as long as the nominal one still tracks it without chatter, which would
    #: saturate the commands and leave the recording's speeds unreadable.
    bandwidth_hz: float = 8.0

    def _phases(self) -> np.ndarray:
        k = np.arange(1, len(self.freq_hz) + len(self.dither_hz) + 1)
        phi = -math.pi * k * (k - 1) / len(k)
        return np.stack([phi, phi + math.pi * k / 2])  # (2, K)

    def q(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Returns (q_des, dq_des) at time t (s): the sines fade in over the first ``ramp_s``
        (a raised cosine), so that the arm starts at rest at the bias."""
        w = 2 * math.pi * np.asarray(self.freq_hz + self.dither_hz)
        arg = w * t + self._phases()
        n = len(self.freq_hz)
        scale = np.empty((2, len(w)))
        scale[:, :n] = np.asarray(self.amp_rad)[:, None] / math.sqrt(n)
        scale[:, n:] = self.dither_rad
        s, ds = (scale * np.sin(arg)).sum(1), (scale * w * np.cos(arg)).sum(1)
        if t < self.ramp_s:
            x = math.pi * t / self.ramp_s
            r, dr = 0.5 * (1 - math.cos(x)), 0.5 * math.pi / self.ramp_s * math.sin(x)
            s, ds = r * s, r * ds + dr * s
        return np.asarray(self.bias_rad) + s, ds

    def to_dict(self) -> dict[str, Any]:
        return {
            "amp_deg": [math.degrees(a) for a in self.amp_rad],
            "bias_deg": [math.degrees(b) for b in self.bias_rad],
            "freq_hz": list(self.freq_hz),
            "ramp_s": self.ramp_s,
            "dither_hz": list(self.dither_hz),
            "dither_deg": math.degrees(self.dither_rad),
            "pd_bandwidth_hz": self.bandwidth_hz,
        }


class Excitation:
    """A policy that tracks a `MultiSine` instead of the env's reference: the policy's
    observation gets the multi-sine's q_des and dq_des at each step's time (PD reads only q,
    dq, q_des and dq_des)."""

    def __init__(self, policy: Policy, signal: MultiSine, ctrl_dt: float) -> None:
        self.policy, self.signal, self.ctrl_dt = policy, signal, ctrl_dt
        self._step = 0

    def reset(self, info: dict[str, Any]) -> None:
        self._step = 0
        inner = getattr(self.policy, "reset", None)
        if callable(inner):
            inner(info)

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        obs = np.array(observation, dtype=np.float64)
        obs[Q_DES], obs[DQ_DES] = self.signal.q(self._step * self.ctrl_dt)
        self._step += 1
        return self.policy.predict(obs, state, episode_start, deterministic)


def _env(cfg: EnvConfig, duration: float, **overrides: Any):
    """The env of ``cfg`` with ``overrides`` for ``duration`` s: an experiment of its own,
    resolved as its kwargs over the default preset."""
    from tendon2r_gym.envs.env import Tendon2REnv

    return Tendon2REnv(resolve({**cfg.to_dict(), **overrides, "episode_duration": duration}))


def record(
    config: EnvConfig | str | os.PathLike,
    policy: str | Policy = "pd",
    duration: float = 10.0,
    seed: int = 0,
    signal: MultiSine | None = None,
    tensions: bool = False,
    model: str | os.PathLike | None = None,
) -> Recording:
    """Runs ``policy`` (a name of tendon2r-evaluate's policies, with ``model`` for a learned
    one, or an object with ``predict``) for ``duration`` s on the arm of ``config`` from
    ``reset(seed=seed)``, tracking ``signal`` if given (else the config's reference), and
    returns the recording: each row the measurement the policy saw (angles and speeds) and
    the command it sent (N); with ``tensions``, the true cable tensions too."""
    from tendon2r_gym.evaluation.evaluator import make_policy

    number("duration", duration, 0.0, 3600.0, lo_open=True)
    cfg = resolve(config)
    overrides = {} if signal is None else _signal_overrides(cfg, signal)
    env = _env(cfg, duration, **overrides)
    try:
        pol = make_policy(policy, env, model) if isinstance(policy, str) else policy
        if signal is not None:
            pol = Excitation(pol, signal, env.ctrl_dt)
        rows, mech = _rollout(env, pol, seed)
        return Recording(
            time=np.arange(len(rows["q"])) * env.ctrl_dt,
            command=np.clip(np.array(rows["command"]), *_command_range(mech)),
            q=np.array(rows["q"]),
            tension=np.array(rows["tension"]) if tensions else None,
            dq=np.array(rows["dq"]),
            source="simulator",
            notes=_notes(env.config, policy, seed),
        )
    finally:
        env.close()


def _signal_overrides(cfg: EnvConfig, signal: MultiSine) -> dict[str, Any]:
    """The env's settings to track ``signal``: at rest at its start, with the arm's force limit."""
    start = [math.degrees(b) for b in signal.bias_rad]
    return {
        "reference": {"amp_deg": [0.0, 0.0], "bias_deg": start},
        "mechanism": cfg.mechanism.to_dict(),  # the force limit resolved: the file's
        "pd_gains": {"bandwidth_hz": signal.bandwidth_hz, "max_delay_phase": None},
    }


def _rollout(env: Any, pol: Any, seed: int) -> tuple[dict[str, list], Any]:
    """Runs one episode of ``pol`` from ``reset(seed=seed)``; returns its rows (q, dq,
    command in N, tension) and the episode's mechanism."""
    obs, info = env.reset(seed=seed)
    reset = getattr(pol, "reset", None)
    if callable(reset):
        reset(info)
    mech = env.mechanism
    gain, offset = mech.command_map
    force = float(mech.max_tendon_force)
    rows: dict[str, list] = {"q": [], "dq": [], "command": [], "tension": []}
    tension = env.tendon_tensions()
    for _ in range(env.timing.max_episode_steps):
        action, _ = pol.predict(obs, deterministic=True)
        rows["q"].append(obs[Q])
        rows["dq"].append(obs[DQ])
        rows["tension"].append(tension)
        obs, _, terminated, _, info = env.step(np.asarray(action, dtype=np.float32))
        rows["command"].append(force * (gain * np.asarray(env.sent_command) + offset))
        tension = env.tendon_tensions()
        if terminated:
            raise RuntimeError(f"the arm diverged at t = {info['time']:.3f} s")
    return rows, mech


def _notes(cfg: EnvConfig, policy: str | Policy, seed: int) -> dict[str, str]:
    """The recording's notes: the simulated arm, policy and seed."""
    return {
        "recorded_on": "tendon2r_gym simulator",
        "policy": policy if isinstance(policy, str) else type(policy).__name__,
        "seed": str(seed),
        "mechanism": str(cfg.mechanism.to_dict()),
        "observation_noise": str(list(cfg.observation_noise)),
        "observation_delay": str(cfg.observation_delay),
    }


def _command_range(mech: Any) -> tuple[float, float]:
    force = float(mech.max_tendon_force)
    return (0.0 if mech.pull_only else -force), force


def design(
    config: EnvConfig | str | os.PathLike, duration: float = 10.0
) -> tuple[MultiSine, Recording]:
    """Returns the excitation of the arm of ``config`` (module docstring) and its rehearsal:
    the recording of PD tracking it on the nominal arm, noise-free."""
    cfg = resolve(config)
    nominal = EnvConfig.from_kwargs(
        {**cfg.to_dict(), "observation_noise": [0.0, 0.0], "observation_delay": 0.0}
    )
    mech = nominal.mechanism
    lo, hi = (math.radians(x) for x in mech.joint_range_deg)
    margin = math.radians(RANGE_MARGIN_DEG)
    bias = tuple(float(np.clip(b, lo + margin, hi - margin)) for b in cfg.reference.bias_rad)
    room = [min(b - lo, hi - b) - margin for b in bias]
    amp = [min(float(a), r) for a, r in zip(cfg.reference.amp_rad, room, strict=True)]
    force = float(mech.max_tendon_force)
    dither, start = MultiSine.dither_rad, list(amp)
    for _ in range(24):
        signal = MultiSine(amp_rad=tuple(amp), bias_rad=bias, dither_rad=dither)
        rec = record(nominal, "pd", duration, seed=0, signal=signal)
        peak = float(np.abs(rec.command).max()) / force
        over = max(float(np.max(np.abs(rec.q - np.asarray(bias)) - np.asarray(room))), 0.0)
        if peak <= FORCE_MARGIN and over == 0.0:
            return signal, rec
        shrink = min(FORCE_MARGIN / peak, 0.9) if peak > FORCE_MARGIN else 0.9
        # The slow sines give way first: the fast ones tell the lag from the delay.
        small = max((a / a0 for a, a0 in zip(amp, start, strict=True) if a0 > 0), default=0.0)
        small = small < MIN_SLOW
        amp = [a * shrink for a in amp]
        dither *= shrink if small or over > 0.0 else 1.0
    raise invalid(
        "reference",
        cfg.reference.to_dict(),
        f"an arm and force limit on which PD can track an excitation within {FORCE_MARGIN:g} "
        f"of max_tendon_force and {RANGE_MARGIN_DEG:g} deg inside joint_range_deg (the last "
        f"try peaked at {peak:.2f} of the limit)",
    )

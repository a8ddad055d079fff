"""Model-based baselines with the SB3 ``predict`` interface: a joint PD and computed torque.

Both see only the observation and the mechanism's parameters: they build their own copy of the
model to compute moment arms and inertia, and never read the environment's MjData.  Joint
torques tau become tendon forces f through J^T f = tau (J = dL/dq), solved with a damped inverse
so that f stays finite near singular configurations, then normalized by the force limit and
clipped to the action box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from tendon2r_gym.config import PD_CONFIG, load_yaml
from tendon2r_gym.mechanism import Mechanism
from tendon2r_gym.model import build_model
from tendon2r_gym.observation import DQ, DQ_DES, Q_DES, Q
from tendon2r_gym.reference import Reference
from tendon2r_gym.validation import check_keys, number


@dataclass(frozen=True)
class Gains:
    """Closed-loop gains that carry over between mechanisms and control rates.

    The joint error obeys e'' + 2 zeta w e' + w^2 e = 0 with w = 2 pi bandwidth_hz, because the
    feedback torque is scaled by the joint inertia M(q).  The bandwidth is capped at
    ``max_bandwidth_fraction`` of the control rate so that the sampled loop stays stable."""

    bandwidth_hz: float = 30.0  # closed-loop natural frequency (Hz)
    damping_ratio: float = 1.0
    max_bandwidth_fraction: float = 0.05  # of the control rate 1 / ctrl_dt
    force_damping: float = 1e-3  # damped-inverse regularization, relative to |J|

    def __post_init__(self) -> None:
        for name in ("bandwidth_hz", "damping_ratio", "max_bandwidth_fraction", "force_damping"):
            number(f"Gains.{name}", getattr(self, name), 0.0, lo_open=True)

    @classmethod
    def from_yaml(cls, path: str | Path = PD_CONFIG) -> Gains:
        data = load_yaml(path)
        check_keys(str(path), data, cls.__dataclass_fields__)
        return cls(**data)

    def natural_frequency(self, ctrl_dt: float) -> float:
        """Returns w (rad/s): the bandwidth, capped at the fraction of the control rate."""
        return 2 * math.pi * min(self.bandwidth_hz, self.max_bandwidth_fraction / ctrl_dt)


class _TendonController:
    """Shared machinery: a private model, joint torque -> normalized tendon command."""

    def __init__(self, mechanism: Mechanism, ctrl_dt: float, gains: Gains | None = None) -> None:
        self.mechanism = mechanism
        self.gains = gains or Gains.from_yaml()
        w = self.gains.natural_frequency(ctrl_dt)
        self.kp, self.kd = w * w, 2.0 * self.gains.damping_ratio * w
        self.model = build_model(mechanism)
        self.data = mujoco.MjData(self.model)
        self._M = np.zeros((self.model.nv, self.model.nv))
        self._J = self.data.ten_J.reshape(self.model.ntendon, self.model.nv)
        self._max_force = mechanism.max_tendon_force

    @classmethod
    def from_env(cls, env: Any, **kwargs: Any) -> _TendonController:
        """Builds the controller from an env's mechanism and control period (not its state)."""
        env = env.unwrapped
        return cls(env.mechanism, env.ctrl_dt, **kwargs)

    def tendon_command(self, tau: np.ndarray | tuple[float, float]) -> np.ndarray:
        """Returns the clipped normalized command whose tendon forces give joint torques tau,
        with J (at the last computed configuration) from the private model:
        f = J (J^T J + lam^2 I)^-1 tau, lam^2 = force_damping |J|_F^2 (closed form for 2x2)."""
        (j11, j12), (j21, j22) = self._J.tolist()
        t1, t2 = float(tau[0]), float(tau[1])
        lam2 = self.gains.force_damping * (j11 * j11 + j12 * j12 + j21 * j21 + j22 * j22)
        a11 = j11 * j11 + j21 * j21 + lam2  # A = J^T J + lam^2 I, symmetric
        a12 = j11 * j12 + j21 * j22
        a22 = j12 * j12 + j22 * j22 + lam2
        det = a11 * a22 - a12 * a12
        if not det > 0.0:  # J = 0 (no tendon touches a pulley) or non-finite
            return np.zeros(2, dtype=np.float32)
        x1, x2 = (a22 * t1 - a12 * t2) / det, (a11 * t2 - a12 * t1) / det
        f_max = self._max_force
        u1, u2 = (j11 * x1 + j12 * x2) / f_max, (j21 * x1 + j22 * x2) / f_max
        return np.array((min(max(u1, -1.0), 1.0), min(max(u2, -1.0), 1.0)), dtype=np.float32)

    def _torque(self, obs: np.ndarray) -> np.ndarray | tuple[float, float]:
        raise NotImplementedError

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3-style: returns (action, state) for one observation or a batch of them."""
        obs = np.asarray(observation, dtype=np.float64)
        if obs.ndim == 1:
            return self.tendon_command(self._torque(obs)), state
        return np.stack([self.tendon_command(self._torque(o)) for o in obs]), state


class PDPolicy(_TendonController):
    """Joint-space PD with reference-velocity feed-forward, scaled by the joint inertia:
    tau = M(q) (kp (q_des - q) + kd (dq_des - dq))."""

    def _torque(self, obs: np.ndarray) -> tuple[float, float]:
        d = self.data
        d.qpos[:] = obs[Q]
        mujoco.mj_fwdPosition(self.model, d)
        mujoco.mj_fullM(self.model, d, self._M)
        (q1, q2), (w1, w2) = obs[Q].tolist(), obs[DQ].tolist()
        (qd1, qd2), (wd1, wd2) = obs[Q_DES].tolist(), obs[DQ_DES].tolist()
        acc1 = self.kp * (qd1 - q1) + self.kd * (wd1 - w1)
        acc2 = self.kp * (qd2 - q2) + self.kd * (wd2 - w2)
        (m11, m12), (m21, m22) = self._M.tolist()
        return (m11 * acc1 + m12 * acc2, m21 * acc1 + m22 * acc2)


class ComputedTorquePolicy(_TendonController):
    """Inverse dynamics of the full model plus PD: the 'perfect model' reference.
    tau = ID(q, dq, ddq_des + kp e + kd de), with ddq_des = -w^2 (q_des - bias) exact for the
    sinusoidal ``reference``.  It knows the reference, so it is a bound, not a deployable
    baseline."""

    def __init__(
        self,
        mechanism: Mechanism,
        ctrl_dt: float,
        reference: Reference,
        gains: Gains | None = None,
    ) -> None:
        super().__init__(mechanism, ctrl_dt, gains)
        self.reference = reference
        self._w2 = np.asarray(reference.omega) ** 2
        self._bias = np.radians(reference.bias_deg)

    @classmethod
    def from_env(cls, env: Any, **kwargs: Any) -> ComputedTorquePolicy:
        env = env.unwrapped
        return cls(env.mechanism, env.ctrl_dt, env.reference, **kwargs)

    def _torque(self, obs: np.ndarray) -> np.ndarray:
        d = self.data
        d.qpos[:] = obs[Q]
        d.qvel[:] = obs[DQ]
        ddq_des = -self._w2 * (obs[Q_DES] - self._bias)
        d.qacc[:] = ddq_des + self.kp * (obs[Q_DES] - obs[Q]) + self.kd * (obs[DQ_DES] - obs[DQ])
        mujoco.mj_inverse(self.model, d)
        return d.qfrc_inverse.copy()

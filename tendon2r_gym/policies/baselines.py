"""Model-based baselines with the SB3 ``predict`` interface: a joint PD and computed torque.

Both see only the observation and the mechanism's parameters: they build their own copy of the
model to compute moment arms and inertia, and never read the environment's MjData.

Tension distribution.  Joint torques tau become tendon tensions t (positive pulling) through
-J^T t = tau (J = dL/dq, one row per tendon), for any number of tendons:
- the minimum-norm tensions t0 = -J (J^T J + lam^2 I)^-1 tau, with a small damping lam^2 so that
  t stays finite near singular configurations;
- pull-only tendons: t = t0 + alpha n, where n is a strictly positive null vector of J^T
  (it exists when the moment arms positively span the torque plane, as the ``n_plus_1``
  routing's do) and alpha is the smallest value that keeps every tension >= the mechanism's
  pretension.  Adding alpha n changes no joint torque.
The tensions are then normalized by the force limit (push-pull: -t / F; pull-only: 2 t / F - 1)
and clipped to the action box, so the force limit clips them.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from tendon2r_gym.envs.env_config import ACTION_MODES
from tendon2r_gym.envs.timing import low_pass_alpha
from tendon2r_gym.simulation.actuation import TorqueToTension
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.task import observation
from tendon2r_gym.task.gains import Gains, gains_of, loop_delay
from tendon2r_gym.task.observation import DQ, DQ_DES, Q_DES, Q
from tendon2r_gym.task.reference import Reference
from tendon2r_gym.validation import invalid


def _env_options(config: Any) -> dict[str, Any]:
    """Returns what a baseline takes from an env config besides the mechanism: its gains
    (``pd_gains``), the action mode, the env's action filter (alpha, where the last command is
    observed) and the age of its measurements (for gains scheduled on the loop delay)."""
    where = observation.last_action_slice(config.preview_steps, config.n_actions)
    return {
        "gains": config.pd_gains,
        "action_mode": config.action_mode,
        "action_filter": (low_pass_alpha(config.action_filter_tau, config.ctrl_dt), where),
        "observation_delay": config.observation_delay,
    }


class _TendonController:
    """Shared machinery: a private model, joint torque -> normalized tendon command, for one
    observation or a batch of them (numpy over the batch; the kinematics of a batch come from
    one ``mujoco.batch`` call, of a single observation from an MjData)."""

    def __init__(
        self,
        mechanism: Mechanism,
        ctrl_dt: float,
        gains: Gains | None = None,
        action_mode: str = "tension",
        action_filter: tuple[float, slice] | None = None,
        observation_delay: float = 0.0,
    ) -> None:
        if action_mode not in ACTION_MODES:
            raise invalid("action_mode", action_mode, f"one of {ACTION_MODES}")
        self.mechanism = mechanism
        self.action_mode = action_mode
        self.ctrl_dt, self.observation_delay = ctrl_dt, observation_delay
        self.gains = gains_of(gains)
        #: The arms, measurement ages and own gains (None: these) that kp, kd were set for.
        self._gains_for: tuple[list[Mechanism], list[float], list[Gains] | None] = (
            [mechanism],
            [observation_delay],
            None,
        )
        self._set_gains(*self._gains_for)
        self.actuation = TorqueToTension(mechanism, self.gains.force_damping)
        self.kinematics = self.actuation.kinematics
        self.tendon_command = self.actuation.command
        # (alpha, slice of the last command in the observation) of the env's action filter
        self._filter = action_filter if action_filter and action_filter[0] != 1.0 else None

    @classmethod
    def from_env(cls, env: Any, **kwargs: Any) -> _TendonController:
        """Builds the controller from an env's mechanism and control period (not its state)."""
        env = env.unwrapped
        return cls(env.mechanism, env.ctrl_dt, **{**_env_options(env.config), **kwargs})

    @property
    def model(self) -> mujoco.MjModel:
        """Returns the private nominal model (of the first arm it follows)."""
        return self.actuation.model

    @property
    def data(self) -> mujoco.MjData:
        """Returns the private MjData of `model`."""
        return self.actuation.data

    def _set_gains(
        self,
        mechanisms: list[Mechanism],
        observation_delays: list[float],
        gains: list[Gains] | None = None,
    ) -> None:
        """Sets kp, kd: numbers, or one row per arm where the arms have their own gains
        (``gains``: drawn per episode) or gains scheduled on the loop delay (each arm held to
        the phase over its own delay: tendon2r_gym.task.gains)."""
        if gains is None and self.gains.max_delay_phase is None:
            w, zeta = self.gains.natural_frequency(self.ctrl_dt), self.gains.damping_ratio
        else:
            per_arm = gains or [self.gains] * len(mechanisms)
            arms = zip(per_arm, mechanisms, observation_delays, strict=True)
            w = np.array(
                [
                    g.natural_frequency(self.ctrl_dt, loop_delay(m, d, self.ctrl_dt))
                    for g, m, d in arms
                ],
                dtype=float,
            )[:, None]
            zeta = np.array([g.damping_ratio for g in per_arm])[:, None]
        self.kp, self.kd = w * w, 2.0 * zeta * w

    def follow(
        self,
        mechanisms: list[Mechanism],
        observation_delays: list[float] | None = None,
        gains: list[Gains] | None = None,
    ) -> None:
        """Controls the arms ``mechanisms`` (one, or one per row of the observations; random
        arms): each one's nominal model and force limit, and with gains scheduled on the loop
        delay each one's gains (``observation_delays``: each arm's age of its measurements;
        None: the env's); ``gains``: each arm's own gains (drawn per episode), None: this
        controller's."""
        self.actuation.follow(mechanisms)
        self.mechanism = mechanisms[0]
        if self.gains.max_delay_phase is not None or gains is not None:
            delays = observation_delays or [self.observation_delay] * len(mechanisms)
            arms = (list(mechanisms), list(delays), None if gains is None else list(gains))
            if arms != self._gains_for:  # the SB3 vector env calls follow at every step
                self._gains_for = arms
                self._set_gains(*arms)

    def reset(self, info: dict[str, Any]) -> None:
        """Follows the episode's arm, if the env draws arms (``mechanism``,
        ``observation_delay`` and, if drawn, ``pd_gains`` in the reset info of the Tendon2R env, or
        of its vector env: one arm per row)."""
        if "mechanism" in info:
            delay = info.get("observation_delay", self.observation_delay)
            delays = np.atleast_1d(delay).astype(float).tolist()
            gains = _per_arm(info, "pd_gains", Gains.from_dict) if "pd_gains" in info else None
            self.follow(_per_arm(info, "mechanism", Mechanism.from_dict), delays, gains)

    def _torque(self, obs: np.ndarray, M: np.ndarray) -> np.ndarray:
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
        batch = np.atleast_2d(obs)
        J, M = self.kinematics(batch[:, Q])
        tau = self._torque(batch, M)
        if self.action_mode == "joint_torque":  # the env distributes the torques
            action = np.clip(tau / self.actuation.max_torque, -1.0, 1.0).astype(np.float32)
        else:
            action = self.tendon_command(J, tau)
        if self._filter is not None:
            # Send the target that the env's filter turns into this command exactly:
            # last + alpha (target - last) = command.
            alpha, where = self._filter
            last = batch[:, where]
            target = last + (action.astype(np.float64) - last) / alpha
            action = np.clip(target, -1.0, 1.0).astype(np.float32)
        return (action[0] if obs.ndim == 1 else action), state


class PDPolicy(_TendonController):
    """Joint-space PD with reference-velocity feed-forward, scaled by the joint inertia:
    tau = M(q) (kp (q_des - q) + kd (dq_des - dq))."""

    def _torque(self, obs: np.ndarray, M: np.ndarray) -> np.ndarray:
        acc = self.kp * (obs[:, Q_DES] - obs[:, Q]) + self.kd * (obs[:, DQ_DES] - obs[:, DQ])
        return np.einsum("nij,nj->ni", M, acc)


class ComputedTorquePolicy(_TendonController):
    """Inverse dynamics of the full model plus PD: the 'perfect model' reference.
    tau = ID(q, dq, ddq_des + kp e + kd de), with ddq_des = -w^2 (q_des - bias) exact for the
    sinusoidal reference.  It knows the reference, so it is a bound, not a deployable baseline:
    `reset` reads each episode's reference from the env's reset info (one env, or every
    arm of a vector env), which ``rollout`` and ``rollouts`` pass it."""

    def __init__(
        self,
        mechanism: Mechanism,
        ctrl_dt: float,
        reference: Reference,
        gains: Gains | None = None,
        action_mode: str = "tension",
        action_filter: tuple[float, slice] | None = None,
        observation_delay: float = 0.0,
    ) -> None:
        super().__init__(mechanism, ctrl_dt, gains, action_mode, action_filter, observation_delay)
        self._set_references([reference])

    @classmethod
    def from_env(cls, env: Any, **kwargs: Any) -> ComputedTorquePolicy:
        env = env.unwrapped
        options = {**_env_options(env.config), **kwargs}
        return cls(env.mechanism, env.ctrl_dt, env.reference, **options)

    def _set_references(self, refs: list[Reference]) -> None:
        self.references = refs
        self._w2 = np.array([r.omega_array**2 for r in refs])  # (1 or N, 2)
        self._bias = np.array([r.bias_rad for r in refs])

    def reset(self, info: dict[str, Any]) -> None:
        """Follows the episode's reference and arm: ``info`` is a reset info of the Tendon2R env
        (its ``reference`` fields) or of its vector env (one reference per arm)."""
        super().reset(info)
        self._set_references(_per_arm(info, "reference", Reference.from_dict))

    def _torque(self, obs: np.ndarray, M: np.ndarray) -> np.ndarray:
        """Joint torques from mj_inverse, one configuration at a time (CT is an evaluation
        bound, not a training-time controller)."""
        if len(self._w2) not in (1, len(obs)):
            raise ValueError(
                f"observations of {len(obs)} arms is invalid; allowed: 1 or the {len(self._w2)} "
                "arms of the last reset (call reset(info) with the vector env's reset info)"
            )
        ddq_des = -self._w2 * (obs[:, Q_DES] - self._bias)
        qacc = (
            ddq_des
            + self.kp * (obs[:, Q_DES] - obs[:, Q])
            + self.kd * (obs[:, DQ_DES] - obs[:, DQ])
        )
        out = np.zeros((len(obs), 2))
        data: dict[int, mujoco.MjData] = {}
        for i, (o, a) in enumerate(zip(obs, qacc, strict=True)):
            model = self.actuation.model_of(i)  # the arm's nominal model
            d = data.get(id(model))
            if d is None:
                d = data[id(model)] = (
                    self.actuation.data if model is self.actuation.model else mujoco.MjData(model)
                )
            d.qpos[:], d.qvel[:], d.qacc[:] = o[Q], o[DQ], a
            mujoco.mj_inverse(model, d)
            out[i] = d.qfrc_inverse
        return out


def _per_arm(info: dict[str, Any], key: str, read: Any) -> list[Any]:
    """Returns ``read(fields)`` of a reset info's nested dict ``key``: one item for a single
    env's info, one per arm for a vector env's (Gymnasium batches each field, with a
    ``_key`` mask)."""
    fields = info[key]
    if f"_{key}" not in info:  # one env
        return [read(fields)]
    names = [k for k in fields if not k.startswith("_")]  # a vector env's masks start so
    plain = lambda v: list(v) if isinstance(v, np.ndarray) else v  # noqa: E731
    n = len(info[f"_{key}"])
    return [read({k: plain(fields[k][i]) for k in names}) for i in range(n)]

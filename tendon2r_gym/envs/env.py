"""Tendon2REnv, the env of every Tendon2R id: track sinusoidal joint references with tendon
motors."""

from __future__ import annotations

import os
from typing import Any

import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.envs.mujoco.mujoco_env import DEFAULT_SIZE, MujocoEnv
from gymnasium.utils import EzPickle

from tendon2r_gym.envs.env_config import EnvConfig, resolve
from tendon2r_gym.envs.formulas import (
    DIVERGENCE_WARNING_IDS,
    Formulas,
    arm_params,
    reference_params,
)
from tendon2r_gym.envs.timing import Timing
from tendon2r_gym.llvm import load_triton
from tendon2r_gym.ops import SCALAR
from tendon2r_gym.simulation.actuation import MomentArms, TorqueToTension, cond_of_rows
from tendon2r_gym.simulation.model import CAMERA, build_model, tendon_name
from tendon2r_gym.simulation.realism import CommandDelay, Drive, Sensors
from tendon2r_gym.task import observation as obs_layout
from tendon2r_gym.task.reference import Reference
from tendon2r_gym.task.rewards import rewards_table
from tendon2r_gym.validation import integer, invalid

#: The env card's sections, in Gymnasium's order: the ``##`` headings of Tendon2REnv's docstring.
CARD_SECTIONS = (
    "Description",
    "Action Space",
    "Observation Space",
    "Rewards",
    "Starting State",
    "Episode End",
    "Arguments",
    "Version History",
)

#: Tendon2REnv's own arguments besides the experiment (its preset or config): rendering.
RENDER_ARGS = ("render_mode", "width", "height", "camera_name")


class Tendon2REnv(MujocoEnv, EzPickle):
    """Tendon-driven 2R planar arm: each joint tracks q_des(t) = amp sin(w t + phase) + bias.

    ## Description
    A 2R arm moves in the x-z plane without gravity.  Spatial tendons (two by default, or any
    routing of 2 or more) run from the wall over pulleys on both joints to the effector, or to
    link c; one motor pulls (and, unless ``pull_only``, pushes) on each.  The links ``a``,
    ``c``, ``b``, the pulleys' diameters ``R1``, ``R2`` and the routings are on
    [mechanism](mechanism.md).  The mechanism, the reference and any other argument below come
    from a preset or an experiment file (``preset``), with keyword overrides.

    ## Action Space
    ``Box(-1, 1, (n_actions,), float32)``, by ``action_mode``:

    - ``"tension"`` (default): one normalized command per tendon motor.  Push-pull: +-1 is
      +-``max_tendon_force`` N along the tendon.  Pull-only (``mechanism.pull_only``): [-1, 1]
      maps affinely to a tension in [0, ``max_tendon_force``] N (-1 slack, +1 full pull).
    - ``"joint_torque"``: one normalized torque per joint, times the torque each joint alone
      reaches before a tendon saturates (``TorqueToTension.max_torque``), turned into tensions
      as PD's are ([from joint torques to tensions](mechanism.md#from-joint-torques-to-tensions)),
      clipped at the force limit.

    With ``action_filter_tau`` > 0 the env applies the command c = c_last + alpha (action -
    c_last), alpha = 1 - exp(-ctrl_dt / action_filter_tau), a first-order low-pass that a
    motor can follow; c_last is observed (``last_action``), so PD and CT send the action that
    the filter turns into their own command.  Out-of-range actions are clipped to [-1, 1]; a
    wrong shape or a non-finite action raises ValueError.

    ## Observation Space
    ``Box(-inf, inf, (n,), float64)``: the entries below, in order (named slices in
    ``tendon2r_gym.task.observation``, P = ``preview_steps``); ``observe`` adds the optional ones.

    {obs_table}

    ``observation_noise`` and ``observation_delay`` make the observation a measurement, noisy
    and late by whole control steps; the reward and ``info`` stay on the true state
    ([real tendons](real_tendons.md#tendons-that-stretch-slip-and-lag)).

    ## Rewards
    ``reward = sum(reward_scales[k] * term_k)`` over the terms below (tendon2r_gym.task.rewards.TERMS;
    each is in ``info`` as ``reward_<k>``, already scaled):

    {rewards}

    ## Starting State
    On the reference: q = q_des(0), dq = dq_des(0), plus uniform noise in
    [-reset_noise_scale, reset_noise_scale] (rad and rad/s), clipped to the joint range.

    ## Episode End
    - Truncation: after ``episode_duration / ctrl_dt`` steps, by the ``TimeLimit`` wrapper that
      ``gym.make`` applies (``env.spec.max_episode_steps``).
    - Termination: if the physics diverges (a MuJoCo instability warning, a joint more than
      0.5 rad past its limit, a joint faster than 1e4 rad/s, or a non-finite state).  That step
      returns the last good observation (never larger than the observations before it) and
      the reward of that state minus ``reward_scales["divergence"]``, so it is bounded: in
      [-1 - divergence - ctrl - action_rate terms, 0] for the "multiscale" and "log" forms.
      ``info["diverged"]`` is True.  Construction refuses parameters the integrator cannot integrate
      (tendon2r_gym.simulation.stability).

    ## Arguments
    ``gym.make(id, **kwargs)`` takes the arguments below; one left out keeps the id's default
    (its version's, over the preset's values).

    Args:
        preset: A bundled preset name or an experiment-file path (.yaml), or an EnvConfig.
        render_mode: "human", "rgb_array" or "depth_array" (None: no rendering).
        width: The render width (px).
        height: The render height (px).
        camera_name: The camera that frames the whole arm ("side"), or None for a free one.

    Real tendons, motors and the model's errors (``mechanism`` fields, off by default) are on
    [real tendons](real_tendons.md), arms drawn at every reset (``mechanism_ranges``) on
    [one policy for every arm](generalist.md), and the ``"auto"`` force limit on
    [mechanism](mechanism.md#the-force-limit).

    ## Version History
    Each id's contract is frozen (tendon2r_gym.envs.contract); CHANGELOG.md says what each changed.

    - v2: the default for new work: v1 with ``action_filter_tau`` 0.002, the command a motor
      follows, so that ordinary PPO settings learn it: SB3's and CleanRL's defaults do; a
      discount of 0.9 (rl_zoo3's Reacher entry) does not, and learns the residual id
      ([training](training.md#your-own-ppo-settings)).  ``Tendon2RResidual-v2`` is residual:
      PD inside, the action a correction of each joint's torque in multiples of its need
      (tendon2r_gym.policies.residual.make_residual_env); every client tried learns it.
    - v1: ``reset_noise_scale`` 0.02 and ``observe=["error_rate"]``, what the shipped plain-PPO
      entries learn on.  ``Tendon2RResidual-v1`` is the same env under a second id.
    - v0: the first id, frozen at its last contract (``reset_noise_scale`` 0.001, no error
      rate in the observation).
    """  # noqa: E501

    metadata = {"render_modes": ["human", "rgb_array", "depth_array"]}

    def __init__(
        self,
        preset: EnvConfig | str | os.PathLike = "default",
        render_mode: str | None = None,
        width: int = DEFAULT_SIZE,
        height: int = DEFAULT_SIZE,
        camera_name: str | None = CAMERA,
        **kwargs: Any,
    ) -> None:
        EzPickle.__init__(self, preset, render_mode, width, height, camera_name, **kwargs)
        # Every argument is checked before the model is built.
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise invalid(
                "render_mode", render_mode, f"None or one of {self.metadata['render_modes']}"
            )
        integer("width", width, 1, 16384)
        integer("height", height, 1, 16384)
        if camera_name not in (None, CAMERA):
            raise invalid("camera_name", camera_name, f"None (free camera) or {CAMERA!r}")
        if render_mode is not None:  # before a GL context can bring Mesa's LLVM in
            load_triton()  # tendon2r_gym.llvm: triton loaded after it segfaults
        self.config = cfg = resolve(preset, **kwargs)
        self.timing = Timing.of(cfg)
        self.mechanism = cfg.mechanism  # the current episode's arm (self.arm: its config)
        self.data: mujoco.MjData | None = None
        self.nominal_reference = self.reference = cfg.reference
        self.reference_ranges = cfg.reference_ranges
        self.ctrl_dt = cfg.ctrl_dt
        self.reward_scales = cfg.reward_scales
        self.preview_steps, self.preview_dt = cfg.preview_steps, cfg.preview_dt

        # render_fps depends on ctrl_dt, so it is set per instance before MujocoEnv checks it.
        self.metadata = {**type(self).metadata, "render_fps": int(round(1.0 / cfg.ctrl_dt))}
        # MujocoEnv insists on an existing model_path and loads it in _initialize_simulation.
        # We build the model in memory with MjSpec (parameters stay exact, no file round trip)
        # and override _initialize_simulation; this module's path only passes the check.
        n_obs = cfg.observation.size
        MujocoEnv.__init__(
            self,
            __file__,
            self.timing.n_substeps,
            observation_space=spaces.Box(-np.inf, np.inf, (n_obs,), np.float64),
            render_mode=render_mode,
            width=width,
            height=height,
            camera_name=camera_name,
        )
        self._resolve_ids()

    # -- set-up ----------------------------------------------------------------------------------
    def _initialize_simulation(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        model = build_model(self.mechanism)  # the current arm's
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, self.width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, self.height)
        return model, mujoco.MjData(model)

    def _set_action_space(self) -> spaces.Box:
        """One normalized command per tendon ("tension") or per joint ("joint_torque")."""
        self.action_space = spaces.Box(-1.0, 1.0, (self.config.n_actions,), np.float32)
        return self.action_space

    def _resolve_ids(self) -> None:
        """Caches views and constants used on every step (no name look-ups in the hot path)."""
        self.formulas = Formulas(self.config)
        cfg, timing = self.config, self.timing
        self._delay: CommandDelay | None = None
        if timing.delay_capacity:
            self._delay = CommandDelay(timing.delay_capacity, 1, cfg.mechanism.n_tendons)
        self._sensing: Sensors | None = None
        if timing.sensed:  # the observation is a measurement; reward and info are true
            self._sensing = Sensors(timing.observation_delay_capacity, 1, timing.noisy)
        self._last_truth: np.ndarray | None = None
        self._n = self.config.n_actions
        self._filtered = timing.action_filter_alpha != 1.0
        self._err = obs_layout.ERROR
        self._fixed_reference: Reference | None = None
        self._bind_arm(self.config)
        self._set_reference(self.reference)
        self._last_obs: np.ndarray | None = None

    def _bind_arm(self, arm: EnvConfig) -> None:
        """Makes ``arm`` (an EnvConfig of one arm: the env's, or a draw of mechanism_ranges)
        the simulated arm: its model (built with MjSpec unless it is the current one), and the
        views and helpers that depend on it."""
        self.arm, self.mechanism = arm, arm.mechanism
        if self.data is None or arm is not self.config:
            self.model, self.data = self._initialize_simulation()
            if self.render_mode is not None:
                from gymnasium.envs.mujoco.mujoco_rendering import MujocoRenderer

                self.mujoco_renderer.close()
                self.mujoco_renderer = MujocoRenderer(
                    self.model, self.data, None, self.width, self.height, 1000, None,
                    self.camera_name,
                )  # fmt: skip
        d = self.data
        # Views into MjData stay valid for its lifetime; fetching them once saves a binding call
        # per access on every step.  The arm's joints are the first two (spools follow).
        self._qpos, self._qvel, self._ctrl = d.qpos[:2], d.qvel[:2], d.ctrl
        self.drive = Drive(self.model, self.mechanism)
        if self._delay is not None or self._sensing is not None:
            timing = self.timing if arm is self.config else Timing.of(arm)
            if self._delay is not None:
                self._delay.set_arm(0, timing.delay_steps, self.drive.ctrl)
            if self._sensing is not None:
                self._sensing.set_arm(0, timing.observation_delay_steps, arm.observation_noise)
        self._last_action = self.formulas.rest_command(arm)
        #: In ``action_mode="joint_torque"``, the map from normalized joint torques to tendon
        #: commands at the current q (its ``max_torque`` scales the action); None in tension
        #: mode.  Public so that tests can check the torque an action asks for.
        self.torque_map: TorqueToTension | None = None
        max_torque = None
        if self.config.action_mode == "joint_torque":
            self.torque_map = TorqueToTension(self.mechanism)
            max_torque = self.torque_map.max_torque
        self._rate_inv = [
            float(x)
            for x in self.formulas.rate_need_inverse(arm.needs.torque_rate_need, max_torque)
        ]
        # Named sensor reads: each tendon's motor force (N, positive lengthens), contiguous.
        first = self.model.sensor(f"force_{tendon_name(0)}").adr[0]
        n = self.mechanism.n_tendons
        self._motor_force = d.sensordata[first : first + n]
        #: Elastic cables: a view of their tensions, the force of each on its spool.
        self._cable_force = (
            self.drive.tension_view(d.qfrc_passive) if self.mechanism.elastic else None
        )
        self._warning_numbers = d.warning.number  # a live view: one count per mjtWarning
        self._warning_count = 0
        self._arms = MomentArms(self.model, d)
        self._arm = arm_params(arm, self.config)

    def _set_reference(self, ref: Reference) -> None:
        """Sets the episode's reference, cached as Python floats for the formulas' scalar math."""
        self.reference = ref
        self._ref = reference_params(ref)

    # -- named quantities ------------------------------------------------------------------------
    def tendon_tensions(self) -> np.ndarray:
        """Returns each tendon's tension (N, positive when it pulls) in the last step: minus the
        motor force along the tendon that the model's force sensors read, or for elastic cables
        the force of their stretch on their spools
        (tendon2r_gym.simulation.realism.Drive.tension_view)."""
        if self._cable_force is not None:
            return self._cable_force.copy()
        return -self._motor_force

    def force_need(self) -> float:
        """Returns the peak tendon force (N) that inverse dynamics of the reference needs (of
        the worst corner of ``reference_ranges``, if set); ``max_tendon_force: auto`` is
        FORCE_HEADROOM times this."""
        return self.arm.needs.force_need

    # -- gymnasium API -----------------------------------------------------------------------------
    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        last = self._last_action
        a = self.formulas.checked_action(action)
        if self._filtered:
            a = self.formulas.command(a, last)
        self._last_action = a
        if self.torque_map is None:
            u = a
        else:  # joint_torque: PD's tension distribution at the current q
            u = self.torque_map.joint_torque_command(self._qpos[None], np.array([a]))[0]
        self.sent_command = u  # the motors' normalized command as sent (recordings hold it)
        if self._delay is not None:  # the motors get the command of delay_steps ago
            u = self._delay.one(u)
        self._ctrl[:] = u
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        state = self._state()
        diverged = self._check_divergence(state)
        state = self._state() if diverged else state  # left finite by _check_divergence
        seen = state
        if self._sensing is not None:  # what the controller gets this step
            seen = self._measured = self._sensing.one(state, self.np_random)
        # A diverged step reports the last good state: nothing enormous reaches a learner.
        entries = None if diverged else self._obs_entries(seen)
        obs = self._last_obs.copy() if entries is None else np.array(entries, dtype=np.float64)
        truth, true_entries = obs, entries
        if self._sensing is not None:  # reward and info on the true state
            if entries is None:
                truth = self._last_truth.copy()
            else:
                true_entries = self._true_entries(entries, state)
                truth = np.array(true_entries, dtype=np.float64)
            self._last_truth = truth
        reward, terms = self._get_rew(
            truth.tolist() if true_entries is None else true_entries, a, last, diverged
        )
        info = self._get_info(truth, terms, diverged)
        self._last_obs = obs
        if self.render_mode == "human":
            self.render()
        return obs, reward, diverged, False, info

    def _warnings(self) -> int:
        """Returns how many of DIVERGENCE_WARNINGS MuJoCo has raised since MjData was made."""
        counts = self._warning_numbers.tolist()
        return sum([counts[w] for w in DIVERGENCE_WARNING_IDS])

    def _check_divergence(self, state: list[float]) -> bool:
        """Returns whether the last step, which left the true ``state`` (`_state`),
        diverged (a new MuJoCo instability warning, or a state outside the valid domain:
        Formulas.out_of_domain); if so, leaves a finite state."""
        n_warn = self._warnings()
        q1, q2, w1, w2 = state
        diverged = n_warn > self._warning_count or self.formulas.out_of_domain(
            SCALAR, q1, q2, w1, w2
        )
        self._warning_count = n_warn
        if diverged:  # MuJoCo already reset the state on a bad QACC; make sure it is finite.
            qpos = self.data.qpos  # the arm's and the spools'
            qpos[:] = np.nan_to_num(qpos, nan=0.0, posinf=0.0, neginf=0.0)
            self.data.qvel[:] = 0.0
        return diverged

    def _state(self) -> list[float]:
        """Returns the true (q_A, q_B, dq_A, dq_B)."""
        return self._qpos.tolist() + self._qvel.tolist()

    def _obs_entries(self, state: list[float]) -> list[float]:
        """Returns the observation's entries (tendon2r_gym.envs.formulas.Formulas.observation
        on this arm) of the joint state (q_A, q_B, dq_A, dq_B)."""
        q1, q2, w1, w2 = state
        return self.formulas.observation(
            SCALAR, q1, q2, w1, w2, self.data.time, self._ref, self._arm, self._last_action
        )

    def current_observation(self, measured: bool = True) -> np.ndarray:
        """Returns the observation now: with sensors (``observation_noise``,
        ``observation_delay``), of what they measured at the last step or reset; without, of
        the joint state (after ``set_state``, of the state set); with ``measured=False``, of the
        true state.  Tests read it."""
        state = self._measured if measured and self._sensing is not None else self._state()
        return np.array(self._obs_entries(state), dtype=np.float64)

    def with_true_state(self, observation: np.ndarray) -> np.ndarray:
        """Returns ``observation``, one the sensors gave at this step, with every entry the
        joint state sets rewritten from the true state: the observation that reward and info
        read (`step` does this rewrite; tests compare it with
        ``current_observation(measured=False)``)."""
        entries = np.asarray(observation, dtype=np.float64).tolist()
        return np.array(self._true_entries(entries, self._state()), dtype=np.float64)

    def _true_entries(self, parts: list[float], state: list[float]) -> list[float]:
        """Returns the observation's entries of the true ``state`` (`_state`): ``parts``
        (the entries of the sensors' observation of this step) with the entries the joint
        state sets rewritten (Formulas.state_entries, and Formulas.error_rate_entries if
        observed)."""
        qd1, qd2 = parts[obs_layout.Q_DES]
        joints, rest = self.formulas.state_entries(SCALAR, *state, qd1, qd2, self._arm)
        head, tail = obs_layout.STATE
        out = joints + parts[head.stop : tail.start] + rest + parts[tail.stop :]
        if self.formulas.observes_rate:
            where = obs_layout.error_rate_slice(self.preview_steps, self._n)
            out[where] = self.formulas.error_rate_entries(
                SCALAR, *state[2:], *parts[obs_layout.DQ_DES], self._arm
            )
        return out

    def _get_rew(
        self, entries: list[float], action: list[float], last: list[float], diverged: bool
    ) -> tuple[float, dict[str, float]]:
        """Returns (reward, scaled terms) from the observation's entries of the true state; the
        reward is the sum of the terms."""
        e1, e2 = entries[self._err]
        de1 = de2 = 0.0
        if self.formulas.weighs_rate:  # the error's rate, read only where it is weighed
            (w1, w2), (v1, v2) = entries[obs_layout.DQ], entries[obs_layout.DQ_DES]
            de1, de2 = v1 - w1, v2 - w2
        terms = self.formulas.reward_terms(
            SCALAR, e1, e2, action, last, self._rate_inv, diverged, de1, de2
        )
        return self.formulas.scale(terms)

    def _get_info(self, obs: np.ndarray, terms: dict[str, float], diverged: bool) -> dict[str, Any]:
        return self.formulas.step_info(
            obs,
            terms,
            self.tendon_tensions(),
            cond_of_rows(SCALAR, self._arms.rows()),
            self.data.time,
            diverged,
        )

    def reset_model(self) -> np.ndarray:
        rng = self.np_random
        arm, ref = self.formulas.episode(rng, self._fixed_reference)
        if arm is not self.arm:  # a drawn arm: its own model
            self._bind_arm(arm)
        self._set_reference(ref)
        q, qdot = self.formulas.initial_state(rng, self.reference)
        if self.drive.has_state:  # spools and lags at rest
            self.drive.settle(self.data, q, qdot)
        else:
            self.set_state(q, qdot)
        self.sent_command = self._last_action = self.formulas.rest_command(self.arm)
        if self._delay is not None:
            self._delay.reset(slice(None))
        if self._sensing is not None:
            self._sensing.reset(0, self._state(), self.np_random)
            self._measured = self._sensing.read()[0].tolist()
            self._last_truth = self.current_observation(measured=False)
        self._warning_count = self._warnings()
        self._last_obs = self.current_observation()
        return self._last_obs

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Resets the episode.  ``options={"reference": {...}}`` fixes this episode's reference
        (Reference fields over the nominal one; it must fit the workspace), e.g. for held-out
        evaluation; ``reference_ranges`` then draws nothing."""
        self._fixed_reference = self.formulas.reference_option(options)
        return super().reset(seed=seed, options=options)

    def _get_reset_info(self) -> dict[str, Any]:
        return self.formulas.reset_info(self.reference, float(self.data.time), self.arm)


Tendon2REnv.__doc__ = Tendon2REnv.__doc__.format(
    obs_table=obs_layout.table().replace("\n", "\n    "),
    rewards=rewards_table().replace("\n", "\n    "),
)

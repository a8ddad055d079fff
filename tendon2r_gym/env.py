"""Tendon2R-v0: track sinusoidal joint references with two tendon motors."""

from __future__ import annotations

import math
import os
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.envs.mujoco.mujoco_env import DEFAULT_SIZE, MujocoEnv
from gymnasium.utils import EzPickle

from tendon2r_gym import observation as obs_layout
from tendon2r_gym.actuation import MomentArms, cond
from tendon2r_gym.config import merge_reference
from tendon2r_gym.env_config import EnvConfig
from tendon2r_gym.model import CAMERA, build_model, tendon_name
from tendon2r_gym.reference import Reference
from tendon2r_gym.validation import integer, invalid

_DIVERGENCE_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
)


DIVERGED_PAST_LIMIT = 0.5  # rad past a joint limit that counts as diverged
#: Degrees from radians as e / RAD_PER_DEG, in the single and the vector env alike (numpy's
#: np.degrees rounds differently from this in the last bit).
RAD_PER_DEG = math.pi / 180.0
#: A joint speed that counts as diverged (rad/s): bang-bang commands at 10x the default force
#: limit reach about 500 rad/s.
DIVERGED_SPEED = 1e4


def _log_error(e: float) -> float:
    return math.copysign(math.log1p(abs(e) / obs_layout.ERROR_LOG_SCALE), e)


def make_env(preset: str | os.PathLike = "default", **kwargs: Any) -> gym.Env:
    """The registered entry point: Tendon2REnv under a TimeLimit of episode_duration / ctrl_dt
    steps, so ``gym.make(..., episode_duration=X, ctrl_dt=Y)`` gives X / Y steps (the TimeLimit
    is the one source of truth for truncation, and ``env.spec.max_episode_steps`` reports it)."""
    env = Tendon2REnv(preset, **kwargs)
    return gym.wrappers.TimeLimit(env, env.config.max_episode_steps)


class Tendon2REnv(MujocoEnv, EzPickle):
    """Tendon-driven 2R planar arm: each joint tracks q_des(t) = amp sin(w t + phase) + bias.

    ## Description
    A fixed base link ``a`` (wall to joint A), link ``c`` (joint A to joint B) and link ``b``
    (joint B to the effector) move in the x-z plane without gravity.  Spatial tendons (two by
    default, or any routing of 2 or more) run from the wall over pulleys on both joints
    (diameters ``R1``, ``R2``) to the effector, or to link c; one motor pulls (and, unless
    ``pull_only``, pushes) on each.  The mechanism, the reference and any other argument below
    come from a preset or an experiment file (``preset``), with keyword overrides.

    ## Action Space
    ``Box(-1, 1, (n_tendons,), float32)``: the normalized command of each motor.  Push-pull
    (default): an action of +-1 is +-``max_tendon_force`` N along the tendon.  Pull-only
    (``mechanism.pull_only``): an action in [-1, 1] maps affinely to a tension in
    [0, ``max_tendon_force``] N (-1 slack, +1 full pull).  Out-of-range actions are clipped
    to [-1, 1]; a wrong shape or a non-finite action raises ValueError.  ``info["tendon_tension"]``
    is each tendon's pulling force in N (positive when it pulls) for every routing.

    ## Observation Space
    ``Box(-inf, inf, (16 + 2 * preview_steps,), float64)``, named slices in
    ``tendon2r_gym.observation``:

    {obs_table}

    ## Rewards
    ``reward = sum(reward_scales[k] * term_k)`` over the terms below (each is in ``info`` as
    ``reward_<k>``, already scaled):

    - ``tracking``: with ``tracking_form="quadratic"``, ``-sum(e^2)`` with the errors e in
      **degrees**; with ``"log"``, ``1 - sum(log(1 + (e / sigma)^2)) / (2 log(1 + (180 /
      sigma)^2))`` with sigma = ``tracking_sigma_deg``: in [0, 1] for |e| <= 180 deg, 1 on
      the reference, and quadratic near it.
    - ``ctrl``: ``-sum(action^2)``, on the clipped action (for pull-only, -1 is slack);
    - ``divergence``: -1 on the step where the physics diverges, else 0.

    ## Starting State
    On the reference: q = q_des(0), dq = dq_des(0), plus uniform noise in
    [-reset_noise_scale, reset_noise_scale] (rad and rad/s), clipped to the joint range.

    ## Episode End
    - Truncation: after ``episode_duration / ctrl_dt`` steps, by the ``TimeLimit`` wrapper that
      ``gym.make`` applies (``env.spec.max_episode_steps``).
    - Termination: if the physics diverges (a MuJoCo instability warning, a joint more than
      0.5 rad past its limit, a joint faster than 1e4 rad/s, or a non-finite state).  That step
      returns the last good observation (never larger than the observations before it) and the
      reward of that state minus ``reward_scales["divergence"]``, so it is bounded: in [-1 -
      divergence, 1] for the "log" form.  ``info["diverged"]`` is True.  Construction refuses
      parameters the integrator cannot integrate (tendon2r_gym.stability).

    ## Arguments

    | argument | default | description |
    |----------|---------|-------------|
    | `preset` | `"default"` | a bundled preset name or an experiment-file path (.yaml) |
    | `mechanism` | `None` | dict of Mechanism fields overriding the preset, or a Mechanism |
    | `reference` | `None` | dict of Reference fields overriding the preset, or a Reference |
    | `reference_ranges` | `None` | dict of ReferenceRanges: draw a new reference every reset |
    | `fit_to_workspace` | `False` | scale the amplitudes down (with a warning) instead of raising |
    | `ctrl_dt` | `0.001` | control period (s), an integer multiple of the mechanism's sim_dt |
    | `episode_duration` | `2.0` | seconds per episode |
    | `reward_scales` | `{{'tracking': 1, 'ctrl': 0.001, 'divergence': 10}}` | term weights |
    | `tracking_form` | `"log"` | "log" (bounded) or "quadratic" tracking reward |
    | `tracking_sigma_deg` | `1.0` | error scale of the "log" tracking reward (deg) |
    | `reset_noise_scale` | `0.001` | initial-state noise (rad, rad/s) |
    | `preview_steps` | `3` | number of future reference samples observed |
    | `preview_dt` | `0.01` | spacing of the future reference samples (s) |
    | `render_mode` | `None` | "human", "rgb_array" or "depth_array" |
    | `width` | `480` | render width (px) |
    | `height` | `480` | render height (px) |
    | `camera_name` | `"side"` | camera that frames the whole arm |

    ``mechanism.max_tendon_force`` defaults to ``"auto"``: FORCE_HEADROOM (2) times the peak
    tendon force that inverse dynamics of the reference needs (for ``reference_ranges``, of its
    worst corner), see ``force_need()``.  A fixed limit below that need warns.

    ## Version History
    - v0 (unreleased, so the id stays v0): initial version, then, before any release:
      - defaults that make the env learnable from scratch, measured by
        tendon2r_gym.studies.learnability (results/learnability.md): the bounded "log" tracking
        reward (was quadratic in deg^2), reward scales ctrl 0.001 and divergence 10 (were
        0.01 and 1000), and the log-scaled tracking error ``error_log`` in the observation;
        the observation reordered into named slices (tendon2r_gym.observation);
      - every argument may come from an experiment file; truncation by a TimeLimit of
        episode_duration / ctrl_dt steps; ``max_tendon_force: auto``;
      - any number of tendons, ``pull_only`` motors, ``info["tendon_tension"]`` (was
        ``tendon_force``, the motor force with the opposite sign);
      - a diverged step returns the last good observation; construction refuses unstable
        physics and late-failing arguments.
    """

    metadata = {"render_modes": ["human", "rgb_array", "depth_array"]}

    def __init__(
        self,
        preset: str | os.PathLike = "default",
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
        self.config = cfg = EnvConfig.make(preset, **kwargs)
        self.mechanism = cfg.mechanism
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
        n_obs = obs_layout.size(cfg.preview_steps)
        MujocoEnv.__init__(
            self,
            __file__,
            cfg.n_substeps,
            observation_space=spaces.Box(-np.inf, np.inf, (n_obs,), np.float64),
            render_mode=render_mode,
            width=width,
            height=height,
            camera_name=camera_name,
        )
        self._resolve_ids()

    # -- set-up ----------------------------------------------------------------------------------
    def _initialize_simulation(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        model = build_model(self.mechanism)
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, self.width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, self.height)
        return model, mujoco.MjData(model)

    def _resolve_ids(self) -> None:
        """Caches views and constants used on every step (no name look-ups in the hot path)."""
        m, d = self.mechanism, self.data
        self._a, self._b, self._c = m.a, m.b, m.c
        self._q_lo, self._q_hi = m.joint_range_rad
        # Soft joint limits let a joint overshoot a little; this far past them (NaN included)
        # the simulation has left its valid domain.
        self._q_lo_div, self._q_hi_div = (
            self._q_lo - DIVERGED_PAST_LIMIT,
            self._q_hi + DIVERGED_PAST_LIMIT,
        )
        # Views into MjData stay valid for its lifetime; fetching them once saves a binding call
        # per access on every step.
        self._qpos, self._qvel, self._ctrl = d.qpos, d.qvel, d.ctrl
        self._n = self.mechanism.n_tendons
        # Named sensor reads: each tendon's motor force (N, positive lengthens), contiguous.
        first = self.model.sensor(f"force_{tendon_name(0)}").adr[0]
        self._motor_force = d.sensordata[first : first + self._n]
        self._warnings = [d.warning[w] for w in _DIVERGENCE_WARNINGS]
        self._arms = MomentArms(self.model, d)
        self._offsets = [k * self.preview_dt for k in range(1, self.preview_steps + 1)]
        cfg = self.config
        self._w_track, self._w_ctrl, self._w_div = (
            cfg.reward_scales[k] for k in ("tracking", "ctrl", "divergence")
        )
        self._log_form = cfg.tracking_form == "log"
        self._err = obs_layout.ERROR
        self._info_keys = {k: f"reward_{k}" for k in cfg.reward_scales}
        self._sigma = cfg.tracking_sigma_deg
        self._log_norm = 2.0 * math.log1p((180.0 / self._sigma) ** 2)
        self._set_reference_cache(self.reference)
        self._warning_count = 0
        self._last_obs: np.ndarray | None = None

    def _set_reference_cache(self, ref: Reference) -> None:
        """Caches the reference as Python floats, joint A then B (scalar math is faster than
        numpy on two-element arrays)."""
        self.reference = ref
        self._amp1, self._amp2 = ref._amp.tolist()
        self._bias1, self._bias2 = ref._bias.tolist()
        self._omega1, self._omega2 = ref._omega.tolist()
        self._phase1, self._phase2 = ref._phase.tolist()

    # -- named quantities ------------------------------------------------------------------------
    def tendon_tensions(self) -> np.ndarray:
        """Returns each tendon's tension (N, positive when it pulls) in the last step: minus the
        motor force along the tendon that the model's force sensors read."""
        return -self._motor_force

    def force_need(self) -> float:
        """Returns the peak tendon force (N) that inverse dynamics of the reference needs (of
        the worst corner of ``reference_ranges``, if set); ``max_tendon_force: auto`` is
        FORCE_HEADROOM times this."""
        return self.config.force_need

    # -- gymnasium API -----------------------------------------------------------------------------
    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        n = self._n
        if type(action) is not np.ndarray or action.shape != (n,):
            action = np.asarray(action, dtype=np.float64)
            if action.shape != (n,):
                raise ValueError(f"action has shape {action.shape}; allowed: ({n},) in [-1, 1]")
        a = action.tolist()
        if not all(math.isfinite(x) for x in a):
            raise ValueError(f"action = {a} is not finite; allowed: {n} values in [-1, 1]")
        a = [min(max(x, -1.0), 1.0) for x in a]
        self._ctrl[:] = a
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        diverged = self._check_divergence()
        # A diverged step reports the last good state: nothing enormous reaches a learner.
        obs = self._last_obs.copy() if diverged else self._get_obs()
        reward, terms = self._get_rew(obs, a, diverged)
        info = self._get_info(obs, terms, diverged)
        self._last_obs = obs
        if self.render_mode == "human":
            self.render()
        return obs, reward, diverged, False, info

    def _check_divergence(self) -> bool:
        """Returns whether the last step diverged (a new MuJoCo instability warning, a
        non-finite state, or a joint far past its limit); if so, leaves a finite state."""
        n_warn = sum(w.number for w in self._warnings)
        (q1, q2), (w1, w2) = self._qpos.tolist(), self._qvel.tolist()
        lo, hi = self._q_lo_div, self._q_hi_div
        diverged = (
            n_warn > self._warning_count
            or not (lo < q1 < hi and lo < q2 < hi)  # also catches NaN
            or not (abs(w1) < DIVERGED_SPEED and abs(w2) < DIVERGED_SPEED)  # NaN too
        )
        self._warning_count = n_warn
        if diverged:  # MuJoCo already reset the state on a bad QACC; make sure it is finite.
            self._qpos[:] = np.nan_to_num(self._qpos, nan=0.0, posinf=0.0, neginf=0.0)
            self._qvel[:] = 0.0
        return diverged

    def _get_obs(self) -> np.ndarray:
        """Writes the observation in the order of ``tendon2r_gym.observation.FIXED``."""
        (q1, q2), (w1, w2) = self._qpos.tolist(), self._qvel.tolist()
        a, b, c = self._a, self._b, self._c
        c1, s1 = math.cos(q1), math.sin(q1)
        c12, s12 = math.cos(q1 + q2), math.sin(q1 + q2)
        w12 = w1 + w2
        t = self.data.time
        amp1, amp2, om1, om2 = self._amp1, self._amp2, self._omega1, self._omega2
        ph1, ph2, bias1, bias2 = self._phase1, self._phase2, self._bias1, self._bias2
        arg1, arg2 = om1 * t + ph1, om2 * t + ph2
        qd1, qd2 = amp1 * math.sin(arg1) + bias1, amp2 * math.sin(arg2) + bias2
        obs = [
            q1, q2, w1, w2,
            qd1, qd2, amp1 * om1 * math.cos(arg1), amp2 * om2 * math.cos(arg2),
            qd1 - q1, qd2 - q2,
            _log_error(qd1 - q1), _log_error(qd2 - q2),
            a + c * c1 + b * c12, c * s1 + b * s12,  # effector x, z
            -c * s1 * w1 - b * s12 * w12, c * c1 * w1 + b * c12 * w12,  # effector velocity
        ]  # fmt: skip
        for dt in self._offsets:
            obs.append(amp1 * math.sin(arg1 + om1 * dt) + bias1)
            obs.append(amp2 * math.sin(arg2 + om2 * dt) + bias2)
        return np.array(obs, dtype=np.float64)

    def _get_rew(
        self, obs: np.ndarray, action: list[float], diverged: bool
    ) -> tuple[float, dict[str, float]]:
        """Returns (reward, scaled terms); the reward is the sum of the terms."""
        e1, e2 = obs[self._err].tolist()
        e1, e2 = e1 / RAD_PER_DEG, e2 / RAD_PER_DEG
        if self._log_form:
            u1, u2 = e1 / self._sigma, e2 / self._sigma
            tracking = 1.0 - (math.log1p(u1 * u1) + math.log1p(u2 * u2)) / self._log_norm
        else:
            tracking = -(e1 * e1 + e2 * e2)
        effort = 0.0  # sum of squares in order, as numpy's sum over a few entries
        for x in action:
            effort += x * x
        terms = {
            "tracking": self._w_track * tracking,
            "ctrl": -self._w_ctrl * effort,
            "divergence": -self._w_div if diverged else 0.0,
        }
        return sum(terms.values()), terms

    def _get_info(self, obs: np.ndarray, terms: dict[str, float], diverged: bool) -> dict[str, Any]:
        return {
            **{self._info_keys[k]: v for k, v in terms.items()},
            "q": obs[obs_layout.Q],
            "q_des": obs[obs_layout.Q_DES],
            "tracking_error_deg": obs[obs_layout.ERROR] / RAD_PER_DEG,
            "tendon_tension": self.tendon_tensions(),
            "moment_arm_cond": cond(self._arms.dense()),
            "effector_pos": obs[obs_layout.EFFECTOR_POS],
            "time": self.data.time,
            "diverged": diverged,
        }

    def reset_model(self) -> np.ndarray:
        if self.reference_ranges is not None:
            self._set_reference_cache(self.reference_ranges.sample(self.np_random, self.mechanism))
        noise = self.config.reset_noise_scale
        q = self.reference.q(0.0) + self.np_random.uniform(-noise, noise, 2)
        qdot = self.reference.qdot(0.0) + self.np_random.uniform(-noise, noise, 2)
        self.set_state(np.clip(q, self._q_lo, self._q_hi), qdot)
        self._warning_count = sum(w.number for w in self._warnings)
        self._last_obs = self._get_obs()
        return self._last_obs

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Resets the episode.  ``options={"reference": {...}}`` fixes this episode's reference
        (Reference fields over the nominal one; it must fit the workspace), e.g. for held-out
        evaluation."""
        if options and "reference" in options:
            ref = Reference.from_dict(
                merge_reference(self.nominal_reference.to_dict(), options["reference"])
            )
            if problems := ref.workspace_violations(self.mechanism):
                raise ValueError(f"options['reference'] leaves the workspace: {problems}")
            saved, self.reference_ranges = self.reference_ranges, None
            self._set_reference_cache(ref)
            try:
                return super().reset(seed=seed, options=options)
            finally:
                self.reference_ranges = saved
        if self.reference_ranges is None:
            self._set_reference_cache(self.nominal_reference)
        return super().reset(seed=seed, options=options)

    def _get_reset_info(self) -> dict[str, Any]:
        return {
            "reference": self.reference.to_dict(),
            "time": float(self.data.time),
            "force_need_N": self.force_need(),
            "max_tendon_force_N": self.mechanism.max_tendon_force,
        }


Tendon2REnv.__doc__ = Tendon2REnv.__doc__.format(
    obs_table=obs_layout.table().replace("\n", "\n    ")
)

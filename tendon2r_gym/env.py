"""Tendon2R-v0: track sinusoidal joint references with two tendon motors."""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.envs.mujoco.mujoco_env import DEFAULT_SIZE, MujocoEnv
from gymnasium.utils import EzPickle

from tendon2r_gym.actuation import cond2, moment_arms_from_data
from tendon2r_gym.config import load_preset
from tendon2r_gym.mechanism import Mechanism
from tendon2r_gym.model import CAMERA, build_model
from tendon2r_gym.reference import Reference, ReferenceRanges

_DIVERGENCE_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
)


DIVERGED_PAST_LIMIT = 0.5  # rad past a joint limit that counts as diverged


def resolve_mechanism(preset_mech: dict[str, Any], override: Mechanism | dict | None) -> Mechanism:
    """Returns the preset's mechanism with ``override`` applied (a dict overrides only the fields
    it names; a Mechanism replaces it)."""
    if isinstance(override, Mechanism):
        return override
    return Mechanism.from_dict({**preset_mech, **(override or {})})


def resolve_reference(preset_ref: dict[str, Any], override: Reference | dict | None) -> Reference:
    """Returns the preset's reference with ``override`` applied (a dict overrides the fields it
    names; naming one of freq_hz / omega_rad_s drops the other)."""
    if isinstance(override, Reference):
        return override
    override = dict(override or {})
    base = dict(preset_ref)
    if {"freq_hz", "omega_rad_s"} & set(override):
        base.pop("freq_hz", None)
        base.pop("omega_rad_s", None)
    return Reference.from_dict({**base, **override})


class Tendon2REnv(MujocoEnv, EzPickle):
    """Tendon-driven 2R planar arm: each joint tracks q_des(t) = amp sin(w t + phase) + bias.

    ## Description
    A fixed base link ``a`` (wall to joint A), link ``c`` (joint A to joint B) and link ``b``
    (joint B to the effector) move in the x-z plane without gravity.  Two spatial tendons run
    from the wall over pulleys on both joints (diameters ``R1``, ``R2``) to the effector; two
    motors push or pull on them.  The mechanism and the reference come from a preset
    (``configs/env/*.yaml``) with optional overrides.

    ## Action Space
    ``Box(-1, 1, (2,), float32)``: the normalized commands of ``motor1`` and ``motor2``; an
    action of +-1 is +-``max_tendon_force`` N on the tendon.  Out-of-range actions are clipped
    to [-1, 1]; a non-finite action raises ValueError.

    ## Observation Space
    ``Box(-inf, inf, (14 + 2 * preview_steps,), float64)``:

    | index | observation | unit |
    |-------|-------------|------|
    | 0-1 | joint angles q_A, q_B | rad |
    | 2-3 | joint velocities | rad/s |
    | 4-5 | effector position x, z | m |
    | 6-7 | effector velocity | m/s |
    | 8-9 | reference q_des(t) | rad |
    | 10-11 | reference velocity dq_des/dt(t) | rad/s |
    | 12 to 11 + 2P | q_des(t + k * preview_dt), k = 1..P (P = preview_steps), A then B | rad |
    | last 2 | tracking error q_des - q | rad |

    ## Rewards
    ``reward = reward_tracking + reward_ctrl + reward_divergence`` (all in ``info``):

    - ``reward_tracking = -tracking_weight * sum((q_des - q)^2)``, errors in **degrees**;
    - ``reward_ctrl = -ctrl_cost_weight * sum(action^2)``, on the clipped action;
    - ``reward_divergence = -divergence_penalty`` on the step where the physics diverges, else 0.

    ## Starting State
    On the reference: q = q_des(0), dq = dq_des(0), plus uniform noise in
    [-reset_noise_scale, reset_noise_scale] (rad and rad/s), clipped to the joint range.

    ## Episode End
    - Truncation: at ``episode_duration`` seconds (the registered ``max_episode_steps`` is the
      default duration divided by the default ``ctrl_dt``).
    - Termination: if the physics diverges (non-finite state, a MuJoCo instability warning, or a
      joint more than 0.5 rad past its limit).
      The reward stays finite, the observation has no NaN, and ``info["diverged"]`` is True.

    ## Arguments

    | argument | default | description |
    |----------|---------|-------------|
    | `preset` | `"default"` | name in configs/env/ or a YAML path |
    | `mechanism` | `None` | dict of Mechanism fields overriding the preset, or a Mechanism |
    | `reference` | `None` | dict of Reference fields overriding the preset, or a Reference |
    | `reference_ranges` | `None` | dict of ReferenceRanges: draw a new reference every reset |
    | `fit_to_workspace` | `False` | scale the amplitudes down (with a warning) instead of raising |
    | `ctrl_dt` | `0.001` | control period (s), an integer multiple of the mechanism's sim_dt |
    | `episode_duration` | `2.0` | seconds per episode |
    | `tracking_weight` | `1.0` | weight of the squared tracking error (deg^2) |
    | `ctrl_cost_weight` | `0.01` | weight of the squared action |
    | `divergence_penalty` | `1000.0` | reward subtracted when the physics diverges |
    | `reset_noise_scale` | `0.001` | initial-state noise (rad, rad/s) |
    | `preview_steps` | `3` | number of future reference samples observed |
    | `preview_dt` | `0.01` | spacing of the future reference samples (s) |
    | `render_mode` | `None` | "human", "rgb_array" or "depth_array" |
    | `width` | `480` | render width (px) |
    | `height` | `480` | render height (px) |
    | `camera_name` | `"side"` | camera that frames the whole arm |

    ## Version History
    - v0: initial version.
    """

    metadata = {"render_modes": ["human", "rgb_array", "depth_array"]}

    def __init__(
        self,
        preset: str = "default",
        mechanism: Mechanism | dict[str, Any] | None = None,
        reference: Reference | dict[str, Any] | None = None,
        reference_ranges: ReferenceRanges | dict[str, Any] | None = None,
        fit_to_workspace: bool = False,
        ctrl_dt: float = 0.001,
        episode_duration: float = 2.0,
        tracking_weight: float = 1.0,
        ctrl_cost_weight: float = 0.01,
        divergence_penalty: float = 1000.0,
        reset_noise_scale: float = 0.001,
        preview_steps: int = 3,
        preview_dt: float = 0.01,
        render_mode: str | None = None,
        width: int = DEFAULT_SIZE,
        height: int = DEFAULT_SIZE,
        camera_name: str | None = CAMERA,
        **kwargs: Any,
    ) -> None:
        EzPickle.__init__(
            self, preset, mechanism, reference, reference_ranges, fit_to_workspace, ctrl_dt,
            episode_duration, tracking_weight, ctrl_cost_weight, divergence_penalty,
            reset_noise_scale, preview_steps, preview_dt, render_mode, width, height,
            camera_name, **kwargs,
        )  # fmt: skip
        sections = load_preset(preset)
        self.mechanism = resolve_mechanism(sections["mechanism"], mechanism)
        ref = resolve_reference(sections["reference"], reference)
        if fit_to_workspace:
            ref = ref.fit_to_workspace(self.mechanism)
        elif problems := ref.workspace_violations(self.mechanism):
            raise ValueError(
                f"reference {ref.to_dict()} leaves the workspace: {'; '.join(problems)} "
                "(pass fit_to_workspace=True to scale the amplitudes down)"
            )
        self.nominal_reference = self.reference = ref
        ranges = reference_ranges or sections["reference_ranges"] or None
        if ranges is not None and not isinstance(ranges, ReferenceRanges):
            ranges = ReferenceRanges.from_dict(ranges)
        self.reference_ranges: ReferenceRanges | None = ranges

        _check_positive("ctrl_dt", ctrl_dt, "> 0 s, a multiple of sim_dt")
        _check_positive("episode_duration", episode_duration, "> 0 s")
        _check_positive("preview_dt", preview_dt, "> 0 s")
        for name, value in (
            ("tracking_weight", tracking_weight),
            ("ctrl_cost_weight", ctrl_cost_weight),
            ("divergence_penalty", divergence_penalty),
            ("reset_noise_scale", reset_noise_scale),
        ):
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"{name} = {value!r} is invalid; allowed: a finite number >= 0")
        if not isinstance(preview_steps, int) or not 0 <= preview_steps <= 100:
            raise ValueError(f"preview_steps = {preview_steps!r} is invalid; allowed: 0..100")
        sim_dt = self.mechanism.sim_dt
        n_substeps = round(ctrl_dt / sim_dt)
        if n_substeps < 1 or abs(n_substeps * sim_dt - ctrl_dt) > 1e-9 * ctrl_dt:
            raise ValueError(
                f"ctrl_dt = {ctrl_dt!r} s is invalid; allowed: a positive integer multiple of "
                f"sim_dt = {sim_dt} s"
            )
        self.ctrl_dt = ctrl_dt
        self.episode_duration = episode_duration
        self.max_steps = round(episode_duration / ctrl_dt)
        self.tracking_weight = tracking_weight
        self.ctrl_cost_weight = ctrl_cost_weight
        self.divergence_penalty = divergence_penalty
        self.reset_noise_scale = reset_noise_scale
        self.preview_steps = preview_steps
        self.preview_dt = preview_dt

        n_obs = 14 + 2 * preview_steps
        # render_fps depends on ctrl_dt, so it is set per instance before MujocoEnv checks it.
        self.metadata = {**type(self).metadata, "render_fps": int(round(1.0 / ctrl_dt))}
        # MujocoEnv insists on an existing model_path and loads it in _initialize_simulation.
        # We build the model in memory with MjSpec (parameters stay exact, no file round trip)
        # and override _initialize_simulation; this module's path only passes the check.
        MujocoEnv.__init__(
            self,
            __file__,
            n_substeps,
            observation_space=spaces.Box(-np.inf, np.inf, (n_obs,), np.float64),
            render_mode=render_mode,
            width=width,
            height=height,
            camera_name=camera_name,
            **kwargs,
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
        self._actuator_force = d.actuator_force
        self._gear = self.model.actuator_gear[:, 0].copy()
        self._warnings = [d.warning[w] for w in _DIVERGENCE_WARNINGS]
        self._ten_J = moment_arms_from_data(self.model, d)
        self._offsets = [k * self.preview_dt for k in range(1, self.preview_steps + 1)]
        self._set_reference_cache(self.reference)
        self._step_count = 0
        self._warning_count = 0

    def _set_reference_cache(self, ref: Reference) -> None:
        """Caches the reference as Python floats, joint A then B (scalar math is faster than
        numpy on two-element arrays)."""
        self.reference = ref
        self._amp1, self._amp2 = ref._amp.tolist()
        self._bias1, self._bias2 = ref._bias.tolist()
        self._omega1, self._omega2 = ref._omega.tolist()
        self._phase1, self._phase2 = ref._phase.tolist()

    # -- named quantities ------------------------------------------------------------------------
    def joint_angles(self) -> np.ndarray:
        """Returns the joint angles (rad)."""
        return self.data.qpos.copy()

    def tendon_forces(self) -> np.ndarray:
        """Returns the tendon motor forces (N): gear times MuJoCo's actuator force, which is in
        actuator units (the clipped command) for a motor with a gear."""
        return self._actuator_force * self._gear

    def moment_arms(self) -> np.ndarray:
        """Returns the tendon moment arms dL/dq (m) at the last computed state."""
        return self._ten_J.copy()

    # -- gymnasium API -----------------------------------------------------------------------------
    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if type(action) is not np.ndarray or action.shape != (2,):
            action = np.asarray(action, dtype=np.float64)
            if action.shape != (2,):
                raise ValueError(f"action has shape {action.shape}; allowed: (2,) in [-1, 1]")
        a1, a2 = action.tolist()
        if not (math.isfinite(a1) and math.isfinite(a2)):
            raise ValueError(f"action = {[a1, a2]} is not finite; allowed: 2 values in [-1, 1]")
        a1, a2 = min(max(a1, -1.0), 1.0), min(max(a2, -1.0), 1.0)
        ctrl = self._ctrl
        ctrl[0], ctrl[1] = a1, a2
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        self._step_count += 1
        diverged = self._check_divergence()
        obs = self._get_obs()
        reward, terms = self._get_rew(obs, (a1, a2), diverged)
        info = self._get_info(obs, terms, diverged)
        truncated = self._step_count >= self.max_steps
        if self.render_mode == "human":
            self.render()
        return obs, reward, diverged, truncated, info

    def _check_divergence(self) -> bool:
        """Returns whether the last step diverged (a new MuJoCo instability warning, a
        non-finite state, or a joint far past its limit); if so, leaves a finite state."""
        n_warn = sum(w.number for w in self._warnings)
        (q1, q2), (w1, w2) = self._qpos.tolist(), self._qvel.tolist()
        lo, hi = self._q_lo_div, self._q_hi_div
        diverged = (
            n_warn > self._warning_count
            or not (lo < q1 < hi and lo < q2 < hi)  # also catches NaN
            or not (math.isfinite(w1) and math.isfinite(w2))
        )
        self._warning_count = n_warn
        if diverged:  # MuJoCo already reset the state on a bad QACC; make sure it is finite.
            self._qpos[:] = np.nan_to_num(self._qpos, nan=0.0, posinf=0.0, neginf=0.0)
            self._qvel[:] = 0.0
        return diverged

    def _get_obs(self) -> np.ndarray:
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
            a + c * c1 + b * c12, c * s1 + b * s12,  # effector x, z
            -c * s1 * w1 - b * s12 * w12, c * c1 * w1 + b * c12 * w12,  # effector velocity
            qd1, qd2,
            amp1 * om1 * math.cos(arg1), amp2 * om2 * math.cos(arg2),
        ]  # fmt: skip
        for dt in self._offsets:
            obs.append(amp1 * math.sin(arg1 + om1 * dt) + bias1)
            obs.append(amp2 * math.sin(arg2 + om2 * dt) + bias2)
        obs.append(qd1 - q1)
        obs.append(qd2 - q2)
        return np.array(obs, dtype=np.float64)

    def _get_rew(
        self, obs: np.ndarray, action: tuple[float, float], diverged: bool
    ) -> tuple[float, dict[str, float]]:
        e1, e2 = math.degrees(obs[-2]), math.degrees(obs[-1])
        a1, a2 = action
        terms = {
            "tracking": -self.tracking_weight * (e1 * e1 + e2 * e2),
            "ctrl": -self.ctrl_cost_weight * (a1 * a1 + a2 * a2),
            "divergence": -self.divergence_penalty if diverged else 0.0,
        }
        return terms["tracking"] + terms["ctrl"] + terms["divergence"], terms

    def _get_info(self, obs: np.ndarray, terms: dict[str, float], diverged: bool) -> dict[str, Any]:
        return {
            "reward_tracking": terms["tracking"],
            "reward_ctrl": terms["ctrl"],
            "reward_divergence": terms["divergence"],
            "q": obs[0:2],
            "q_des": obs[8:10],
            "tracking_error_deg": np.degrees(obs[-2:]),
            "tendon_force": self.tendon_forces(),
            "moment_arm_cond": cond2(self._ten_J),
            "effector_pos": obs[4:6],
            "time": self.data.time,
            "diverged": diverged,
        }

    def reset_model(self) -> np.ndarray:
        if self.reference_ranges is not None:
            self._set_reference_cache(self.reference_ranges.sample(self.np_random, self.mechanism))
        noise = self.reset_noise_scale
        q = self.reference.q(0.0) + self.np_random.uniform(-noise, noise, 2)
        qdot = self.reference.qdot(0.0) + self.np_random.uniform(-noise, noise, 2)
        self.set_state(np.clip(q, self._q_lo, self._q_hi), qdot)
        self._step_count = 0
        self._warning_count = sum(w.number for w in self._warnings)
        return self._get_obs()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Resets the episode.  ``options={"reference": {...}}`` fixes this episode's reference
        (Reference fields; it must fit the workspace), e.g. for held-out evaluation."""
        if options and "reference" in options:
            ref = resolve_reference(self.nominal_reference.to_dict(), options["reference"])
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
        return {"reference": self.reference.to_dict(), "time": float(self.data.time)}


def _check_positive(name: str, value: float, allowed: str) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{name} = {value!r} is invalid; allowed: {allowed}")
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} = {value!r} is invalid; allowed: {allowed}")

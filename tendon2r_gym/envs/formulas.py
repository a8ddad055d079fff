"""The formulas of the Tendon2R env, written once for both envs: observation, reward terms,
divergence, reset and info of the task that tendon2r_gym.task defines.

dm_control's Physics/Task split: the envs own the physics (one MjData in Tendon2REnv, N
simulations of ``mujoco.batch`` in Tendon2RVectorEnv) and call `Formulas` for every formula
of the task.  Each formula is plain arithmetic on per-joint quantities, run on Python floats
with `tendon2r_gym.ops.SCALAR` (the single env) or on arrays over N arms with
`BATCH` (the vector env), so the two envs agree bit for bit.

Reward terms come back unscaled, keyed like ``reward_scales``, and are scaled once
(mujoco_playground's ``scales``): a new term is one entry of `TERMS` and one line of
`Formulas.reward_terms`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from tendon2r_gym.envs.timing import low_pass_alpha
from tendon2r_gym.ops import Ops
from tendon2r_gym.presets import merge_reference
from tendon2r_gym.task import observation as L
from tendon2r_gym.task.arms import draw_episode_arm
from tendon2r_gym.task.gains import gains_of
from tendon2r_gym.task.reference import Reference
from tendon2r_gym.task.rewards import MULTISCALE, TERMS
from tendon2r_gym.validation import invalid, real_array

if TYPE_CHECKING:
    from tendon2r_gym.envs.env_config import EnvConfig

#: Degrees from radians as e / RAD_PER_DEG, in every env (numpy's np.degrees rounds
#: differently from this in the last bit).
RAD_PER_DEG = math.pi / 180.0
DIVERGED_PAST_LIMIT = 0.5  # rad past a joint limit that counts as diverged
#: A joint speed that counts as diverged (rad/s): bang-bang commands at 10x the default force
#: limit reach about 500 rad/s.
DIVERGED_SPEED = 1e4

#: MuJoCo's warnings that mean the integration failed (DIVERGENCE_WARNING_IDS: their indices
#: into MjData.warning, which both envs count).
DIVERGENCE_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
)
DIVERGENCE_WARNING_IDS = [int(w) for w in DIVERGENCE_WARNINGS]
#: Keys of ``info`` after every step, in both envs (the vector env adds Gymnasium's masks).
STEP_INFO_KEYS = (
    *(f"reward_{k}" for k in TERMS),
    "q",
    "q_des",
    "tracking_error_deg",
    "tendon_tension",
    "moment_arm_cond",
    "effector_pos",
    "time",
    "diverged",
)
#: Keys of ``info`` after every reset; with ``mechanism_ranges`` also ``mechanism``, the
#: episode's arm (Mechanism fields), which PD, CT and the residual wrapper follow, and its
#: sensors' ``observation_noise`` and ``observation_delay``; where mechanism_ranges draws PD's
#: gains, also the episode's ``pd_gains`` (Gains fields).
#: ``torque_need_Nm`` is each joint's peak torque need (EnvConfig.needs.torque_need).
RESET_INFO_KEYS = ("reference", "time", "force_need_N", "torque_need_Nm", "max_tendon_force_N")


def reference_params(ref: Reference) -> tuple[float, ...]:
    """Returns (amp_A, amp_B, omega_A, omega_B, phase_A, phase_B, bias_A, bias_B) in rad and
    rad/s: the per-joint numbers `Formulas.observation` reads."""
    return (
        *ref.amp_rad.tolist(),
        *ref.omega_array.tolist(),
        *ref.phase_rad.tolist(),
        *ref.bias_rad.tolist(),
    )


#: Where `arm_params` holds the link lengths (a, b, c) and EnvConfig.needs.rate_to_action
#: (row by row), which the observation reads but does not hold; its observed entries follow.
LINKS, RATE_TO_ACTION = slice(0, 3), slice(3, 7)
N_ARM_PARAMS = RATE_TO_ACTION.stop


def arm_params(arm: EnvConfig, observed: EnvConfig) -> tuple[float, ...]:
    """Returns the per-arm numbers `Formulas.observation` reads: the link lengths (a, b, c)
    of the episode's arm config ``arm`` and its EnvConfig.needs.rate_to_action (row by row), then
    the observation's last per-arm entries if the env's config ``observed`` holds them:
    ``force_limit_log``, ln of the arm's force limit (N), and the arm's features over its
    ranges."""
    mech = arm.mechanism
    (r00, r01), (r10, r11) = arm.needs.rate_to_action
    force = [math.log(mech.max_tendon_force)] if "force_limit" in observed.observe else []
    features = observed.feature_ranges.features(arm) if "arm" in observed.observe else []
    return (mech.a, mech.b, mech.c, r00, r01, r10, r11, *force, *features)


def to_action(arm: Sequence[Any], v1: Any, v2: Any) -> tuple[Any, Any]:
    """Returns EnvConfig.needs.rate_to_action (`arm_params`' ``RATE_TO_ACTION``) times the
    joints' speed changes (v1, v2) in one control step: the normalized joint torques that give
    them."""
    r00, r01, r10, r11 = arm[RATE_TO_ACTION]
    return r00 * v1 + r01 * v2, r10 * v1 + r11 * v2


def signed_log(ops: Ops, x: Any, scale: float) -> Any:
    """Returns sign(x) log(1 + |x| / scale): linear below ``scale``, logarithmic above (the
    observation's ``error_log`` and ``error_rate_log``)."""
    return ops.copysign(ops.log1p(abs(x) / scale), x)


class Formulas:
    """Every formula of the task, for one EnvConfig (see the module docstring): the envs'
    ``formulas``."""

    def __init__(self, config: EnvConfig) -> None:
        self.config = config
        self.n_actions = config.n_actions
        # The optional entries, read on every step.
        self.observes_rate = "error_rate" in config.observe
        self.observes_feedforward = "feedforward" in config.observe
        mech = config.mechanism
        self.q_lo, self.q_hi = mech.joint_range_rad
        # Soft joint limits let a joint overshoot a little; this far past them (NaN included)
        # the simulation has left its valid domain.
        self.div_lo, self.div_hi = self.q_lo - DIVERGED_PAST_LIMIT, self.q_hi + DIVERGED_PAST_LIMIT
        self.scales = dict(config.reward_scales)
        self.offsets = [k * config.preview_dt for k in range(1, config.preview_steps + 1)]
        self.sigma = config.tracking_sigma_deg
        self.log_norm = 2.0 * math.log1p((180.0 / self.sigma) ** 2)
        # "multiscale": (1 / sigma_k, 2 K log(1 + (180 / sigma_k)^2)) per scale
        n = len(MULTISCALE)
        self.kernels = [
            (1.0 / (k * self.sigma), 2.0 * n * math.log1p((180.0 / (k * self.sigma)) ** 2))
            for k in MULTISCALE
        ]
        self.form = config.tracking_form
        self.horizon = config.tracking_horizon
        #: Whether tracking_rate is weighed: only then does the reward read the error's rate.
        self.weighs_rate = self.scales["tracking_rate"] != 0.0
        self.alpha = low_pass_alpha(config.action_filter_tau, config.ctrl_dt)
        # The effort term charges the commanded tension as a fraction of the force limit
        # (Mechanism.command_map: (command + 1) / 2 for pull-only motors, whose -1 is slack) in
        # tension mode, the normalized joint torque in joint-torque mode.
        tension = config.action_mode == "tension"
        self.effort_gain, self.effort_offset = mech.command_map if tension else (1.0, 0.0)
        # With no offset and a gain of +-1, f^2 is the command's own square: skip the map.
        self._effort_mapped = self.effort_offset != 0.0 or abs(self.effort_gain) != 1.0
        self.obs_size = config.observation.size
        self._info_keys = {k: f"reward_{k}" for k in TERMS}  # formatted once, not every step

    # -- reset -----------------------------------------------------------------------------------
    def reference_option(self, options: Any) -> Reference | None:
        """Returns the reference fixed by ``reset(options={"reference": {...}})`` (Reference
        fields over the nominal one; it must fit the workspace), or None."""
        if options is None:
            return None
        if not isinstance(options, Mapping):
            raise invalid("options", options, "None or a mapping, e.g. {'reference': {...}}")
        if "reference" not in options:
            return None
        value = options["reference"]
        if isinstance(value, Reference):
            ref = value
        elif isinstance(value, Mapping):
            ref = Reference.from_dict(merge_reference(self.config.reference.to_dict(), value))
        else:
            raise invalid(
                "options['reference']",
                value,
                "a Reference or a mapping of Reference fields (amp_deg, bias_deg, freq_hz, "
                "omega_rad_s, phase_deg)",
            )
        if problems := ref.workspace_violations(self.config.mechanism):
            raise invalid(
                "options['reference']",
                ref.to_dict(),
                f"a reference inside the workspace, but it leaves it: {problems}",
            )
        return ref

    def episode(
        self, rng: np.random.Generator, fixed: Reference | None
    ) -> tuple[EnvConfig, Reference]:
        """Returns the episode's arm config and reference.  With ``mechanism_ranges``: a drawn
        arm and its reference (``fixed``, else a draw of reference_ranges, else the nominal
        one; tendon2r_gym.task.arms.draw_episode_arm), the arm's force limit sized for it.
        Else the env's config and ``fixed``, else a draw from ``reference_ranges``, else the
        nominal reference."""
        cfg = self.config
        if cfg.mechanism_ranges is not None:
            arm = draw_episode_arm(cfg, rng, fixed)
            return arm, arm.reference
        if fixed is not None:
            return cfg, fixed
        if cfg.reference_ranges is not None:
            return cfg, cfg.reference_ranges.sample(rng, cfg.mechanism)
        return cfg, cfg.reference

    def initial_state(self, rng: np.random.Generator, ref: Reference) -> tuple[np.ndarray, ...]:
        """Returns (q, dq) on the reference at t = 0 plus uniform noise in
        [-reset_noise_scale, reset_noise_scale], q clipped to the joint range."""
        noise = self.config.reset_noise_scale
        q = ref.q(0.0) + rng.uniform(-noise, noise, 2)
        qdot = ref.qdot(0.0) + rng.uniform(-noise, noise, 2)
        return np.clip(q, self.q_lo, self.q_hi), qdot

    def reset_info(self, ref: Reference, time: float, arm: EnvConfig) -> dict[str, Any]:
        """Returns the info of a reset (one arm; ``arm``: its config)."""
        info = {
            "reference": ref.to_dict(),
            "time": time,
            "force_need_N": arm.needs.force_need,
            "torque_need_Nm": np.array(arm.needs.torque_need),
            "max_tendon_force_N": arm.mechanism.max_tendon_force,
        }
        if self.config.mechanism_ranges is not None:
            info["mechanism"] = arm.mechanism.to_dict()
            info["observation_noise"] = list(arm.observation_noise)
            info["observation_delay"] = arm.observation_delay
            if self.config.mechanism_ranges.draws_gains:
                info["pd_gains"] = gains_of(arm.pd_gains).to_dict()
        return info

    # -- observation -----------------------------------------------------------------------------
    def observation(
        self,
        ops: Ops,
        q1: Any,
        q2: Any,
        w1: Any,
        w2: Any,
        t: Any,
        ref: Sequence[Any],
        arm: Sequence[Any],
        last_action: Sequence[Any],
    ) -> list[Any]:
        """Returns the observation's entries in the order of tendon2r_gym.task.observation (q, dq,
        q_des, dq_des, error, error_log, effector_pos, effector_vel, preview, last action, then
        error_rate_log, feedforward, force_limit_log and arm if observed), from the joint
        angles and speeds, the time, `reference_params`, `arm_params` and the last
        clipped action (one value, or one column of N values, per action dimension)."""
        amp1, amp2, om1, om2, ph1, ph2, bias1, bias2 = ref
        sin, cos = ops.sin, ops.cos
        arg1, arg2 = om1 * t + ph1, om2 * t + ph2
        qd1, qd2 = amp1 * sin(arg1) + bias1, amp2 * sin(arg2) + bias2
        joints, rest = self.state_entries(ops, q1, q2, w1, w2, qd1, qd2, arm)
        dqd1, dqd2 = amp1 * om1 * cos(arg1), amp2 * om2 * cos(arg2)
        joints += [qd1, qd2, dqd1, dqd2, *rest]
        for dt in self.offsets:
            joints += [amp1 * sin(arg1 + om1 * dt) + bias1, amp2 * sin(arg2 + om2 * dt) + bias2]
        joints += last_action
        if self.observes_rate:
            joints += self.error_rate_entries(ops, w1, w2, dqd1, dqd2, arm)
        if self.observes_feedforward:
            joints += self.feedforward_entries(ops, t, ref, arm)
        if len(arm) > N_ARM_PARAMS:  # force_limit_log and arm, if observed
            joints += arm[N_ARM_PARAMS:]
        return joints

    def state_entries(
        self, ops: Ops, q1: Any, q2: Any, w1: Any, w2: Any, qd1: Any, qd2: Any, arm: Sequence[Any]
    ) -> tuple[list[Any], list[Any]]:
        """Returns the observation's entries that the joint state sets, in two runs:
        (q, dq) and (error, error_log, effector_pos, effector_vel), from the joint angles and
        speeds, the reference q_des and `arm_params` (tendon2r_gym.task.observation.STATE
        gives their slices).  With sensors, the envs rewrite these of the measured observation
        with the true state for the reward and info."""
        a, b, c = arm[LINKS]
        sin, cos = ops.sin, ops.cos
        c1, s1 = cos(q1), sin(q1)
        q12 = q1 + q2
        c12, s12 = cos(q12), sin(q12)
        w12 = w1 + w2
        e1, e2 = qd1 - q1, qd2 - q2
        rest = [
            e1, e2,
            *self._log_entries(ops, e1, e2, L.ERROR_LOG_SCALE, arm, self.config.ctrl_dt),
            a + c * c1 + b * c12, c * s1 + b * s12,  # effector x, z
            -c * s1 * w1 - b * s12 * w12, c * c1 * w1 + b * c12 * w12,  # effector velocity
        ]  # fmt: skip
        return [q1, q2, w1, w2], rest

    def error_rate_entries(
        self, ops: Ops, w1: Any, w2: Any, dqd1: Any, dqd2: Any, arm: Sequence[Any]
    ) -> list[Any]:
        """Returns ``error_rate_log`` (observe ``error_rate``) from the joint speeds and the
        reference's: `_log_entries` of de = dq_des - dq."""
        return self._log_entries(ops, dqd1 - w1, dqd2 - w2, L.ERROR_RATE_LOG_SCALE, arm)

    def feedforward_entries(
        self, ops: Ops, t: Any, ref: Sequence[Any], arm: Sequence[Any]
    ) -> list[Any]:
        """Returns ``feedforward`` (observe ``feedforward``): rate_to_action (`arm_params`)
        times ctrl_dt ddq_des(t + ctrl_dt / 2), the normalized joint torques that give the
        reference's acceleration at the middle of the next control step."""
        amp1, amp2, om1, om2, ph1, ph2, _, _ = ref
        dt = self.config.ctrl_dt
        mid = t + 0.5 * dt
        v1 = -amp1 * om1 * om1 * dt * ops.sin(om1 * mid + ph1)
        v2 = -amp2 * om2 * om2 * dt * ops.sin(om2 * mid + ph2)
        return list(to_action(arm, v1, v2))

    def _log_entries(
        self, ops: Ops, x1: Any, x2: Any, scale: float, arm: Sequence[Any], per: float = 1.0
    ) -> list[Any]:
        """Returns sign(y) log(1 + |y| / s) of each joint's y: with error_units "rad", y = x
        and s = ``scale``; with "action", y = rate_to_action (x / per) (`arm_params`), the
        normalized joint torques that change the joints' speeds by x / per in one control step,
        and s = ACTION_LOG_SCALE."""
        if self.config.error_units == "rad":
            return [signed_log(ops, x1, scale), signed_log(ops, x2, scale)]
        y1, y2 = to_action(arm, x1 / per, x2 / per)
        return [signed_log(ops, y1, L.ACTION_LOG_SCALE), signed_log(ops, y2, L.ACTION_LOG_SCALE)]

    # -- action ----------------------------------------------------------------------------------
    def checked_action(self, action: Any) -> list[float]:
        """Returns one env's action as its n floats clipped to [-1, 1], or raises a ValueError
        naming it (a float array of the right shape takes the fast path)."""
        n = self.n_actions
        if type(action) is not np.ndarray or action.shape != (n,) or action.dtype.kind != "f":
            action = real_array("action", action, (n,), self._allowed_actions())
        a = action.tolist()
        # A finite sum has finite terms; only a non-finite one needs each term checked.
        if not math.isfinite(sum(a)) and not all(map(math.isfinite, a)):
            raise invalid("action", action, self._allowed_actions())
        return [-1.0 if x < -1.0 else 1.0 if x > 1.0 else x for x in a]

    def _allowed_actions(self) -> str:
        return f"({self.n_actions},) finite real numbers in [-1, 1]; values outside are clipped"

    def rest_command(self, arm: EnvConfig) -> list[float]:
        """Returns the command at rest on the arm of config ``arm``, the "last command" after a
        reset: no force, or for pull-only tendons in tension mode the pretension (-1 would be
        slack)."""
        cfg = self.config
        rest = arm.mechanism.rest_ctrl if cfg.action_mode == "tension" else 0.0
        return [rest] * cfg.n_actions

    def command(self, action: Sequence[Any], last: Sequence[Any]) -> Sequence[Any]:
        """Returns the command the env applies: the clipped action through the first-order
        filter of ``action_filter_tau``, last + alpha (action - last), or the action itself
        without a filter (``last``: the command applied on the step before)."""
        alpha = self.alpha
        if alpha == 1.0:
            return action
        return [c + alpha * (x - c) for x, c in zip(action, last, strict=True)]

    # -- reward ----------------------------------------------------------------------------------
    def rate_need_inverse(self, torque_rate_need: Any, max_torque: Any) -> list[Any]:
        """Returns, per action dimension, 1 / s of the ``action_rate_need`` term:
        max_torque_j / (torque_rate_need_j ctrl_dt) in joint-torque mode (each (2,) of one arm,
        or (N, 2) of N arms: one float, or one array of N, per joint), zeros in tension mode."""
        if self.config.action_mode != "joint_torque":
            return [0.0] * self.config.n_actions
        inv = np.asarray(max_torque) / (np.asarray(torque_rate_need) * self.config.ctrl_dt)
        return [inv[..., j] for j in range(2)]

    def reward_terms(
        self,
        ops: Ops,
        e1: Any,
        e2: Any,
        action: Sequence[Any],
        last_action: Sequence[Any],
        rate_need_inverse: Sequence[Any],
        diverged: Any,
        de1: Any = 0.0,
        de2: Any = 0.0,
    ) -> dict[str, Any]:
        """Returns the unscaled reward terms (keys of TERMS) from the tracking errors (rad), the
        clipped action and the one before it (one value, or one column of N values, per action
        dimension), `rate_need_inverse` of the arm (per action dimension), divergence
        and the errors' rates (rad/s; read only when ``tracking_rate`` is weighed)."""
        e1, e2 = e1 / RAD_PER_DEG, e2 / RAD_PER_DEG
        quadratic = -(e1 * e1 + e2 * e2)
        tracking = self._tracking(ops, e1, e2, quadratic)
        ahead = 0.0 * quadratic  # a zero per arm, unless weighed
        if self.weighs_rate:  # the error tracking_horizon s ahead (deg)
            h = self.horizon / RAD_PER_DEG
            a1, a2 = e1 + h * de1, e2 + h * de2
            ahead = self._tracking(ops, a1, a2, -(a1 * a1 + a2 * a2))
        effort = rate = rate_need = 0.0  # in action order, as numpy's sum over a few entries
        gain, offset, mapped = self.effort_gain, self.effort_offset, self._effort_mapped
        for x, x0, inv in zip(action, last_action, rate_need_inverse, strict=False):
            f = x * gain + offset if mapped else x
            effort += f * f
            d = x - x0
            rate += d * d
            r = d * inv
            rate_need += ops.log1p(r * r)
        return {
            "tracking": tracking,
            "tracking_quadratic": quadratic,
            "tracking_rate": ahead,
            "ctrl": -effort,
            "action_rate": -rate,
            "action_rate_need": -rate_need,
            "divergence": ops.where(diverged, -1.0, 0.0),
        }

    def _tracking(self, ops: Ops, e1: Any, e2: Any, quadratic: Any) -> Any:
        """Returns the ``tracking_form`` kernel of the errors (deg; ``quadratic``: -sum e^2)."""
        if self.form == "log":
            u1, u2 = e1 / self.sigma, e2 / self.sigma
            return -(ops.log1p(u1 * u1) + ops.log1p(u2 * u2)) / self.log_norm
        if self.form == "multiscale":
            tracking = 0.0
            log1p = ops.log1p
            for inv, norm in self.kernels:
                u1, u2 = e1 * inv, e2 * inv
                tracking -= (log1p(u1 * u1) + log1p(u2 * u2)) / norm
            return tracking
        return quadratic

    def scale(self, terms: Mapping[str, Any]) -> tuple[Any, dict[str, Any]]:
        """Returns (reward, scaled terms): each term times its weight, keyed ``reward_<name>``
        as ``info`` reports it, and their sum (in the order of ``terms``, as ``sum``)."""
        scales, keys = self.scales, self._info_keys
        scaled = {}
        reward = 0
        for k, v in terms.items():
            scaled[keys[k]] = x = scales[k] * v
            reward = reward + x
        return reward, scaled

    # -- divergence ------------------------------------------------------------------------------
    def out_of_domain(self, ops: Ops, q1: Any, q2: Any, w1: Any, w2: Any) -> Any:
        """Returns whether the state has left the simulation's valid domain: a joint far past
        its limit or faster than DIVERGED_SPEED, or a non-finite state (NaN fails every test)."""
        lo, hi, fast = self.div_lo, self.div_hi, DIVERGED_SPEED
        inside = (lo < q1) & (q1 < hi) & (lo < q2) & (q2 < hi) & (abs(w1) < fast) & (abs(w2) < fast)
        return ops.not_(inside)

    # -- info ------------------------------------------------------------------------------------
    def step_info(
        self,
        obs: np.ndarray,
        scaled: Mapping[str, Any],
        tension: np.ndarray,
        cond: Any,
        time: Any,
        diverged: Any,
    ) -> dict[str, Any]:
        """Returns the info of a step (keys STEP_INFO_KEYS) from the observation (one, or N
        rows), the scaled reward terms (`scale`), the tendon tensions (N, positive
        pulling), the moment-arm condition number, the time and divergence."""
        info = dict(scaled)
        if obs.ndim == 1:  # one env
            q, q_des, err, pos = obs[L.Q], obs[L.Q_DES], obs[L.ERROR], obs[L.EFFECTOR_POS]
        else:  # N arms
            q, q_des = obs[:, L.Q], obs[:, L.Q_DES]
            err, pos = obs[:, L.ERROR], obs[:, L.EFFECTOR_POS]
        info["q"], info["q_des"] = q, q_des
        info["tracking_error_deg"] = err / RAD_PER_DEG
        info["tendon_tension"] = tension
        info["moment_arm_cond"] = cond
        info["effector_pos"] = pos
        info["time"] = time
        info["diverged"] = diverged
        return info

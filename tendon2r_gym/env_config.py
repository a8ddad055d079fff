"""EnvConfig: every argument of Tendon2R-v0 except rendering, resolved and validated once.

``EnvConfig.make(preset, **overrides)`` reads the preset or experiment file, applies the
overrides (:func:`tendon2r_gym.presets.merge_env_kwargs`), checks every value, fits the reference
to the workspace if asked, and sizes ``max_tendon_force: auto``.  Every error is raised here,
before any MuJoCo model is built.  ``to_dict()`` is what a training run records, and what a
trained model is checked against when it is loaded.
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import mujoco
import numpy as np

from tendon2r_gym import observation
from tendon2r_gym.actuation import MomentArms, distribute, max_joint_torque
from tendon2r_gym.arms import (
    CONTROLLER,
    DELAYS,
    MAX_TRIES,
    SENSING,
    TUNED_PHASE,
    MechanismRanges,
    gain_field,
    reference_ranges,
)
from tendon2r_gym.gains import Gains, gains_of, tuned_bandwidth
from tendon2r_gym.mechanism import AUTO, Mechanism
from tendon2r_gym.model import build_model
from tendon2r_gym.presets import SECTIONS, load_preset, merge_env_kwargs
from tendon2r_gym.reference import Reference, ReferenceRanges
from tendon2r_gym.rewards import ERROR_UNITS, MAX_REWARD_WEIGHT, REWARD_SCALES, TRACKING_FORMS
from tendon2r_gym.stability import check_stability
from tendon2r_gym.validation import (
    boolean,
    check_keys,
    choice,
    integer,
    invalid,
    mapping,
    number,
    pair,
)

#: ``max_tendon_force: auto`` is this many times the peak force that inverse dynamics of the
#: reference needs: PD's feedback and the start-up transient need room above feed-forward.
FORCE_HEADROOM = 2.0
#: The least motion ``auto`` sizes the force limit for (per joint, about the reference's bias).
AUTO_FLOOR = {"amp_deg": (10.0, 10.0), "freq_hz": (1.0, 1.0)}


#: What the action commands: "tension", each tendon motor (normalized by max_tendon_force);
#: "joint_torque", each joint's torque (normalized by TorqueToTension.max_torque), which the env
#: turns into tendon tensions with PD's distribution (tendon2r_gym.actuation.TorqueToTension).
ACTION_MODES = ("tension", "joint_torque")


@dataclass(frozen=True)
class EnvConfig:
    """The resolved arguments of Tendon2R-v0 (see the Tendon2REnv docstring for each one)."""

    mechanism: Mechanism
    reference: Reference
    reference_ranges: ReferenceRanges | None = None
    #: Draw a new arm at every reset (tendon2r_gym.arms.MechanismRanges; "course": the
    #: course's geometry), and its reference: each pair valid, with its own ``auto`` force
    #: limit, as one user's experiment file (draw_arm).
    mechanism_ranges: MechanismRanges | None = None
    #: Observe the drawn fields, normalized over mechanism_ranges (the ``arm`` slice).
    observe_arm: bool = False
    #: The ranges the ``arm`` slice covers and is normalized over, if not mechanism_ranges:
    #: a policy trained on random arms with observe_arm sees one fixed arm as it saw the
    #: arms it was trained on (fine-tuning a generalist on one arm).
    arm_feature_ranges: MechanismRanges | None = None
    fit_to_workspace: bool = False
    ctrl_dt: float = 0.001
    action_mode: str = "tension"
    action_filter_tau: float = 0.0
    episode_duration: float = 2.0
    reward_scales: Mapping[str, float] = field(default_factory=lambda: dict(REWARD_SCALES))
    tracking_form: str = "multiscale"
    tracking_sigma_deg: float = 1.0
    reset_noise_scale: float = 0.001
    preview_steps: int = 3
    preview_dt: float = 0.01
    #: Observe the tracking error's rate, log-scaled (``error_rate_log``, after last_action).
    observe_error_rate: bool = False
    #: What error_log and error_rate_log log-scale (tendon2r_gym.task.ERROR_UNITS): "rad", the
    #: tracking error and its rate; "action", the normalized joint torques that close the
    #: error and cancel its rate on the episode's arm (rate_to_action), so that a policy's
    #: gains on them move the joints alike on every arm.
    error_units: str = "rad"
    #: Observe the reference's acceleration as the normalized joint torques that give it
    #: (``feedforward``, after error_rate_log): rate_to_action (ctrl_dt ddq_des).
    observe_feedforward: bool = False
    #: Observe ln of the force limit max_tendon_force (``force_limit_log``, after
    #: error_rate_log): a normalized action's scale, which ``auto`` sizes per arm.
    observe_force_limit: bool = False
    #: What the controller measures (tendon2r_gym.realism.Sensors): Gaussian noise (std, rad
    #: and rad/s) on each joint's angle and speed, and their age (s, whole control steps).
    observation_noise: tuple[float, float] = (0.0, 0.0)
    observation_delay: float = 0.0
    #: Gains of PD and CT on this arm (tendon2r_gym.gains.Gains fields over data/pd.yaml; None:
    #: data/pd.yaml), and of the PD inside a residual policy trained here.  A lagging arm may
    #: need lower ones: ``tendon2r-tune-pd`` finds them.
    pd_gains: Gains | None = None
    #: Peak tendon force (N) that inverse dynamics of the reference (or of the worst corner of
    #: reference_ranges) needs; computed, not an argument.
    force_need: float = field(default=math.nan, compare=False)
    #: Peak torque (N m) of each joint that inverse dynamics of the same references needs (of
    #: AUTO_FLOOR's motion, if more): the scale of a residual relative to the arm's need
    #: (tendon2r_gym.learned, ``residual_relative_to: need``); computed, not an argument.
    torque_need: tuple[float, float] = field(default=(math.nan, math.nan), compare=False)
    #: Peak rate (N m / s) of each joint's torque that inverse dynamics of the same references
    #: needs (of AUTO_FLOOR's motion, if more): the scale of the ``action_rate_need`` reward
    #: term (Task.rate_need_inverse); computed, not an argument.
    torque_rate_need: tuple[float, float] = field(default=(math.nan, math.nan), compare=False)
    #: Each joint's control authority (rad/s per unit of normalized joint-torque action): the
    #: most its speed changes in one control step per unit of action on it alone, ctrl_dt
    #: max_torque_j (M(q)^-1)_jj (TorqueToTension.max_torque at this force limit) at the q
    #: of the same references where the arm is lightest.  A derivative gain that is stable on
    #: one arm chatters on an arm of far more authority.  Computed, not an argument.
    control_authority: tuple[float, float] = field(default=(math.nan, math.nan), compare=False)
    #: The normalized joint-torque actions that change the joints' speeds by dq (rad/s) in
    #: one control step, diag(1 / max_torque) M(q) / ctrl_dt, as a 2 x 2 matrix (rows: the
    #: actions) at the reference's bias: the unit of ``error_units: action``.  Each
    #: joint's action moves the other's speed too, on some arms several times its own; in
    #: these units a policy's gain acts alike on every arm.  Computed, not an argument.
    rate_to_action: tuple[tuple[float, float], tuple[float, float]] = field(
        default=((math.nan, math.nan), (math.nan, math.nan)), compare=False
    )
    #: The mechanism as given (max_tendon_force possibly "auto"): what arms are drawn over.
    base_mechanism: Mechanism | None = field(default=None, compare=False, repr=False)

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def make(cls, preset: str | os.PathLike = "default", **overrides: Any) -> EnvConfig:
        """Returns the config of a preset name or experiment-file path with ``overrides``."""
        allowed = arguments()
        check_keys("Tendon2R-v0", overrides, allowed)
        kwargs = merge_env_kwargs(load_preset(preset, allowed), overrides)
        return cls.from_kwargs(kwargs)

    @classmethod
    def from_kwargs(cls, kwargs: Mapping[str, Any]) -> EnvConfig:
        """Validates and resolves merged keyword arguments (sections may be dicts)."""
        kwargs = dict(kwargs)
        check_keys("Tendon2R-v0", kwargs, arguments())
        mech = kwargs.pop("mechanism", None)
        if not isinstance(mech, Mechanism):
            mech = Mechanism.from_dict(mapping("mechanism", mech))
        ref = kwargs.pop("reference", None)
        if not isinstance(ref, Reference):
            ref = Reference.from_dict(mapping("reference", ref))
        ranges = kwargs.pop("reference_ranges", None)
        if ranges is not None and not isinstance(ranges, ReferenceRanges):
            ranges = reference_ranges(ranges)
        arms = kwargs.pop("mechanism_ranges", None)
        if arms is not None:
            arms = MechanismRanges.from_value(arms)
        features = kwargs.pop("arm_feature_ranges", None)
        if features is not None:
            try:
                features = MechanismRanges.from_value(features)
            except ValueError as e:  # the same rules as mechanism_ranges: name the field
                raise ValueError(f"arm_feature_ranges: {e}") from None
        if kwargs.get("pd_gains") is not None:
            kwargs["pd_gains"] = gains_of(kwargs["pd_gains"])
        return cls(
            mechanism=mech,
            reference=ref,
            reference_ranges=ranges,
            mechanism_ranges=arms,
            arm_feature_ranges=features,
            **kwargs,
        )

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        set_("fit_to_workspace", boolean("fit_to_workspace", self.fit_to_workspace))
        sim_dt = self.mechanism.sim_dt
        set_("ctrl_dt", number("ctrl_dt", self.ctrl_dt, sim_dt, 0.1))
        n_sub = round(self.ctrl_dt / sim_dt)
        # Relative 1e-6: a float32 ctrl_dt (np.float32(0.002)) is still a multiple.
        if abs(n_sub * sim_dt - self.ctrl_dt) > 1e-6 * self.ctrl_dt:
            raise invalid("ctrl_dt", self.ctrl_dt, f"an integer multiple of sim_dt = {sim_dt} s")
        set_("ctrl_dt", n_sub * sim_dt)
        choice("action_mode", self.action_mode, ACTION_MODES)
        set_("action_filter_tau", number("action_filter_tau", self.action_filter_tau, 0.0, 1.0))
        set_("episode_duration", number("episode_duration", self.episode_duration, self.ctrl_dt))
        scales = mapping("reward_scales", self.reward_scales)
        check_keys("reward_scales", scales, REWARD_SCALES)
        set_(
            "reward_scales",
            {
                k: number(f"reward_scales.{k}", scales.get(k, default), 0.0, MAX_REWARD_WEIGHT)
                for k, default in REWARD_SCALES.items()
            },
        )
        need_weight = self.reward_scales["action_rate_need"]
        if need_weight > 0 and self.action_mode != "joint_torque":
            raise invalid(
                "reward_scales.action_rate_need",
                need_weight,
                f"0 in action_mode {self.action_mode!r} (a joint's torque rate is the scale; "
                "use action_mode 'joint_torque')",
            )
        choice("tracking_form", self.tracking_form, TRACKING_FORMS)
        set_(
            "tracking_sigma_deg",
            number("tracking_sigma_deg", self.tracking_sigma_deg, 0.0, 90.0, lo_open=True),
        )
        set_("reset_noise_scale", number("reset_noise_scale", self.reset_noise_scale, 0.0, 0.5))
        set_("preview_steps", integer("preview_steps", self.preview_steps, 0, 100))
        set_("preview_dt", number("preview_dt", self.preview_dt, 0.0, 1.0, lo_open=True))
        noise = pair("observation_noise", self.observation_noise, 0.0, 1e3,
                     "angle std (rad), speed std (rad/s)")  # fmt: skip
        set_("observation_noise", noise)
        delay = number("observation_delay", self.observation_delay, 0.0, 1.0)
        set_("observation_delay", delay)
        delays = {"observation_delay": delay, "mechanism.motor_delay": self.mechanism.motor_delay}
        for name, value in delays.items():
            if abs(round(value / self.ctrl_dt) * self.ctrl_dt - value) > 1e-6 * self.ctrl_dt:
                raise invalid(name, value, f"a multiple of ctrl_dt = {self.ctrl_dt} s")
        set_("observe_arm", boolean("observe_arm", self.observe_arm))
        set_("observe_error_rate", boolean("observe_error_rate", self.observe_error_rate))
        choice("error_units", self.error_units, ERROR_UNITS)
        set_("observe_feedforward", boolean("observe_feedforward", self.observe_feedforward))
        set_("observe_force_limit", boolean("observe_force_limit", self.observe_force_limit))
        if self.observe_arm and self.feature_ranges is None:
            raise invalid(
                "observe_arm", True, "False without mechanism_ranges or arm_feature_ranges"
            )
        if self.arm_feature_ranges is not None and not self.observe_arm:
            raise invalid(
                "arm_feature_ranges", self.arm_feature_ranges.to_dict(), "None unless observe_arm"
            )
        if self.base_mechanism is None:
            set_("base_mechanism", self.mechanism)
        self._check_reference()
        self._size_force_limit()
        if self.mechanism_ranges is not None:  # raises now if no valid arm can be drawn
            self.draw_arm(np.random.default_rng(0))

    def _check_reference(self) -> None:
        mech, ref = self.mechanism, self.reference
        if self.fit_to_workspace:
            object.__setattr__(self, "reference", ref.fit_to_workspace(mech))
        elif problems := ref.workspace_violations(mech):
            raise invalid(
                "reference",
                ref.to_dict(),
                f"a reference inside the workspace, but it leaves it: {'; '.join(problems)} "
                "(or pass fit_to_workspace=True to scale the amplitudes down)",
            )
        nyquist = 0.5 / self.ctrl_dt
        freqs = [max(self.reference.omega) / (2 * math.pi)]
        if self.reference_ranges is not None:
            freqs.append(max(hi for _, hi in self.reference_ranges.freq_hz))
            if problems := self.reference_ranges.corner_violations(mech):
                raise invalid(
                    "reference_ranges.bias_deg",
                    self.reference_ranges.bias_deg,
                    "biases that fit the workspace, but a draw could leave it: "
                    + "; ".join(problems),
                )
        if max(freqs) * self.ctrl_dt > 0.1:
            raise invalid(
                "reference frequency (Hz)",
                max(freqs),
                f"<= {0.1 / self.ctrl_dt:g} Hz: at least 10 control steps per period, a fifth "
                f"of the Nyquist limit 0.5 / ctrl_dt = {nyquist:g} Hz (use a smaller ctrl_dt)",
            )

    def _size_force_limit(self) -> None:
        refs = [self.reference]
        if self.reference_ranges is not None:
            refs += self.reference_ranges.corners()
        # A slow or constant reference needs almost no force, but feedback still does: "auto"
        # never falls below the need of AUTO_FLOOR's motion about the same bias (last entry).
        refs.append(Reference(bias_deg=self.reference.bias_deg, **AUTO_FLOOR))
        per_ref, torque_per_newton, inertia = _physics(
            self.mechanism.replace(max_tendon_force=1.0), tuple(refs)
        )
        torque = np.max([t for _, t, _, _ in per_ref], axis=0)
        object.__setattr__(self, "torque_need", (float(torque[0]), float(torque[1])))
        rate = np.max([r for _, _, r, _ in per_ref], axis=0)
        object.__setattr__(self, "torque_rate_need", (float(rate[0]), float(rate[1])))
        inverse_inertia = np.max([m for *_, m in per_ref], axis=0)
        *needs, floor_need = [f for f, _, _, _ in per_ref]
        need = max(needs)
        if self.mechanism.pull_only:
            need = max(need, self.mechanism.pretension)
        object.__setattr__(self, "force_need", need)
        limit = self.mechanism.max_tendon_force
        if limit == AUTO:
            auto = FORCE_HEADROOM * max(need, floor_need)
            object.__setattr__(
                self, "mechanism", self.mechanism.replace(max_tendon_force=float(f"{auto:.3g}"))
            )
        elif limit < need:
            warnings.warn(
                f"max_tendon_force = {limit} N is below the {need:.3g} N that inverse dynamics "
                f"of the reference needs: the motors will saturate and tracking will fail "
                f"(use max_tendon_force: auto, which gives {FORCE_HEADROOM:g} x the need)",
                stacklevel=3,
            )
        force = self.mechanism.max_tendon_force
        max_torque = force * torque_per_newton
        authority = self.ctrl_dt * max_torque * inverse_inertia
        object.__setattr__(self, "control_authority", (float(authority[0]), float(authority[1])))
        with np.errstate(divide="ignore"):  # a joint no tendon spans: no action moves it
            to_action = inertia / (self.ctrl_dt * max_torque[:, None])
        if not np.all(np.isfinite(to_action)):
            if self.error_units == "action":
                raise invalid(
                    "error_units", self.error_units, "'rad' on an arm with a joint no tendon spans"
                )
            if self.observe_feedforward:
                raise invalid(
                    "observe_feedforward", True, "False on an arm with a joint no tendon spans"
                )
        to_action = tuple(tuple(float(x) for x in row) for row in to_action)
        object.__setattr__(self, "rate_to_action", to_action)

    # -- random arms ---------------------------------------------------------------------------
    def draw_arm(self, rng: np.random.Generator, reference: Reference | None = None) -> EnvConfig:
        """Returns the config of a random arm of ``mechanism_ranges`` and its episode's
        reference (``reference``, else a draw of reference_ranges on that arm, else the
        nominal one): :meth:`for_arm`.  Draws again until the pair is valid (a Mechanism,
        stable, the reference's bias in its workspace); raises after MAX_TRIES draws."""
        ranges = self.mechanism_ranges
        if ranges is None:
            return self
        for _ in range(MAX_TRIES):
            drawn = ranges.sample(rng)
            for k in DELAYS:  # whole control steps
                if k in drawn:
                    drawn[k] = round(drawn[k] / self.ctrl_dt) * self.ctrl_dt
            noise = [
                drawn.pop(k, v) for k, v in zip(SENSING[1:], self.observation_noise, strict=True)
            ]
            delay = drawn.pop("observation_delay", self.observation_delay)
            gains = {gain_field(k): drawn.pop(k) for k in CONTROLLER if k in drawn}
            phase = drawn.pop(TUNED_PHASE, None)
            try:
                mech = self.base_mechanism.replace(**drawn)
                if phase is not None:  # the bandwidth a tuning would pick on this arm
                    f = tuned_bandwidth(mech, delay, self.ctrl_dt, phase)
                    lo, hi = dict(ranges.ranges)["pd_bandwidth_hz"]
                    gains["bandwidth_hz"] = min(max(f, lo), hi)
                ref = reference
                if ref is None and self.reference_ranges is not None:
                    ref = self.reference_ranges.sample(rng, mech)
                drawn_env = {"observation_noise": tuple(noise), "observation_delay": delay}
                if gains:
                    drawn_env["pd_gains"] = dataclasses.replace(gains_of(self.pd_gains), **gains)
                return self.for_arm(mech, ref, **drawn_env)
            except ValueError:
                continue
        raise invalid(
            "mechanism_ranges",
            ranges.to_dict(),
            f"ranges where a valid arm (with this reference) is found in {MAX_TRIES} draws",
        )

    def for_arm(
        self, mechanism: Mechanism, reference: Reference | None = None, **drawn_env: Any
    ) -> EnvConfig:
        """Returns the config of one arm and one reference (default: the nominal one), as a
        user's experiment file gives them: nothing drawn, the reference's amplitudes fitted
        to the arm's workspace (quietly), and an ``auto`` force limit sized for this arm and
        this reference; ``drawn_env``: its observation_noise, observation_delay and pd_gains,
        if drawn.
        An env with this config runs the randomized env's episode exactly."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return dataclasses.replace(
                self,
                mechanism=mechanism,
                base_mechanism=None,
                reference=self.reference if reference is None else reference,
                reference_ranges=None,
                mechanism_ranges=None,
                observe_arm=False,
                arm_feature_ranges=None,
                fit_to_workspace=True,
                **drawn_env,
            )

    # -- derived quantities ------------------------------------------------------------------
    @property
    def n_arm_features(self) -> int:
        """Returns the length of the observation's ``arm`` slice (0 unless observe_arm)."""
        return len(self.arm_fields)

    @property
    def observation_size(self) -> int:
        """Returns the observation's length (tendon2r_gym.observation.size)."""
        return observation.size(
            self.preview_steps, self.n_actions, self.n_arm_features, self.optional_entries
        )

    def observation_layout(self) -> list[list]:
        """Returns the observation's named layout (tendon2r_gym.observation.layout)."""
        return observation.layout(
            self.preview_steps, self.n_actions, self.n_arm_features, self.optional_entries
        )

    @property
    def optional_entries(self) -> tuple[str, ...]:
        """Returns the optional entries the observation holds (tendon2r_gym.observation
        .OPTIONAL names whose flag, e.g. observe_error_rate, is set)."""
        return tuple(e[0] for e, flag in observation.OPTIONAL.items() if getattr(self, flag))

    @property
    def feature_ranges(self) -> MechanismRanges | None:
        """Returns the ranges the observation's ``arm`` slice is normalized over:
        arm_feature_ranges, else mechanism_ranges (None without either)."""
        return self.arm_feature_ranges or self.mechanism_ranges

    @property
    def arm_fields(self) -> tuple[str, ...]:
        """Returns the fields of the observation's ``arm`` slice, in order (none unless
        observe_arm)."""
        return self.feature_ranges.names if self.observe_arm else ()

    def observation_mask(self, hidden: Any) -> np.ndarray:
        """Returns the 0/1 multiplier that blanks the observation entries named in ``hidden``
        (layout names, or ``arm.<field>``: tendon2r_gym.observation.layout_mask)."""
        return observation.layout_mask(self.observation_layout(), hidden, self.arm_fields)

    def observation_entries(self) -> list[str]:
        """Returns the names :meth:`observation_mask` accepts."""
        return observation.entry_names(self.observation_layout(), self.arm_fields)

    @property
    def n_substeps(self) -> int:
        """Returns the physics steps per control step."""
        return round(self.ctrl_dt / self.mechanism.sim_dt)

    @property
    def n_actions(self) -> int:
        """Returns the action's length: one per tendon ("tension") or per joint
        ("joint_torque")."""
        return self.mechanism.n_tendons if self.action_mode == "tension" else 2

    @property
    def delay_steps(self) -> int:
        """Returns the control steps each motor command is held back (mechanism.motor_delay)."""
        return round(self.mechanism.motor_delay / self.ctrl_dt)

    @property
    def observation_delay_steps(self) -> int:
        """Returns the control steps each measurement is late (observation_delay)."""
        return round(self.observation_delay / self.ctrl_dt)

    def _drawn_high(self, name: str, value: float) -> float:
        """Returns the largest value of field ``name`` an episode can have: ``value`` (the
        config's), or the top of its range if mechanism_ranges draws it."""
        ranges = self.mechanism_ranges
        return value if ranges is None or name not in ranges.names else ranges.high(name)

    @property
    def delay_capacity(self) -> int:
        """Returns the most control steps any episode holds a command back (0: no delay)."""
        return round(self._drawn_high("motor_delay", self.mechanism.motor_delay) / self.ctrl_dt)

    @property
    def observation_delay_capacity(self) -> int:
        """Returns the most control steps any episode's measurements are late."""
        return round(self._drawn_high("observation_delay", self.observation_delay) / self.ctrl_dt)

    @property
    def noisy(self) -> bool:
        """Returns whether any episode's measurements can carry noise."""
        return any(
            self._drawn_high(k, v) > 0
            for k, v in zip(SENSING[1:], self.observation_noise, strict=True)
        )

    @property
    def sensed(self) -> bool:
        """Returns whether the observation is (or in some episode may be) a measurement, noisy
        or late, not the state."""
        return self.observation_delay_capacity > 0 or self.noisy

    @property
    def action_filter_alpha(self) -> float:
        """Returns the weight of a new action in the applied command, 1 - exp(-ctrl_dt / tau)
        (1: no filter)."""
        return low_pass_alpha(self.action_filter_tau, self.ctrl_dt)

    @property
    def max_episode_steps(self) -> int:
        """Returns the control steps per episode: episode_duration / ctrl_dt."""
        return round(self.episode_duration / self.ctrl_dt)

    def to_dict(self) -> dict[str, Any]:
        """Returns the config as plain YAML-friendly env kwargs (an experiment file)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            if f.name in COMPUTED:
                continue
            value = getattr(self, f.name)
            out[f.name] = value.to_dict() if hasattr(value, "to_dict") else value
        out["observation_noise"] = list(self.observation_noise)
        if self.mechanism_ranges is not None:  # arms are drawn over the mechanism as given
            out["mechanism"] = self.base_mechanism.to_dict()
        return out


#: EnvConfig fields that are computed, not arguments.
COMPUTED = (
    "force_need",
    "torque_need",
    "torque_rate_need",
    "control_authority",
    "rate_to_action",
    "base_mechanism",
)


def arguments() -> list[str]:
    """Returns the keyword arguments an experiment file (or gym.make) may give."""
    return [f.name for f in dataclasses.fields(EnvConfig) if f.name not in COMPUTED]


@lru_cache(maxsize=64)
def _physics(
    mech: Mechanism, refs: tuple[Reference, ...]
) -> tuple[tuple[tuple[float, np.ndarray, np.ndarray, np.ndarray], ...], np.ndarray, np.ndarray]:
    """Checks that MuJoCo compiles ``mech`` and that the integrator can integrate it; returns,
    from the nominal model (no stretch, lag or friction: inverse dynamics of the arm), for
    each reference its force need (N), each joint's torque need (N m), torque-rate need (N m /
    s) and peak (M^-1)_jj (1 / (kg m^2)); each joint's torque per newton of force limit (N m /
    N, max_joint_torque at q = 0); and the inertia M (kg m^2, 2 x 2) at the first reference's
    bias."""
    model = build_model(mech)
    if mech.realistic:
        model = build_model(mech.ideal())
    check_stability(model, mech)
    out = []
    for r in refs:
        J, tau, inverse_inertia = inverse_dynamics_grid(model, [r])
        out.append(
            (
                peak_tension(J, tau, mech.pull_only, mech.pretension),
                np.max(np.abs(tau), 0),
                np.max(np.abs(torque_rate(tau, r)), 0),
                np.max(inverse_inertia, 0),
            )
        )
    data = mujoco.MjData(model)
    mujoco.mj_fwdPosition(model, data)  # q = 0
    unit_torque = max_joint_torque(MomentArms(model, data).dense(), 1.0)
    data.qpos[:2] = refs[0].bias_rad
    mujoco.mj_fwdPosition(model, data)
    inertia = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, inertia)
    return tuple(out), unit_torque, inertia[:2, :2]


assert set(SECTIONS) <= set(arguments())


def force_need(
    model: mujoco.MjModel,
    references: Sequence[Reference],
    pull_only: bool = False,
    pretension: float = 0.0,
    grid: int = 24,
) -> float:
    """Returns the peak tendon tension (N) that inverse dynamics needs to follow any of
    ``references`` exactly, over every combination of the two joints' phases: the tensions of
    :func:`inverse_dynamics_grid`'s torques from tendon2r_gym.actuation.distribute (with the
    pretension for pull-only tendons)."""
    J, tau, _ = inverse_dynamics_grid(model, references, grid)
    return peak_tension(J, tau, pull_only, pretension)


def peak_tension(J: np.ndarray, tau: np.ndarray, pull_only: bool, pretension: float) -> float:
    """Returns the peak tendon tension (N) that gives the joint torques ``tau`` (K, 2) through
    the moment arms ``J`` (K, n_tendons, 2): tendon2r_gym.actuation.distribute, one batch."""
    return float(np.max(np.abs(distribute(J, tau, pull_only, pretension))))


def inverse_dynamics_grid(
    model: mujoco.MjModel, references: Sequence[Reference], grid: int = 24
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Returns the moment arms J (K, n_tendons, 2), the joint torques tau (K, 2) that inverse
    dynamics needs to follow ``references`` and the diagonal of the inverse inertia M(q)^-1
    (K, 2) at every combination of the two joints' phases.  Each joint j moves as q = bias +
    amp sin(theta_j); tau comes from mj_inverse at (q, dq, ddq) on a ``grid`` x ``grid`` grid
    of (theta_A, theta_B).  Taking every phase pair bounds the need of any start time, phase
    and episode length."""
    data = mujoco.MjData(model)
    arms = MomentArms(model, data)
    theta = np.linspace(0.0, 2.0 * np.pi, grid, endpoint=False)
    s = np.stack(np.meshgrid(np.sin(theta), np.sin(theta), indexing="ij"), -1).reshape(-1, 2)
    c = np.stack(np.meshgrid(np.cos(theta), np.cos(theta), indexing="ij"), -1).reshape(-1, 2)
    J, tau = [], []
    M = np.zeros((len(references) * len(s), model.nv, model.nv))
    for ref in references:
        amp, bias, w = ref.amp_rad, ref.bias_rad, ref.omega_array
        for q, dq, ddq in zip(bias + amp * s, amp * w * c, -amp * w * w * s, strict=True):
            data.qpos[:], data.qvel[:], data.qacc[:] = q, dq, ddq
            mujoco.mj_inverse(model, data)
            J.append(arms.dense().copy())
            tau.append(data.qfrc_inverse.copy())
            mujoco.mj_fullM(model, data, M[len(tau) - 1])
    inverse_inertia = np.diagonal(np.linalg.inv(M), axis1=1, axis2=2)[:, :2]
    return np.array(J), np.array(tau), inverse_inertia


def torque_rate(tau: np.ndarray, ref: Reference) -> np.ndarray:
    """Returns the rate (N m / s) of the joint torques ``tau`` (grid^2, 2) of one reference on
    :func:`inverse_dynamics_grid`'s phase grid: d tau / dt = omega_A d tau / d theta_A + omega_B
    d tau / d theta_B, each partial a periodic central difference over the grid."""
    grid = math.isqrt(len(tau))
    t = tau.reshape(grid, grid, -1)
    step = 2.0 * (2.0 * math.pi / grid)
    d_a = (np.roll(t, -1, axis=0) - np.roll(t, 1, axis=0)) / step
    d_b = (np.roll(t, -1, axis=1) - np.roll(t, 1, axis=1)) / step
    w = ref.omega_array
    return (w[0] * d_a + w[1] * d_b).reshape(tau.shape)


def low_pass_alpha(tau: float, dt: float) -> float:
    """Returns the weight of a new input to a first-order low-pass of time constant ``tau``
    sampled every ``dt``, y <- y + alpha (x - y): alpha = 1 - exp(-dt / tau), 1 for ``tau =
    0`` (no filter).  The env's action filter and a residual's filter (learned.ResidualFilter)
    both use it."""
    return 1.0 if tau == 0.0 else -math.expm1(-dt / tau)

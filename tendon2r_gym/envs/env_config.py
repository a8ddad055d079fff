"""EnvConfig: every argument of the Tendon2R env except rendering, resolved and validated once.

``EnvConfig.make(preset, **overrides)`` reads the preset or experiment file, applies the
overrides (`tendon2r_gym.presets.merge_env_kwargs`), checks every value, fits the reference
to the workspace if asked, and sizes ``max_tendon_force: auto``.  Every error is raised here,
before any MuJoCo model is built.  ``to_dict()`` is what a training run records, and what a
trained model is checked against when it is loaded.

An experiment is resolved once, where it enters (a CLI, ``gym.make``'s keywords, a library
function given env kwargs: `resolve`), and the EnvConfig is passed down: the envs take one.
Drawing an episode's arm is tendon2r_gym.task.arms.draw_episode_arm; the control steps and
sensing the envs derive from a config are tendon2r_gym.envs.timing.Timing.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tendon2r_gym.presets import SECTIONS, load_preset, merge_env_kwargs
from tendon2r_gym.simulation.mechanism import AUTO, Mechanism
from tendon2r_gym.simulation.stability import stable_sim_dt
from tendon2r_gym.task import observation
from tendon2r_gym.task.arms import MechanismRanges, draw_episode_arm, reference_ranges
from tendon2r_gym.task.gains import Gains, gains_of
from tendon2r_gym.task.needs import Needs, force_needs
from tendon2r_gym.task.reference import Reference, ReferenceRanges, checked_reference
from tendon2r_gym.task.rewards import ERROR_UNITS, MAX_REWARD_WEIGHT, REWARD_SCALES, TRACKING_FORMS
from tendon2r_gym.validation import (
    boolean,
    check_keys,
    choice,
    integer,
    invalid,
    is_number,
    mapping,
    number,
    pair,
    subset,
)

#: ``max_tendon_force: auto`` is this many times the peak force that inverse dynamics of the
#: reference needs: PD's feedback and the start-up transient need room above feed-forward.
FORCE_HEADROOM = 2.0
#: The least motion ``auto`` sizes the force limit for (per joint, about the reference's bias).
AUTO_FLOOR = {"amp_deg": (10.0, 10.0), "freq_hz": (1.0, 1.0)}


#: What the action commands: "tension", each tendon motor (normalized by max_tendon_force);
#: "joint_torque", each joint's torque (normalized by TorqueToTension.max_torque), which the env
#: turns into tendon tensions with PD's distribution
#: (tendon2r_gym.simulation.actuation.TorqueToTension).
ACTION_MODES = ("tension", "joint_torque")
MAX_SUBSTEPS = 1000  # physics steps per control step (ctrl_dt / sim_dt), at most


@dataclass(frozen=True)
class EnvConfig:
    """The resolved arguments of the Tendon2R env, every id's.

    Each field's description is the ``#:`` comment above it, the one place it is written: the
    env card's Arguments table (scripts/gen_docs.py) is generated from these comments and the
    defaults.
    """

    #: Mechanism fields over the preset's (a dict), or a Mechanism: geometry, routing, force
    #: limit, cables and motors.
    mechanism: Mechanism
    #: Reference fields over the preset's (a dict), or a Reference: each joint's sinusoid.
    reference: Reference
    #: ReferenceRanges (a dict): draw a new reference every reset.
    reference_ranges: ReferenceRanges | None = None
    #: Draw a new arm and its reference at every reset (draw_episode_arm), each pair valid with its
    #: own ``auto`` force limit: {field: [lo, hi]} of Mechanism, sensor or PD gain fields, a
    #: named set ("course", "envelope", "real_arm") or a list of these
    #: (tendon2r_gym.task.arms.MechanismRanges).
    mechanism_ranges: MechanismRanges | None = None
    #: The optional observation entries (the Observation Space table): any of ``error_rate``,
    #: ``feedforward``, ``force_limit`` and ``arm`` (tendon2r_gym.task.observation.OBSERVABLE).
    observe: tuple[str, ...] = ()
    #: The ranges the ``arm`` slice is normalized over, if not mechanism_ranges: one fixed arm
    #: seen as a generalist saw its training arms (fine-tuning a generalist on one arm).
    arm_feature_ranges: MechanismRanges | None = None
    #: Scale the reference's amplitudes down to the arm's workspace (with a warning) instead
    #: of raising.
    fit_to_workspace: bool = False
    #: The control period (s), an integer multiple of the mechanism's sim_dt.
    ctrl_dt: float = 0.001
    #: What the action commands: "tension" (one command per tendon motor) or "joint_torque"
    #: (one per joint, distributed over the tendons as PD's are).
    action_mode: str = "tension"
    #: The time constant (s) of a first-order low-pass filter on the applied command (0: none).
    action_filter_tau: float = 0.0
    #: Seconds per episode.
    episode_duration: float = 2.0
    #: The reward terms' weights (the Rewards table); a term left out keeps its default.
    reward_scales: Mapping[str, float] = field(default_factory=lambda: dict(REWARD_SCALES))
    #: The tracking reward's form: "multiscale", "log" (both bounded) or "quadratic".
    tracking_form: str = "multiscale"
    #: The error scale (deg) of the "multiscale" and "log" tracking forms.
    tracking_sigma_deg: float = 1.0
    #: How far ahead (s) the ``tracking_rate`` reward term looks: e + tracking_horizon de.
    tracking_horizon: float = 0.05
    #: The initial state's uniform noise about the reference (rad, rad/s).
    reset_noise_scale: float = 0.001
    #: The number of future reference samples observed.
    preview_steps: int = 3
    #: The spacing (s) of the future reference samples.
    preview_dt: float = 0.01
    #: What error_log and error_rate_log log-scale: "rad", the error and its rate; "action",
    #: the normalized joint torques that close the error and cancel its rate on the episode's
    #: arm (rate_to_action), alike on every arm.
    error_units: str = "rad"
    #: The std of the Gaussian noise on each measured joint angle (rad) and speed (rad/s)
    #: (tendon2r_gym.simulation.realism.Sensors).
    observation_noise: tuple[float, float] = (0.0, 0.0)
    #: The measurements' age (s), a multiple of ctrl_dt.
    observation_delay: float = 0.0
    #: Gains of PD, CT and a residual's PD on this arm (tendon2r_gym.task.gains.Gains fields
    #: over data/pd.yaml; None: data/pd.yaml); ``tendon2r-tune-pd`` finds them.
    pd_gains: Gains | None = None
    #: What inverse dynamics of the reference (or of the worst corner of reference_ranges)
    #: needs of this arm, and its control authority (tendon2r_gym.task.needs.Needs); computed,
    #: not an argument.
    needs: Needs = field(default=None, compare=False, repr=False)  # type: ignore[assignment]
    #: The mechanism as given (max_tendon_force possibly "auto"): what arms are drawn over.
    base_mechanism: Mechanism | None = field(default=None, compare=False, repr=False)

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def make(cls, preset: str | os.PathLike = "default", **overrides: Any) -> EnvConfig:
        """Returns the config of a preset name or experiment-file path with ``overrides``."""
        allowed = arguments()
        # An older experiment file or record may hold the flags that ``observe`` replaced.
        base = observation.from_flags(load_preset(preset, [*allowed, *observation.FLAGS]))
        overrides = observation.from_flags(overrides, base.get("observe", ()))
        check_keys("Tendon2R", overrides, allowed)
        return cls.from_kwargs(merge_env_kwargs(base, overrides))

    @classmethod
    def from_kwargs(cls, kwargs: Mapping[str, Any]) -> EnvConfig:
        """Validates and resolves merged keyword arguments (sections may be dicts)."""
        kwargs = observation.from_flags(kwargs)
        check_keys("Tendon2R", kwargs, arguments())
        mech = kwargs.pop("mechanism", None)
        if not isinstance(mech, Mechanism):
            given = mapping("mechanism", mech)
            mech = Mechanism.from_dict(given)
            ctrl_dt = kwargs.get("ctrl_dt", cls.__dataclass_fields__["ctrl_dt"].default)
            if "sim_dt" not in given and is_number(ctrl_dt) and 0 < ctrl_dt <= 0.1:
                # left out: a step the integrator keeps stable (a bad ctrl_dt: refused below)
                mech = mech.replace(sim_dt=stable_sim_dt(mech, float(ctrl_dt), MAX_SUBSTEPS))
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
        # at most MAX_SUBSTEPS physics steps per control step
        set_("ctrl_dt", number("ctrl_dt", self.ctrl_dt, sim_dt, min(0.1, MAX_SUBSTEPS * sim_dt)))
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
        set_("tracking_horizon", number("tracking_horizon", self.tracking_horizon, 0.0, 10.0))
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
        set_("observe", subset("observe", self.observe, observation.OBSERVABLE))
        choice("error_units", self.error_units, ERROR_UNITS)
        if "arm" in self.observe and self.feature_ranges is None:
            raise invalid(
                "observe", list(self.observe),
                "a list without 'arm' unless mechanism_ranges or arm_feature_ranges is set",
            )  # fmt: skip
        if self.arm_feature_ranges is not None and "arm" not in self.observe:
            raise invalid(
                "arm_feature_ranges",
                self.arm_feature_ranges.to_dict(),
                "None unless observe lists 'arm'",
            )
        if self.base_mechanism is None:
            set_("base_mechanism", self.mechanism)
        self._check_reference()
        self._size_force_limit()
        if self.mechanism_ranges is not None:  # raises now if no valid arm can be drawn
            draw_episode_arm(self, np.random.default_rng(0))

    def _check_reference(self) -> None:
        ref = checked_reference(
            self.reference,
            self.reference_ranges,
            self.mechanism,
            self.ctrl_dt,
            self.fit_to_workspace,
        )
        object.__setattr__(self, "reference", ref)

    def _size_force_limit(self) -> None:
        refs = [self.reference]
        if self.reference_ranges is not None:
            refs += self.reference_ranges.corners()
        # A slow or constant reference needs almost no force, but feedback still does: "auto"
        # never falls below the need of AUTO_FLOOR's motion about the same bias (last entry).
        refs.append(Reference(bias_deg=self.reference.bias_deg, **AUTO_FLOOR))
        need, floor_need = force_needs(self.mechanism, tuple(refs))
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
        arm = Needs.of(self.mechanism, tuple(refs), self.ctrl_dt)
        object.__setattr__(self, "needs", arm)
        if not np.all(np.isfinite(arm.rate_to_action)):  # a joint no tendon spans
            if self.error_units == "action":
                raise invalid(
                    "error_units", self.error_units, "'rad' on an arm with a joint no tendon spans"
                )
            if "feedforward" in self.observe:
                raise invalid(
                    "observe",
                    list(self.observe),
                    "a list without 'feedforward' on an arm with a joint no tendon spans",
                )

    # -- derived quantities ------------------------------------------------------------------
    @property
    def observation(self) -> observation.Layout:
        """Returns the observation's layout (tendon2r_gym.task.observation.Layout): the
        optional entries ``observe`` lists, and the arm slice's fields if it lists ``arm``."""
        optional = tuple(e[0] for e, name in observation.OPTIONAL.items() if name in self.observe)
        arm = self.feature_ranges.names if "arm" in self.observe else ()
        return observation.Layout(self.preview_steps, self.n_actions, optional, arm)

    @property
    def feature_ranges(self) -> MechanismRanges | None:
        """Returns the ranges the observation's ``arm`` slice is normalized over:
        arm_feature_ranges, else mechanism_ranges (None without either)."""
        return self.arm_feature_ranges or self.mechanism_ranges

    @property
    def n_actions(self) -> int:
        """Returns the action's length: one per tendon ("tension") or per joint
        ("joint_torque")."""
        return self.mechanism.n_tendons if self.action_mode == "tension" else 2

    def to_dict(self) -> dict[str, Any]:
        """Returns the config as plain YAML-friendly env kwargs (an experiment file)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            if f.name in COMPUTED:
                continue
            value = getattr(self, f.name)
            out[f.name] = value.to_dict() if hasattr(value, "to_dict") else value
        out["observation_noise"] = list(self.observation_noise)
        out["observe"] = list(self.observe)
        if self.mechanism_ranges is not None:  # arms are drawn over the mechanism as given
            out["mechanism"] = self.base_mechanism.to_dict()
        return out


#: EnvConfig fields that are computed, not arguments.
COMPUTED = ("needs", "base_mechanism")


def arguments() -> list[str]:
    """Returns the keyword arguments an experiment file (or gym.make) may give."""
    return [f.name for f in dataclasses.fields(EnvConfig) if f.name not in COMPUTED]


assert set(SECTIONS) <= set(arguments())


def resolve(
    env: EnvConfig | Mapping[str, Any] | str | os.PathLike = "default",
    **overrides: Any,
) -> EnvConfig:
    """Returns the EnvConfig of ``env``: itself if it is one (then no ``overrides``), else the
    config of env kwargs (a mapping, ``preset`` among them) or of a preset name or
    experiment-file path, with ``overrides``.  The one door from kwargs to a config: the envs'
    keyword path and every library function given env kwargs go through it."""
    if isinstance(env, EnvConfig):
        if overrides:
            raise invalid(
                "preset",
                f"an EnvConfig beside {sorted(overrides)}",
                "an EnvConfig alone (it is resolved: give no env kwarg beside it; an id with "
                "defaults of its own, such as Tendon2R-v2, adds them: make Tendon2REnv(config))",
            )
        return env
    if isinstance(env, Mapping):
        overrides = {**env, **overrides}
        env = overrides.pop("preset", "default")
    return EnvConfig.make(env, **overrides)

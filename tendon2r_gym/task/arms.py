"""Random arms: the course's parameter ranges, a seeded sampler of valid arms, and the ranges
that the envs draw a new arm from at every reset (``mechanism_ranges``).

The students' arms span pulley diameters of 0.011 to 0.047 m, links of 0.03 to 0.095 m,
amplitudes up to 53 deg, biases up to 44 deg and frequencies up to 3.9 Hz (NOTES.md).
`draw_arm` draws uniformly in these ranges and keeps only arms that are valid:

- the mechanism passes ``Mechanism``'s checks (pulleys that fit on link c and clear the wall,
  a link radius below the pulleys);
- the reference's biases fit the workspace, and its amplitudes are fitted to it (the course's
  rule: decrease the amplitude);
- the force limit is ``auto``: sized from the arm's own inverse dynamics.

Each draw is an experiment file's content (``mechanism``, ``reference``,
``fit_to_workspace``), so ``tendon2r-benchmark --env-config`` runs it as a user's arm.

`MechanismRanges` is the one per-episode randomization of the arm, shared by the random
geometry of "One policy for every arm" and the random cables and motors of "Real tendons":
uniform ranges of Mechanism fields, drawn by `draw_episode_arm` at every reset, and the
arm's features normalized over them (the optional ``arm`` slice of the observation).  It
also draws the motor's dead time and what the sensors measure (noise and delay), so that one
mechanism randomizes every effect of a real arm.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import numpy as np

from tendon2r_gym.simulation.mechanism import (
    LIMITS,
    MODEL_ERROR_LIMITS,
    MODEL_ERRORS,
    REALISM_LIMITS,
    Mechanism,
)
from tendon2r_gym.task.gains import gains_of, tuned_bandwidth
from tendon2r_gym.task.reference import Reference, ReferenceRanges
from tendon2r_gym.validation import invalid, mapping, pair

Range = tuple[float, float]


@dataclass(frozen=True)
class ArmRanges:
    """Uniform ranges [lo, hi] of a random arm (defaults: the course's)."""

    R1: Range = (0.011, 0.047)  # pulley diameter at joint A (m)
    R2: Range = (0.011, 0.047)  # pulley diameter at joint B (m)
    a: Range = (0.03, 0.095)  # m
    b: Range = (0.03, 0.095)
    c: Range = (0.03, 0.095)
    amp_deg: Range = (5.0, 53.0)  # per joint
    bias_deg: Range = (-44.0, 44.0)
    freq_hz: Range = (0.5, 3.9)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            lo, hi = pair(f"arm_ranges.{f.name}", getattr(self, f.name))
            if lo > hi:
                raise invalid(f"arm_ranges.{f.name}", getattr(self, f.name), "[lo, hi], lo <= hi")
            object.__setattr__(self, f.name, (lo, hi))


COURSE = ArmRanges()
#: The envelope of arms that users bring, wider than any course: what the generalists train on
#: and accept (research/results/envelope.md surveys it).
ENVELOPE = ArmRanges(
    R1=(0.008, 0.06), R2=(0.008, 0.06), a=(0.025, 0.12), b=(0.025, 0.12), c=(0.025, 0.12),
    amp_deg=(0.0, 60.0), bias_deg=(-50.0, 50.0), freq_hz=(0.3, 5.0),
)  # fmt: skip
#: The named ArmRanges that ``mechanism_ranges`` (their geometry) and ``reference_ranges``
#: (their amplitudes, frequencies and biases) read.
NAMED_RANGES = {"course": COURSE, "envelope": ENVELOPE}
#: Draws tried before giving up (about 1 in 3 course draws is a valid arm).
MAX_TRIES = 1000


def draw_arm(
    rng: np.random.Generator,
    ranges: ArmRanges = COURSE,
    base: Mechanism | None = None,
) -> dict[str, Any]:
    """Returns a valid random arm as experiment-file content: ``mechanism`` (``base``'s fields,
    default Mechanism(), with the drawn geometry and ``max_tendon_force: auto``), ``reference``
    and ``fit_to_workspace: true``.  Raises if no valid arm is found in MAX_TRIES draws."""
    base = base or Mechanism()
    u = lambda r: float(rng.uniform(*r))  # noqa: E731
    for _ in range(MAX_TRIES):
        geometry = {k: round(u(getattr(ranges, k)), 4) for k in ("R1", "R2", "a", "b", "c")}
        try:
            mech = base.replace(**geometry, max_tendon_force="auto")
        except ValueError:
            continue
        ref = Reference(
            amp_deg=(round(u(ranges.amp_deg), 2), round(u(ranges.amp_deg), 2)),
            bias_deg=(round(u(ranges.bias_deg), 2), round(u(ranges.bias_deg), 2)),
            freq_hz=(round(u(ranges.freq_hz), 2), round(u(ranges.freq_hz), 2)),
        )
        try:
            ref.fit_to_workspace(mech, warn=False)  # its bias must fit at zero amplitude
        except ValueError:
            continue
        return {
            "mechanism": mech.to_dict(),
            "reference": ref.to_dict(),
            "fit_to_workspace": True,
        }
    raise invalid("arm_ranges", ranges, f"ranges where a valid arm is found in {MAX_TRIES} draws")


def draw_arms(seed: int, n: int, ranges: ArmRanges = COURSE, **kw: Any) -> list[dict[str, Any]]:
    """Returns ``n`` valid random arms drawn with ``seed`` (the same seed, the same arms)."""
    rng = np.random.default_rng(seed)
    return [draw_arm(rng, ranges, **kw) for _ in range(n)]


#: The geometry fields of an arm (the course's ranges: ArmRanges).
GEOMETRY = ("R1", "R2", "a", "b", "c")
#: Mechanism fields that ``mechanism_ranges`` may draw: numbers that change the compiled model's
#: parameters but not its layout (the routing, pull_only, the integrator and the joint range
#: stay the nominal arm's), and the motor's dead time (whole control steps, not a model
#: parameter).
RANDOMIZABLE = (
    *LIMITS,
    "joint_damping",
    "tendon_stiffness",
    "tendon_damping",
    "pretension",
    "tendon_elasticity",
    "motor_mass",
    "tendon_friction",
    "motor_tau",
    "motor_delay",
    *MODEL_ERRORS,
)
#: What the sensors measure, drawn per episode too: EnvConfig's ``observation_delay`` (s) and
#: the two entries of its ``observation_noise`` (angle std, rad; speed std, rad/s).
SENSING = ("observation_delay", "observation_noise_angle", "observation_noise_speed")
#: The gains of the env's PD (and of the PD inside a residual), drawn per episode too: Gains'
#: ``bandwidth_hz`` and ``max_delay_phase`` (tendon2r_gym.task.gains).  A residual that sees them
#: (observe ``arm``) learns on any PD, and runs on the one ``tendon2r-tune-pd`` finds for an arm.
CONTROLLER = ("pd_bandwidth_hz", "pd_max_delay_phase")
#: The unit of each CONTROLLER field.
GAIN_UNITS = {"pd_bandwidth_hz": "Hz", "pd_max_delay_phase": "rad"}
#: ``mechanism_ranges`` key of the phase at which PD's bandwidth is drawn as tuned for each
#: drawn arm (MechanismRanges.tuned_phase, tendon2r_gym.task.gains.tuned_bandwidth).
TUNED_PHASE = "pd_tuned_phase"
#: Every field ``mechanism_ranges`` may draw.
DRAWABLE = (*RANDOMIZABLE, *SENSING, *CONTROLLER)
#: Drawn delays are rounded to whole control steps (`draw_episode_arm`).
DELAYS = ("motor_delay", "observation_delay")
#: Fields whose zero and non-zero values compile to models of different layouts (spools,
#: friction tendons, actuator states): their range must not straddle 0.
LAYOUT_FIELDS = ("tendon_elasticity", "tendon_friction", "motor_tau")
#: ``mechanism_ranges: real_arm``: the cables, motors and sensors of the real-arm study's
#: perturbed arms (tendon2r_gym.simulation.realism.PERTURBATIONS).
REAL_ARM_NAME = "real_arm"


def drawn_value(arm: Any, name: str) -> float | None:
    """Returns the value of a DRAWABLE field ``name`` in the arm config ``arm`` (an
    EnvConfig): a mechanism field, one of SENSING, or one of CONTROLLER (None: a
    max_delay_phase that is not set)."""
    if name in CONTROLLER:
        return getattr(gains_of(arm.pd_gains), gain_field(name))
    if name == "observation_delay":
        return arm.observation_delay
    if name in SENSING:
        return arm.observation_noise[SENSING.index(name) - 1]
    return getattr(arm.mechanism, name)


def gain_field(name: str) -> str:
    """Returns the Gains field of a CONTROLLER field (``pd_bandwidth_hz``: bandwidth_hz)."""
    return name.removeprefix("pd_")


@dataclass(frozen=True)
class MechanismRanges:
    """Uniform ranges [lo, hi] of DRAWABLE fields (Mechanism fields: RANDOMIZABLE; sensors:
    SENSING; PD's gains: CONTROLLER), drawn independently in this order at every reset; every
    other field keeps the nominal arm's value.  From YAML: a mapping ``{field: [lo, hi]}``,
    ``course`` or ``envelope`` (NAMED_RANGES' geometry, R1 R2 a b c) or ``real_arm`` (cables,
    motors and sensors: tendon2r_gym.simulation.realism.PERTURBATIONS).

    ``pd_tuned_phase: [lo, hi]`` (``tuned_phase``, with ``pd_bandwidth_hz`` drawn) ties PD's
    bandwidth to the drawn arm, as ``tendon2r-tune-pd`` would tune it there: the bandwidth
    at which the arm's true loop delay takes a phase drawn from [lo, hi]
    (tendon2r_gym.task.gains.tuned_bandwidth), clipped to the ``pd_bandwidth_hz`` range.  It is a
    rule of the draw, not an arm feature: the bandwidth is what is observed."""

    ranges: tuple[tuple[str, tuple[float, float]], ...]
    tuned_phase: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not self.ranges:
            raise invalid("mechanism_ranges", {}, f"at least one of {DRAWABLE}")
        out = []
        for name, value in self.ranges:
            field = f"mechanism_ranges.{name}"
            if name not in DRAWABLE:
                raise invalid(
                    "mechanism_ranges", name, f"fields among {DRAWABLE}, and {TUNED_PHASE}"
                )
            limits = {**LIMITS, **REALISM_LIMITS, **MODEL_ERROR_LIMITS, "observation_delay": 1.0}
            hi_limit = limits.get(name, 1e6)
            lo, hi = pair(field, value, 0.0, hi_limit)
            if lo > hi:
                raise invalid(field, value, f"[lo, hi] with 0 <= lo <= hi <= {hi_limit:g}")
            if name in CONTROLLER and lo <= 0.0:
                raise invalid(field, value, f"[lo, hi] with 0 < lo <= hi <= {hi_limit:g}")
            if name in LAYOUT_FIELDS and lo == 0.0 < hi:
                raise invalid(
                    field,
                    value,
                    "[0, 0] or 0 < lo <= hi: a zero and a non-zero value compile to models of "
                    "different layouts, which one vector env cannot step together",
                )
            out.append((name, (lo, hi)))
        object.__setattr__(self, "ranges", tuple(out))
        if self.tuned_phase is not None:
            field = f"mechanism_ranges.{TUNED_PHASE}"
            lo, hi = pair(field, self.tuned_phase, 0.0, np.pi / 2)
            if not 0.0 < lo <= hi:
                raise invalid(field, self.tuned_phase, "[lo, hi] with 0 < lo <= hi <= pi / 2")
            if "pd_bandwidth_hz" not in self.names:
                raise invalid(
                    field,
                    self.tuned_phase,
                    "a range only beside pd_bandwidth_hz's (the bandwidths it may give)",
                )
            object.__setattr__(self, "tuned_phase", (lo, hi))

    @classmethod
    def from_value(cls, value: Any) -> MechanismRanges:
        """Reads ``course``, ``envelope``, ``real_arm``, a mapping ``{field: [lo, hi]}``, or a
        list of these merged in order (a later range of a field replaces an earlier one), e.g.
        ``[real_arm, {pd_bandwidth_hz: [12, 47]}]``."""
        if isinstance(value, np.ndarray):  # an array of names is a list of them
            value = value.tolist()
        if isinstance(value, list | tuple) and not isinstance(value, str):
            if not value:
                raise invalid("mechanism_ranges", value, f"at least one of {DRAWABLE}")
            merged: dict[str, tuple[float, float]] = {}
            phase = None
            for part in value:
                if isinstance(part, list | tuple):
                    raise invalid("mechanism_ranges", value, "a list of names and mappings")
                ranges = cls.from_value(part)
                merged.update(ranges.ranges)
                phase = ranges.tuned_phase or phase
            return cls(tuple(merged.items()), phase)
        if isinstance(value, str) and value in NAMED_RANGES:
            return cls(tuple((k, getattr(NAMED_RANGES[value], k)) for k in GEOMETRY))
        if value == REAL_ARM_NAME:
            from tendon2r_gym.simulation.realism import PERTURBATIONS

            return cls(tuple(PERTURBATIONS.items()))
        if isinstance(value, MechanismRanges):
            return value
        values = dict(mapping("mechanism_ranges", value))
        phase = values.pop(TUNED_PHASE, None)
        return cls(tuple((str(k), v) for k, v in values.items()), phase)

    def to_dict(self) -> dict[str, list[float]]:
        """Returns the ranges as plain YAML-friendly lists (what from_value reads)."""
        out = {name: list(r) for name, r in self.ranges}
        if self.tuned_phase is not None:
            out[TUNED_PHASE] = list(self.tuned_phase)
        return out

    @property
    def names(self) -> tuple[str, ...]:
        """Returns the drawn fields, in drawing order (and the order of the arm features)."""
        return tuple(name for name, _ in self.ranges)

    @property
    def draws_gains(self) -> bool:
        """Returns whether PD's gains are drawn (a CONTROLLER field)."""
        return any(name in CONTROLLER for name in self.names)

    def high(self, name: str) -> float:
        """Returns the upper end of the range of ``name`` (0 if it is not drawn)."""
        return dict(self.ranges).get(name, (0.0, 0.0))[1]

    def sample(self, rng: np.random.Generator) -> dict[str, float]:
        """Returns a uniform draw of every field, in drawing order, then of the tuned phase
        if set (`draw_episode_arm` makes it an arm and checks it)."""
        out = {name: float(rng.uniform(lo, hi)) for name, (lo, hi) in self.ranges}
        if self.tuned_phase is not None:
            out[TUNED_PHASE] = float(rng.uniform(*self.tuned_phase))
        return out

    def features(self, arm: Any) -> list[float]:
        """Returns the drawn fields of the arm config ``arm`` normalized over their ranges to
        [-1, 1] (0 for a range of one value): the ``arm`` slice of the observation.  A
        max_delay_phase that is not set (no cap: the env's own config, before its first
        draw) counts as the top of its range."""
        out = []
        for name, (lo, hi) in self.ranges:
            value = drawn_value(arm, name)
            value = hi if value is None else value
            out.append(0.0 if hi == lo else 2.0 * (value - lo) / (hi - lo) - 1.0)
        return out

    def violations(self, arm: Any) -> list[str]:
        """Returns the fields of the arm config ``arm`` outside the ranges (empty if it is
        inside)."""
        inside = lambda v, lo, hi: v is not None and lo - 1e-12 <= v <= hi + 1e-12  # noqa: E731
        return [
            f"{name} = {drawn_value(arm, name)!r} outside [{lo:g}, {hi:g}]"
            for name, (lo, hi) in self.ranges
            if not inside(drawn_value(arm, name), lo, hi)
        ]


def reference_ranges(value: Any) -> ReferenceRanges:
    """Reads ``reference_ranges``: ``course`` or ``envelope`` (the amplitudes, frequencies and
    biases of NAMED_RANGES' ArmRanges, both joints, any phase) or a mapping of ReferenceRanges
    fields."""
    if isinstance(value, str) and value in NAMED_RANGES:
        arm = NAMED_RANGES[value]
        return ReferenceRanges(
            amp_deg=(arm.amp_deg,) * 2, freq_hz=(arm.freq_hz,) * 2, bias_deg=(arm.bias_deg,) * 2
        )
    return ReferenceRanges.from_dict(mapping("reference_ranges", value))


# -- an episode's arm ---------------------------------------------------------------------------
class ArmConfig(Protocol):
    """What drawing an episode's arm reads of an env config (an EnvConfig: tendon2r_gym.envs
    is a later layer, so it is named by the fields it must have)."""

    @property
    def mechanism(self) -> Mechanism: ...
    @property
    def base_mechanism(self) -> Mechanism | None: ...
    @property
    def reference(self) -> Reference: ...
    @property
    def reference_ranges(self) -> ReferenceRanges | None: ...
    @property
    def mechanism_ranges(self) -> MechanismRanges | None: ...
    @property
    def observe(self) -> tuple[str, ...]: ...
    @property
    def ctrl_dt(self) -> float: ...
    @property
    def observation_noise(self) -> tuple[float, float]: ...
    @property
    def observation_delay(self) -> float: ...
    @property
    def pd_gains(self) -> Any: ...


C = TypeVar("C", bound=ArmConfig)


def draw_episode_arm(config: C, rng: np.random.Generator, reference: Reference | None = None) -> C:
    """Returns the config of a random arm of ``config.mechanism_ranges`` (``config`` itself
    without them) and its episode's reference (``reference``, else a draw of reference_ranges
    on that arm, else the nominal one): `arm_config`.  Draws again until the pair is valid (a
    Mechanism, stable, the reference's bias in its workspace); raises after MAX_TRIES draws."""
    ranges = config.mechanism_ranges
    if ranges is None:
        return config
    for _ in range(MAX_TRIES):
        drawn = ranges.sample(rng)
        for k in DELAYS:  # whole control steps
            if k in drawn:
                drawn[k] = round(drawn[k] / config.ctrl_dt) * config.ctrl_dt
        sensed = zip(SENSING[1:], config.observation_noise, strict=True)
        noise = [drawn.pop(k, v) for k, v in sensed]
        delay = drawn.pop("observation_delay", config.observation_delay)
        gains = {gain_field(k): drawn.pop(k) for k in CONTROLLER if k in drawn}
        phase = drawn.pop(TUNED_PHASE, None)
        try:
            mech = config.base_mechanism.replace(**drawn)
            if phase is not None:  # the bandwidth a tuning would pick on this arm
                f = tuned_bandwidth(mech, delay, config.ctrl_dt, phase)
                lo, hi = dict(ranges.ranges)["pd_bandwidth_hz"]
                gains["bandwidth_hz"] = min(max(f, lo), hi)
            ref = reference
            if ref is None and config.reference_ranges is not None:
                ref = config.reference_ranges.sample(rng, mech)
            drawn_env = {"observation_noise": tuple(noise), "observation_delay": delay}
            if gains:
                drawn_env["pd_gains"] = dataclasses.replace(gains_of(config.pd_gains), **gains)
            return arm_config(config, mech, ref, **drawn_env)
        except ValueError:
            continue
    raise invalid(
        "mechanism_ranges",
        ranges.to_dict(),
        f"ranges where a valid arm (with this reference) is found in {MAX_TRIES} draws",
    )


def arm_config(
    config: C, mechanism: Mechanism, reference: Reference | None = None, **drawn_env: Any
) -> C:
    """Returns the config of one arm and one reference (default: ``config``'s nominal one), as
    a user's experiment file gives them: nothing drawn, the reference's amplitudes fitted to
    the arm's workspace (quietly), and an ``auto`` force limit sized for this arm and this
    reference; ``drawn_env``: its observation_noise, observation_delay and pd_gains, if drawn.
    An env with this config runs the randomized env's episode exactly."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return dataclasses.replace(  # type: ignore[type-var]
            config,
            mechanism=mechanism,
            base_mechanism=None,
            reference=config.reference if reference is None else reference,
            reference_ranges=None,
            mechanism_ranges=None,
            observe=tuple(x for x in config.observe if x != "arm"),
            arm_feature_ranges=None,
            fit_to_workspace=True,
            **drawn_env,
        )


def drawn_high(config: ArmConfig, name: str, value: float) -> float:
    """Returns the largest value of field ``name`` an episode of ``config`` can have: ``value``
    (the config's), or the top of its range if mechanism_ranges draws it."""
    ranges = config.mechanism_ranges
    return value if ranges is None or name not in ranges.names else ranges.high(name)

"""Mechanism parameters: a frozen, validated description of the tendon-driven 2R arm.

Geometry conventions (docs/mechanism.md):
- ``a``: fixed base link, wall (x = 0) to joint A.  ``c``: joint A to joint B.  ``b``: joint B to
  the effector.  The 2R chain has l1 = c and l2 = b.
- ``R1``, ``R2`` are pulley **diameters**; the pulley radii are ``R1 / 2`` and ``R2 / 2``.
- The arm moves in the x-z plane.  Both hinges turn about -y, so a positive joint angle lifts the
  arm (+z):  x = a + c cos q1 + b cos(q1 + q2),  z = c sin q1 + b sin(q1 + q2).
- A tendon passes each pulley on side +1 (over the top, +z in the link frame) or -1 (under).
  Side 0 on pulley 2 means the tendon does not reach pulley 2: it ends on link c and spans
  joint A only.  Its moment arms are dL/dq = (-s1 r1, -s2 r2).
- ``pull_only``: the motors only pull, as real tendons do (a pushed tendon goes slack).  Two
  pull-only tendons cannot reverse a joint torque; n + 1 tendons whose moment arms positively
  span the torque plane can (tendon2r_gym.simulation.routing.positive_span).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from tendon2r_gym.simulation import routing as routings
from tendon2r_gym.simulation.routing import Sides
from tendon2r_gym.validation import boolean, check_keys, invalid, is_number, mapping, number

INTEGRATORS = ("Euler", "RK4", "implicit", "implicitfast")
#: The smallest physics time step (s): a microsecond, a thousand steps per millisecond.
MIN_SIM_DT = 1e-6

#: Upper bounds of the size and mass fields: a desk-top arm (the course's links are 0.03 to
#: 0.095 m, its pulleys 0.011 to 0.047 m), with a wide margin; a 1 km link diverges at once.
LIMITS = {
    "R1": 1.0,  # m
    "R2": 1.0,
    "a": 1.0,
    "b": 1.0,
    "c": 1.0,
    "density": 1e5,  # kg/m^3 (osmium: 2.3e4)
    "link_radius": 0.1,  # m
    "pulley_thickness": 0.1,
}
#: Upper bounds of the realism fields (tendon2r_gym.simulation.realism), far above any desk-top arm.
REALISM_LIMITS = {
    "tendon_elasticity": 1e7,  # N/m
    "tendon_friction": 1e3,  # N
    "motor_tau": 1.0,  # s
    "motor_delay": 1.0,  # s
}
#: The nominal model's errors (tendon2r_gym.simulation.realism), each at its exact value: what the
#: real arm
#: has and the controllers' nominal model (`Mechanism.ideal`) does not.
MODEL_ERRORS = {"density_scale": 1.0, "extra_joint_damping": 0.0}
#: Upper bounds of the model errors: a 100x heavier arm, damping far above any bearing's.
MODEL_ERROR_LIMITS = {"density_scale": 100.0, "extra_joint_damping": 1.0}
#: ``max_tendon_force: auto`` sizes the force limit from the reference (Tendon2REnv does it).
AUTO = "auto"


def _fail(name: str, value: Any, allowed: str) -> ValueError:
    return invalid(f"Mechanism.{name}", value, allowed)


@dataclass(frozen=True)
class Mechanism:
    """Parameters of the tendon-driven 2R arm.  All lengths in m, forces in N, times in s."""

    # Geometry.
    R1: float = 0.014  # pulley diameter at joint A (m)
    R2: float = 0.022  # pulley diameter at joint B (m)
    a: float = 0.052  # base link, wall to joint A (m)
    b: float = 0.073  # link from joint B to the effector (m)
    c: float = 0.094  # link from joint A to joint B (m)
    # Routing: a name of tendon2r_gym.simulation.routing.ROUTINGS or sides ((s11, s12), (s21, s22),
    # ...).
    routing: str | Sides = "asymmetric"
    # Actuation: push-pull, an action of +-1 is +-max_tendon_force on the tendon; pull-only,
    # an action in [-1, 1] is a tension in [0, max_tendon_force].  "auto": the env sets the
    # limit from the peak force that inverse dynamics of its reference needs, times
    # FORCE_HEADROOM (tendon2r_gym.task.needs).
    max_tendon_force: float | str = AUTO  # (N)
    pull_only: bool = False
    # The least tension that model-based controllers keep in every pull-only tendon (N).
    pretension: float = 0.02
    # Mass and joints.
    density: float = 1000.0  # of links and pulleys (kg/m^3)
    link_radius: float = 0.002  # capsule radius of the links (m)
    pulley_thickness: float = 0.002  # (m)
    joint_range_deg: tuple[float, float] = (-90.0, 90.0)  # both joints (deg)
    joint_damping: float = 0.0  # (N m s / rad)
    # A spring and a damper along each tendon's path, in parallel with the motor (a spring
    # on the joints, at rest at q = 0); series elasticity is tendon_elasticity.
    tendon_stiffness: float = 0.0  # (N / m)
    tendon_damping: float = 0.0  # (N s / m); with tendon_elasticity, the cable's own damping
    # Real tendons and motors (tendon2r_gym.simulation.realism; every one off by default: an
    # inextensible,
    # frictionless cable and a motor that acts at once).  Typical small servo-and-cable arm:
    # configs/examples/real_arm.yaml and the real_arm preset.
    tendon_elasticity: float = 0.0  # series stiffness of each cable, EA / length (N / m)
    motor_mass: float = 0.05  # motor and spool inertia felt along the cable (kg)
    tendon_friction: float = 0.0  # dry friction of each cable sliding on its pulleys (N)
    motor_tau: float = 0.0  # time constant of the motor force's first-order lag (s)
    motor_delay: float = 0.0  # dead time between a command and the motor (s), whole ctrl_dt
    # The nominal model's errors: the real links' and pulleys' density over ``density``, and
    # joint damping (N m s / rad, both joints) over ``joint_damping``; the controllers' model
    # keeps the nominal values (ideal()).
    density_scale: float = 1.0
    extra_joint_damping: float = 0.0
    # Simulation.
    # RK4 at 1 ms stays within 4e-4 deg of RK4 at 2e-5 s on both presets under PD, at 1/8 the
    # cost of the reports' RK4 at 1e-4 s (research/results/timestep_study.md).
    # Left out of an experiment (EnvConfig.from_kwargs): 1 ms if the integrator keeps it
    # stable for the arm, else the largest ctrl_dt / k that it does (stable_sim_dt).
    sim_dt: float = 1e-3  # physics time step (s)
    integrator: str = "RK4"

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        for name, hi in LIMITS.items():
            set_(name, number(f"Mechanism.{name}", getattr(self, name), 0.0, hi, lo_open=True))
        if not (isinstance(self.max_tendon_force, str) and self.max_tendon_force == AUTO):
            set_(
                "max_tendon_force",
                _positive_or_auto("max_tendon_force", self.max_tendon_force),
            )
        set_("pull_only", boolean("Mechanism.pull_only", self.pull_only))
        for name in ("joint_damping", "tendon_stiffness", "tendon_damping", "pretension"):
            set_(name, number(f"Mechanism.{name}", getattr(self, name), 0.0))
        for name, hi in REALISM_LIMITS.items():
            set_(name, number(f"Mechanism.{name}", getattr(self, name), 0.0, hi))
        set_("motor_mass", number("Mechanism.motor_mass", self.motor_mass, 0.0, 1e3, lo_open=True))
        for name, hi in MODEL_ERROR_LIMITS.items():
            lo_open = MODEL_ERRORS[name] > 0  # a scale, not an offset
            set_(name, number(f"Mechanism.{name}", getattr(self, name), 0.0, hi, lo_open=lo_open))
        if self.tendon_elasticity > 0 and self.tendon_stiffness > 0:
            raise _fail(
                "tendon_stiffness",
                self.tendon_stiffness,
                "0 when tendon_elasticity > 0 (a series-elastic cable carries its own spring; "
                "tendon_stiffness is a spring in parallel with it)",
            )
        set_("sim_dt", number("Mechanism.sim_dt", self.sim_dt, MIN_SIM_DT, 0.01))
        r1, r2 = self.R1 / 2, self.R2 / 2
        if r1 >= self.a:
            raise _fail("R1", self.R1, f"R1/2 < a = {self.a} (pulley 1 must clear the wall)")
        if r1 + r2 >= self.c:
            raise _fail(
                "R2",
                self.R2,
                f"R1/2 + R2/2 < c = {self.c} (the pulleys must not overlap on link c, and a "
                "crossed belt needs room between them)",
            )
        if r2 >= self.b:
            raise _fail("R2", self.R2, f"R2/2 < b = {self.b} (pulley 2 must fit on link b)")
        if self.link_radius >= min(r1, r2):
            raise _fail(
                "link_radius", self.link_radius, f"< the smaller pulley radius {min(r1, r2)}"
            )
        if not isinstance(self.integrator, str) or self.integrator not in INTEGRATORS:
            raise _fail("integrator", self.integrator, f"one of {INTEGRATORS}")
        rng = self.joint_range_deg
        allowed = "(lo, hi) with -180 < lo < hi < 180 (deg)"
        if isinstance(rng, (str, bytes)) or not hasattr(rng, "__len__") or len(rng) != 2:
            raise _fail("joint_range_deg", rng, allowed)
        lo, hi = (number("Mechanism.joint_range_deg", v, -180, 180) for v in rng)
        if not -180 < lo < hi < 180:
            raise _fail("joint_range_deg", rng, allowed)
        set_("joint_range_deg", (lo, hi))
        set_("routing", _normalize_routing(self.routing))
        if self.pull_only:
            spans, why = routings.positive_span_of_sides(self.tendon_sides, self.r1, self.r2)
            if not spans:
                raise _fail(
                    "pull_only",
                    True,
                    f"False with routing {self.routing!r}: {why} (use routing 'n_plus_1')",
                )

    # -- construction ------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Mechanism:
        """Builds a Mechanism from a mapping with the same keys as the fields."""
        values = mapping("mechanism", values)
        check_keys("mechanism", values, [f.name for f in dataclasses.fields(cls)])
        return cls(**values)

    def replace(self, **changes: Any) -> Mechanism:
        """Returns a copy with the named fields changed (validated again)."""
        return Mechanism.from_dict({**self.to_dict(), **changes})

    def to_dict(self) -> dict[str, Any]:
        """Returns the fields as plain YAML-friendly values."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        out["joint_range_deg"] = list(self.joint_range_deg)
        if not isinstance(self.routing, str):
            out["routing"] = [list(s) for s in self.routing]
        return out

    # -- derived quantities ------------------------------------------------------------------
    @property
    def r1(self) -> float:
        """Returns the radius of pulley 1 (m)."""
        return self.R1 / 2

    @property
    def r2(self) -> float:
        """Returns the radius of pulley 2 (m)."""
        return self.R2 / 2

    @property
    def tendon_sides(self) -> Sides:
        """Returns ((s11, s12), (s21, s22), ...): the side each tendon takes on each pulley."""
        return routings.sides_of(self.routing)

    @property
    def n_tendons(self) -> int:
        """Returns the number of tendons (and motors)."""
        return len(self.tendon_sides)

    @property
    def elastic(self) -> bool:
        """Returns whether the cables stretch (tendon_elasticity > 0): each motor then drives a
        spool of mass ``motor_mass`` that pulls its cable, one extra degree of freedom each."""
        return self.tendon_elasticity > 0

    @property
    def realistic(self) -> bool:
        """Returns whether any realism field is on, or the nominal model has an error
        (tendon2r_gym.simulation.realism)."""
        return any(getattr(self, k) > 0 for k in REALISM_LIMITS) or any(
            getattr(self, k) != exact for k, exact in MODEL_ERRORS.items()
        )

    def ideal(self) -> Mechanism:
        """Returns the nominal mechanism: every realism field off, the model errors at their
        exact values (MODEL_ERRORS), ``motor_mass`` (which only elastic cables use) at its
        default, and no ``tendon_damping`` if the cables were elastic (it was theirs); the
        model that PD's and CT's distribution and inverse dynamics use, and what a trained
        policy's arm is checked against."""
        default_mass = Mechanism.__dataclass_fields__["motor_mass"].default
        if not self.realistic and self.motor_mass == default_mass:
            return self
        off = dict.fromkeys(REALISM_LIMITS, 0.0)
        if self.elastic:  # then tendon_damping is the cable's own damping
            off["tendon_damping"] = 0.0
        return self.replace(**off, **MODEL_ERRORS, motor_mass=default_mass)

    @property
    def true_density(self) -> float:
        """Returns the density (kg/m^3) of the simulated links and pulleys: ``density`` times
        ``density_scale``."""
        return self.density * self.density_scale

    @property
    def true_joint_damping(self) -> float:
        """Returns the simulated damping (N m s / rad) of each joint: ``joint_damping`` plus
        ``extra_joint_damping``."""
        return self.joint_damping + self.extra_joint_damping

    @property
    def rest_tension(self) -> float:
        """Returns the tension (N) each cable holds at rest: the pretension for pull-only
        tendons (a slack cable would have to be taken up first), else 0."""
        return self.pretension if self.pull_only else 0.0

    @property
    def command_map(self) -> tuple[float, float]:
        """Returns (gain, offset) of a tendon motor's normalized command u in [-1, 1]: its
        cable's tension is F (gain u + offset), F = max_tendon_force.  Pull-only motors pull
        F (u + 1) / 2, so u = -1 is slack; push-pull ones -F u (a positive command pushes).
        The one home of this map: the model's actuators, PD's distribution, the rest command
        and the effort term all read it."""
        return (0.5, 0.5) if self.pull_only else (-1.0, 0.0)

    @property
    def rest_ctrl(self) -> float:
        """Returns the normalized motor command whose tension is `rest_tension`: 0 for
        push-pull motors, 2 pretension / F - 1 for pull-only ones (F = max_tendon_force, once
        resolved from "auto")."""
        if not self.pull_only:
            return 0.0
        gain, offset = self.command_map
        return (self.rest_tension / self.max_tendon_force - offset) / gain

    @property
    def joint_range_rad(self) -> tuple[float, float]:
        """Returns the joint range (rad), the same for both joints."""
        lo, hi = self.joint_range_deg
        return math.radians(lo), math.radians(hi)

    @property
    def workspace_radii(self) -> tuple[float, float]:
        """Returns the inner and outer radius (m) of the workspace annulus about joint A."""
        return abs(self.c - self.b), self.c + self.b

    def forward_kinematics(self, q: np.ndarray) -> np.ndarray:
        """Returns the effector (x, z) in m for joint angles q (rad), shape (..., 2)."""
        q = np.asarray(q, dtype=float)
        q1, q12 = q[..., 0], q[..., 0] + q[..., 1]
        x = self.a + self.c * np.cos(q1) + self.b * np.cos(q12)
        z = self.c * np.sin(q1) + self.b * np.sin(q12)
        return np.stack([x, z], axis=-1)

    def joint_b_position(self, q: np.ndarray) -> np.ndarray:
        """Returns the position (x, z) in m of joint B for joint angles q (rad)."""
        q = np.asarray(q, dtype=float)
        return np.stack([self.a + self.c * np.cos(q[..., 0]), self.c * np.sin(q[..., 0])], -1)


def _normalize_routing(routing: Any) -> str | Sides:
    out = routings.normalize(routing)
    if out is None:
        raise _fail("routing", routing, routings.ALLOWED)
    return out


def _positive_or_auto(name: str, value: Any) -> float:
    if not is_number(value) or not math.isfinite(value) or value <= 0:
        raise _fail(name, value, f"a finite number > 0 (N) or {AUTO!r}")
    return float(value)

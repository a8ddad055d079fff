"""Builds the MuJoCo model of a Mechanism with MjSpec (no string templates, no welds, no floating
bodies).

Frame: the arm moves in the x-z plane; the wall is the plane x = 0; hinges turn about -y; there is
no gravity.  Body tree: world (wall, base link ``a``) -> ``link_c`` (hinge ``A``, ``pulley1``) ->
``link_b`` (hinge ``B``, ``pulley2``, ``effector``).

Real tendons (tendon2r_gym.simulation.realism, all off by default, and then the model is exactly
the ideal
one): with ``tendon_elasticity`` each motor drives a ``spool`` body on its own slide joint behind
the wall (mass ``motor_mass``, after the arm's two joints in qpos), and the cable runs from the
spool over the wall anchor; its spring pulls only when stretched (pull-only) or both ways
(push-pull).  ``tendon_friction`` is MuJoCo's tendon frictionloss (on a passive copy of each
cable's path from the wall when the cable is elastic, so that it opposes sliding over the
pulleys, not stretch); ``motor_tau`` a first-order filter (dyntype filter, filterexact off
RK4; actearly).  ``motor_delay`` is not in the model: the envs hold each command back by whole
control steps (tendon2r_gym.simulation.realism.CommandDelay).

Every field is set on the spec (``build_spec``; the cables' rest lengths by compiling it once),
and the envs step ``build_model``'s compilation of it as it is.  ``to_xml`` (``tendon2r-export``)
writes the spec as MJCF that MuJoCo compiles to that model exactly; what MJCF cannot hold, the
envs do in Python (``tendon2r-export --help`` lists it).

Each spatial tendon runs: wall anchor -> wraps ``pulley1`` -> guide site on link c (on the common
tangent of the two pulleys for that tendon's sides, so the path is a true belt path) -> wraps
``pulley2`` -> end site at the tip.  A tendon is anchored on the wall at z = s1 * R1/2 and ends on
the tip at z = s2 * R2/2, where s1, s2 are the sides it takes on the pulleys.  Anchoring on the
opposite side would make the tendon cross its pulley's centre at large joint angles, where its
moment arm changes sign and the moment-arm matrix loses rank.
"""

from __future__ import annotations

import math
import re

import mujoco
import numpy as np

from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.validation import invalid

JOINTS = ("A", "B")
CAMERA = "side"
#: Fairleads (eyelets) sit on the straight tendon line this many pulley radii before pulley 1 and
#: after pulley 2.  MuJoCo decides wrap contact from the straight line between the neighbouring
#: path points: with the wall anchor far away, a tendon jumps to the wrong side of pulley 1 at
#: large angles; with a fairlead at the tangent point, a lifted-off tendon loses its moment arm.
#: One radius keeps cond(J) < 10 over +-90 deg on every parameter set we tried (tests check it).
FAIRLEAD_GAP = 1.0

#: The path of every tendon: sites and wrapped pulleys (with the sidesite that picks the side).
PATH = (
    ("site", "anchor", None),
    ("site", "fairlead1", None),
    ("geom", "pulley1", "side1"),
    ("site", "guide", None),
    ("geom", "pulley2", "side2"),
    ("site", "fairlead2", None),
    ("site", "end", None),
)

_HINGE_AXIS = (0.0, -1.0, 0.0)  # positive angles lift the arm (+z)
_Y_AXIS_QUAT = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)  # cylinder axis (local z) along -y
_CAMERA_QUAT = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)  # looks along +y, z up
_CAMERA_FOVY = 45.0  # deg

_RGBA = {
    "wall": (0.55, 0.55, 0.6, 1.0),
    "link_a": (0.35, 0.35, 0.4, 1.0),
    "link_c": (0.15, 0.55, 0.85, 1.0),
    "link_b": (0.15, 0.75, 0.35, 1.0),
    "pulley1": (0.95, 0.75, 0.1, 0.9),
    "pulley2": (0.95, 0.45, 0.1, 0.9),
    "tendons": ((0.85, 0.1, 0.1, 1.0), (0.6, 0.1, 0.8, 1.0), (0.1, 0.45, 0.9, 1.0)),
    "site": (0.1, 0.1, 0.1, 1.0),
}


def belt_tangent(r1: float, r2: float, c: float, s1: int, s2: int) -> tuple[np.ndarray, np.ndarray]:
    """Returns the tangent points (x, z) on pulley 1 (at the origin) and pulley 2 (at (c, 0)) of
    the straight belt that passes pulley 1 on side s1 and pulley 2 on side s2, in link-c frame."""
    nx = (s1 * r1 - s2 * r2) / c  # unit normal m of the belt line: m.p + s*r = h for both pulleys
    m = np.array([nx, math.sqrt(1.0 - nx * nx)])
    return s1 * r1 * m, np.array([c, 0.0]) + s2 * r2 * m


def guide_site_positions(mech: Mechanism) -> list[np.ndarray]:
    """Returns, per tendon, the (x, z) of its guide site on link c: the middle of its belt."""
    out = []
    for s1, s2 in mech.tendon_sides:
        t1, t2 = belt_tangent(mech.r1, mech.r2, mech.c, s1, s2)
        out.append(0.5 * (t1 + t2))
    return out


def spool_gap(mech: Mechanism) -> float:
    """Returns how far behind the wall each spool sits at rest (m): more than any change of a
    tendon's path over the joint range, so that a spool never reaches its anchor."""
    return 2.0 * math.pi * (mech.r1 + mech.r2) + 0.05


def build_spec(mech: Mechanism) -> mujoco.MjSpec:
    """Returns the MjSpec of the mechanism with every field of it set on the spec, the
    cables' rest lengths included (measured by compiling it once): ``build_model`` compiles
    it, ``to_xml`` writes it."""
    spec = mujoco.MjSpec()
    spec.modelname = "tendon2r"
    spec.option.timestep = mech.sim_dt
    spec.option.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{mech.integrator.upper()}")
    spec.option.gravity = [0.0, 0.0, 0.0]
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT  # planar arm, nothing to hit
    # One kinematic chain is one constraint island: island discovery costs about 7% of an
    # RK4 step's instructions and changes no result (tests/test_model.py compares trajectories).
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_ISLAND
    spec.compiler.degree = False
    spec.visual.global_.offwidth = 640
    spec.visual.global_.offheight = 480
    spec.visual.headlight.ambient = [0.5, 0.5, 0.5]
    r1, r2, a, b, c = mech.r1, mech.r2, mech.a, mech.b, mech.c
    rl, half_t = mech.link_radius, mech.pulley_thickness / 2
    lo, hi = mech.joint_range_rad
    sides = mech.tendon_sides
    reach = b + c
    world = spec.worldbody

    def geom(body, name, gtype, size, rgba, **kw):
        g = body.add_geom(name=name, type=gtype, size=size, rgba=rgba, **kw)
        g.contype = g.conaffinity = 0
        g.density = mech.true_density
        return g

    def site(body, name, pos, size=0.0012, rgba=_RGBA["site"]):
        return body.add_site(name=name, pos=[pos[0], 0.0, pos[1]], size=[size, 0, 0], rgba=rgba)

    def link(parent, name, x, joint, length, pulley, radius):
        """Adds a body at x on the parent's axis: its hinge, its capsule of the given length
        along +x, and its pulley (a cylinder of the given radius) on the hinge."""
        body = parent.add_body(name=name, pos=[x, 0.0, 0.0])
        body.add_joint(
            name=joint,
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=_HINGE_AXIS,
            range=[lo, hi],
            limited=mujoco.mjtLimited.mjLIMITED_TRUE,
            damping=mech.true_joint_damping,
        )
        capsule = mujoco.mjtGeom.mjGEOM_CAPSULE
        geom(body, name, capsule, [rl, 0, 0], _RGBA[name], fromto=[0, 0, 0, length, 0, 0])
        cylinder = mujoco.mjtGeom.mjGEOM_CYLINDER
        geom(body, pulley, cylinder, [radius, half_t, 0], _RGBA[pulley], quat=_Y_AXIS_QUAT)
        return body

    # The wall (x <= 0, visual only) and the fixed base link a.
    world.add_light(name="light", pos=[a, -3 * reach, 2 * reach], dir=[0, 1, -0.5])
    half_h = reach + 0.02
    geom(
        world,
        "wall",
        mujoco.mjtGeom.mjGEOM_BOX,
        [0.002, 0.02, half_h],
        _RGBA["wall"],
        pos=[-0.002, 0.0, 0.0],
    )
    geom(
        world,
        "link_a",
        mujoco.mjtGeom.mjGEOM_CAPSULE,
        [rl, 0, 0],
        _RGBA["link_a"],
        fromto=[0, 0, 0, a, 0, 0],
    )
    for i, (s1, _) in enumerate(sides):
        site(world, f"anchor{i + 1}", (0.0, s1 * r1))
        site(world, f"fairlead1_t{i + 1}", (a - FAIRLEAD_GAP * r1, s1 * r1), size=0.0008)
    # The camera frames the disc of radius b + c about joint A, and the wall.
    width = a + reach
    dist = 1.15 * max(width / 2 / 0.75, half_h) / math.tan(math.radians(_CAMERA_FOVY / 2))
    world.add_camera(
        name=CAMERA, pos=[width / 2 - 0.01, -dist, 0.0], quat=_CAMERA_QUAT, fovy=_CAMERA_FOVY
    )

    # Link c, hinge A, pulley 1, guide sites and the sidesites of pulley 2.
    link_c = link(world, "link_c", a, "A", c, "pulley1", r1)
    for i, pos in enumerate(guide_site_positions(mech)):
        site(link_c, f"guide{i + 1}", pos)

    # Sidesites pick the side each tendon passes a pulley on.  Both sit on link c, which carries
    # pulley 1 and is the proximal link of pulley 2 (measured: on the world or on link b, the
    # choice fails for large wraps, and the moment-arm matrix loses rank).
    for i, (s1, s2) in enumerate(sides):
        site(link_c, f"side1_t{i + 1}", (0.0, s1 * 2.0 * r1), size=0.0005)
        if s2:
            site(link_c, f"side2_t{i + 1}", (c, s2 * 2.0 * r2), size=0.0005)

    # Link b, hinge B, pulley 2, the effector and the tendon ends.
    link_b = link(link_c, "link_b", c, "B", b, "pulley2", r2)
    site(link_b, "effector", (b, 0.0), size=0.003, rgba=(0.9, 0.9, 0.9, 1.0))
    for i, (_, s2) in enumerate(sides):
        if s2:
            site(link_b, f"fairlead2_t{i + 1}", (FAIRLEAD_GAP * r2, s2 * r2), size=0.0008)
            site(link_b, f"end{i + 1}", (b, s2 * r2))

    # Series-elastic cables: a spool per motor, added after the arm so that qpos[:2] stays
    # (q_A, q_B).  Only its mass matters (it slides); the inertia only has to be valid.
    if mech.elastic:
        for i, (s1, _) in enumerate(sides):
            spool = world.add_body(name=spool_name(i), pos=[-spool_gap(mech), 0.0, s1 * r1])
            spool.explicitinertial = True
            # At the spool's centre.  Left unset, MuJoCo 4.0 compiles it at the spool's pos
            # once more, and its XML leaves the inertial out, or its pos, which loading needs.
            spool.ipos = [0.0, 0.0, 0.0]
            spool.mass = mech.motor_mass
            spool.inertia = [mech.motor_mass * 1e-4] * 3
            spool.add_joint(name=spool_name(i), type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0])
            site(spool, spool_name(i), (0.0, 0.0))

    # Tendons, their motors and one tension sensor each.  Motors are general actuators with
    # gear 1, so MuJoCo's actuator force is the force along the tendon in N (positive
    # lengthens): minus the tension that Mechanism.command_map gives the command, F ctrl
    # push-pull and -F (ctrl + 1) / 2 pull-only.  An unresolved "auto" limit builds with F = 1 N.
    force = mech.max_tendon_force if isinstance(mech.max_tendon_force, float) else 1.0
    gain, bias = (-force * k for k in mech.command_map)
    for i, (_, s2) in enumerate(sides):
        name = tendon_name(i)
        t = spec.add_tendon(
            name=name,
            width=0.0006,
            rgba=_RGBA["tendons"][i % len(_RGBA["tendons"])],
            stiffness=mech.tendon_elasticity if mech.elastic else mech.tendon_stiffness,
            damping=mech.tendon_damping,
        )
        if mech.elastic:
            t.wrap_site(spool_name(i))
        else:
            t.frictionloss = mech.tendon_friction
        _wrap_path(t, i, s2)
        if mech.elastic:  # the motor pulls its spool: a force along -x pulls the cable
            act = spec.add_actuator(
                name=motor_name(i), trntype=mujoco.mjtTrn.mjTRN_JOINT, target=spool_name(i)
            )
        else:
            act = spec.add_actuator(
                name=motor_name(i), trntype=mujoco.mjtTrn.mjTRN_TENDON, target=name
            )
        act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        act.gainprm[0] = gain
        act.biasprm[:3] = [bias, 0.0, 0.0]
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.ctrlrange = [-1.0, 1.0]
        if mech.motor_tau > 0:  # force = gain act + bias, d act / dt = (ctrl - act) / tau
            # RK4 integrates the filter's ODE to 1e-5 (measured; with filterexact, whose exact
            # update assumes an Euler step, RK4's time constant came out 15% long).
            exact = mech.integrator != "RK4"
            act.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT if exact else mujoco.mjtDyn.mjDYN_FILTER
            act.dynprm[0] = mech.motor_tau
            act.actearly = True  # the force of a step already uses that step's act
        spec.add_sensor(
            name=f"force_{name}",
            type=mujoco.mjtSensor.mjSENS_ACTUATORFRC,
            objtype=mujoco.mjtObj.mjOBJ_ACTUATOR,
            objname=motor_name(i),
        )
    if mech.elastic and mech.tendon_friction > 0:
        # Friction acts where the cable slides on its pulleys: along its path from the wall.
        for i, (_, s2) in enumerate(sides):
            path = spec.add_tendon(name=f"path{i + 1}", frictionloss=mech.tendon_friction)
            _wrap_path(path, i, s2)
    if mech.elastic:  # each cable is at rest at its length with the arm and spools at 0
        rest = _compile(spec, mech).tendon_length0
        for i in range(mech.n_tendons):
            slack = 0.0 if mech.pull_only else rest[i]  # pull-only: no push below the rest
            spec.tendon(tendon_name(i)).springlength = [slack, rest[i]]
    return spec


def _wrap_path(tendon: mujoco.MjsTendon, i: int, s2: int) -> None:
    """Adds PATH's points of tendon i (a tendon with side 0 on pulley 2 ends at its guide site
    on link c)."""
    for kind, point, side in PATH if s2 else PATH[:4]:
        if kind == "site":
            shared = point in ("anchor", "guide", "end")
            tendon.wrap_site(f"{point}{i + 1}" if shared else f"{point}_t{i + 1}")
        else:
            tendon.wrap_geom(point, f"{side}_t{i + 1}")


def spool_name(i: int) -> str:
    """Returns the name of the spool body, joint and site of tendon i (0-based)."""
    return f"spool{i + 1}"


def tendon_name(i: int) -> str:
    """Returns the name of tendon i (0-based): tendon1, tendon2, ..."""
    return f"tendon{i + 1}"


def motor_name(i: int) -> str:
    """Returns the name of the motor of tendon i (0-based): motor1, motor2, ..."""
    return f"motor{i + 1}"


def build_model(mech: Mechanism) -> mujoco.MjModel:
    """Returns the compiled MuJoCo model of the mechanism: ``build_spec(mech)`` compiled; a
    mechanism MuJoCo cannot compile (a massless link, degenerate inertia) raises a ValueError
    naming the mass fields."""
    return _compile(build_spec(mech), mech)


def _compile(spec: mujoco.MjSpec, mech: Mechanism) -> mujoco.MjModel:
    """Returns ``spec`` compiled, or raises a ValueError naming the mechanism's mass fields."""
    try:
        return spec.compile()
    except ValueError as e:  # MuJoCo's compiler message names its element, not our field
        fields = {k: getattr(mech, k) for k in ("density", "link_radius", "pulley_thickness")}
        raise invalid(
            "Mechanism mass fields",
            fields,
            "values that give every moving link a mass and an inertia MuJoCo can integrate "
            f"(its compiler says: {str(e).splitlines()[0]})",
        ) from None


def to_xml(mech: Mechanism, comment: str = "") -> str:
    """Returns the MJCF XML of ``build_spec(mech)``, which ``mujoco.MjModel.from_xml_string``
    compiles to ``build_model(mech)`` exactly (tests/test_export.py compares every array and
    trajectory), with ``comment`` at its top (a ``--``, which XML forbids in a comment, is
    written ``- -``).

    The spec is saved as written (``compiler.savecompiled`` false): every number exactly, and
    each element in the notation this module writes it in (``savecanonical`` false: fromto,
    not pos and quat).  Saved as compiled, MuJoCo 4.0 rounds every number to 6 digits: the
    default arm's trajectory moved by 3.6e-5 rad in 1000 steps."""
    spec = build_spec(mech)
    _compile(spec, mech)
    spec.compiler.savecompiled = False
    spec.compiler.savecanonical = False
    spec.comment = re.sub(r"-(?=-|$)", "- ", comment)
    return spec.to_xml()

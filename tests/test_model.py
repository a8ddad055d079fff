"""The compiled MuJoCo model matches the mechanism's geometry and tendon physics."""

import math

import mujoco
import numpy as np
import pytest

from tendon2r_gym import ActuationAnalysis, Mechanism, build_model
from tendon2r_gym.simulation.model import JOINTS, motor_name, tendon_name


def _forward(model, q):
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_forward(model, data)
    return data


def test_structure_has_no_welds_and_no_floating_bodies(mech):
    m = build_model(mech)
    assert m.neq == 0
    assert m.nq == m.nv == 2
    assert [m.joint(j).type for j in JOINTS] == [mujoco.mjtJoint.mjJNT_HINGE] * 2
    assert np.all(m.opt.gravity == 0)
    assert m.ntendon == m.nu == mech.n_tendons
    for i in range(mech.n_tendons):
        assert m.tendon(tendon_name(i)).id == i
        act = m.actuator(motor_name(i))
        assert act.trntype == mujoco.mjtTrn.mjTRN_TENDON
        np.testing.assert_array_equal(act.ctrlrange, [-1, 1])
        # Force along the tendon at ctrl = +1 and -1 (N, positive lengthens).
        at = lambda u, act=act: act.gainprm[0] * u + act.biasprm[0]  # noqa: E731
        force = mech.max_tendon_force
        expected = (0.0, -force) if mech.pull_only else (-force, force)
        assert (at(-1.0), at(1.0)) == pytest.approx(expected)


def test_anchors_effector_and_pulley_radii(mech):
    m = build_model(mech)
    d = _forward(m, [0.0, 0.0])
    np.testing.assert_allclose(d.body("link_c").xpos, [mech.a, 0, 0], atol=1e-12)
    np.testing.assert_allclose(d.body("link_b").xpos, [mech.a + mech.c, 0, 0], atol=1e-12)
    np.testing.assert_allclose(
        d.site("effector").xpos, [mech.a + mech.b + mech.c, 0, 0], atol=1e-12
    )
    assert abs(m.geom("pulley1").size[0] - mech.R1 / 2) < 1e-9
    assert abs(m.geom("pulley2").size[0] - mech.R2 / 2) < 1e-9
    for j, name in enumerate(JOINTS):
        np.testing.assert_allclose(
            d.xanchor[m.joint(name).id], d.body(["link_c", "link_b"][j]).xpos
        )
        np.testing.assert_allclose(d.xaxis[m.joint(name).id], [0, -1, 0])


def test_forward_kinematics_matches_compiled_model(mech):
    """x = a + c cos q1 + b cos(q1+q2), z = +(c sin q1 + b sin(q1+q2)): hinges turn about -y,
    so positive angles lift the arm."""
    m = build_model(mech)
    rng = np.random.default_rng(0)
    for q in rng.uniform(*mech.joint_range_rad, size=(20, 2)):
        d = _forward(m, q)
        x = mech.a + mech.c * math.cos(q[0]) + mech.b * math.cos(q[0] + q[1])
        z = mech.c * math.sin(q[0]) + mech.b * math.sin(q[0] + q[1])
        np.testing.assert_allclose(d.site("effector").xpos, [x, 0.0, z], atol=1e-12)
        np.testing.assert_allclose(mech.forward_kinematics(q), [x, z], atol=1e-12)


def test_workspace_radii_about_joint_a(mech):
    wide = mech.replace(joint_range_deg=(-179.999, 179.999))
    m = build_model(wide)
    reach = []
    for q2 in np.radians(np.linspace(-179.99, 179.99, 721)):
        d = _forward(m, [0.3, q2])
        reach.append(np.linalg.norm(d.site("effector").xpos - d.body("link_c").xpos))
    inner, outer = mech.workspace_radii
    assert inner == pytest.approx(abs(mech.c - mech.b))
    assert min(reach) == pytest.approx(inner, abs=1e-6)
    assert max(reach) == pytest.approx(outer, abs=1e-12)


def _wrapped_geoms(model, data, tendon):
    adr, num = data.ten_wrapadr[tendon], data.ten_wrapnum[tendon]
    return set(data.wrap_obj.ravel()[adr : adr + num].tolist()) - {-1}


def test_tendon_length_changes_by_radius_times_angle_where_it_wraps(mech):
    """dL_i/dq_k = -s_ik * r_k for every pulley k that tendon i wraps (central differences)."""
    m = build_model(mech)
    radii = (mech.r1, mech.r2)
    pulleys = (m.geom("pulley1").id, m.geom("pulley2").id)
    rng = np.random.default_rng(1)
    checked = 0
    for q in rng.uniform(*mech.joint_range_rad, size=(40, 2)):
        wraps = [_wrapped_geoms(m, _forward(m, q), i) for i in range(mech.n_tendons)]
        for k in range(2):
            dq = np.zeros(2)
            dq[k] = 1e-6
            dl = (_forward(m, q + dq).ten_length - _forward(m, q - dq).ten_length) / 2e-6
            for i in range(mech.n_tendons):
                if mech.tendon_sides[i][k] == 0:  # ends on link c: no arm on joint B
                    assert dl[i] == pytest.approx(0.0, abs=1e-9)
                elif pulleys[k] in wraps[i]:
                    expected = -mech.tendon_sides[i][k] * radii[k]
                    assert dl[i] == pytest.approx(expected, rel=1e-5), (q, i, k)
                    checked += 1
    assert checked > 40  # the tendons do wrap their pulleys over most of the range


@pytest.mark.parametrize("routing", ["parallel", "crossed"])
def test_mirror_image_routings_are_rank_one_at_zero(mech, routing):
    analysis = ActuationAnalysis(build_model(mech.replace(routing=routing, pull_only=False)))
    assert analysis.condition_number(np.zeros(2)) > 1e6


def test_asymmetric_routing_is_full_rank_over_the_joint_range(mech):
    analysis = ActuationAnalysis(build_model(mech))
    grid = np.linspace(*mech.joint_range_rad, 19)
    cond = analysis.grid(grid, grid, analysis.condition_number)
    assert np.all(np.isfinite(cond))
    assert cond.max() < 10, cond.max()
    np.testing.assert_allclose(
        cond[3, 5], np.linalg.cond(analysis.moment_arms(np.array([grid[3], grid[5]]))), rtol=1e-9
    )


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("a", -0.01),
        ("b", 0.0),
        ("c", float("nan")),
        ("R1", float("inf")),
        ("R1", 0.2),  # pulley 1 larger than link a
        ("R2", 0.2),  # the pulleys overlap on link c
        ("routing", "zigzag"),
        ("routing", [[1, 1], [1, 2]]),
        ("max_tendon_force", 0.0),
        ("sim_dt", -1e-4),
        ("integrator", "leapfrog"),
        ("joint_range_deg", (10, -10)),
        ("joint_damping", -1.0),
    ],
)
def test_bad_parameters_raise_value_error_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        Mechanism(**{field: value})


def test_unknown_field_is_rejected():
    with pytest.raises(ValueError, match="radius"):
        Mechanism.from_dict({"radius": 1.0})


def test_explicit_routing_equals_named_routing():
    named = build_model(Mechanism(routing="asymmetric"))
    explicit = build_model(Mechanism(routing=[[1, 1], [-1, 1]]))
    q = np.array([0.2, -0.4])
    np.testing.assert_array_equal(
        ActuationAnalysis(named).moment_arms(q), ActuationAnalysis(explicit).moment_arms(q)
    )


def test_disabling_island_discovery_changes_no_trajectory(mech):
    """The model skips island discovery (one chain, one island); with it on, the same bang-bang
    commands, which drive the arm into its joint limits, give bit-identical states."""
    off = build_model(mech)
    assert off.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_ISLAND
    on = build_model(mech)
    on.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_ISLAND)
    states, limited = [], 0
    for model in (off, on):
        data, rng, traj = mujoco.MjData(model), np.random.default_rng(0), []
        for k in range(3000):
            if k % 100 == 0:
                data.ctrl[:] = rng.choice([-1.0, 1.0], model.nu)
            mujoco.mj_step(model, data)
            traj.append(np.concatenate([data.qpos, data.qvel, data.qacc]))
            limited += data.nefc > 0
        states.append(np.array(traj))
    assert limited > 100  # the joint-limit constraints were active
    np.testing.assert_array_equal(states[0], states[1])

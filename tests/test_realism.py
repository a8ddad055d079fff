"""Real tendons and motors (tendon2r_gym.simulation.realism), checked on the compiled MuJoCo
model."""

import math

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from tendon2r_gym import Mechanism, build_model
from tendon2r_gym.simulation.mechanism import REALISM_LIMITS
from tendon2r_gym.simulation.model import motor_name, to_xml
from tendon2r_gym.simulation.realism import Drive, cable_tensions
from tendon2r_gym.simulation.stability import rates

PUSH_PULL = Mechanism(max_tendon_force=1.0)
PULL_ONLY = Mechanism(routing="n_plus_1", pull_only=True, max_tendon_force=1.0)


def _held(model, data, steps):
    """Steps with the arm clamped on the bench: a huge armature on its joints."""
    model.dof_armature[:2] = 1e9
    for _ in range(steps):
        mujoco.mj_step(model, data)
    mujoco.mj_forward(model, data)


def test_every_effect_off_is_the_ideal_model():
    """Every realism field at 0 gives the ideal model (the same MJCF), and ideal() is a no-op."""
    zeros = PUSH_PULL.replace(**dict.fromkeys(REALISM_LIMITS, 0.0), motor_mass=0.3)
    assert to_xml(zeros) == to_xml(PUSH_PULL)
    assert PUSH_PULL.ideal() is PUSH_PULL and not PUSH_PULL.realistic
    real = PUSH_PULL.replace(tendon_elasticity=1e3, motor_tau=0.01)
    assert real.realistic and real.ideal() == PUSH_PULL
    assert PUSH_PULL.replace(motor_mass=0.3).ideal() == PUSH_PULL


@pytest.mark.parametrize("mech", [PUSH_PULL, PULL_ONLY], ids=["push_pull", "pull_only"])
def test_steady_stretch_is_tension_over_stiffness(mech):
    """A held arm: after the cable-spool oscillation dies out, each cable is stretched by
    tension / k past its rest length, and carries the commanded tension."""
    k = 2000.0
    elastic = mech.replace(tendon_elasticity=k, tendon_damping=5.0, motor_mass=0.02)
    model = build_model(elastic)
    data = mujoco.MjData(model)
    drive = Drive(model, elastic)
    drive.settle(data, np.array([0.2, -0.3]), np.zeros(2))
    n = elastic.n_tendons
    rest = drive.tension_view(data.qfrc_passive)
    np.testing.assert_allclose(rest, elastic.rest_tension, atol=1e-9)  # settle's rest state
    ctrl = np.array([0.3, -0.2, 0.5])[:n]
    data.ctrl[:] = ctrl
    _held(model, data, 3000)
    commanded = -np.array([data.actuator(motor_name(i)).force[0] for i in range(n)])
    stretch = data.ten_length[:n] - drive.rest_length
    np.testing.assert_allclose(stretch, commanded / k, rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(
        cable_tensions(data.ten_length[:n], np.zeros(n), *drive.cable), commanded, 1e-4
    )


def test_slack_cable_transmits_no_force():
    """A pull-only cable shorter than its rest length is slack: no force on the arm, whatever
    its stiffness."""
    mech = PULL_ONLY.replace(tendon_elasticity=5000.0, pretension=0.0)
    model = build_model(mech)
    data = mujoco.MjData(model)
    Drive(model, mech).settle(data, np.zeros(2), np.zeros(2))
    spool = model.joint("spool1").qposadr[0]
    data.qpos[spool] += 0.003  # spool toward the wall: 3 mm of slack
    mujoco.mj_forward(model, data)
    assert data.ten_length[0] < model.tendon_lengthspring[0, 1]
    np.testing.assert_allclose(data.qfrc_passive, 0.0, atol=1e-12)
    data.qpos[spool] -= 0.006  # 3 mm of stretch: it pulls with k x 3 mm
    mujoco.mj_forward(model, data)
    J = np.zeros((model.ntendon, model.nv))
    mujoco.mju_sparse2dense(J, data.ten_J, model.ten_J_rownnz, model.ten_J_rowadr,
                            model.ten_J_colind)  # fmt: skip
    np.testing.assert_allclose(data.qfrc_passive, -J[0] * 5000.0 * 0.003, rtol=1e-6)


@pytest.mark.parametrize("preset", ["default", "pull_only"])
def test_the_reported_tension_is_the_cable_models(preset):
    """The envs report each elastic cable's force on its spool (MuJoCo's passive force, the
    tendon spring's): it is realism.cable_tensions of the cable's length and speed (stretch
    times stiffness, nothing when slack, plus damping) to within rounding, over an episode
    of random commands that slackens, stretches and (push-pull) compresses the cables."""
    mech = {"tendon_elasticity": 3000.0, "tendon_damping": 2.0, "motor_mass": 0.01}
    env = gym.make("Tendon2R-v0", preset=preset, mechanism=mech)
    env.reset(seed=0)
    u, rng = env.unwrapped, np.random.default_rng(0)
    n = u.mechanism.n_tendons
    slack = stretched = 0
    for _ in range(300):
        tension = env.step(rng.uniform(-1, 1, env.action_space.shape))[4]["tendon_tension"]
        length, speed = u.data.ten_length[:n], u.data.ten_velocity[:n]
        model = cable_tensions(length, speed, *u.drive.cable)
        np.testing.assert_allclose(tension, model, rtol=1e-12, atol=1e-12)
        slack += int(np.sum(length < u.drive.rest_length))
        stretched += int(np.sum(length > u.drive.rest_length))
    assert slack and stretched  # both regimes were visited


@pytest.mark.parametrize("elastic", [False, True])
def test_friction_opposes_sliding_with_its_magnitude(elastic):
    """A cable sliding over its pulleys feels its set dry friction f against the motion: once
    the sliding is fast, MuJoCo's (soft) friction constraint of each cable's path has
    saturated at -f sign(dL/dt); slower, it stays within f.  For an elastic cable it acts on
    the path from the wall, not on the stretch."""
    f = 0.05
    mech = PUSH_PULL.replace(tendon_friction=f, tendon_elasticity=3000.0 if elastic else 0.0)
    model = build_model(mech)
    data = mujoco.MjData(model)
    for speed, saturated in ((10.0, True), (0.3, False)):
        Drive(model, mech).settle(data, np.zeros(2), np.array([speed, 0.0]))
        rows = data.efc_type == mujoco.mjtConstraint.mjCNSTR_FRICTION_TENDON
        tendons = data.efc_id[rows]
        assert sorted(tendons) == list(range(mech.n_tendons, 2 * mech.n_tendons) if elastic
                                       else range(mech.n_tendons))  # fmt: skip
        sliding = data.ten_velocity[tendons]
        if elastic:  # settled: the cables do not stretch, yet their paths slide
            np.testing.assert_allclose(data.ten_velocity[: mech.n_tendons], 0.0, atol=1e-12)
        force = data.efc_force[rows]
        if saturated:
            np.testing.assert_allclose(force, -f * np.sign(sliding), rtol=1e-9)
        else:
            assert np.all(np.abs(force) < f) and np.all(force * sliding < 0)


@pytest.mark.parametrize("integrator", ["RK4", "Euler", "implicitfast"])
def test_lag_step_response_has_its_time_constant(integrator):
    """From rest, a step of the command: the motor's force state reaches 1 - exp(-t / tau) of
    the step after t (exactly off RK4, to RK4's accuracy on it)."""
    tau = 0.004
    mech = PUSH_PULL.replace(motor_tau=tau, integrator=integrator)
    model = build_model(mech)
    data = mujoco.MjData(model)
    Drive(model, mech).settle(data, np.zeros(2), np.zeros(2))
    step = np.array([0.5, -0.25])
    data.ctrl[:] = step
    act = []
    for _ in range(20):
        mujoco.mj_step(model, data)
        act.append(data.act.copy())
    t = mech.sim_dt * np.arange(1, 21)
    expected = np.outer(1 - np.exp(-t / tau), step)
    np.testing.assert_allclose(act, expected, rtol=1e-4 if integrator == "RK4" else 1e-12)
    force = model.actuator_gainprm[:, 0] * data.act + model.actuator_biasprm[:, 0]
    np.testing.assert_allclose(force, mech.max_tendon_force * data.act)


@pytest.mark.parametrize("k", [1, 3])
@pytest.mark.parametrize("preset", ["default", "pull_only"])
def test_delay_of_k_steps_shifts_the_response_by_k_steps(k, preset):
    """With motor_delay = k ctrl_dt the arm moves as the ideal arm does under the same actions
    sent k steps later (the rest command before them), bit for bit."""
    delayed = gym.make("Tendon2R-v0", preset=preset, mechanism={"motor_delay": k * 0.001})
    ideal = gym.make("Tendon2R-v0", preset=preset)
    rest = np.array(ideal.unwrapped.formulas.rest_command(ideal.unwrapped.arm))
    actions = np.random.default_rng(0).uniform(-1, 1, (30, *ideal.action_space.shape))
    shifted = np.concatenate([np.tile(rest, (k, 1)), actions[:-k]])
    delayed.reset(seed=1), ideal.reset(seed=1)
    q = [delayed.step(a)[4]["q"] for a in actions]
    q_ideal = [ideal.step(a)[4]["q"] for a in shifted]
    np.testing.assert_array_equal(q, q_ideal)
    with pytest.raises(ValueError, match=r"mechanism\.motor_delay = 0\.003 .*ctrl_dt = 0\.002"):
        gym.make("Tendon2R-v0", mechanism={"motor_delay": 0.003}, ctrl_dt=0.002)


def test_stiff_cables_on_a_light_spool_are_refused():
    """The cable's frequency bounds the time step: the error names the field and its limit."""
    omega = rates(build_model(PUSH_PULL), PUSH_PULL.replace(tendon_elasticity=1e5, motor_mass=0.01))
    assert omega["tendon_elasticity"] * PUSH_PULL.sim_dt > 2.7
    with pytest.raises(ValueError, match=r"Mechanism\.tendon_elasticity = 100000\.0.*<= "):
        gym.make("Tendon2R-v0", mechanism={"tendon_elasticity": 1e5, "motor_mass": 0.01,
                                           "sim_dt": 0.001})  # fmt: skip
    # left out, the step sizes itself: ctrl_dt / k, small enough for the cable
    cfg = gym.make("Tendon2R-v0", mechanism={"tendon_elasticity": 1e5, "motor_mass": 0.01})
    dt = cfg.unwrapped.config.mechanism.sim_dt
    assert omega["tendon_elasticity"] * dt <= 2.7 < omega["tendon_elasticity"] * 0.001


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [("tendon_elasticity", -1.0, r"tendon_elasticity = -1\.0"),
     ("tendon_friction", math.nan, "tendon_friction"),
     ("motor_tau", 2.0, r"motor_tau = 2\.0 .*\[0, 1\]"),
     ("motor_delay", -0.001, r"motor_delay = -0\.001"),
     ("motor_mass", 0.0, r"motor_mass = 0\.0"),
     ("tendon_stiffness", 10.0, r"tendon_stiffness = 10\.0 .*tendon_elasticity"),
     ("density_scale", 0.0, r"density_scale = 0\.0 .*\(0, 100\]"),
     ("extra_joint_damping", -1e-6, r"extra_joint_damping = -1e-06")],
)  # fmt: skip
def test_bad_realism_fields_raise_naming_the_field(field, value, match):
    extra = {"tendon_elasticity": 1000.0} if field == "tendon_stiffness" else {}
    with pytest.raises(ValueError, match=match):
        PUSH_PULL.replace(**extra, **{field: value})


@pytest.mark.parametrize("preset", ["default", "pull_only"])
def test_env_starts_at_rest_and_reports_cable_tension(preset):
    """With every effect on, a reset starts each cable at its rest tension and still; the
    observation keeps its layout; the same seed gives the same episode."""
    real = {"tendon_elasticity": 3000.0, "tendon_friction": 0.01, "motor_tau": 0.004,
            "motor_delay": 0.002}  # fmt: skip
    env = gym.make("Tendon2R-v0", preset=preset, mechanism=real)
    ideal = gym.make("Tendon2R-v0", preset=preset)
    assert env.observation_space == ideal.observation_space
    obs, _ = env.reset(seed=3)
    np.testing.assert_array_equal(obs, ideal.reset(seed=3)[0])  # same q, dq, reference
    u = env.unwrapped
    rest = u.tendon_tensions()
    np.testing.assert_allclose(rest, u.mechanism.rest_tension, atol=1e-9)
    actions = np.random.default_rng(0).uniform(-1, 1, (50, *env.action_space.shape))
    runs = []
    for _ in range(2):
        env.reset(seed=3)
        runs.append([env.step(a)[4]["tendon_tension"] for a in actions])
    np.testing.assert_array_equal(*runs)


def test_late_observation_is_the_state_k_steps_before():
    """observation_delay = k ctrl_dt: the observed q and dq are the true ones of k steps before
    (the reset state until then); reward and info stay on the true state."""
    from tendon2r_gym.task.observation import DQ, Q

    k = 3
    env = gym.make("Tendon2R-v0", observation_delay=k * 0.001)
    ideal = gym.make("Tendon2R-v0")
    obs, _ = env.reset(seed=2)
    ideal_obs, _ = ideal.reset(seed=2)
    true = [ideal_obs]
    actions = np.random.default_rng(0).uniform(-1, 1, (12, 2))
    for t, a in enumerate(actions, start=1):
        obs, reward, *_, info = env.step(a)
        ideal_out = ideal.step(a)
        true.append(ideal_out[0])
        late = true[max(t - k, 0)]
        np.testing.assert_array_equal(obs[Q], late[Q])
        np.testing.assert_array_equal(obs[DQ], late[DQ])
        assert reward == ideal_out[1]  # the true error
        np.testing.assert_array_equal(info["q"], ideal_out[4]["q"])


def test_noise_has_its_std_and_the_same_seed_gives_the_same_noise():
    from tendon2r_gym.task.observation import DQ, Q

    std = (1e-3, 0.05)
    env = gym.make("Tendon2R-v0", observation_noise=list(std))
    runs = []
    for _ in range(2):
        env.reset(seed=5)
        dev = []
        for _ in range(1500):
            obs, *_, info = env.step(np.zeros(2))
            dev.append(np.r_[obs[Q] - info["q"], obs[DQ]])
        runs.append(np.array(dev))
    np.testing.assert_array_equal(*runs)
    np.testing.assert_allclose(runs[0][:, :2].std(0), std[0], rtol=0.1)
    with pytest.raises(ValueError, match=r"observation_noise = \[0\.1\]"):
        gym.make("Tendon2R-v0", observation_noise=[0.1])
    with pytest.raises(ValueError, match=r"observation_delay = 0\.0015 .*ctrl_dt = 0\.001"):
        gym.make("Tendon2R-v0", observation_delay=0.0015)


def test_model_errors_change_the_simulated_arm_and_not_the_controllers_model():
    """density_scale scales every moving mass and inertia of the compiled model, and
    extra_joint_damping adds to each joint's damping; PD's and CT's model stays the nominal
    one, and the stability criterion sees the true inertia and damping."""
    from tendon2r_gym.policies.baselines import ComputedTorquePolicy, PDPolicy

    nominal = PUSH_PULL.replace(joint_damping=1e-6)
    wrong = nominal.replace(density_scale=1.7, extra_joint_damping=3e-6)
    assert wrong.realistic and wrong.ideal() == nominal
    m0, m1 = build_model(nominal), build_model(wrong)
    np.testing.assert_allclose(m1.body_mass, 1.7 * m0.body_mass, rtol=1e-12)
    np.testing.assert_allclose(m1.body_inertia, 1.7 * m0.body_inertia, rtol=1e-12)
    np.testing.assert_allclose(m1.dof_damping, [4e-6, 4e-6], rtol=1e-12)
    for cls in (PDPolicy, ComputedTorquePolicy):
        env = gym.make("Tendon2R-v0", mechanism=wrong.to_dict())
        policy = cls.from_env(env)
        np.testing.assert_array_equal(policy.model.body_mass, m0.body_mass)
        np.testing.assert_array_equal(policy.model.dof_damping, m0.dof_damping)
    r0, r1 = rates(m0, nominal), rates(m0, wrong)
    assert r1["joint_damping"] == pytest.approx(r0["joint_damping"] * 4 / 1.7, rel=1e-12)
    assert r1["tendon_stiffness"] == r0["tendon_stiffness"] == 0.0
    with pytest.raises(ValueError, match=r"joint_damping \+ extra_joint_damping = 0\.1 .*<= "):
        gym.make("Tendon2R-v0", mechanism={"extra_joint_damping": 0.1, "sim_dt": 0.001})


def test_a_model_of_the_ideal_arm_loads_on_the_real_one_only():
    """check_model_env compares the nominal arms: real cables and sensors are deployment
    conditions, another geometry is another arm."""
    from tendon2r_gym.artifacts.model_env import check_model_env

    recorded = gym.make("Tendon2R-v0", preset="pull_only").unwrapped.config.to_dict()
    from tendon2r_gym.task import observation

    recorded["observation"] = observation.layout(3, 3)
    check_model_env(recorded, gym.make("Tendon2R-v0", preset="real_arm"), "model")
    errors = {"density_scale": 1.5, "extra_joint_damping": 1e-6}  # unknown to the controller
    check_model_env(recorded, gym.make("Tendon2R-v0", preset="real_arm", mechanism=errors), "m")
    with pytest.raises(ValueError, match="trained for another env: mechanism"):
        other = gym.make("Tendon2R-v0", preset="real_arm", mechanism={"R1": 0.012})
        check_model_env(recorded, other, "model")


@pytest.mark.parametrize("preset", ["default", "real_arm"])
def test_moment_arm_rows_are_the_dense_matrix(preset):
    """MomentArms.rows (floats, the env's info) is MomentArms.dense (the array PD reads) bit for
    bit, on the ideal model and on a realistic one (spools, friction tendons, sparse ten_J),
    and the info's condition number is actuation.cond of it."""
    from tendon2r_gym.simulation.actuation import MomentArms, cond

    env = gym.make("Tendon2R-v0", preset=preset)
    env.reset(seed=0)
    arms = MomentArms(env.unwrapped.model, env.unwrapped.data)  # as the env reads its own
    for a in np.random.default_rng(0).uniform(-1, 1, (20, *env.action_space.shape)):
        info = env.step(a)[4]
        assert [list(r) for r in arms.rows()] == arms.dense().tolist()
        assert info["moment_arm_cond"] == cond(arms.dense())

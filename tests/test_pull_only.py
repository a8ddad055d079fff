"""Real tendons only pull: routings of any size, pull-only motors, positive spanning and
tension distribution, all checked against the compiled model."""

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from tendon2r_gym import Mechanism, build_model
from tendon2r_gym.evaluation.evaluator import evaluate
from tendon2r_gym.simulation.actuation import ActuationAnalysis, TorqueToTension, distribute
from tendon2r_gym.simulation.model import motor_name, tendon_name
from tendon2r_gym.simulation.routing import positive_span


def test_a_positive_motor_force_lengthens_the_tendon():
    """MuJoCo 4: a positive tendon-actuator force lengthens the tendon, so pulling is a negative
    force (checked on our compiled model, from rest, one motor at a time)."""
    for pull_only, routing in ((False, "asymmetric"), (True, "n_plus_1")):
        m = build_model(Mechanism(routing=routing, pull_only=pull_only, max_tendon_force=0.5))
        for i in range(m.nu):
            d = mujoco.MjData(m)
            d.ctrl[:] = -1.0 if pull_only else 0.0  # slack / no force
            d.ctrl[i] = 1.0  # push-pull: +F (a push); pull-only: full pull
            for _ in range(5):
                mujoco.mj_step(m, d)
            force = d.actuator_force[i]
            velocity = d.ten_velocity[i]
            assert np.sign(velocity) == np.sign(force) != 0, (routing, i, force, velocity)
            assert (force < 0) == pull_only


@pytest.mark.parametrize("pull_only", [False, True])
def test_command_map_is_the_compiled_motors_and_pds_inverse(pull_only):
    """Mechanism.command_map, the one home of the command -> tension map, is what the compiled
    motors apply (force = -tension along the tendon) and what PD's distribution inverts."""
    mech = Mechanism(routing="n_plus_1", pull_only=pull_only, max_tendon_force=0.5)
    gain, offset = mech.command_map
    m, u = build_model(mech), np.linspace(-1.0, 1.0, 9)
    d = mujoco.MjData(m)
    for x in u:
        d.ctrl[:] = x
        mujoco.mj_forward(m, d)
        np.testing.assert_allclose(-d.actuator_force, 0.5 * (gain * x + offset), atol=1e-12)
    analysis = TorqueToTension(mech)
    J, _ = analysis.kinematics(np.array([[0.3, -0.4]]))
    tau = np.array([[0.002, -0.001]])
    t = distribute(J, tau, pull_only, mech.pretension, analysis.damping)
    np.testing.assert_allclose(0.5 * (gain * analysis.command(J, tau) + offset), t, atol=1e-7)
    assert np.isclose(0.5 * (gain * mech.rest_ctrl + offset), mech.rest_tension)


def test_info_tension_is_positive_when_pulling_for_every_routing():
    for preset, pull in (("default", np.array([-1.0, -1.0])), ("pull_only", np.ones(3))):
        env = gym.make("Tendon2R-v0", preset=preset)
        env.reset(seed=0)
        *_, info = env.step(pull)
        limit = env.unwrapped.mechanism.max_tendon_force
        np.testing.assert_allclose(info["tendon_tension"], limit)
    env = gym.make("Tendon2R-v0", preset="pull_only")
    env.reset(seed=0)
    *_, info = env.step(-np.ones(3))
    np.testing.assert_allclose(info["tendon_tension"], 0.0, atol=1e-12)


def test_action_space_has_one_entry_per_tendon():
    env = gym.make("Tendon2R-v0", preset="pull_only")
    assert env.action_space.shape == (3,) and env.action_space.dtype == np.float32
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"allowed: \(3,\)"):
        env.step(np.zeros(2))


@pytest.mark.parametrize(
    ("routing", "match"),
    [
        ("asymmetric", "2 pull-only tendons cannot reverse a joint torque"),
        ([[1, 1], [1, -1], [-1, 1]], "span only on the boundary"),
    ],
)
def test_pull_only_refuses_routings_that_cannot_span(routing, match):
    with pytest.raises(ValueError, match=match):
        Mechanism(routing=routing, pull_only=True)


def test_n_plus_1_positively_spans_over_the_whole_joint_range():
    mech = Mechanism(routing="n_plus_1", pull_only=True, max_tendon_force=1.0)
    analysis = ActuationAnalysis(build_model(mech))
    grid = np.linspace(*mech.joint_range_rad, 13)
    margin = analysis.grid(grid, grid, analysis.span_margin)
    assert margin.min() > 0.3, margin.min()
    # Two tendons never positively span, on the compiled model either.
    two = ActuationAnalysis(build_model(Mechanism(max_tendon_force=1.0)))
    assert not positive_span(two.moment_arms(np.zeros(2)))[0]


def test_corner_routing_fails_the_span_test_on_the_compiled_model():
    """Three tendons that all wrap both pulleys: the moment arms are corners (+-r1, +-r2), and
    the origin sits on an edge of their triangle: no margin."""
    mech = Mechanism(routing=[[1, 1], [1, -1], [-1, 1]], max_tendon_force=1.0)
    J = ActuationAnalysis(build_model(mech)).moment_arms(np.zeros(2))
    spans, margin = positive_span(J)
    assert not spans and margin == pytest.approx(0.0, abs=1e-6)


def test_tension_distribution_gives_the_torque_and_keeps_the_pretension():
    mech = Mechanism(routing="n_plus_1", pull_only=True, max_tendon_force=1.0)
    analysis = ActuationAnalysis(build_model(mech))
    rng = np.random.default_rng(0)
    for _ in range(50):
        J = analysis.moment_arms(rng.uniform(-1.4, 1.4, 2))
        tau = rng.uniform(-1, 1, 2) * 1e-3
        t = distribute(J, tau, pull_only=True, pretension=0.05)
        np.testing.assert_allclose(-J.T @ t, tau, atol=1e-12)
        assert t.min() == pytest.approx(0.05)


@pytest.mark.parametrize("policy", ["pd", "ct"])
def test_pull_only_targets_and_no_negative_tension(policy):
    metrics, _ = evaluate(policy, {"preset": "pull_only"}, [0, 1])
    limit = {"pd": 0.3, "ct": 0.02}[policy]
    assert max(metrics["rms_deg"]) <= limit, metrics["rms_deg"]
    assert metrics["negative_tension_steps"] == 0
    assert min(metrics["min_tension_N"]) >= 0.0


def test_random_actions_never_push():
    env = gym.make("Tendon2R-v0", preset="pull_only")
    env.reset(seed=0)
    for _ in range(300):
        *_, terminated, truncated, info = env.step(env.action_space.sample())
        assert np.all(info["tendon_tension"] >= 0.0)
        if terminated or truncated:
            env.reset()


def test_tendon_names_follow_the_routing():
    m = build_model(Mechanism(routing="n_plus_1", max_tendon_force=1.0))
    assert [m.tendon(tendon_name(i)).name for i in range(3)] == ["tendon1", "tendon2", "tendon3"]
    assert m.actuator(motor_name(2)).trnid[0] == m.tendon("tendon3").id


FOUR = [[1, 1], [1, -1], [-1, 0], [-1, 1]]  # four tendons: distribute's general branch


def test_four_pull_only_tendons_distribute_exactly_and_track():
    """With 4 tendons the null space is 2-D: the tensions still give the asked joint torques
    exactly, keep the pretension, and PD tracks without a pushing tendon."""
    mech = Mechanism(routing=FOUR, pull_only=True, max_tendon_force=1.0, pretension=0.03)
    analysis = ActuationAnalysis(build_model(mech))
    rng = np.random.default_rng(0)
    for q in rng.uniform(-1.2, 1.2, (20, 2)):
        J = analysis.moment_arms(q)
        assert J.shape == (4, 2)
        tau = rng.normal(0.0, 1e-3, 2)
        t = distribute(J, tau, pull_only=True, pretension=0.03)
        np.testing.assert_allclose(-J.T @ t, tau, atol=1e-12)
        assert t.min() == pytest.approx(0.03)
    metrics, _ = evaluate("pd", {"preset": "pull_only", "mechanism": {"routing": FOUR}}, [0])
    assert max(metrics["rms_deg"]) <= 0.3 and metrics["negative_tension_steps"] == 0
    assert len(metrics["rms_tension_N"]) == 4

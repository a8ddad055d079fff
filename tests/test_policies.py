"""PD and computed torque: closed-loop behaviour, and the evaluation script's outputs."""

import json

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from tendon2r_gym import Tendon2REnv
from tendon2r_gym.app.cli import evaluate_main
from tendon2r_gym.evaluation.evaluator import evaluate
from tendon2r_gym.evaluation.metrics import tracking_metrics
from tendon2r_gym.evaluation.rollout import rollout, rollouts
from tendon2r_gym.policies.baselines import ComputedTorquePolicy, Gains, PDPolicy
from tendon2r_gym.task.observation import ERROR, Q_DES


def test_pd_removes_a_step_error():
    # A step needs far more force than tracking a smooth reference: the limit is given.
    env = Tendon2REnv(
        reference={"amp_deg": [0, 0], "bias_deg": [10, -10]},
        mechanism={"max_tendon_force": 0.5},
        episode_duration=0.3,
    )
    obs, _ = env.reset(seed=0)
    env.set_state(np.zeros(2), np.zeros(2))  # 10 deg away from the set point on both joints
    obs = env.current_observation()
    pd = PDPolicy.from_env(env)
    start = np.abs(np.degrees(obs[ERROR]))
    for _ in range(300):
        obs, *_ = env.step(pd.predict(obs)[0])
    assert np.all(start > 9.9)
    assert np.all(np.abs(np.degrees(obs[ERROR])) < 0.01 * start)


@pytest.mark.parametrize("policy", [PDPolicy, ComputedTorquePolicy])
def test_baselines_never_read_the_env_state(policy):
    """The action depends on the observation only: scrambling the env's MjData after the
    observation changes nothing."""
    env = Tendon2REnv()
    ctrl = policy.from_env(env)
    assert ctrl.actuation.model is not env.model and ctrl.actuation.data is not env.data
    obs, _ = env.reset(seed=0)
    for _ in range(5):
        obs, *_ = env.step(ctrl.predict(obs)[0])
    before, _ = ctrl.predict(obs)
    env.data.qpos[:], env.data.qvel[:] = 1.0, -5.0
    mujoco.mj_forward(env.model, env.data)
    np.testing.assert_array_equal(ctrl.predict(obs)[0], before)


def test_ct_follows_each_episodes_reference_under_reference_ranges():
    """CT reads the episode's reference from the reset info: on random references it tracks
    as on fixed ones (it used to track the nominal reference and reach 0.05 deg)."""
    ranges = {"amp_deg": [[5, 25], [5, 20]], "freq_hz": [[0.5, 3], [0.5, 3]],
              "bias_deg": [[-10, 10], [-15, 5]]}  # fmt: skip
    kwargs = {"preset": "default", "reference_ranges": ranges, "episode_duration": 1.0}
    env = gym.make("Tendon2R-v0", **kwargs)
    ct = ComputedTorquePolicy.from_env(env)
    traces = rollouts(ct, kwargs, [0, 1, 2])
    fixed = []
    for seed in (0, 1, 2):
        drawn = env.reset(seed=seed)[1]["reference"]
        fixed.append(tracking_metrics([rollout(ct, env, 0, {"reference": drawn})])["rms_deg"])
    ranged = tracking_metrics(traces)["rms_deg"]
    assert max(ranged) <= 2 * max(max(f) for f in fixed) and max(ranged) < 0.01, (ranged, fixed)


def test_settled_rms_leaves_out_the_resets_transient():
    """settled_rms_deg is the RMS error after each episode's first SETTLE_S: an error only
    inside that window counts in rms_deg and not there."""
    from tendon2r_gym.evaluation.metrics import SETTLE_S
    from tendon2r_gym.evaluation.rollout import Trace

    steps, dt = 100, 0.001
    time = dt * np.arange(1, steps + 1)
    error = np.zeros((steps, 2))
    error[time <= time[0] + SETTLE_S, 1] = 0.03
    error[-1, 0] = 0.01
    z = np.zeros((steps, 2))
    trace = Trace(0, time, z, z, error, z, z, z, np.zeros(steps), False)
    m = tracking_metrics([trace, trace])
    assert m["settled_rms_deg"][1] == 0.0 < m["rms_deg"][1]
    after = np.sum(time > time[0] + SETTLE_S)
    assert m["settled_rms_deg"][0] == pytest.approx(0.01 / np.sqrt(after))


def test_pd_action_is_bounded_and_batched():
    env = Tendon2REnv()
    obs, _ = env.reset(seed=0)
    obs = obs.copy()
    obs[Q_DES] += 3.0  # a huge error saturates the command
    pd = PDPolicy.from_env(env)
    single, _ = pd.predict(obs)
    batch, _ = pd.predict(np.stack([obs, obs]))
    assert single.shape == (2,) and batch.shape == (2, 2)
    assert np.all(np.abs(single) <= 1.0)
    np.testing.assert_array_equal(batch[0], single)


def test_bandwidth_is_capped_by_the_control_rate():
    gains = Gains(bandwidth_hz=1000.0, max_bandwidth_fraction=0.05)
    assert gains.natural_frequency(0.001) == pytest.approx(2 * np.pi * 50)
    with pytest.raises(ValueError, match="bandwidth_hz"):
        Gains(bandwidth_hz=-1.0)


def test_computed_torque_beats_pd_on_default():
    kwargs = {"preset": "default", "episode_duration": 1.0}
    pd, _ = evaluate("pd", kwargs, [0])
    ct, _ = evaluate("ct", kwargs, [0])
    assert all(c < p for c, p in zip(ct["rms_deg"], pd["rms_deg"], strict=True))


@pytest.mark.parametrize(
    ("preset", "policy", "limit_deg"),
    [("default", "pd", 0.3), ("default", "ct", 0.02), ("report_002", "pd", 1.0)],
)
def test_tracking_targets(preset, policy, limit_deg):
    metrics, _ = evaluate(policy, {"preset": preset}, [0, 1])
    assert max(metrics["rms_deg"]) <= limit_deg, metrics["rms_deg"]
    assert metrics["diverged_episodes"] == 0


#: Mechanisms the PD gains were not tuned on: other pulley sizes and link lengths.
UNTUNED = [
    {"R1": 0.03, "R2": 0.01, "a": 0.02, "b": 0.12, "c": 0.06, "max_tendon_force": 1.0},
    {"R1": 0.02, "R2": 0.02, "a": 0.1, "b": 0.03, "c": 0.2, "max_tendon_force": 1.0},
    {"R1": 0.01, "R2": 0.04, "a": 0.03, "b": 0.05, "c": 0.08, "max_tendon_force": 1.0},
]


@pytest.mark.parametrize("mechanism", UNTUNED)
def test_same_pd_config_tracks_untuned_mechanisms(mechanism):
    metrics, _ = evaluate("pd", {"preset": "default", "mechanism": mechanism}, [0])
    assert max(metrics["rms_deg"]) <= 1.0, (mechanism, metrics["rms_deg"])


def test_evaluate_script_writes_json_plots_and_video(tmp_path):
    config = tmp_path / "my_arm.yaml"
    config.write_text(
        "mechanism: {R1: 0.012, R2: 0.02, a: 0.05, b: 0.07, c: 0.09, max_tendon_force: 0.5}\n"
        "reference: {amp_deg: [10, 10], omega_rad_s: [6.0, 9.0], bias_deg: [0, -5]}\n"
    )
    out = tmp_path / "m.json"
    evaluate_main(
        [
            "--policy",
            "pd",
            "--env-config",
            str(config),
            "--episodes",
            "2",
            "--episode-duration",
            "0.1",
            "--json",
            str(out),
            "--plots",
            str(tmp_path / "p"),
            "--video",
            str(tmp_path / "v.gif"),
        ]
    )
    metrics = json.loads(out.read_text())
    for key in ("rms_deg", "max_deg", "rms_tension_N", "saturated_fraction"):
        assert len(metrics[key]) == 2
    assert metrics["episodes"] == 2 and metrics["seeds"] == [0, 1]
    for name in ("tracking.png", "forces.png", "effector_path.png"):
        assert (tmp_path / "p" / name).stat().st_size > 1000
    assert (tmp_path / "v.gif").stat().st_size > 1000


def test_evaluate_rejects_unknown_policy():
    with pytest.raises(ValueError, match="allowed"):
        evaluate("lqr", {"preset": "default", "episode_duration": 0.01}, [0])


def test_computed_torque_uses_the_model_not_the_env():
    env = Tendon2REnv()
    ct = ComputedTorquePolicy.from_env(env)
    assert ct.data is not env.data


def test_tendon_command_is_the_damped_inverse_of_the_moment_arms():
    """The closed-form 2x2 solve equals numpy's damped least squares, and the resulting tendon
    forces give the asked joint torque through J^T (to the damping's relative error)."""
    env = Tendon2REnv()
    pd = PDPolicy.from_env(env)
    rng = np.random.default_rng(0)
    lo, hi = env.mechanism.joint_range_rad
    for _ in range(20):
        J = pd.kinematics(rng.uniform(0.8 * lo, 0.8 * hi, (1, 2)))[0][0]  # at q, PD's own model
        tau = rng.uniform(-1, 1, 2) * 1e-3  # small: no saturation
        lam2 = pd.gains.force_damping * np.sum(J * J)
        f = J @ np.linalg.solve(J.T @ J + lam2 * np.eye(2), tau)
        u = pd.tendon_command(J[None], tau[None])[0]
        np.testing.assert_allclose(u, f / env.mechanism.max_tendon_force, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(J.T @ f, tau, rtol=0.05, atol=1e-9)
    # No tendon touches a pulley: no force rather than a division by zero.
    np.testing.assert_array_equal(pd.tendon_command(np.zeros((1, 2, 2)), np.ones((1, 2))), [[0, 0]])


def test_residual_wrapper_with_zero_residual_is_pd():
    from tendon2r_gym.policies.residual import Residual
    from tendon2r_gym.training.manager import make_training_env

    wrapped = make_training_env({"preset": "default"}, Residual(0.5))
    plain = Tendon2REnv()
    pd = PDPolicy.from_env(plain)
    obs_w, _ = wrapped.reset(seed=3)
    obs_p, _ = plain.reset(seed=3)
    for _ in range(100):
        obs_w, *_ = wrapped.step(np.zeros(2, np.float32))
        obs_p, *_ = plain.step(pd.predict(obs_p)[0])
    np.testing.assert_array_equal(obs_w, obs_p)
    for bad in (np.array([np.nan, 0.0]), np.zeros(3)):
        with pytest.raises(ValueError, match=r"action = .* allowed: finite real numbers of shape"):
            wrapped.step(bad)

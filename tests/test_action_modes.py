"""action_mode "joint_torque": the env turns normalized joint torques into tendon tensions with
PD's distribution, and every consumer (PD, CT, the residual wrapper, the vector env) follows."""

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from tendon2r_gym.envs.env import Tendon2REnv
from tendon2r_gym.evaluation.evaluator import evaluate
from tendon2r_gym.policies.baselines import PDPolicy
from tendon2r_gym.policies.residual import NO_RESIDUAL, Residual, ResidualPDWrapper
from tendon2r_gym.task import observation as L


@pytest.mark.parametrize("preset", ["default", "pull_only"])
def test_joint_torque_action_applies_that_torque(preset):
    """On the compiled model, the motors' joint torque equals action * max_torque (to
    the distribution's damping) on every step where no motor saturates, and pull-only
    tensions stay >= the pretension."""
    env = Tendon2REnv(preset, action_mode="joint_torque")
    assert env.action_space.shape == (2,)
    env.reset(seed=0)
    m, d = env.model, env.data
    check = mujoco.MjData(m)
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(40):
        q, dq = d.qpos.copy(), d.qvel.copy()
        a = rng.uniform(-0.3, 0.3, 2)
        obs, *_ = env.step(a)
        np.testing.assert_array_equal(obs[L.last_action_slice(3, 2)], a)
        if np.max(np.abs(d.ctrl)) >= 0.999:
            continue  # a saturated motor: the torque is clipped
        checked += 1
        check.qpos[:], check.qvel[:], check.ctrl[:] = q, dq, d.ctrl
        mujoco.mj_forward(m, check)
        tau = a * env.torque_map.max_torque
        np.testing.assert_allclose(
            check.qfrc_actuator, tau, rtol=1e-2, atol=1e-2 * np.max(np.abs(tau))
        )
        if env.mechanism.pull_only:
            assert np.all(env.tendon_tensions() >= env.mechanism.pretension - 1e-12)
    assert checked >= 10


def test_max_joint_torque_saturates_a_tendon():
    """At q = 0, a full normalized torque on one joint drives some tendon to its force limit."""
    env = Tendon2REnv(action_mode="joint_torque")
    env.reset(seed=0, options={"reference": {"amp_deg": [0, 0], "bias_deg": [0, 0]}})
    env.unwrapped.set_state(np.zeros(2), np.zeros(2))
    for j in range(2):
        a = np.zeros(2)
        a[j] = 1.0
        u = env.torque_map.joint_torque_command(np.zeros((1, 2)), a[None])[0]
        assert np.max(np.abs(u)) == pytest.approx(1.0, rel=1e-2)


@pytest.mark.parametrize("preset", ["default", "pull_only"])
def test_pd_tracks_in_both_action_modes(preset):
    """PD outputs the env's kind of action, and tracks as well in either mode."""
    tension, _ = evaluate("pd", {"preset": preset, "episode_duration": 1.0}, [0])
    torque, _ = evaluate(
        "pd", {"preset": preset, "episode_duration": 1.0, "action_mode": "joint_torque"}, [0]
    )
    np.testing.assert_allclose(torque["rms_deg"], tension["rms_deg"], rtol=0.05)
    ct, _ = evaluate(
        "ct", {"preset": preset, "episode_duration": 1.0, "action_mode": "joint_torque"}, [0]
    )
    assert all(c < p for c, p in zip(ct["rms_deg"], torque["rms_deg"], strict=True))


def test_residual_wrapper_in_joint_torque_mode_starts_at_pd():
    """A zero residual on the registered env in joint_torque mode reproduces PD exactly."""
    env = ResidualPDWrapper(gym.make("Tendon2R-v0", action_mode="joint_torque"), 0.5)
    ref = gym.make("Tendon2R-v0", action_mode="joint_torque")
    pd = PDPolicy.from_env(ref)
    obs, _ = env.reset(seed=3)
    obs_ref, _ = ref.reset(seed=3)
    for _ in range(50):
        obs, *_ = env.step(np.zeros(2))
        obs_ref, *_ = ref.step(pd.predict(obs_ref)[0])
        np.testing.assert_array_equal(obs, obs_ref)


def test_residual_filter_low_passes_the_residual_and_not_pd():
    """residual_filter_tau: the command is PD's, unfiltered, plus the residual through a
    first-order low-pass with that time constant (a unit step reaches 1 - 1/e of the way
    after tau / ctrl_dt steps), restarting from 0 with each episode."""
    tau = 0.01
    env = ResidualPDWrapper(gym.make("Tendon2R-v0"), 0.5, residual_filter_tau=tau)
    ref = gym.make("Tendon2R-v0")
    pd = PDPolicy.from_env(ref)
    steps = round(tau / ref.unwrapped.config.ctrl_dt)
    step = np.array([1.0, -1.0])
    for seed in (3, 4):  # the second episode starts its filter anew
        obs, _ = env.reset(seed=seed)
        obs_ref, _ = ref.reset(seed=seed)
        alpha, y = -np.expm1(-ref.unwrapped.config.ctrl_dt / tau), np.zeros(2)
        for _ in range(steps):
            y = y + alpha * (0.5 * step - y)
            command = np.clip(pd.predict(obs_ref)[0] + y, -1.0, 1.0)
            obs, *_ = env.step(step)
            obs_ref, *_ = ref.step(command)
            np.testing.assert_array_equal(obs, obs_ref)
        np.testing.assert_allclose(y, 0.5 * step * (1 - np.exp(-1)), rtol=1e-9)
    with pytest.raises(ValueError, match=r"residual_filter_tau = 2 .*\[0, 1\]"):
        ResidualPDWrapper(gym.make("Tendon2R-v0"), 0.5, residual_filter_tau=2)


def test_residual_settings_travel_as_one_record():
    """A Residual reads back from the record it writes (an entry's and run.json's names); a
    record without residual fields (plain PPO, or none) is no residual, and one written before
    the filter existed takes its default; bad values name the record's field."""
    for residual in (Residual(0.5), Residual(1.5, 0.002), NO_RESIDUAL):
        assert Residual.from_record(residual.to_record()) == residual
    assert Residual.from_record(None) == Residual.from_record({}) == NO_RESIDUAL
    assert not NO_RESIDUAL.active and Residual(0.5).active
    assert Residual.from_record({"residual_scale": 0.5}) == Residual(0.5, 0.0)
    for bad, match in (
        ({"scale": 3.0}, r"residual_scale = 3"),
        ({"filter_tau": 0.01}, r"residual_filter_tau = 0.01 .*without a residual"),
    ):
        with pytest.raises(ValueError, match=match):
            Residual(**bad)


def test_bad_action_mode_names_the_field():
    with pytest.raises(ValueError, match="action_mode"):
        gym.make("Tendon2R-v0", action_mode="torque")
    with pytest.raises(ValueError, match=r"action = .*\(2,\)"):
        Tendon2REnv("pull_only", action_mode="joint_torque").step(np.zeros(3))


def test_action_filter_step_response_has_its_time_constant():
    """A unit step of the action reaches 1 - 1/e of the way after tau / ctrl_dt steps, and the
    observation carries the applied command."""
    env = Tendon2REnv(action_filter_tau=0.01)
    env.reset(seed=0)
    where = L.last_action_slice(3, 2)
    for _ in range(10):  # tau / ctrl_dt = 10 steps
        obs, *_ = env.step(np.array([1.0, -1.0]))
    np.testing.assert_allclose(obs[where], [1 - np.exp(-1), -(1 - np.exp(-1))], rtol=1e-12)
    limit = env.mechanism.max_tendon_force
    np.testing.assert_allclose(env.tendon_tensions(), -obs[where] * limit, rtol=1e-12)


@pytest.mark.parametrize("preset", ["default", "report_002"])
def test_baselines_track_through_the_action_filter(preset):
    """PD sends the action that the filter turns into its own command: the same tracking."""
    kwargs = {"preset": preset, "episode_duration": 1.0}
    plain, _ = evaluate("pd", kwargs, [0])
    filtered, _ = evaluate("pd", {**kwargs, "action_filter_tau": 0.01}, [0])
    np.testing.assert_allclose(filtered["rms_deg"], plain["rms_deg"], rtol=0.01)


def test_bad_action_filter_names_the_field():
    with pytest.raises(ValueError, match="action_filter_tau"):
        gym.make("Tendon2R-v0", action_filter_tau=-0.01)


@pytest.mark.parametrize(
    ("field", "trained", "deployed"),
    [("action_mode", "tension", "joint_torque"), ("action_filter_tau", 0.0, 0.005)],
)
def test_a_model_runs_only_in_the_action_semantics_it_was_trained_in(field, trained, deployed):
    """A model's actions mean tensions or joint torques, filtered or not: another setting is a
    ValueError naming it, and a run recorded before the setting existed takes its default."""
    from tendon2r_gym.artifacts.model_env import check_model_env

    def recorded(**kw):
        config = gym.make("Tendon2R-v0", **kw).unwrapped.config
        return {**config.to_dict(), "observation": config.observation.layout()}

    check_model_env(recorded(**{field: trained}), gym.make("Tendon2R-v0"), "model")
    old = {k: v for k, v in recorded().items() if k != field}
    check_model_env(old, gym.make("Tendon2R-v0"), "model")
    with pytest.raises(ValueError, match=f"model was trained for another env: {field} = "):
        check_model_env(recorded(), gym.make("Tendon2R-v0", **{field: deployed}), "model")

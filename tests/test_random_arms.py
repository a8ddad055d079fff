"""Random arms (``mechanism_ranges``): each reset draws a valid arm and its reference; the
episode is the one an experiment file of that arm gives; PD and CT follow the arm."""

import dataclasses

import gymnasium as gym
import numpy as np
import pytest

from tendon2r_gym.artifacts.model_env import check_model_env
from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.envs.timing import Timing
from tendon2r_gym.policies.baselines import ComputedTorquePolicy, PDPolicy
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.task import observation
from tendon2r_gym.task.arms import (
    COURSE,
    ENVELOPE,
    GEOMETRY,
    NAMED_RANGES,
    ArmRanges,
    MechanismRanges,
    draw_episode_arm,
    reference_ranges,
)
from tendon2r_gym.task.reference import Reference

CABLES = {"tendon_elasticity": [2000.0, 6000.0], "motor_tau": [0.001, 0.004]}
#: Random motor and sensor delays (whole control steps, 0 to 3).
DELAYS = {"motor_delay": [0.0, 0.003], "observation_delay": [0.0, 0.003]}


def _episode(env, policy, seed, steps=200):
    obs, info = env.reset(seed=seed)
    policy.reset(info)
    out = [obs]
    for _ in range(steps):
        obs, *_ = env.step(policy.predict(obs)[0])
        out.append(obs)
    return info, np.array(out)


@pytest.mark.parametrize(
    ("ranges", "match"),
    [({"R9": [0.01, 0.02]}, "mechanism_ranges = 'R9'"),
     ({"c": [0.09, 0.08]}, r"mechanism_ranges.c = .*lo <= hi"),
     ({"c": [0.08, 2.0]}, r"mechanism_ranges.c"),
     ({"motor_tau": [0.0, 0.01]}, r"mechanism_ranges.motor_tau = .*different layouts"),
     ({}, "mechanism_ranges = {}"),
     ("everything", "mechanism_ranges = 'everything'"),
     ({"a": [0.001, 0.002]}, "mechanism_ranges = .*valid arm"),
     ({"pd_bandwidth_hz": [0.0, 30.0]}, r"mechanism_ranges.pd_bandwidth_hz = .*0 < lo"),
     ({"c": [0.08, 0.09], "pd_tuned_phase": [0.4, 0.8]},
      r"mechanism_ranges.pd_tuned_phase = .*pd_bandwidth_hz"),
     ({"pd_bandwidth_hz": [10.0, 40.0], "pd_tuned_phase": [0.0, 0.8]},
      r"mechanism_ranges.pd_tuned_phase = .*0 < lo"),
     ({"pd_bandwidth_hz": [10.0, 40.0], "pd_tuned_phase": [0.5, 2.0]},
      r"mechanism_ranges.pd_tuned_phase = \[0.5, 2.0\]"),
     ([], r"mechanism_ranges = \[\]"),
     (["real_arm", [{"c": [0.05, 0.06]}]], "mechanism_ranges = .*a list of names and mappings")],
)  # fmt: skip
def test_bad_ranges_raise_at_construction_naming_the_field(ranges, match):
    with pytest.raises(ValueError, match=match):
        EnvConfig.make("default", mechanism_ranges=ranges)


def test_observing_the_arm_needs_ranges():
    with pytest.raises(ValueError, match=r"observe = \['arm'\] .* without 'arm' unless"):
        EnvConfig.make("default", observe=["arm"])
    with pytest.raises(ValueError, match="arm_feature_ranges = .* None unless observe lists"):
        EnvConfig.make("default", arm_feature_ranges="course")
    with pytest.raises(ValueError, match="arm_feature_ranges: .*'R9' is invalid"):
        EnvConfig.make("default", observe=["arm"], arm_feature_ranges={"R9": [0.0, 1.0]})


def test_one_arm_observed_over_given_ranges():
    """arm_feature_ranges: one fixed arm's slice is its fields normalized over those ranges,
    as a generalist trained on them saw it, in both envs; the arm itself is not drawn."""
    from tendon2r_gym.envs.vector_env import Tendon2RVectorEnv

    kwargs = {"preset": "default", "observe": ["arm"], "arm_feature_ranges": "course"}
    config = EnvConfig.make(**kwargs)
    expected = MechanismRanges.from_value("course").features(config)
    assert (
        config.observation.arm_fields == ("R1", "R2", "a", "b", "c")
        and config.mechanism_ranges is None
    )
    env = gym.make("Tendon2R-v0", **kwargs)
    venv = Tendon2RVectorEnv(2, **kwargs)
    arm = observation.arm_slice(3, 2, 5)
    for seed in (0, 1):
        obs, info = env.reset(seed=seed)
        assert obs[arm].tolist() == expected and "mechanism" not in info
    vobs, _ = venv.reset(seed=0)
    assert (vobs[:, arm] == np.array(expected)).all()
    assert np.array_equal(vobs[0], env.reset(seed=0)[0])


@pytest.mark.parametrize("name", sorted(NAMED_RANGES))
def test_named_ranges_are_their_arm_ranges(name):
    """``course`` and ``envelope`` give their ArmRanges' geometry to mechanism_ranges and
    their amplitudes, frequencies and biases (both joints) to reference_ranges."""
    arm = NAMED_RANGES[name]
    ranges = MechanismRanges.from_value(name)
    assert ranges.names == GEOMETRY
    assert ranges.to_dict() == {k: list(getattr(arm, k)) for k in GEOMETRY}
    ref = reference_ranges(name)
    for k in ("amp_deg", "freq_hz", "bias_deg"):
        assert getattr(ref, k) == (getattr(arm, k),) * 2


def test_the_envelope_holds_the_course():
    """The generalists' envelope is wider than the course on every range."""
    for f in dataclasses.fields(ArmRanges):
        (lo, hi), (clo, chi) = getattr(ENVELOPE, f.name), getattr(COURSE, f.name)
        assert lo <= clo and chi <= hi, f.name


def test_each_reset_draws_a_valid_arm_inside_the_ranges_same_seed_same_arm():
    env = gym.make("Tendon2R-v0", preset="generalist")
    ranges = env.unwrapped.config.mechanism_ranges
    arms = []
    for seed in range(6):
        _, info = env.reset(seed=seed)
        mech = Mechanism.from_dict(info["mechanism"])
        assert mech == env.unwrapped.mechanism
        assert not ranges.violations(env.unwrapped.arm)
        assert info["max_tendon_force_N"] == mech.max_tendon_force
        arms.append(info["mechanism"])
    assert len({a["c"] for a in arms}) == len(arms)  # a new arm every reset
    _, again = env.reset(seed=3)
    assert again["mechanism"] == arms[3] and again["reference"] == env.unwrapped.reference.to_dict()
    # the compiled model is the drawn arm's: joint B sits c from joint A
    m = env.unwrapped.mechanism
    assert np.isclose(env.unwrapped.model.body("link_b").pos[0], m.c)


REAL = {"tendon_elasticity": 4000.0, "motor_tau": 0.002}


@pytest.mark.parametrize(
    "kwargs",
    [{"preset": "generalist"},
     {"preset": "pull_only", "mechanism": REAL, "mechanism_ranges": CABLES},
     {"preset": "real_arm", "observation_noise": [0.0, 0.0], "mechanism_ranges": DELAYS},
     {"preset": "real_arm", "observation_noise": [0.0, 0.0],
      "mechanism_ranges": [DELAYS, {"pd_bandwidth_hz": [10.0, 40.0]}]}],
)  # fmt: skip
def test_a_random_episode_is_the_episode_of_its_arms_experiment_file(kwargs):
    """The drawn arm, as a static config (tendon2r_gym.task.arms.arm_config: the arm, its
    reference, its own auto force limit), runs the same episode under PD, bit for bit; PD
    follows the arm."""
    rand = gym.make("Tendon2R-v0", reset_noise_scale=0.0, **kwargs)
    pd = PDPolicy.from_env(rand)
    for seed in (0, 1):
        info, obs = _episode(rand, pd, seed)
        arm = rand.unwrapped.arm
        assert arm.mechanism_ranges is None and arm.reference.to_dict() == info["reference"]
        static = gym.make("Tendon2R-v0", **{**arm.to_dict(), "preset": "default"})
        assert static.unwrapped.config.mechanism == arm.mechanism  # its own auto limit
        _, obs_static = _episode(static, PDPolicy.from_env(static), seed)
        np.testing.assert_array_equal(obs, obs_static)


def test_arm_features_are_the_drawn_fields_normalized():
    env = gym.make("Tendon2R-v0", preset="generalist", observe=["arm"])
    cfg = env.unwrapped.config
    where = observation.arm_slice(cfg.preview_steps, cfg.n_actions, len(GEOMETRY))
    assert env.observation_space.shape == (where.stop,)
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        mech = Mechanism.from_dict(info["mechanism"])
        expected = [
            2 * (getattr(mech, k) - lo) / (hi - lo) - 1  # geometry: mechanism fields
            for k, (lo, hi) in cfg.mechanism_ranges.ranges
        ]
        np.testing.assert_allclose(obs[where], expected, rtol=0, atol=1e-12)
        assert np.all(np.abs(obs[where]) <= 1)
        obs, *_ = env.step(env.action_space.sample())
        np.testing.assert_allclose(obs[where], expected, rtol=0, atol=1e-12)  # constant
    assert ["arm", len(GEOMETRY)] in cfg.observation.layout()
    assert "arm" not in dict(EnvConfig.make("default").observation.layout())


def test_ct_follows_the_arm_and_the_reference():
    """Computed torque with the drawn arm's model tracks it to the accuracy it has on a
    static arm (far better than PD): it uses the arm's inverse dynamics, not the nominal's."""
    env = gym.make("Tendon2R-v0", preset="generalist")
    ct, pd = ComputedTorquePolicy.from_env(env), PDPolicy.from_env(env)
    for seed in (0, 1):
        _, obs_ct = _episode(env, ct, seed, 400)
        _, obs_pd = _episode(env, pd, seed, 400)
        err = lambda o: np.sqrt(np.mean(o[100:, observation.ERROR] ** 2))  # noqa: E731
        assert err(obs_ct) < 0.2 * err(obs_pd)


def test_generalist_loads_on_arms_inside_its_ranges_only():
    recorded = {
        **EnvConfig.make("generalist").to_dict(),
        "observation": EnvConfig.make("generalist").observation.layout(),
    }
    inside = gym.make("Tendon2R-v0", mechanism={"c": 0.09, "R1": 0.02})
    check_model_env(recorded, inside, "generalist")
    # how the arm is integrated is not the arm
    simulated = {"c": 0.09, "sim_dt": 5e-4, "integrator": "Euler"}
    other_step = gym.make("Tendon2R-v0", mechanism=simulated)
    check_model_env(recorded, other_step, "generalist")
    outside = gym.make("Tendon2R-v0", mechanism={"c": 0.13})
    with pytest.raises(ValueError, match=r"c = 0.13 outside \[0.025, 0.12\]"):
        check_model_env(recorded, outside, "generalist")
    too_fast = gym.make("Tendon2R-v0", reference={"freq_hz": [5.5, 1.0]})
    with pytest.raises(ValueError, match=r"reference.freq_hz of joint A = 5.5 outside"):
        check_model_env(recorded, too_fast, "generalist")
    other_routing = gym.make("Tendon2R-v0", preset="pull_only")
    with pytest.raises(ValueError, match="trained for another env"):
        check_model_env(recorded, other_routing, "generalist")
    damped = gym.make("Tendon2R-v0", mechanism={"joint_damping": 1e-3})  # not drawn
    with pytest.raises(ValueError, match="trained for another env: mechanism"):
        check_model_env(recorded, damped, "generalist")


def test_fixed_reference_option_on_random_arms():
    env = gym.make("Tendon2R-v0", preset="generalist")
    ref = {"amp_deg": [5.0, 5.0], "bias_deg": [0.0, 0.0], "freq_hz": [1.0, 1.0]}
    _, info = env.reset(seed=0, options={"reference": ref})
    assert Reference.from_dict(info["reference"]) == Reference.from_dict(
        {**ref, "phase_deg": [0.0, 0.0]}
    )


def test_a_residual_policy_follows_the_arm_in_rollouts():
    """PPOPolicy's inner PD follows each episode's arm (rollouts call reset(info)): with a
    zero residual it acts exactly as PD does on every drawn arm."""
    from tendon2r_gym.policies.learned import PPOPolicy
    from tendon2r_gym.policies.residual import Residual

    class Zero:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.zeros((*np.shape(obs)[:-1], 2), dtype=np.float32), state

    env = gym.make("Tendon2R-v0", preset="generalist")
    residual = PPOPolicy(Zero(), None, Residual(0.5), env)
    for seed in (0, 1):
        _, ours = _episode(env, residual, seed, 50)
        _, pd = _episode(env, PDPolicy.from_env(env), seed, 50)
        np.testing.assert_array_equal(ours, pd)


def test_real_arm_ranges_are_the_perturbed_arms_ranges():
    """mechanism_ranges: real_arm draws the cables, motors and sensors of the benchmark's
    perturbed arms (one home: realism.PERTURBATIONS), and every draw has the real arm's model
    layout."""
    from tendon2r_gym.simulation.realism import PERTURBATIONS

    env = gym.make("Tendon2R-v0", preset="real_arm", mechanism_ranges="real_arm")
    ranges = env.unwrapped.config.mechanism_ranges
    assert dict(ranges.ranges) == PERTURBATIONS
    nq = env.unwrapped.model.nq
    for seed in range(3):
        _, info = env.reset(seed=seed)
        assert not ranges.violations(env.unwrapped.arm)
        assert env.unwrapped.model.nq == nq


def test_delays_and_noise_are_drawn_per_episode_in_whole_steps():
    """mechanism_ranges draws the motor's dead time and the sensors' delay and noise too: each
    episode's values lie in the ranges, delays in whole control steps, and the reset info and
    the arm features report them; each episode's delay shifts its own PD response."""
    env = gym.make("Tendon2R-v0", preset="real_arm", mechanism_ranges="real_arm", observe=["arm"])
    cfg = env.unwrapped.config
    ranges, dt = cfg.mechanism_ranges, cfg.ctrl_dt
    timing = env.unwrapped.timing
    assert timing.delay_capacity == timing.observation_delay_capacity == 2
    seen = set()
    for seed in range(8):
        obs, info = env.reset(seed=seed)
        arm = env.unwrapped.arm
        assert not ranges.violations(arm)
        for delay in (arm.mechanism.motor_delay, arm.observation_delay):
            assert delay / dt == round(delay / dt)
        assert info["observation_noise"] == list(arm.observation_noise)
        assert info["observation_delay"] == arm.observation_delay
        assert info["mechanism"]["motor_delay"] == arm.mechanism.motor_delay
        where = observation.arm_slice(cfg.preview_steps, cfg.n_actions, len(ranges.names))
        np.testing.assert_allclose(obs[where], ranges.features(arm), rtol=0, atol=1e-12)
        seen.add((Timing.of(arm).delay_steps, Timing.of(arm).observation_delay_steps))
    assert len(seen) > 2  # several delay combinations drawn


@pytest.mark.parametrize("steps", [[0, 2, 1], [2, 2, 2]])
def test_command_delay_holds_each_arm_its_own_steps(steps):
    from tendon2r_gym.simulation.realism import CommandDelay

    delay = CommandDelay(max(steps), 3, 1)
    for i, k in enumerate(steps):
        delay.set_arm(i, k, [-1.0])
    delay.reset(slice(None))
    out = [delay(np.full((3, 1), float(t)))[:, 0] for t in range(6)]
    for i, k in enumerate(steps):
        np.testing.assert_array_equal([o[i] for o in out], [-1.0] * k + list(range(6 - k)))
    with pytest.raises(ValueError, match="motor delay"):
        delay.set_arm(0, max(steps) + 1, [0.0])


def test_a_list_of_ranges_merges_in_order():
    """``[real_arm, {...}]``: the named set's ranges, then the mapping's, a later range of a
    field replacing an earlier one in place."""
    from tendon2r_gym.simulation.realism import PERTURBATIONS

    merged = MechanismRanges.from_value(
        ["real_arm", {"motor_tau": [0.002, 0.003], "pd_bandwidth_hz": [10.0, 40.0]}]
    )
    expected = {**PERTURBATIONS, "motor_tau": (0.002, 0.003), "pd_bandwidth_hz": (10.0, 40.0)}
    assert merged.ranges == tuple(expected.items())
    assert merged.draws_gains and not MechanismRanges.from_value("real_arm").draws_gains


def test_drawn_pd_gains_are_each_episodes_and_pd_follows_them():
    """pd_bandwidth_hz drawn: each reset draws a bandwidth inside the range, reports the
    episode's gains in the reset info and observes it (normalized) in the arm slice; PD and a
    residual's PD use it: kp = (2 pi bandwidth)^2 on the arm."""
    from tendon2r_gym.policies.residual import ResidualPDWrapper

    lo, hi = 10.0, 40.0
    kwargs = {"preset": "real_arm", "observe": ["arm"]}
    env = gym.make(
        "Tendon2R-v0", mechanism_ranges=[DELAYS, {"pd_bandwidth_hz": [lo, hi]}], **kwargs
    )
    pd, residual = PDPolicy.from_env(env), ResidualPDWrapper(env, 0.5)
    seen = set()
    for seed in range(4):
        obs, info = env.reset(seed=seed)
        bandwidth = info["pd_gains"]["bandwidth_hz"]
        assert lo <= bandwidth <= hi and bandwidth == env.unwrapped.arm.pd_gains.bandwidth_hz
        assert obs[-1] == 2 * (bandwidth - lo) / (hi - lo) - 1
        pd.reset(info)
        residual.reset(seed=seed)
        for controller in (pd, residual.pd):
            np.testing.assert_allclose(controller.kp, (2 * np.pi * bandwidth) ** 2, rtol=1e-12)
        seen.add(bandwidth)
    assert len(seen) == 4
    _, info = gym.make("Tendon2R-v0", mechanism_ranges=DELAYS, **kwargs).reset(seed=0)
    assert "pd_gains" not in info  # only where they are drawn


def test_a_model_trained_on_drawn_gains_runs_on_the_users_tuned_gains():
    """Deployed on one arm, a residual trained on drawn PD gains runs the PD of the arm's own
    gains (what tendon2r-tune-pd wrote) and sees them; gains outside its training range, or
    none where a phase was drawn, are refused by name."""
    from tendon2r_gym.artifacts.model_env import arm_features, deployed_gains

    ranges = ["real_arm", {"pd_bandwidth_hz": [10.0, 40.0]}]
    trained = EnvConfig.make("real_arm", mechanism_ranges=ranges, observe=["arm"],
                             pd_gains={"bandwidth_hz": 12.0, "damping_ratio": 0.9})  # fmt: skip
    recorded = {**trained.to_dict(), "observation": trained.observation.layout()}
    arm = gym.make("Tendon2R-v0", preset="real_arm", pd_gains={"bandwidth_hz": 25.0})
    check_model_env(recorded, arm, "model")
    gains = deployed_gains(recorded, arm)
    assert (gains.bandwidth_hz, gains.damping_ratio) == (25.0, 0.9)  # the arm's, the model's
    assert arm_features(recorded, arm)[-1] == 2 * (25.0 - 10.0) / 30.0 - 1
    too_stiff = gym.make("Tendon2R-v0", preset="real_arm", pd_gains={"bandwidth_hz": 45.0})
    with pytest.raises(ValueError, match=r"pd_bandwidth_hz = 45.0 outside \[10, 40\]"):
        check_model_env(recorded, too_stiff, "model")
    phase = {**recorded, "mechanism_ranges": [*ranges, {"pd_max_delay_phase": [0.3, 0.6]}]}
    with pytest.raises(ValueError, match=r"pd_max_delay_phase = None outside \[0.3, 0.6\]"):
        check_model_env(phase, arm, "model")


def test_a_drawn_delay_phase_schedules_each_episodes_pd_on_its_loop_delay():
    """pd_max_delay_phase drawn (the env's own gains set none): each episode's PD is held to
    the drawn phase over the arm's loop delay, and the env builds and observes it."""
    from tendon2r_gym.task.gains import loop_delay

    kwargs = {"preset": "real_arm", "observe": ["arm"]}
    ranges = ["real_arm", {"pd_max_delay_phase": [0.3, 0.6]}]
    env = gym.make("Tendon2R-v0", mechanism_ranges=ranges, **kwargs)
    pd = PDPolicy.from_env(env)
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        phase = info["pd_gains"]["max_delay_phase"]
        assert 0.3 <= phase <= 0.6 and obs[-1] == 2 * (phase - 0.3) / 0.3 - 1
        pd.reset(info)
        arm = env.unwrapped.arm
        tau = loop_delay(arm.mechanism, arm.observation_delay, env.unwrapped.ctrl_dt)
        w = min(2 * np.pi * info["pd_gains"]["bandwidth_hz"], phase / tau)
        np.testing.assert_allclose(pd.kp, w * w, rtol=1e-12)


def test_a_tuned_phase_draws_each_arms_bandwidth_as_a_tuning_would_pick_it():
    """pd_tuned_phase: each episode's bandwidth takes a phase in the range of the drawn arm's
    true loop (w tau / sqrt(density_scale)), clipped to pd_bandwidth_hz's range, so a heavier
    or faster arm gets a stiffer PD; the rule survives the run's record (to_dict)."""
    from tendon2r_gym.task.gains import loop_delay, tuned_bandwidth

    lo, hi, phase = 10.0, 40.0, (0.5, 0.7)
    ranges = ["real_arm", {"pd_bandwidth_hz": [lo, hi], "pd_tuned_phase": list(phase)}]
    cfg = EnvConfig.make("real_arm", mechanism_ranges=ranges, observe=["arm"])
    assert MechanismRanges.from_value(cfg.mechanism_ranges.to_dict()) == cfg.mechanism_ranges
    assert (
        cfg.observation.arm_fields == cfg.mechanism_ranges.names
    )  # the bandwidth is seen, not the phase
    rng, clipped, inside = np.random.default_rng(0), 0, 0
    for _ in range(200):
        arm = draw_episode_arm(cfg, rng)
        f = arm.pd_gains.bandwidth_hz
        m = arm.mechanism
        tau = loop_delay(m, arm.observation_delay, cfg.ctrl_dt)
        taken = 2 * np.pi * f * tau / np.sqrt(m.density_scale)
        if lo < f < hi:
            assert phase[0] - 1e-12 <= taken <= phase[1] + 1e-12
            inside += 1
        else:
            clipped += 1
        heavier = m.replace(density_scale=2 * m.density_scale)
        assert tuned_bandwidth(heavier, arm.observation_delay, cfg.ctrl_dt, 0.6) == pytest.approx(
            np.sqrt(2) * tuned_bandwidth(m, arm.observation_delay, cfg.ctrl_dt, 0.6)
        )
    assert inside > 100 and clipped > 0

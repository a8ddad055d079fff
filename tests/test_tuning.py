"""PD gains per experiment file (``pd_gains``) and the bandwidth scan that tunes them."""

import math

import gymnasium as gym
import numpy as np
import pytest
import yaml

from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.evaluation.evaluator import evaluate
from tendon2r_gym.evaluation.tuning import (
    GRID_RATIO,
    MIN_BANDWIDTH_HZ,
    bandwidth_grid,
    delay_phase_grid,
    tune_pd,
)
from tendon2r_gym.policies.baselines import ComputedTorquePolicy, PDPolicy
from tendon2r_gym.policies.learned import PPOPolicy
from tendon2r_gym.policies.residual import Residual, ResidualPDWrapper
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.task.arms import arm_config
from tendon2r_gym.task.gains import Gains, default_gains, loop_delay

#: An arm whose motor lag and delays make the default 30 Hz PD diverge.
LAGGING = {"preset": "real_arm", "mechanism": {"motor_delay": 0.002, "motor_tau": 0.004},
           "observation_delay": 0.002, "episode_duration": 0.5}  # fmt: skip


@pytest.mark.parametrize(
    ("gains", "match"),
    [({"bandwidth": 10.0}, "pd_gains: unknown key 'bandwidth'; did you mean 'bandwidth_hz'"),
     ({"bandwidth_hz": -1.0}, r"pd_gains.bandwidth_hz = -1.0 .*\(0, inf\)"),
     ({"damping_ratio": "high"}, "pd_gains.damping_ratio = 'high'"),
     ("fast", "pd_gains = 'fast'")],
)  # fmt: skip
def test_bad_gains_raise_at_construction_naming_the_field(gains, match):
    with pytest.raises(ValueError, match=match):
        EnvConfig.make("default", pd_gains=gains)


def test_gains_of_the_experiment_file_reach_pd_ct_and_the_residual_wrapper():
    env = gym.make("Tendon2R-v0", pd_gains={"bandwidth_hz": 12.0})
    expected = Gains.from_dict({"bandwidth_hz": 12.0})
    assert env.unwrapped.config.pd_gains == expected
    assert expected.damping_ratio == default_gains().damping_ratio  # the others kept
    assert PDPolicy.from_env(env).gains == expected
    assert ComputedTorquePolicy.from_env(env).gains == expected
    assert ResidualPDWrapper(env, 0.5).pd.gains == expected
    assert PDPolicy.from_env(gym.make("Tendon2R-v0")).gains == default_gains()
    pd = PDPolicy.from_env(env)
    assert math.isclose(pd.kp, (2 * math.pi * 12.0) ** 2)
    # an override names only the fields it changes
    cfg = EnvConfig.make("default", pd_gains={"bandwidth_hz": 12.0})
    assert EnvConfig.from_kwargs({**cfg.to_dict(), "pd_gains": {"damping_ratio": 0.7}}) \
        .pd_gains.damping_ratio == 0.7  # fmt: skip


def test_a_residual_keeps_the_pd_it_was_trained_on():
    """PPOPolicy's inner PD has the gains recorded with the model, not the env's."""
    env = gym.make("Tendon2R-v0", pd_gains={"bandwidth_hz": 20.0})
    trained_on = {"bandwidth_hz": 15.0}
    policy = PPOPolicy(None, None, Residual(0.5), env, trained_on)
    assert policy.pd.gains == Gains.from_dict(trained_on)
    assert PPOPolicy(None, None, Residual(0.5), env).pd.gains == default_gains()  # recorded: none


def test_bandwidth_grid_is_geometric_through_the_default_up_to_the_cap():
    for kwargs in ({}, {"ctrl_dt": 0.002}, {"pd_gains": {"bandwidth_hz": 9.0}}):
        cfg = EnvConfig.make("default", **kwargs)
        grid = bandwidth_grid(cfg)
        cap = default_gains().max_bandwidth_fraction / cfg.ctrl_dt
        assert grid[0] >= MIN_BANDWIDTH_HZ and grid[-1] <= cap + 1e-9
        assert grid[-1] * GRID_RATIO > cap and grid[0] / GRID_RATIO < MIN_BANDWIDTH_HZ
        np.testing.assert_allclose(np.diff(np.log(grid)), math.log(GRID_RATIO), atol=1e-6)
        assert min(default_gains().bandwidth_hz, cap) in grid


def test_tuning_finds_stable_gains_where_the_default_diverges():
    """On a lagging arm the default PD fails; the scan picks a lower bandwidth whose next grid
    point holds too, and the tuned PD tracks on the evaluation seeds (not the tuning ones)."""
    scan = tune_pd(LAGGING, episodes=1)
    default, _ = evaluate("pd", LAGGING, [0])
    tuned, _ = evaluate("pd", {**LAGGING, "pd_gains": scan.gains.to_dict()}, [0])
    assert scan.chosen < default_gains().bandwidth_hz
    assert max(default["rms_deg"]) > 10.0 > 10 * max(tuned["rms_deg"])
    i = scan.values.index(scan.chosen)
    assert max(scan.worst_deg[i + 1]) < 10.0  # the gain margin: one grid step above holds
    assert scan.gains == Gains.from_dict({"bandwidth_hz": scan.chosen})


def test_tune_pd_command_writes_a_file_that_tunes_to_itself(tmp_path):
    from tendon2r_gym.app.cli import tune_pd_main

    arm = tmp_path / "arm.yaml"
    overrides = {k: v for k, v in LAGGING.items() if k != "preset"}
    arm.write_text(yaml.safe_dump({**yaml.safe_load(open(_preset("real_arm"))), **overrides}))
    out = tmp_path / "tuned.yaml"
    first = tune_pd_main(["--env-config", str(arm), "--episodes", "1", "--out", str(out)])
    assert EnvConfig.make(str(out)).pd_gains.to_dict() == first["pd_gains"]
    again = tune_pd_main(["--env-config", str(out), "--episodes", "1"])
    assert again["pd_gains"] == first["pd_gains"]
    with pytest.raises(ValueError, match="--episodes = 0"):
        tune_pd_main(["--episodes", "0"])


def _preset(name):
    from tendon2r_gym.presets import preset_path

    return preset_path(name)


# -- gains scheduled on each arm's loop delay (pd_gains.max_delay_phase) -------------------------
def test_delay_phase_caps_the_bandwidth_at_the_phase_over_the_loop_delay():
    mech = EnvConfig.make("real_arm").mechanism
    delay = loop_delay(mech, 0.001, 0.001)
    assert math.isclose(delay, 0.001 + mech.motor_delay + mech.motor_tau + 0.0005)
    free = Gains.from_dict({"bandwidth_hz": 40.0})
    assert free.natural_frequency(0.001, delay) == 2 * math.pi * 40.0  # no phase: no cap
    held = Gains.from_dict({"bandwidth_hz": 40.0, "max_delay_phase": 0.5})
    w = held.natural_frequency(0.001, np.array([delay, 1e-4]))
    np.testing.assert_allclose(w, [0.5 / delay, 2 * math.pi * 40.0])  # a short delay: the cap
    with pytest.raises(ValueError, match=r"pd_gains.max_delay_phase = 0 .*\(0, inf\)"):
        Gains.from_dict({"max_delay_phase": 0})


def test_scheduled_pd_is_the_fixed_pd_of_each_drawn_arms_bandwidth():
    """Under mechanism_ranges each episode draws delays; PD with max_delay_phase then acts as
    the PD with that arm's bandwidth, phase / (2 pi loop delay), in the single env (its reset
    info) and in every row of the vector env."""
    phase = 0.5
    kwargs = {"preset": "real_arm", "mechanism_ranges": "real_arm", "episode_duration": 0.05,
              "pd_gains": {"bandwidth_hz": 46.0, "max_delay_phase": phase}}  # fmt: skip

    def fixed_pd(cfg):
        bw = phase / (2 * math.pi * loop_delay(cfg.mechanism, cfg.observation_delay, 0.001))
        assert 5.0 < bw < 46.0  # the phase sets it, on every drawn arm
        return PDPolicy(cfg.mechanism, 0.001, {"bandwidth_hz": bw})

    env = gym.make("Tendon2R-v0", **kwargs)
    pd = PDPolicy.from_env(env)
    for seed in (0, 1):
        obs, info = env.reset(seed=seed)
        pd.reset(info)
        arm = arm_config(
            env.unwrapped.config,
            Mechanism.from_dict(info["mechanism"]),
            observation_delay=info["observation_delay"],
        )
        np.testing.assert_array_equal(pd.predict(obs)[0], fixed_pd(arm).predict(obs)[0])
    venv = gym.make_vec("Tendon2R-v0", 3, vectorization_mode="vector_entry_point", **kwargs)
    obs, info = venv.reset(seed=0)
    pd = PDPolicy.from_env(venv)
    pd.reset(info)
    actions, _ = pd.predict(obs)
    arms = venv.unwrapped.arms
    assert len({a.observation_delay + a.mechanism.motor_tau for a in arms}) > 1  # different arms
    for i, arm in enumerate(arms):
        np.testing.assert_array_equal(actions[i], fixed_pd(arm).predict(obs[i])[0])


def test_tune_pd_scans_the_delay_phase():
    """The scan holds the bandwidth at the control rate's cap and chooses a phase; the tuned
    PD tracks the lagging arm where the default diverges."""
    scan = tune_pd(LAGGING, episodes=1, scan="max_delay_phase")
    assert scan.field == "max_delay_phase" and scan.values == tuple(delay_phase_grid())
    assert scan.gains.max_delay_phase == scan.chosen
    assert scan.gains.bandwidth_hz == max(bandwidth_grid(EnvConfig.make(**LAGGING)))
    tuned, _ = evaluate("pd", {**LAGGING, "pd_gains": scan.gains.to_dict()}, [0])
    assert max(tuned["rms_deg"]) < 1.0
    with pytest.raises(ValueError, match="scan = 'kp'"):
        tune_pd(LAGGING, scan="kp")


def test_tuning_an_env_that_draws_pd_gains_is_refused():
    """A scan cannot set gains that the env draws per episode: refused, naming the ranges."""
    drawn = {**LAGGING, "mechanism_ranges": ["real_arm", {"pd_bandwidth_hz": [10.0, 40.0]}]}
    with pytest.raises(ValueError, match="mechanism_ranges = .*pd_bandwidth_hz.*leave PD's gains"):
        tune_pd(drawn, episodes=1)

"""Every bad input gets a clear ValueError at construction; good numbers of any numeric type are
accepted; unstable physics is refused; a diverged step stays bounded."""

import math
import warnings

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from tendon2r_gym import Mechanism, Reference, ReferenceRanges
from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.simulation.model import build_model
from tendon2r_gym.simulation.stability import LIMITS, check_stability, rates

RANGES = {"amp_deg": [[5, 20], [5, 20]], "freq_hz": [[0.5, 3], [0.5, 3]],
          "bias_deg": [[-10, 10], [-10, 10]]}  # fmt: skip

#: (gym.make kwargs, what the message must contain).  Each names the field and the value.
BAD_ENV_KWARGS = [
    ({"tracking_weigth": 1}, r"unknown key 'tracking_weigth'.*allowed"),
    ({"ctrl_dtt": 0.001}, r"did you mean 'ctrl_dt'"),
    ({"mechanism": {"R11": 0.01}}, r"did you mean 'R1'"),
    ({"reference": {"amp_dg": [1, 1]}}, r"did you mean 'amp_deg'"),
    ({"reward_scales": {"trackin": 1}}, r"did you mean 'tracking'"),
    ({"mechanism": {"R1": "0.01"}}, r"Mechanism.R1 = '0.01' is invalid; allowed: a finite"),
    ({"mechanism": {"R1": True}}, r"Mechanism.R1 = True is invalid"),
    ({"mechanism": {"a": -1.0}}, r"Mechanism.a = -1.0 is invalid"),
    ({"mechanism": {"b": math.nan}}, r"Mechanism.b = nan is invalid"),
    ({"mechanism": {"joint_damping": True}}, r"Mechanism.joint_damping = True"),
    ({"mechanism": {"tendon_stiffness": False}}, r"Mechanism.tendon_stiffness = False"),
    ({"mechanism": {"tendon_damping": "x"}}, r"Mechanism.tendon_damping = 'x'"),
    ({"mechanism": {"max_tendon_force": "big"}}, r"max_tendon_force = 'big'.*'auto'"),
    ({"mechanism": {"max_tendon_force": 0}}, r"max_tendon_force = 0 is invalid"),
    ({"mechanism": {"sim_dt": 0.05}}, r"Mechanism.sim_dt = 0.05 is invalid"),
    ({"mechanism": {"integrator": "rk4"}}, r"Mechanism.integrator = 'rk4'"),
    ({"mechanism": {"routing": "zigzag"}}, r"Mechanism.routing = 'zigzag'"),
    ({"mechanism": {"routing": [[1.5, 1], [-1, 1]]}}, r"Mechanism.routing = \[\[1.5"),
    ({"mechanism": {"routing": [[1, 1]]}}, r"Mechanism.routing"),
    ({"mechanism": {"joint_range_deg": [90, -90]}}, r"joint_range_deg"),
    ({"mechanism": {"R1": 0.2}}, r"Mechanism.R1 = 0.2 is invalid"),
    ({"mechanism": "big arm"}, r"mechanism = 'big arm' is invalid; allowed: a mapping"),
    ({"reference": "fast"}, r"reference = 'fast' is invalid; allowed: a mapping"),
    ({"reference": {"amp_deg": "ab"}}, r"reference.amp_deg = 'ab' is invalid"),
    ({"reference": {"amp_deg": [1, 2, 3]}}, r"reference.amp_deg = \[1, 2, 3\]"),
    ({"reference": {"amp_deg": [95, 10]}}, r"joint range"),
    ({"reference": {"freq_hz": [200, 1]}}, r"reference.freq_hz = \[200, 1\]"),
    ({"ctrl_dt": 0.01, "reference": {"freq_hz": [20, 1]}}, r"reference frequency.*10 control"),
    ({"reference": {"omega_rad_s": [1, 1], "freq_hz": [1, 1]}}, "exactly one"),
    ({"reference_ranges": {"amp_deg": [[5, 20]]}}, r"reference_ranges.*freq_hz"),
    ({"reference_ranges": {**RANGES, "freq_hz": [[3, 1], [1, 2]]}}, r"reference_ranges.freq_hz"),
    ({"reference_ranges": {**RANGES, "bias_deg": [[-95, 95], [0, 0]]}}, r"could leave it"),
    (
        {"ctrl_dt": 0.01, "reference_ranges": {**RANGES, "freq_hz": [[1, 20], [1, 2]]}},
        r"reference frequency",
    ),
    ({"reference_ranges": "random"}, r"reference_ranges = 'random' is invalid"),
    ({"fit_to_workspace": "yes"}, r"fit_to_workspace = 'yes' is invalid; allowed: true or false"),
    ({"ctrl_dt": 0.00125}, r"ctrl_dt = 0.00125 is invalid; allowed: an integer multiple"),
    ({"ctrl_dt": "1ms"}, r"ctrl_dt = '1ms' is invalid"),
    ({"ctrl_dt": 0.01, "episode_duration": 0.005}, r"episode_duration = 0.005 is invalid"),
    ({"episode_duration": -1}, r"episode_duration = -1 is invalid"),
    ({"reward_scales": {"tracking": -1}}, r"reward_scales.tracking = -1 is invalid"),
    ({"reward_scales": {"ctrl": 1e308}}, r"reward_scales.ctrl = 1e\+308 is invalid.*1e\+06\]"),
    ({"observation_noise": [1e-4]}, r"observation_noise = \[0.0001\] is invalid"),
    ({"observation_noise": np.array([1e-4, np.inf])}, r"observation_noise = array"),
    ({"mechanism": {"motor_tau": 1e-4, "sim_dt": 1e-3}},
     r"Mechanism.motor_tau = 0.0001 is invalid; allowed: >="),
    ({"reward_scales": [1, 2]}, r"reward_scales = \[1, 2\] is invalid"),
    ({"tracking_form": "cubic"}, r"tracking_form = 'cubic' is invalid"),
    ({"tracking_sigma_deg": 0}, r"tracking_sigma_deg = 0 is invalid"),
    ({"reset_noise_scale": 1e6}, r"reset_noise_scale = 1000000.0 is invalid"),
    ({"preview_steps": True}, r"preview_steps = True is invalid"),
    ({"preview_steps": 2.0}, r"preview_steps = 2.0 is invalid"),
    ({"preview_steps": -1}, r"preview_steps = -1 is invalid"),
    ({"preview_dt": 0}, r"preview_dt = 0 is invalid"),
    ({"render_mode": "rgb"}, r"render_mode = 'rgb' is invalid"),
    ({"camera_name": "nope"}, r"camera_name = 'nope' is invalid"),
    ({"width": -5}, r"width = -5 is invalid"),
    ({"height": 1.5}, r"height = 1.5 is invalid"),
    ({"preset": "nope"}, r"unknown preset 'nope'"),
    ({"preset": "/no/such.yaml"}, r"preset = '/no/such.yaml' is invalid"),
    ({"preset": 3}, r"preset = 3 is invalid"),
    ({"mechanism": {"joint_damping": 0.01, "sim_dt": 1e-3}}, r"joint_damping = 0.01.*implicitfast"),
    ({"mechanism": {"tendon_damping": 10, "sim_dt": 1e-3}}, r"tendon_damping = 10.*sim_dt"),
    ({"mechanism": {"tendon_stiffness": 1e5, "sim_dt": 1e-3}},
     r"tendon_stiffness = 100000.0.*sim_dt"),
    ({"mechanism": {"b": 1e6}}, r"Mechanism.b = 1000000.0 is invalid; allowed: .*\(0, 1\]"),
    ({"mechanism": {"c": 1e6}}, r"Mechanism.c = 1000000.0 is invalid"),
    ({"mechanism": {"R1": 1e-9}}, r"Mechanism.link_radius = 0.002 is invalid; .*pulley radius"),
    ({"mechanism": {"density": 1e-12}}, r"Mechanism mass fields = .*density.*allowed: .*mass"),
    ({"mechanism": {"link_radius": 1e-9, "R1": 1e-8}}, r"Mechanism mass fields = .*mjMINVAL"),
]


@pytest.mark.parametrize(("kwargs", "match"), BAD_ENV_KWARGS)
def test_bad_env_kwargs_raise_a_clear_error_at_construction(kwargs, match, monkeypatch):
    from tendon2r_gym.envs import env as env_module

    built = []
    build = env_module.build_model  # the env's own model, from its arm

    def spy(mechanism):  # builds as usual: a late failure still raises, but after the spy saw it
        built.append(1)
        return build(mechanism)

    monkeypatch.setattr(env_module, "build_model", spy)
    with pytest.raises(ValueError, match=match) as err:
        gym.make("Tendon2R-v0", **kwargs)
    assert "allowed" in str(err.value) or "did you mean" in str(err.value)
    assert not built, "refused before any MuJoCo model is built"


@pytest.mark.parametrize(
    "kwargs",
    [
        {"mechanism": {"R1": np.float32(0.014), "a": np.float64(0.052), "c": np.int64(1)}},
        {"ctrl_dt": np.float32(0.002)},
        {"preview_steps": np.int64(3)},
        {"episode_duration": np.float16(1.0)},
        {"mechanism": {"routing": np.array([[1, 1], [-1, 1]])}},
        {"reference": {"amp_deg": np.array([10.0, 5.0])}},
        {"fit_to_workspace": np.bool_(True)},
        {"observation_noise": np.array([1e-4, 0.05])},
        {"reference": {"freq_hz": np.array([1.0, 2.0])}, "reward_scales": {"ctrl": np.float32(1)}},
    ],
)
def test_numpy_numbers_are_numbers(kwargs):
    env = gym.make("Tendon2R-v0", **kwargs)
    obs, _ = env.reset(seed=0)
    assert np.isfinite(obs).all()


def test_the_largest_reward_weights_give_a_finite_reward():
    """Every weight at its bound, from a start far off the reference: the reward is finite."""
    from tendon2r_gym.task.rewards import MAX_REWARD_WEIGHT, REWARD_SCALES

    scales = dict.fromkeys(REWARD_SCALES, MAX_REWARD_WEIGHT)
    env = gym.make("Tendon2R-v0", reward_scales=scales, action_mode="joint_torque")
    env.reset(seed=0)
    for _ in range(20):
        _, reward, *_ = env.step(env.action_space.high)
        assert np.isfinite(reward) and np.isfinite(np.float32(reward))


def test_the_vector_env_takes_numpy_seeds():
    from tendon2r_gym.envs.vector_env import Tendon2RVectorEnv

    envs = Tendon2RVectorEnv(2)
    a, _ = envs.reset(seed=np.array([3, 4]))
    b, _ = envs.reset(seed=[3, 4])
    c, _ = envs.reset(seed=np.int64(3))
    assert np.array_equal(a, b) and np.array_equal(a, c)
    with pytest.raises(ValueError, match=r"seed\[1\] = 'x' is invalid"):
        envs.reset(seed=[3, "x"])


def test_float32_ctrl_dt_keeps_its_step_count():
    env = gym.make("Tendon2R-v0", ctrl_dt=np.float32(0.002), episode_duration=0.1)
    assert env.spec.max_episode_steps == 50 and env.unwrapped.frame_skip == 2


def test_reference_ranges_never_fail_after_construction():
    """Ranges whose corners fit are accepted, and no draw then fails at reset."""
    ranges = {"amp_deg": [[5, 80], [5, 80]], "freq_hz": [[0, 4], [0, 4]],
              "bias_deg": [[-30, 30], [-40, 40]]}  # fmt: skip
    env = gym.make("Tendon2R-v0", reference_ranges=ranges)
    for seed in range(50):
        env.reset(seed=seed)


def test_direct_constructors_share_the_checks():
    with pytest.raises(ValueError, match="reference.bias_deg"):
        Reference(amp_deg=(1, 1), bias_deg=(1, "x"), freq_hz=(1, 1))
    with pytest.raises(ValueError, match="reference_ranges.phase_deg"):
        ReferenceRanges(amp_deg=((0, 1), (0, 1)), freq_hz=((0, 1), (0, 1)),
                        bias_deg=((0, 1), (0, 1)), phase_deg=((0, 1000), (0, 1)))  # fmt: skip
    assert Mechanism(R1=np.float32(0.014)).R1 == pytest.approx(0.014)


# -- numerical stability: both sides of the criterion -------------------------------------------
def _limit(field: str, integrator: str) -> float:
    """The largest value of ``field`` the criterion accepts on the default mechanism."""
    mech = Mechanism(max_tendon_force=0.5, integrator=integrator, **{field: 1.0})
    rate = rates(build_model(mech), mech)[field] * mech.sim_dt
    limits = LIMITS[integrator]
    return (limits.stiffness / rate) ** 2 if field == "tendon_stiffness" else limits.damping / rate


def _diverges(mech: Mechanism) -> bool:
    m = build_model(mech)
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = (0.3, -0.4), (5.0, -5.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(2000):
            mujoco.mj_step(m, d)
            if (
                not np.all(np.abs(d.qvel) < 1e4)
                or d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number
            ):
                return True
    return False


@pytest.mark.parametrize(
    ("field", "integrator"),
    [("joint_damping", "RK4"), ("tendon_damping", "RK4"), ("tendon_stiffness", "RK4"),
     ("tendon_damping", "Euler"), ("tendon_stiffness", "implicitfast")],
)  # fmt: skip
def test_stability_criterion_on_both_sides(field, integrator):
    limit = _limit(field, integrator)
    below = {"integrator": integrator, field: 0.5 * limit, "max_tendon_force": 0.5}
    env = gym.make("Tendon2R-v0", mechanism=below)
    env.reset(seed=0)
    for _ in range(200):
        *_, terminated, _, info = env.step(env.action_space.sample())
        assert not terminated
    above = {"integrator": integrator, field: 2.0 * limit}
    with pytest.raises(ValueError, match=rf"Mechanism.{field} = .* is invalid; allowed: <= "):
        gym.make("Tendon2R-v0", mechanism={**above, "sim_dt": 0.001})  # explicit: no resizing
    assert _diverges(Mechanism(max_tendon_force=0.5, **above)), "the refused value diverges"


#: The real_arm preset's cables and motors, without its lag and delays.
ELASTIC = {"routing": "n_plus_1", "pull_only": True, "pretension": 0.02,
           "tendon_elasticity": 400.0, "motor_mass": 0.002}  # fmt: skip


def _drive_diverges(mech: Mechanism) -> bool:
    """Whether 2 s of the motors held at half their range, from a moving start, diverge."""
    m = build_model(mech)
    d = mujoco.MjData(m)
    d.qpos[:2], d.qvel[:2], d.ctrl[:] = (0.3, -0.4), (5.0, -5.0), 0.5
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(2000):
            mujoco.mj_step(m, d)
            state = np.concatenate([d.qvel, d.act])
            bad = d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number
            if bad or not np.all(np.abs(state) < 1e4):
                return True
    return False


@pytest.mark.parametrize("integrator", ["RK4", "Euler"])
def test_stability_criterion_covers_the_motor_lag_and_the_cable_damping(integrator):
    """The realism fields' own states: the motor filter's lag (RK4 integrates it explicitly)
    and a series-elastic cable's damping across its spool."""
    base = Mechanism(integrator=integrator, **ELASTIC)
    r = rates(build_model(base.ideal()), Mechanism(integrator=integrator, tendon_damping=1.0,
                                                   motor_tau=1.0, **ELASTIC))  # fmt: skip
    limits, dt = LIMITS[integrator], base.sim_dt
    cases = [("tendon_damping", limits.cable_damping / (r["tendon_damping"] * dt), 2.0)]
    if integrator == "RK4":  # the lag's rate is 1 / motor_tau: its limit is a least value
        cases.append(("motor_tau", dt / limits.lag * r["motor_tau"], 0.5))
    for field, limit, outside in cases:
        inside = {**ELASTIC, "integrator": integrator, field: limit / outside}
        env = gym.make("Tendon2R-v0", mechanism=inside)
        env.reset(seed=0)
        n = env.action_space.shape[0]
        for k in range(300):  # a square wave of the commands: steps the lag and the cables
            action = np.full(n, 0.3 if (k // 50) % 2 else -0.3)
            *_, terminated, _, info = env.step(action)
            assert not terminated and not info["diverged"], (field, inside[field], k)
        above = {**ELASTIC, "integrator": integrator, field: limit * outside}
        with pytest.raises(ValueError, match=rf"Mechanism.{field} = .* is invalid; allowed: "):
            gym.make("Tendon2R-v0", mechanism={**above, "sim_dt": dt})  # explicit: no resizing
        assert _drive_diverges(Mechanism(**above)), f"the refused {field} diverges"


def test_the_motor_lag_is_exact_outside_rk4():
    for integrator in ("Euler", "implicitfast"):
        mech = {**ELASTIC, "integrator": integrator, "motor_tau": 1e-5}
        gym.make("Tendon2R-v0", mechanism=mech)
        assert not _drive_diverges(Mechanism(**mech))


def test_implicitfast_integrates_damping_that_rk4_cannot():
    """Joint damping 3 times RK4's limit at the default step: RK4 diverges from a moving start
    and the env refuses it; implicitfast integrates the same arm and the env accepts it."""
    damped = {"joint_damping": 0.01, "max_tendon_force": 0.5}
    assert damped["joint_damping"] > 3 * _limit("joint_damping", "RK4")
    assert _diverges(Mechanism(integrator="RK4", **damped))
    with pytest.raises(ValueError, match=r"Mechanism.joint_damping = 0.01 is invalid; allowed: "):
        gym.make("Tendon2R-v0", mechanism={"integrator": "RK4", "sim_dt": 0.001, **damped})
    assert not _diverges(Mechanism(integrator="implicitfast", **damped))
    gym.make("Tendon2R-v0", mechanism={"integrator": "implicitfast", **damped})


# -- diverged steps stay bounded ------------------------------------------------------------------
def test_a_diverged_step_returns_the_last_good_state():
    env = gym.make("Tendon2R-v0", mechanism={"max_tendon_force": 1e9})
    obs, _ = env.reset(seed=0)
    seen = [np.abs(obs).max()]
    for _ in range(200):
        obs, reward, terminated, truncated, info = env.step(np.array([1.0, -1.0]))
        if terminated:
            break
        seen.append(np.abs(obs).max())
    assert terminated and info["diverged"]
    assert np.abs(obs).max() <= max(seen), "nothing enormous reaches a learner"
    divergence = env.unwrapped.config.reward_scales["divergence"]
    assert -1.0 - divergence - 0.1 <= reward <= 0.0
    assert info["reward_divergence"] == -divergence


def test_a_step_left_out_sizes_itself_to_what_the_integrator_keeps_stable():
    """Damped series-elastic cables on a light motor: at an explicit 1 ms RK4 step the env
    refuses them, naming the field and the fix; with sim_dt left out the experiment gets the
    largest step that divides ctrl_dt and is stable, and its episode runs.  Arms stable at
    1 ms keep it (every registered id: the contract tests)."""
    damped = {"tendon_damping": 4.0, "motor_mass": 0.001}
    with pytest.raises(ValueError, match=r"^Mechanism.tendon_damping = 4.0 is invalid; allowed: "):
        gym.make("Tendon2R-v2", preset="real_arm", mechanism={**damped, "sim_dt": 0.001})
    env = gym.make("Tendon2R-v2", preset="real_arm", mechanism=damped)
    cfg = env.unwrapped.config
    dt, n_sub = cfg.mechanism.sim_dt, round(cfg.ctrl_dt / cfg.mechanism.sim_dt)
    assert dt < 0.001 and n_sub * dt == pytest.approx(cfg.ctrl_dt)
    mech = cfg.mechanism
    check_stability(build_model(mech.ideal()), mech)
    with pytest.raises(ValueError):  # the next larger step is not stable: the largest is taken
        check_stability(build_model(mech.ideal()), mech.replace(sim_dt=cfg.ctrl_dt / (n_sub - 1)))
    env.reset(seed=0)
    # Seeded commands: some unseeded draws of full-range random pulls swing this light arm
    # more than DIVERGED_PAST_LIMIT past a joint limit within 300 steps (physics, not a failed
    # integration); seed 0's do not.
    env.action_space.seed(0)
    for _ in range(300):
        *_, terminated, _, info = env.step(env.action_space.sample())
        assert not terminated and not info["diverged"]
    assert EnvConfig.make("real_arm").mechanism.sim_dt == 0.001

"""Tendon2R-v0 behaves as a Gymnasium / SB3 user expects."""

import copy
import itertools
import pickle
import re

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from tendon2r_gym import EnvConfig, Tendon2REnv
from tendon2r_gym.task import observation as L
from tendon2r_gym.task.rewards import TERMS


def _rollout(env, seed, n=50):
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out = [obs]
    for _ in range(n):
        obs, *_ = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        out.append(obs)
    return np.array(out)


def test_registered_and_importable_by_module_prefix():
    env = gym.make("tendon2r_gym:Tendon2R-v0")
    assert isinstance(env.unwrapped, Tendon2REnv)
    cfg = env.unwrapped.config
    assert env.spec.max_episode_steps == round(cfg.episode_duration / cfg.ctrl_dt)


def _episode_length(env) -> int:
    env.reset(seed=0)
    n = 0
    while True:
        n += 1
        _, _, terminated, truncated, info = env.step(np.zeros(2))
        assert not terminated
        if truncated:
            return n


@pytest.mark.parametrize(("duration", "ctrl_dt"), [(0.05, 0.001), (0.3, 0.002), (0.05, 0.005)])
def test_episode_length_is_duration_over_ctrl_dt(duration, ctrl_dt):
    """One source of truth: gym.make and gym.make_vec give episode_duration / ctrl_dt steps."""
    steps = round(duration / ctrl_dt)
    env = gym.make("Tendon2R-v0", episode_duration=duration, ctrl_dt=ctrl_dt)
    assert env.spec.max_episode_steps == steps
    assert _episode_length(env) == steps
    envs = gym.make_vec("Tendon2R-v0", num_envs=2, episode_duration=duration, ctrl_dt=ctrl_dt)
    envs.reset(seed=0)
    for i in range(steps):
        *_, trunc, _ = envs.step(np.zeros((2, 2)))
        assert trunc.all() == (i == steps - 1)


def test_episode_duration_in_an_experiment_file(tmp_path):
    path = tmp_path / "arm.yaml"
    path.write_text(
        "episode_duration: 0.04\nctrl_dt: 2e-3\nmechanism: {R1: 0.02}\n"
        "reference: {amp_deg: [10, 10], bias_deg: [0, 0], freq_hz: [1, 1]}\n"
    )
    env = gym.make("Tendon2R-v0", preset=str(path))
    assert env.unwrapped.mechanism.R1 == 0.02
    assert _episode_length(env) == 20
    assert _episode_length(gym.make("Tendon2R-v0", preset=str(path), ctrl_dt=0.001)) == 40


def test_gymnasium_and_sb3_checkers_pass():
    env = gym.make("Tendon2R-v0")
    gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped)


def test_reward_equals_sum_of_terms_and_info_keys():
    env = Tendon2REnv()
    env.reset(seed=3)
    for _ in range(20):
        obs, reward, *_, info = env.step(env.action_space.sample())
        terms = [v for k, v in info.items() if k.startswith("reward_")]
        assert len(terms) == len(env.config.reward_scales)
        assert reward == pytest.approx(sum(terms), abs=1e-12)
        assert obs.dtype == env.observation_space.dtype
        assert env.observation_space.contains(obs)
        np.testing.assert_allclose(
            info["tracking_error_deg"], np.degrees(info["q_des"] - info["q"])
        )
    for key in ("q", "q_des", "tendon_tension", "moment_arm_cond", "effector_pos", "time"):
        assert key in info


def test_observation_entries_match_the_physics():
    env = Tendon2REnv()
    env.reset(seed=0)
    obs, *_ = env.step(np.array([0.3, -0.2]))
    d = env.unwrapped.data
    import mujoco

    mujoco.mj_forward(env.model, d)
    np.testing.assert_allclose(obs[L.Q], d.qpos)
    np.testing.assert_allclose(obs[L.EFFECTOR_POS], d.site("effector").xpos[[0, 2]], atol=1e-12)
    jac = np.zeros((3, 2))
    mujoco.mj_jacSite(env.model, d, jac, None, env.model.site("effector").id)
    np.testing.assert_allclose(obs[L.EFFECTOR_VEL], (jac @ d.qvel)[[0, 2]], atol=1e-12)
    ref = env.reference
    np.testing.assert_allclose(obs[L.Q_DES], ref.q(d.time))
    np.testing.assert_allclose(obs[L.DQ_DES], ref.qdot(d.time))
    np.testing.assert_allclose(obs[L.ERROR], ref.q(d.time) - d.qpos)
    preview = ref.q(d.time + np.array([1, 2, 3]) * 0.01).ravel()
    np.testing.assert_allclose(obs[L.preview_slice(3)], preview)
    assert obs.shape == (L.size(3, 2),)
    np.testing.assert_array_equal(obs[L.last_action_slice(3, 2)], [0.3, -0.2])
    # Push-pull: motor force = action * limit along the tendon; tension is minus that.
    limit = env.unwrapped.mechanism.max_tendon_force
    assert env.unwrapped.tendon_tensions() == pytest.approx(-np.array([0.3, -0.2]) * limit)


def test_error_rate_entry_is_the_log_scaled_rate_of_the_error():
    """observe "error_rate" adds error_rate_log after the last action: sign(de) log(1 + |de| / s),
    de = dq_des - dq; every other entry is as without it, and without it (the default) the
    observation is the registered one."""
    plain, env = Tendon2REnv(), Tendon2REnv(observe=["error_rate"])
    assert [n for n, _ in plain.config.observation.layout()][-1] == "last_action"
    assert plain.observation_space.shape == (L.size(3, 2),)
    assert env.config.observation.layout()[-1] == ["error_rate_log", 2]
    with_rate = L.size(3, 2, observed=[L.ERROR_RATE[0]])
    assert env.observation_space.shape == (with_rate,) == (L.size(3, 2) + 2,)
    plain.reset(seed=0)
    env.reset(seed=0)
    for a in ([0.3, -0.2], [-0.1, 0.5]):
        obs, plain_obs = env.step(np.array(a))[0], plain.step(np.array(a))[0]
    where = L.error_rate_slice(3, 2)
    np.testing.assert_array_equal(np.delete(obs, np.r_[where]), plain_obs)
    de = env.reference.qdot(env.data.time) - obs[L.DQ]
    assert np.all(np.abs(de) > L.ERROR_RATE_LOG_SCALE)  # past the linear part of the log
    expected = np.sign(de) * np.log1p(np.abs(de) / L.ERROR_RATE_LOG_SCALE)
    np.testing.assert_allclose(obs[where], expected, rtol=1e-12)
    with pytest.raises(ValueError, match=r"observe = \['rate'\] is invalid; allowed: a list"):
        gym.make("Tendon2R-v0", observe=["rate"])
    with pytest.raises(ValueError, match="observe = 'error_rate' is invalid; allowed: a list"):
        gym.make("Tendon2R-v0", observe="error_rate")


def test_force_limit_entry_is_the_log_of_each_episodes_force_limit():
    """observe "force_limit" adds force_limit_log = ln(max_tendon_force / 1 N) after
    error_rate_log and before the arm slice; on random arms it follows each episode's auto
    force limit (the reset info's), and every other entry is as without it."""
    kw = {"preset": "generalist"}
    plain = Tendon2REnv(**kw, observe=["error_rate", "arm"])
    env = Tendon2REnv(**kw, observe=["arm", "force_limit", "error_rate"])  # any order
    names = [n for n, _ in env.config.observation.layout()]
    assert names[-3:] == ["error_rate_log", "force_limit_log", "arm"]
    cfg = env.config
    where = L.optional_slice(L.FORCE_LIMIT[0], 3, 2, cfg.observation.optional)
    assert where == slice(L.error_rate_slice(3, 2).stop, L.error_rate_slice(3, 2).stop + 1)
    arm = L.arm_slice(3, 2, len(cfg.observation.arm_fields), cfg.observation.optional)
    assert arm.start == where.stop and arm.stop == env.observation_space.shape[0]
    limits = set()
    for seed in (0, 1):
        obs, info = env.reset(seed=seed)
        plain_obs, plain_info = plain.reset(seed=seed)
        assert info["max_tendon_force_N"] == plain_info["max_tendon_force_N"]
        limits.add(info["max_tendon_force_N"])
        assert obs[where] == pytest.approx([np.log(info["max_tendon_force_N"])], rel=1e-12)
        np.testing.assert_array_equal(np.delete(obs, np.r_[where]), plain_obs)
        obs = env.step(np.array([0.3, -0.2]))[0]
        assert obs[where] == pytest.approx([np.log(info["max_tendon_force_N"])], rel=1e-12)
    assert len(limits) == 2  # a new arm, a new force limit
    with pytest.raises(ValueError, match=r"observe = \[1.5\] is invalid"):
        gym.make("Tendon2R-v0", observe=[1.5])


def test_feedforward_entry_is_the_references_acceleration_in_action_units():
    """observe "feedforward" adds feedforward = rate_to_action (ctrl_dt ddq_des(t + ctrl_dt / 2))
    between error_rate_log and force_limit_log; on random arms it follows each episode's arm
    and reference, and every other entry is as without it."""
    kw = {"preset": "generalist", "action_mode": "joint_torque"}
    plain = Tendon2REnv(**kw, observe=["error_rate", "force_limit", "arm"])
    env = Tendon2REnv(**kw, observe=["error_rate", "feedforward", "force_limit", "arm"])
    names = [n for n, _ in env.config.observation.layout()]
    assert names[-4:] == ["error_rate_log", "feedforward", "force_limit_log", "arm"]
    where = L.optional_slice(L.FEEDFORWARD[0], 3, 2, env.config.observation.optional)
    assert where.start == L.error_rate_slice(3, 2).stop and where.stop - where.start == 2
    seen = []
    for seed in (0, 1):
        obs, info = env.reset(seed=seed)
        plain_obs, _ = plain.reset(seed=seed)
        np.testing.assert_array_equal(np.delete(obs, np.r_[where]), plain_obs)
        for a in ([0.3, -0.2], [-0.1, 0.5]):
            obs, plain_obs = env.step(np.array(a))[0], plain.step(np.array(a))[0]
        np.testing.assert_array_equal(np.delete(obs, np.r_[where]), plain_obs)
        u = env.unwrapped
        assert u.reference.to_dict() == info["reference"]
        assert u.arm.mechanism.to_dict() == info["mechanism"]
        dt, ref = u.config.ctrl_dt, u.reference
        mid = u.data.time + dt / 2
        ddq = -ref.amp_rad * ref.omega_array**2 * np.sin(ref.omega_array * mid + ref.phase_rad)
        expected = np.array(u.arm.needs.rate_to_action) @ (dt * ddq)
        assert np.all(np.abs(expected) > 1e-6)
        np.testing.assert_allclose(obs[where], expected, rtol=1e-9)
        seen.append(obs[where])
    assert not np.allclose(*seen)  # a new arm and reference, a new feed-forward
    with pytest.raises(ValueError, match=r"observe = \['feedforward', 'feedforward'\]"):
        gym.make("Tendon2R-v0", observe=["feedforward", "feedforward"])


@pytest.mark.parametrize(
    "field, value, allowed",
    [
        ("error_units", "action", "'rad'"),
        ("observe", ["feedforward"], "a list without 'feedforward'"),
    ],
)
def test_action_unit_entries_are_refused_on_an_arm_with_a_joint_no_tendon_spans(
    field: str, value: object, allowed: str
) -> None:
    """Both tendons end on link c: no action moves joint B, so an entry in action units (an
    infinite rate_to_action) is refused at construction, named, and the arm itself is not."""
    mechanism = {"routing": [[1, 0], [-1, 0]], "max_tendon_force": 5.0}
    env = Tendon2REnv(mechanism=mechanism)
    assert np.all(np.isinf(env.config.needs.rate_to_action[1]))
    assert np.all(np.isfinite(env.config.needs.rate_to_action[0]))
    with pytest.raises(
        ValueError, match=rf"{field} = {re.escape(repr(value))} .*{allowed} on an arm"
    ):
        Tendon2REnv(mechanism=mechanism, **{field: value})


def test_the_true_observation_under_sensor_noise_is_that_of_the_true_state():
    """With sensors, reward and info read the measured observation with every state-set entry
    rewritten from the true state: the result equals the observation of the true state."""
    for kwargs in ({}, {"observe": ["error_rate", "feedforward", "force_limit"]}):
        env = Tendon2REnv(observation_noise=[1e-3, 0.1], **kwargs)
        env.reset(seed=0)
        obs = env.step(np.array([0.3, -0.2]))[0]
        truth = env.with_true_state(obs)
        assert not np.allclose(obs, truth)
        true_state = env.current_observation(measured=False)
        np.testing.assert_allclose(truth, true_state, rtol=1e-12, atol=1e-15)


def test_same_seed_same_episode_bit_for_bit():
    a, b = Tendon2REnv(), Tendon2REnv()
    np.testing.assert_array_equal(_rollout(a, 7), _rollout(b, 7))
    assert not np.array_equal(_rollout(a, 7), _rollout(a, 8))


def test_random_reference_is_seeded():
    ranges = {
        "amp_deg": [[5, 20], [5, 20]],
        "freq_hz": [[0.5, 3], [0.5, 3]],
        "bias_deg": [[-10, 10], [-10, 10]],
    }
    a = Tendon2REnv(reference_ranges=ranges)
    b = Tendon2REnv(reference_ranges=ranges)
    _, info_a = a.reset(seed=1)
    _, info_b = b.reset(seed=1)
    assert info_a["reference"] == info_b["reference"]
    _, info_c = a.reset(seed=2)
    assert info_c["reference"] != info_a["reference"]


def test_pickle_and_deepcopy_round_trip():
    env = Tendon2REnv(mechanism={"R2": 0.03}, preview_steps=2)
    env.reset(seed=0)
    for clone in (pickle.loads(pickle.dumps(env)), copy.deepcopy(env)):
        assert clone.mechanism == env.mechanism
        np.testing.assert_array_equal(_rollout(clone, 4), _rollout(env, 4))


@pytest.mark.parametrize("bad", [[np.nan, 0.0], [0.0, np.inf]])
def test_non_finite_action_raises(bad):
    env = Tendon2REnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action = .* allowed: \(2,\) finite real numbers"):
        env.step(np.array(bad))


@pytest.mark.parametrize(
    "bad",
    [np.zeros(3), np.zeros((2, 1)), [0.1], "ab", {"a": 1}, [1j, 0.0], [True, False], None],
)
def test_wrong_action_raises_naming_the_action(bad):
    env = Tendon2REnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"(?s)action = .* invalid; allowed: \(2,\) finite"):
        env.step(bad)


def test_list_and_float32_actions_match_float64():
    envs = [Tendon2REnv() for _ in range(3)]
    outs = []
    for env, action in zip(
        envs,
        ([0.25, -0.5], np.array([0.25, -0.5], np.float32), np.array([0.25, -0.5])),
        strict=True,
    ):
        env.reset(seed=0)
        outs.append(env.step(action)[0])
    np.testing.assert_array_equal(outs[0], outs[1])
    np.testing.assert_array_equal(outs[0], outs[2])


def test_out_of_range_action_is_clipped():
    env = Tendon2REnv()
    env.reset(seed=0)
    env.step(np.array([5.0, -7.0]))
    np.testing.assert_array_equal(env.data.ctrl, [1.0, -1.0])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"mechanism": {"a": -1.0}}, "Mechanism.a"),
        ({"mechanism": {"routing": "zigzag"}}, "routing"),
        ({"reference": {"amp_deg": [95, 10]}}, "joint range"),
        (
            {"reference": {"bias_deg": [0, 0], "amp_deg": [60, 85]}, "mechanism": {"a": 0.01}},
            "wall",
        ),
        ({"reference": {"omega_rad_s": [1, 1], "freq_hz": [1, 1]}}, "exactly one"),
        ({"ctrl_dt": 0.00125}, "ctrl_dt"),
        ({"preset": "nope"}, "unknown preset"),
        ({"tracking_weight": -1.0}, "tracking_weight"),
    ],
)
def test_invalid_configuration_raises_at_make(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make("Tendon2R-v0", **kwargs)


def test_fit_to_workspace_scales_amplitude_and_warns():
    with pytest.warns(UserWarning, match="fit_to_workspace"):
        env = gym.make("Tendon2R-v0", reference={"amp_deg": [95, 10]}, fit_to_workspace=True)
    ref = env.unwrapped.reference
    assert ref.amp_deg[0] < 95 and ref.bias_deg == (-0.4, -9.7)
    assert not ref.workspace_violations(env.unwrapped.mechanism)


def test_omega_and_freq_give_the_same_reference():
    hz = Tendon2REnv(reference={"freq_hz": [2.0, 1.0]})
    rad = Tendon2REnv(reference={"omega_rad_s": [4 * np.pi, 2 * np.pi]})
    t = np.linspace(0, 1, 11)
    np.testing.assert_allclose(hz.reference.q(t), rad.reference.q(t))


def test_preset_plus_partial_override():
    env = gym.make("Tendon2R-v0", preset="report_002", mechanism={"R1": 0.02})
    mech = env.unwrapped.mechanism
    assert mech.R1 == 0.02 and mech.R2 == 0.045 and mech.c == 0.087
    assert env.unwrapped.model.geom("pulley1").size[0] == pytest.approx(0.01)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"mechanism": {"max_tendon_force": 1e9}},
        {
            "mechanism": {"sim_dt": 0.01, "integrator": "Euler", "max_tendon_force": 50.0},
            "ctrl_dt": 0.01,
        },
    ],
)
def test_forced_divergence_ends_episode_cleanly(kwargs):
    env = gym.make("Tendon2R-v0", **kwargs)
    env.reset(seed=0)
    for _ in range(200):
        obs, reward, terminated, truncated, info = env.step(np.array([1.0, -1.0]))
        assert np.isfinite(obs).all() and np.isfinite(reward)
        if terminated:
            break
    assert terminated and info["diverged"]
    assert info["reward_divergence"] < 0


def test_rgb_array_render_is_not_blank():
    env = gym.make("Tendon2R-v0", render_mode="rgb_array", width=160, height=120)
    env.reset(seed=0)
    img = env.render()
    env.close()
    assert img.shape == (120, 160, 3)
    assert img.std() > 5  # something other than a flat background


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_vector_envs(mode):
    envs = gym.make_vec("Tendon2R-v0", num_envs=2, vectorization_mode=mode)
    obs, _ = envs.reset(seed=0)
    obs2, rew, term, trunc, info = envs.step(np.zeros((2, 2), np.float32))
    envs.close()
    assert obs.shape == obs2.shape == (2, L.size(3, 2))
    assert rew.shape == (2,)


def test_readme_python_examples_run():
    """The README's Python blocks run as written, in order, in one namespace."""
    from pathlib import Path

    readme = (Path(__file__).resolve().parent.parent / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    assert len(blocks) >= 2
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, "README.md", "exec"), namespace)  # noqa: S102
    assert namespace["env"].action_space.contains(namespace["action"])


def test_multiscale_tracking_reward_is_bounded_and_keeps_a_gradient_near_zero():
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.envs.formulas import RAD_PER_DEG, Formulas
    from tendon2r_gym.ops import SCALAR

    multiscale = Formulas(EnvConfig.make(tracking_form="multiscale"))
    log = Formulas(EnvConfig.make(tracking_form="log"))

    def r(t, deg):
        e = deg * RAD_PER_DEG
        return t.reward_terms(SCALAR, e, e, [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], False)["tracking"]

    errors = [0.0, 0.001, 0.01, 0.05, 0.1, 1.0, 10.0, 90.0, 180.0]
    values = [r(multiscale, e) for e in errors]
    assert values[0] == 0.0 and values[-1] == pytest.approx(-1.0, abs=1e-12)
    assert all(a > b for a, b in itertools.pairwise(values)), values
    # From 0.05 to 0.01 deg the multiscale reward gains far more than the log form.
    assert r(multiscale, 0.01) - r(multiscale, 0.05) > 100 * (r(log, 0.01) - r(log, 0.05))


@pytest.mark.parametrize("form", ["multiscale", "log", "quadratic"])
def test_tracking_rate_is_the_tracking_kernel_of_the_error_ahead(form):
    """tracking_rate is the tracking form's kernel of e + tracking_horizon de: at errors e
    changing at de, it is the tracking term at the errors e + h de; unweighted, it is 0."""
    from tendon2r_gym.envs.formulas import RAD_PER_DEG, Formulas
    from tendon2r_gym.ops import SCALAR

    def terms(e1, e2, de1=0.0, de2=0.0, weight=1.0, horizon=0.05):
        cfg = EnvConfig.make(tracking_form=form, tracking_horizon=horizon,
                             reward_scales={"tracking_rate": weight})  # fmt: skip
        zero = [0.0, 0.0]
        return Formulas(cfg).reward_terms(SCALAR, e1, e2, zero, zero, zero, False, de1, de2)

    e1, e2, de1, de2 = (x * RAD_PER_DEG for x in (0.25, -0.5, 4.0, 1.0))
    moving = terms(e1, e2, de1, de2)
    there = terms(e1 + 0.05 * de1, e2 + 0.05 * de2)
    assert moving["tracking_rate"] == pytest.approx(there["tracking"], rel=1e-12)
    assert moving["tracking_rate"] != moving["tracking"]
    assert terms(e1, e2, de1, de2, horizon=0.0)["tracking_rate"] == moving["tracking"]
    assert terms(e1, e2, de1, de2, weight=0.0)["tracking_rate"] == 0.0


def test_the_reward_is_the_sum_of_its_terms_with_tracking_rate():
    env = gym.make("Tendon2R-v1", reward_scales={"tracking_rate": 0.5})
    env.reset(seed=0)
    for k in range(20):
        _, reward, _, _, info = env.step(np.array([np.sin(k), 0.3], dtype=np.float32))
        parts = [info[f"reward_{name}"] for name in TERMS]
        assert reward == pytest.approx(sum(parts), rel=1e-12, abs=1e-15)
        assert info["reward_tracking_rate"] != 0.0


@pytest.mark.parametrize("preset", ["default", "pull_only"])
def test_effort_term_charges_the_commanded_tension(preset):
    """The ctrl term is the commanded tension as a fraction of the force limit: slack tendons
    cost nothing (pull-only: command -1; push-pull: 0) and a tendon at its limit costs 1, in
    both envs; in joint-torque mode it is the normalized torque."""
    from tendon2r_gym.envs.formulas import Formulas
    from tendon2r_gym.ops import SCALAR

    def effort(formulas, command):
        zero = [0.0] * len(command)
        return formulas.reward_terms(SCALAR, 0.0, 0.0, command, zero, zero, False)["ctrl"]

    cfg = EnvConfig.make(preset=preset)
    tension, n = Formulas(cfg), cfg.n_actions
    slack = -1.0 if cfg.mechanism.pull_only else 0.0
    assert effort(tension, [slack] * n) == 0.0
    assert effort(tension, [1.0] * n) == -n
    assert effort(tension, [1.0] + [slack] * (n - 1)) == -1.0
    torque = Formulas(EnvConfig.make(preset=preset, action_mode="joint_torque"))
    assert effort(torque, [0.0, 0.0]) == 0.0 and effort(torque, [-1.0, 0.5]) == -1.25
    # The env reports the same term for the command it applied.
    env = gym.make("Tendon2R-v0", preset=preset)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.full(n, slack, dtype=np.float32))
    assert info["reward_ctrl"] == 0.0


def test_torque_rate_need_is_the_peak_rate_of_inverse_dynamics_along_the_reference():
    """EnvConfig.needs.torque_rate_need (the phase grid's d tau / dt) against mj_inverse of the
    compiled model along the reference in time, differenced in time: the grid bounds every
    start phase, so the trajectory's peak is at most the grid's; with one joint moving, the
    trajectory covers the grid's phases and the two agree."""
    import mujoco

    from tendon2r_gym.simulation.model import build_model

    for amp_b in (0.0, 13.06):
        cfg = EnvConfig.make(action_mode="joint_torque", reference={"amp_deg": [21.45, amp_b]})
        ref, mech = cfg.reference, cfg.mechanism
        model = build_model(mech)
        data = mujoco.MjData(model)
        dt = 1e-5
        t = np.arange(0.0, 1.0, 2e-4)
        torques = []
        for shift in (0.0, dt):
            w, amp, bias = ref.omega_array, ref.amp_rad, ref.bias_rad
            rows = []
            for ti in t + shift:
                data.qpos[:2] = bias + amp * np.sin(w * ti)
                data.qvel[:2] = amp * w * np.cos(w * ti)
                data.qacc[:2] = -amp * w * w * np.sin(w * ti)
                mujoco.mj_inverse(model, data)
                rows.append(data.qfrc_inverse[:2].copy())
            torques.append(np.array(rows))
        peak = np.max(np.abs((torques[1] - torques[0]) / dt), axis=0)
        need = np.array(cfg.needs.torque_rate_need)
        assert np.all(peak <= need * 1.02), (peak, need)
        if amp_b == 0.0:  # joint A alone: one phase, the grid's own
            np.testing.assert_allclose(peak[0], need[0], rtol=0.02)


def test_action_rate_need_counts_the_rate_in_multiples_of_the_arms_own():
    """The action_rate_need term of a step is -sum log(1 + (d / s)^2) with s the joint's
    torque-rate need per control step over its torque range, on the episode's drawn arm;
    a tension-mode env refuses a weight for it, naming the field."""
    from tendon2r_gym.simulation.actuation import TorqueToTension

    env = gym.make("Tendon2R-v0", preset="generalist", action_mode="joint_torque",
                   reward_scales={"action_rate_need": 2.0})  # fmt: skip
    env.reset(seed=3)
    arm = env.unwrapped.arm
    s = (np.array(arm.needs.torque_rate_need) * arm.ctrl_dt
         / TorqueToTension(arm.mechanism).max_torque)  # fmt: skip
    a0, a1 = np.array([0.2, -0.1], np.float32), np.array([0.25, -0.3], np.float32)
    env.step(a0)
    info = env.step(a1)[4]
    d = a1.astype(np.float64) - a0.astype(np.float64)
    expected = -2.0 * np.sum(np.log1p((d / s) ** 2))
    assert info["reward_action_rate_need"] == pytest.approx(expected, rel=1e-9)
    with pytest.raises(ValueError, match=r"reward_scales.action_rate_need = 0.5 .*'tension'"):
        gym.make("Tendon2R-v0", reward_scales={"action_rate_need": 0.5})


def test_tracking_quadratic_is_the_squared_error_in_degrees_and_off_by_default():
    """The tracking_quadratic term of a step is -weight sum(e^2), e the step's tracking errors
    in deg; at its default weight 0 the reward is the registered one, bit for bit."""
    plain = Tendon2REnv()
    env = Tendon2REnv(reward_scales={"tracking_quadratic": 50.0})
    plain.reset(seed=5)
    env.reset(seed=5)
    for action in ([0.3, -0.2], [-0.1, 0.4]):
        r0, info0 = plain.step(np.array(action))[1::3]
        r, info = env.step(np.array(action))[1::3]
        e = np.asarray(info["tracking_error_deg"])
        assert info["reward_tracking_quadratic"] == pytest.approx(-50.0 * np.sum(e**2), rel=1e-9)
        assert info0["reward_tracking_quadratic"] == 0.0
        assert r == pytest.approx(r0 + info["reward_tracking_quadratic"], abs=1e-12)
        assert r != r0
    with pytest.raises(ValueError, match=r"reward_scales.tracking_quadratic = -1"):
        Tendon2REnv(reward_scales={"tracking_quadratic": -1})


def test_control_authority_is_the_speed_a_full_joint_torque_adds_in_one_step():
    """EnvConfig.needs.control_authority against the compiled model: from rest at a q on the
    reference's path, a joint-torque action on joint j alone adds ctrl_dt max_torque_j
    (M^-1)_jj(q) per unit of action to that joint's speed in one control step (the simulated
    response to a small action, which no tendon saturates, minus the rest action's), and its
    peak over the path is the authority."""
    import mujoco

    env = Tendon2REnv(action_mode="joint_torque")
    env.reset(seed=0)
    cfg = env.config
    model, data = env.model, env.data
    ref = cfg.reference
    rng = np.random.default_rng(0)
    phases = np.concatenate([rng.uniform(0, 2 * np.pi, (60, 2)), [[np.pi / 2, -np.pi / 2]]])
    gained = np.zeros((len(phases), 2))
    M = np.zeros((model.nv, model.nv))
    for k, theta in enumerate(phases):
        q = ref.bias_rad + ref.amp_rad * np.sin(theta)
        for j in range(2):
            speeds = []
            for a in (np.zeros(2), 0.2 * np.eye(2)[j]):
                mujoco.mj_resetData(model, data)
                data.qpos[:2] = q
                env.step(a.astype(np.float32))
                speeds.append(data.qvel[j])
            gained[k, j] = (speeds[1] - speeds[0]) / 0.2
        data.qpos[:2] = q
        mujoco.mj_fwdPosition(model, data)
        mujoco.mj_fullM(model, data, M)
        expected = cfg.ctrl_dt * env.torque_map.max_torque * np.diag(np.linalg.inv(M))[:2]
        np.testing.assert_allclose(gained[k], expected, rtol=0.02)
    peak = gained.max(axis=0)
    authority = np.array(cfg.needs.control_authority)
    assert np.all(peak <= authority * 1.02), (peak, authority)
    assert np.all(peak >= authority * 0.9), (peak, authority)


def test_rate_to_action_is_the_action_that_changes_the_speeds_in_one_step():
    """EnvConfig.needs.rate_to_action against the compiled model: from rest at the reference's bias,
    a small joint-torque action a changes the joints' speeds by dq in one control step, and
    rate_to_action dq gives a back (each joint's action moves the other's speed too)."""
    import mujoco

    env = Tendon2REnv(action_mode="joint_torque")
    env.reset(seed=0)
    model, data = env.model, env.data
    rate_to_action = np.array(env.config.needs.rate_to_action)
    for a in ([0.2, 0.0], [0.0, 0.2], [-0.1, 0.15]):
        speeds = []
        for action in (np.zeros(2), np.array(a)):
            mujoco.mj_resetData(model, data)
            data.qpos[:2] = env.config.reference.bias_rad
            env.step(action.astype(np.float32))
            speeds.append(data.qvel[:2].copy())
        np.testing.assert_allclose(rate_to_action @ (speeds[1] - speeds[0]), a, atol=2e-3)


def test_error_units_action_log_scale_the_actions_that_close_the_error_and_its_rate():
    """error_units 'action': error_log and error_rate_log are sign(y) log(1 + |y| /
    ACTION_LOG_SCALE) of y = rate_to_action (e / ctrl_dt) and y = rate_to_action (dq_des - dq)
    of the episode's arm, every other entry as in rad; a bad value is refused, named."""
    kw = {"preset": "generalist", "observe": ["error_rate"], "action_mode": "joint_torque"}
    plain, env = Tendon2REnv(**kw), Tendon2REnv(**kw, error_units="action")
    assert plain.config.observation.layout() == env.config.observation.layout()
    plain.reset(seed=4)
    env.reset(seed=4)
    for a in ([0.3, -0.2], [-0.1, 0.5]):
        obs, plain_obs = env.step(np.array(a))[0], plain.step(np.array(a))[0]
    logged = np.r_[L.ERROR_LOG, L.error_rate_slice(3, 2)]
    np.testing.assert_array_equal(np.delete(obs, logged), np.delete(plain_obs, logged))
    arm = env.arm
    assert arm.needs.rate_to_action != env.config.needs.rate_to_action  # the drawn arm's own
    rate_to_action = np.array(arm.needs.rate_to_action)
    de = env.reference.qdot(env.data.time) - obs[L.DQ]
    for where, y in ((L.ERROR_LOG, rate_to_action @ (obs[L.ERROR] / arm.ctrl_dt)),
                     (L.error_rate_slice(3, 2), rate_to_action @ de)):  # fmt: skip
        expected = np.sign(y) * np.log1p(np.abs(y) / L.ACTION_LOG_SCALE)
        np.testing.assert_allclose(obs[where], expected, rtol=1e-12)
    with pytest.raises(ValueError, match=r"error_units = 'deg' .*'rad', 'action'"):
        gym.make("Tendon2R-v0", error_units="deg")

"""The native vector env: Gymnasium's vector API, bit-exact with N single envs, and SB3 on top."""

import gymnasium as gym
import numpy as np
import pytest

from tendon2r_gym.envs.vector_env import Tendon2RVectorEnv
from tendon2r_gym.policies.baselines import PDPolicy

RANGES = {"amp_deg": [[5, 20], [5, 20]], "freq_hz": [[0.5, 3], [0.5, 3]],
          "bias_deg": [[-10, 10], [-10, 10]]}  # fmt: skip
#: Every realism effect on (tendon2r_gym.simulation.realism).
REAL = {"tendon_elasticity": 3000.0, "tendon_damping": 1.0, "tendon_friction": 0.01,
        "motor_tau": 0.004, "motor_delay": 0.002}  # fmt: skip
#: Random arms with random cables and motors (tendon2r_gym.task.arms.MechanismRanges).
ARMS = {"c": [0.08, 0.1], "tendon_elasticity": [2000.0, 6000.0], "motor_tau": [0.001, 0.004],
        "tendon_friction": [0.005, 0.02], "joint_damping": [0.0, 1e-4]}  # fmt: skip


#: Random real arms, each with its own PD bandwidth (Hz).
GAINS = ["real_arm", {"pd_bandwidth_hz": [10.0, 40.0]}]
#: ... and with the bandwidth a tuning would pick on each arm.
TUNED = ["real_arm", {"pd_bandwidth_hz": [10.0, 40.0], "pd_tuned_phase": [0.5, 0.7]}]


def _native(n, **kw):
    return gym.make_vec("Tendon2R-v0", num_envs=n, vectorization_mode="vector_entry_point", **kw)


@pytest.mark.parametrize(
    ("n", "nthread", "kwargs"),
    [(3, 1, {}), (3, 1, {"preset": "pull_only"}), (3, 1, {"reference_ranges": RANGES}),
     (3, 1, {"tracking_form": "quadratic"}), (3, 1, {"preset": "report_002", "ctrl_dt": 0.002}),
     (17, 2, {"preview_steps": 6}), (9, None, {"preview_steps": 0}),
     (3, 1, {"action_mode": "joint_torque"}),
     (5, 1, {"action_mode": "joint_torque", "preset": "pull_only"}),
     (4, 1, {"action_filter_tau": 0.005, "preset": "pull_only"}),
     (3, 1, {"action_mode": "joint_torque", "action_filter_tau": 0.002, "preset": "pull_only"}),
     (3, 1, {"mechanism": REAL}), (3, 1, {"preset": "pull_only", "mechanism": REAL}),
     (3, 1, {"action_mode": "joint_torque", "mechanism": REAL}),
     (3, 1, {"observation_noise": [1e-3, 0.1], "observation_delay": 0.002}),
     (3, 1, {"observation_noise": [1e-3, 0.1], "observe": ["error_rate"]}),
     (4, 2, {"observation_noise": [0, 0.1], "mechanism": REAL, "preset": "pull_only"}),
     (3, 1, {"preset": "generalist", "observe": ["arm"]}),
     (3, 1, {"preset": "generalist", "observe": ["error_rate", "arm"]}),
     (3, 1, {"preset": "generalist", "observe": ["arm", "force_limit"],
             "action_mode": "joint_torque"}),
     (3, 1, {"preset": "generalist", "action_mode": "joint_torque"}),
     (3, 1, {"preset": "generalist", "action_mode": "joint_torque",
             "reward_scales": {"action_rate_need": 0.01, "tracking_quadratic": 100.0}}),
     (3, 1, {"action_mode": "joint_torque", "reference_ranges": RANGES,
             "reward_scales": {"action_rate_need": 1.0}}),
     (3, 1, {"preset": "generalist", "action_mode": "joint_torque", "observe": ["error_rate"],
             "error_units": "action", "observation_noise": [0, 0.1]}),
     (3, 1, {"preset": "generalist", "action_mode": "joint_torque",
             "observe": ["feedforward", "arm"], "observation_delay": 0.002}),
     (3, 1, {"preset": "pull_only", "mechanism": REAL, "mechanism_ranges": ARMS}),
     (4, 1, {"preset": "real_arm", "mechanism_ranges": "real_arm", "observe": ["arm"]}),
     (3, 1, {"preset": "real_arm", "mechanism_ranges": GAINS, "observe": ["arm"]}),
     (3, 1, {"reward_scales": {"tracking_rate": 1.0}, "observation_noise": [1e-3, 0.1]})],
)  # fmt: skip
@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_same_seeds_same_trajectories_as_single_envs_bit_for_bit(n, nthread, kwargs, mode):
    """Observations, rewards, terminations, truncations and infos (every key, reset info and
    final_info included) equal a SyncVectorEnv of gym.make envs exactly, through several
    autoresets in both autoreset modes, with any number of MuJoCo threads."""
    native = _native(n, episode_duration=0.03, nthread=nthread, autoreset_mode=mode, **kwargs)
    sync = gym.make_vec("Tendon2R-v0", num_envs=n, vectorization_mode="sync",
                        episode_duration=0.03, vector_kwargs={"autoreset_mode": mode},
                        **kwargs)  # fmt: skip
    assert isinstance(native.unwrapped, Tendon2RVectorEnv)
    np.testing.assert_array_equal(native.reset(seed=11)[0], sync.reset(seed=11)[0])
    rng = np.random.default_rng(0)
    for _ in range(100):
        action = rng.uniform(-1.2, 1.2, native.action_space.shape)
        a, b = native.step(action), sync.step(action)
        for x, y in zip(a[:4], b[:4], strict=True):
            np.testing.assert_array_equal(x, y)
        _assert_same_info(a[4], b[4])


def _assert_same_info(ours: dict, theirs: dict) -> None:
    """Every key, every mask, and every masked value equal (nested dicts too)."""
    assert set(ours) == set(theirs)
    for key, value in theirs.items():
        if isinstance(value, dict):
            _assert_same_info(ours[key], value)
        elif key == "final_obs":
            mask = theirs["_final_obs"]
            for x, y in zip(ours[key][mask], value[mask], strict=True):
                np.testing.assert_array_equal(x, y)
        elif key.startswith("_"):
            np.testing.assert_array_equal(ours[key], value, err_msg=key)
        else:
            mask = theirs[f"_{key}"]
            for x, y in zip(ours[key][mask], value[mask], strict=True):
                np.testing.assert_array_equal(x, y, err_msg=key)


def test_next_step_autoreset_follows_gymnasium():
    envs = _native(2, episode_duration=0.003)
    envs.reset(seed=0)
    for _ in range(2):
        *_, trunc, _ = envs.step(np.zeros((2, 2)))
        assert not trunc.any()
    _, _, _, trunc, _ = envs.step(np.zeros((2, 2)))
    assert trunc.all()
    obs, reward, term, trunc, info = envs.step(np.ones((2, 2)))  # the reset step
    assert not (term | trunc).any() and np.all(reward == 0.0)
    assert "tracking_error_deg" not in info, "no step info on the reset step"
    assert info["_reference"].all() and np.all(info["time"] == 0.0), "but the reset info"
    assert np.all(obs[:, 0] != 0.0)
    for _ in range(2):  # a new episode: its full length of steps again
        assert not envs.step(np.zeros((2, 2)))[3].any()
    assert envs.step(np.zeros((2, 2)))[3].all()


def test_same_step_autoreset_reports_the_final_observation():
    envs = Tendon2RVectorEnv(2, autoreset_mode="SameStep", episode_duration=0.002)
    envs.reset(seed=0)
    envs.step(np.zeros((2, 2)))
    obs, _, _, trunc, info = envs.step(np.zeros((2, 2)))
    assert trunc.all() and info["_final_obs"].all()
    assert not np.array_equal(info["final_obs"][0], obs[0]), "obs is already the reset one"


@pytest.mark.parametrize(
    ("action", "match"),
    [
        (np.zeros((3, 2)), r"(?s)actions = .*allowed: \(2, 2\) finite"),
        (np.full((2, 2), np.nan), r"(?s)actions = .*allowed: \(2, 2\) finite"),
        ("ab", "actions = 'ab' is invalid"),
        (np.full((2, 2), 1j), "actions = "),
    ],
)
def test_bad_actions_raise(action, match):  # fmt: skip
    envs = _native(2)
    envs.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        envs.step(action)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"num_envs": 0}, r"num_envs = 0 is invalid; allowed: .*1"),
     ({"nthread": -1}, r"nthread = -1 is invalid; allowed: .*0"),
     ({"nthread": 1.5}, "nthread = 1.5 is invalid"),
     ({"autoreset_mode": "Disabled"}, r"autoreset_mode = 'Disabled' is invalid; .*NEXT_STEP"),
     ({"autoreset_mode": "next"}, r"autoreset_mode = 'next' is invalid; allowed: .*'SameStep'"),
     ({"max_episode_steps": 0}, "max_episode_steps = 0 is invalid"),
     ({"stagger": "yes"}, "stagger = 'yes' is invalid; allowed: true or false"),
     ({"ctrl_dt": -1.0}, "ctrl_dt = -1.0 is invalid")],
)  # fmt: skip
def test_bad_constructor_arguments_raise_naming_the_field(kwargs, match):
    kwargs = {"num_envs": 2, **kwargs}
    with pytest.raises(ValueError, match=match):
        Tendon2RVectorEnv(**kwargs)


def test_default_threads_follow_the_number_of_arms(monkeypatch):
    """One MuJoCo thread per ARMS_PER_THREAD arms, at least one, at most the usable CPUs."""
    from tendon2r_gym.envs import vector_env

    monkeypatch.setattr(vector_env.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    per = vector_env.ARMS_PER_THREAD
    assert [vector_env.default_nthread(n) for n in (1, per, 2 * per, 100 * per)] == [1, 1, 2, 2]
    assert Tendon2RVectorEnv(2 * per).batch.nthread == 2
    assert Tendon2RVectorEnv(2 * per, nthread=1).batch.nthread == 1
    monkeypatch.setenv(vector_env.CPUS_VAR, "1")  # a job's share, from an executor
    assert vector_env.default_nthread(100 * per) == 1
    assert Tendon2RVectorEnv(2 * per).batch.nthread == 1
    monkeypatch.setenv(vector_env.CPUS_VAR, "3")  # a share beyond the usable CPUs
    assert vector_env.default_nthread(100 * per) == 2


def test_batched_pd_equals_single_pd():
    env = gym.make("Tendon2R-v0", preset="pull_only")
    pd = PDPolicy.from_env(env)
    rng = np.random.default_rng(0)
    obs = np.stack([env.reset(seed=int(s))[0] for s in rng.integers(0, 100, 16)])
    obs[:, :2] += rng.uniform(-0.1, 0.1, (16, 2))
    batch, _ = pd.predict(obs)
    single = np.stack([pd.predict(o)[0] for o in obs])
    np.testing.assert_allclose(batch, single, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(
    "kwargs",
    [{"preset": "default", "episode_duration": 0.01},
     # random real arms, PD's gains scheduled on each one's loop delay (pd_gains)
     {"preset": "real_arm", "mechanism_ranges": "real_arm", "episode_duration": 0.01,
      "pd_gains": {"bandwidth_hz": 46.0, "max_delay_phase": 0.5}},
     # random real arms, each with its own drawn PD bandwidth
     {"preset": "real_arm", "mechanism_ranges": GAINS, "episode_duration": 0.01},
     {"preset": "real_arm", "mechanism_ranges": TUNED, "episode_duration": 0.01}],
)  # fmt: skip
def test_sb3_adapter_steps_like_dummy_vec_env(kwargs):
    """SB3's VecEnv API over the native env (SAME_STEP autoreset, terminal_observation,
    TimeLimit.truncated) gives what SB3's DummyVecEnv of single envs gives, residual PD
    included (on random arms: each arm's PD); training adds only the staggered first
    episodes."""
    from stable_baselines3.common.env_util import make_vec_env

    from tendon2r_gym.policies.residual import Residual
    from tendon2r_gym.training.manager import make_training_env
    from tendon2r_gym.training.vector_env_sb3 import SB3VecEnv

    native = SB3VecEnv(Tendon2RVectorEnv(3, autoreset_mode="SameStep", **kwargs), Residual(0.5))
    dummy = make_vec_env(make_training_env, n_envs=3,
                         env_kwargs={"env_kwargs": kwargs, "residual": Residual(0.5)})  # fmt: skip
    native.seed(5)
    dummy.seed(5)
    np.testing.assert_array_equal(native.reset(), dummy.reset())
    rng = np.random.default_rng(0)
    for _ in range(25):
        action = rng.uniform(-1, 1, (3, *native.action_space.shape)).astype(np.float32)
        (o1, r1, d1, i1), (o2, r2, d2, i2) = native.step(action), dummy.step(action)
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(d1, d2)
        np.testing.assert_equal(native.reset_infos, dummy.reset_infos)
        for a, b in zip(i1, i2, strict=True):  # every entry, as DummyVecEnv's (not Monitor's)
            b = {k: v for k, v in b.items() if k != "episode"}
            assert sorted(a) == sorted(b)
            for key in a:
                np.testing.assert_equal(a[key], b[key], err_msg=key)


def test_sb3_adapter_filters_the_residual_as_the_wrapper_does():
    """residual_filter_tau: the native vector env's batched residual passes the same filter as
    ResidualPDWrapper's, each slot's restarting with its episode (8-step episodes here)."""
    from stable_baselines3.common.env_util import make_vec_env

    from tendon2r_gym.policies.residual import Residual
    from tendon2r_gym.training.manager import make_training_env
    from tendon2r_gym.training.vector_env_sb3 import SB3VecEnv

    kwargs = {"episode_duration": 0.008}
    filtered = Residual(0.5, filter_tau=0.004)
    native = SB3VecEnv(Tendon2RVectorEnv(2, autoreset_mode="SameStep", **kwargs), filtered)
    dummy = make_vec_env(make_training_env, n_envs=2,
                         env_kwargs={"env_kwargs": kwargs, "residual": filtered})  # fmt: skip
    plain = SB3VecEnv(Tendon2RVectorEnv(2, autoreset_mode="SameStep", **kwargs), Residual(0.5))
    ends, differs = _step_alike(native, dummy, plain, 1.0)
    assert ends >= 4 and differs  # episodes restarted, and the filter changed the commands


def _step_alike(native, dummy, other, action_value: float) -> tuple[int, bool]:
    """Steps the three SB3 VecEnvs 20 times with the same constant action after seed 5: the
    native one and SB3's DummyVecEnv of single envs agree bit for bit; returns the episodes
    ended and whether ``other`` (one setting changed) ever differed."""
    for venv in (native, dummy, other):
        venv.seed(5)
        venv.reset()
    ends, differs = 0, False
    for _ in range(20):
        action = np.full((2, *native.action_space.shape), action_value, dtype=np.float32)
        o1, _, d1, _ = native.step(action)
        o2, _, d2, _ = dummy.step(action)
        o3, *_ = other.step(action)
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(d1, d2)
        ends, differs = ends + int(d1.sum()), differs or not np.array_equal(o1, o3)
    return ends, differs


def test_training_staggers_the_first_episodes():
    envs = Tendon2RVectorEnv(4, stagger=True, episode_duration=0.008)
    envs.reset(seed=0)
    lengths = np.zeros(4, dtype=int)
    for step in range(1, 9):
        *_, trunc, _ = envs.step(np.zeros((4, 2)))
        lengths[trunc & (lengths == 0)] = step
    assert sorted(lengths.tolist()) == [2, 4, 6, 8]

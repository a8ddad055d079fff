"""Tendon2RResidual-v2 is residual: gym.make gives PD inside, and the action corrects it."""

import gymnasium as gym
import numpy as np
import pytest

import tendon2r_gym  # noqa: F401  (registers the ids)
from tendon2r_gym.envs.registration import make as make_base
from tendon2r_gym.evaluation.rollout import rollout
from tendon2r_gym.policies.baselines import PDPolicy
from tendon2r_gym.policies.residual import ResidualPDWrapper
from tendon2r_gym.task.observation import last_action_slice

RESIDUAL_ID = "Tendon2RResidual-v2"
WRAPPER_KEYS = ("residual_scale", "residual_units", "residual_filter_tau")


def _base_kwargs() -> dict:
    """The env kwargs under the residual id's wrapper."""
    return {k: v for k, v in gym.spec(RESIDUAL_ID).kwargs.items() if k not in WRAPPER_KEYS}


class _Zero:
    def predict(self, obs, *args, **kwargs):
        return np.zeros(2, dtype=np.float32), None


def _wrapper(env: gym.Env) -> ResidualPDWrapper:
    while not isinstance(env, ResidualPDWrapper):
        env = env.env
    return env


def test_gym_make_gives_pd_inside():
    env = gym.make(RESIDUAL_ID)
    assert isinstance(_wrapper(env), ResidualPDWrapper)
    assert env.spec.max_episode_steps == env.unwrapped.timing.max_episode_steps
    assert env.action_space.shape == (2,)


def test_a_zero_correction_is_pd_bit_for_bit():
    residual = rollout(_Zero(), gym.make(RESIDUAL_ID, episode_duration=0.1), seed=3)
    base = make_base(**_base_kwargs(), episode_duration=0.1)
    pd = rollout(PDPolicy.from_env(base), base, seed=3)
    np.testing.assert_array_equal(residual.error_deg, pd.error_deg)
    np.testing.assert_array_equal(residual.tendon_tension, pd.tendon_tension)


def test_a_correction_of_one_adds_each_joints_torque_need():
    env = gym.make(RESIDUAL_ID)
    where = last_action_slice(env.unwrapped.config.preview_steps, 2)
    commands = []
    for action in ([0.0, 0.0], [1.0, -1.0]):
        _, info = env.reset(seed=0)
        obs, *_ = env.step(np.array(action, dtype=np.float32))
        commands.append(obs[where])  # the joint torques applied, over max_torque
    max_torque = _wrapper(env).pd.actuation.max_torque
    need = np.asarray(info["torque_need_Nm"])
    added = (commands[1] - commands[0]) * max_torque
    np.testing.assert_allclose(added, [need[0], -need[1]], rtol=1e-9)


def test_need_units_are_refused_on_tension_commands():
    env = make_base(action_mode="tension")
    with pytest.raises(ValueError, match=r"residual_units = 'need'.*joint_torque"):
        ResidualPDWrapper(env, 1.0, residual_units="need")
    with pytest.raises(ValueError, match=r"residual_units = 'torque'.*one of"):
        ResidualPDWrapper(env, 1.0, residual_units="torque")


def test_gym_make_vec_gives_pd_in_every_env():
    envs = gym.make_vec(RESIDUAL_ID, num_envs=2, vectorization_mode="sync")
    obs, info = envs.reset(seed=[5, 6])
    obs, reward, terminated, truncated, info = envs.step(np.zeros((2, 2), dtype=np.float32))
    single = gym.make(RESIDUAL_ID)
    single.reset(seed=5)
    first, *_ = single.step(np.zeros(2, dtype=np.float32))
    np.testing.assert_array_equal(obs[0], first)
    envs.close()

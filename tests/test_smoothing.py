"""CAPS's smoothness terms (tendon2r_gym.training.smoothing): off, SB3's PPO bit for bit; on, a
smoother mean action; validated, recorded, resumed and refused where the zoo cannot run them."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
import yaml
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

import tendon2r_gym  # noqa: F401 (registers Tendon2R-v0)
from tendon2r_gym.policies.runs import CONFIG, RunFolder
from tendon2r_gym.training import Hyperparams, train_run
from tendon2r_gym.training.hyperparams import Smoothing
from tendon2r_gym.training.manager import _load_newest
from tendon2r_gym.training.manager import make_vec_env as make_vec_env_of
from tendon2r_gym.training.smoothing import SmoothPPO
from tendon2r_gym.training.zoo import zoo_entry

ENV = {"preset": "default", "episode_duration": 0.05}
PPO_KW = {"n_steps": 64, "batch_size": 64, "n_epochs": 2, "seed": 3, "device": "cpu"}


def _venv():
    return VecNormalize(make_vec_env("Tendon2R-v0", n_envs=2, seed=3, env_kwargs=ENV))


def _flat(model) -> th.Tensor:
    return th.cat([p.detach().flatten() for p in model.policy.parameters()])


def _gaps(model, obs: th.Tensor, sigma: float) -> tuple[float, float]:
    """Returns the mean |mu(s_t) - mu(s_t+1)| along obs and |mu(s) - mu(s + sigma n)|."""
    gen = th.Generator().manual_seed(0)
    with th.no_grad():
        mu = model.policy.get_distribution(obs).mode()
        near = model.policy.get_distribution(obs + sigma * th.randn(obs.shape, generator=gen))
        temporal = th.linalg.vector_norm(mu[1:] - mu[:-1], dim=1).mean()
        spatial = th.linalg.vector_norm(mu - near.mode(), dim=1).mean()
    return float(temporal), float(spatial)


def test_without_smoothing_it_is_sb3s_ppo_bit_for_bit():
    plain = PPO("MlpPolicy", _venv(), **PPO_KW).learn(256)
    smooth = SmoothPPO("MlpPolicy", _venv(), smoothing=Smoothing(), **PPO_KW).learn(256)
    assert th.equal(_flat(plain), _flat(smooth))


def test_smoothing_gives_a_smoother_mean_action_than_the_same_ppo_without_it():
    sigma = 0.5
    plain = PPO("MlpPolicy", _venv(), **PPO_KW).learn(1024)
    smooth = SmoothPPO(
        "MlpPolicy", _venv(), smoothing=Smoothing(10.0, 10.0, sigma), **PPO_KW
    ).learn(1024)
    assert not th.equal(_flat(plain), _flat(smooth))
    # the last rollout, flattened by PPO's train env by env: env 0's states in time order
    obs = th.as_tensor(plain.rollout_buffer.observations[: PPO_KW["n_steps"]])
    plain_gaps, smooth_gaps = _gaps(plain, obs, sigma), _gaps(smooth, obs, sigma)
    assert smooth_gaps[0] < plain_gaps[0] and smooth_gaps[1] < plain_gaps[1]
    logged = smooth.logger.name_to_value  # the terms are logged with PPO's losses
    assert {"train/smoothness_temporal", "train/smoothness_spatial"} <= set(logged)


def test_one_term_alone_is_descended_and_logged():
    model = SmoothPPO("MlpPolicy", _venv(), smoothing=Smoothing(temporal=1.0), **PPO_KW)
    model.learn(128)
    assert "train/smoothness_temporal" in model.logger.name_to_value
    assert "train/smoothness_spatial" not in model.logger.name_to_value


@pytest.mark.parametrize(
    ("value", "match"),
    [({"spatial": -1}, r"smoothing.spatial = -1 is invalid; allowed: a finite number in \[0"),
     ({"temporal": float("nan")}, "smoothing.temporal = nan"),
     ({"sigma": 0}, r"smoothing.sigma = 0 is invalid; allowed: a finite number in \(0"),
     ({"samples": 0.5}, r"smoothing.samples = 0.5 is invalid; allowed: an integer"),
     ({"temporl": 1.0}, "did you mean 'temporal'"),
     ([1.0], "smoothing = \\[1.0\\] is invalid")],
)  # fmt: skip
def test_bad_smoothing_is_refused_at_construction_naming_the_field(value, match):
    with pytest.raises(ValueError, match=match):
        Hyperparams.from_entry("default").replace(smoothing=value)


def test_the_zoo_refuses_an_entry_with_smoothing():
    hp = Hyperparams.from_entry("default").replace(smoothing={"spatial": 1.0})
    with pytest.raises(ValueError, match="smoothing = .* none in an rl_zoo3 entry"):
        zoo_entry(hp)
    assert zoo_entry(hp.replace(smoothing={}))  # both weights 0: SB3's PPO, exported


def test_a_smoothed_run_records_resumes_and_deploys_with_plain_ppo(tmp_path):
    smoothing = {"temporal": 0.5, "spatial": 2.0, "sigma": 0.2, "samples": 64}
    base = Hyperparams.from_entry("default_scratch")
    hp = base.replace(
        env_kwargs=ENV, ppo={**base.ppo, "n_steps": 64, "batch_size": 64, "n_epochs": 1},
        total_timesteps=256, n_envs=2, eval_freq=128, checkpoint_freq=128, eval_seeds=[0],
        vec_env="dummy", smoothing=smoothing,
    )  # fmt: skip
    run = RunFolder(tmp_path / "run")
    train_run(hp, run, seed=0)
    assert yaml.safe_load(run.file(CONFIG).read_text())["smoothing"] == smoothing
    recorded = Hyperparams.from_dict(run.read_config())
    assert recorded.smoothing == Smoothing(**smoothing)
    resumed, _ = _load_newest(run, make_vec_env_of(recorded, 0), recorded)
    assert isinstance(resumed, SmoothPPO) and resumed.smoothing == recorded.smoothing
    longer = recorded.replace(total_timesteps=384)
    assert train_run(longer, run, seed=0, resume=True)["timesteps"] >= 384
    model = PPO.load(run.last, device="cpu")  # the settings stay in config.yaml
    assert not hasattr(model, "smoothing")
    obs = gym.make("Tendon2R-v0", **ENV).reset(seed=0)[0]
    assert np.all(np.isfinite(model.predict(obs, deterministic=True)[0]))

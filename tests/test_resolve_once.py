"""An experiment is resolved once, where it enters, and its EnvConfig passed down: the envs
take one, evaluate() resolves once, and EnvConfig keeps one job (the record of an experiment;
arms are drawn by tendon2r_gym.task.arms, the steps and sensing are envs.timing.Timing)."""

import ast
import pickle

import gymnasium as gym
import numpy as np
import pytest
from test_structure import PACKAGE, code_lines

import tendon2r_gym  # noqa: F401  (registers the ids)
from tendon2r_gym.envs.env import Tendon2REnv
from tendon2r_gym.envs.env_config import EnvConfig, resolve
from tendon2r_gym.envs.registration import make as make_env
from tendon2r_gym.envs.timing import Timing
from tendon2r_gym.envs.vector_env import Tendon2RVectorEnv
from tendon2r_gym.evaluation.evaluator import evaluate

#: The most places in the library that may call EnvConfig.make (docstrings included).
MAX_MAKE_SITES = 3
#: The most methods EnvConfig may have (properties and private ones count).
MAX_CONFIG_METHODS = 12
#: Every module of envs/ stays this far below tests/test_structure.py's cap (code lines).
ENVS_MAX_LINES = 420


def test_the_library_calls_envconfig_make_in_few_places():
    sites = {
        str(p.relative_to(PACKAGE)): n
        for p in PACKAGE.rglob("*.py")
        if (n := p.read_text().count("EnvConfig.make(")) > 0
    }
    assert sum(sites.values()) <= MAX_MAKE_SITES, sites


def test_envconfig_has_few_methods():
    tree = ast.parse((PACKAGE / "envs" / "env_config.py").read_text())
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "EnvConfig")
    methods = [n.name for n in cls.body if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)]
    assert len(methods) <= MAX_CONFIG_METHODS, methods


def test_no_envs_module_is_near_the_line_cap():
    long = {
        p.name: n
        for p in (PACKAGE / "envs").glob("*.py")
        if (n := code_lines(p.read_text())) > ENVS_MAX_LINES
    }
    assert not long, long


@pytest.fixture
def resolutions(monkeypatch):
    """Counts the resolutions of env kwargs (EnvConfig.from_kwargs, which make calls)."""
    calls = []
    original = EnvConfig.from_kwargs.__func__

    def counted(cls, kwargs):
        calls.append(dict(kwargs))
        return original(cls, kwargs)

    monkeypatch.setattr(EnvConfig, "from_kwargs", classmethod(counted))
    return calls


def test_evaluate_resolves_the_experiment_once(resolutions):
    metrics, traces = evaluate("pd", {"preset": "default", "episode_duration": 0.05}, [0, 1])
    assert len(resolutions) == 1 and len(traces) == 2 and metrics["steps"] > 0
    resolutions.clear()
    config = EnvConfig.make(episode_duration=0.05)
    assert len(resolutions) == 1
    again, _ = evaluate("pd", config, [0, 1])
    assert len(resolutions) == 1  # a config: not resolved again
    assert again["rms_deg"] == metrics["rms_deg"]


def test_gym_make_resolves_once_and_the_envs_take_a_config(resolutions):
    env = gym.make("Tendon2R-v2")
    assert len(resolutions) == 1
    config = env.unwrapped.config
    by_config = [Tendon2REnv(config), Tendon2REnv(preset=config), make_env(preset=config)]
    vector = [Tendon2RVectorEnv(2, config), Tendon2RVectorEnv(2, preset=config)]
    assert len(resolutions) == 1  # none of them resolves it again
    assert all(e.unwrapped.config is config for e in by_config)
    assert all(v.config is config for v in vector)
    assert make_env(preset=config).spec.max_episode_steps == env.spec.max_episode_steps
    obs = [e.reset(seed=3)[0] for e in (env, *by_config)]
    assert all(np.array_equal(o, obs[0]) for o in obs)
    assert np.array_equal(vector[0].reset(seed=[3, 4])[0][0], obs[0])
    copied = pickle.loads(pickle.dumps(by_config[1]))
    assert copied.config == config


def test_a_config_comes_alone():
    config = resolve("default")
    assert resolve(config) is config and resolve({"preset": "default"}) == config
    beside = r"^preset = \"an EnvConfig beside \['episode_duration'\]\" is invalid"
    with pytest.raises(ValueError, match=beside):
        Tendon2REnv(config, episode_duration=1.0)
    with pytest.raises(ValueError, match=r"^preset = \"an EnvConfig beside \['action_filter_tau'"):
        gym.make("Tendon2R-v2", preset=config)  # v2's defaults are kwargs beside it


def test_timing_counts_control_steps_and_drawn_delays():
    timing = Timing.of(EnvConfig.make("real_arm", mechanism_ranges="real_arm"))
    assert timing.delay_capacity == timing.observation_delay_capacity == 2
    assert timing.sensed and timing.noisy
    config = EnvConfig.make("default", ctrl_dt=0.002, episode_duration=0.5)
    plain = Timing.of(config)
    assert plain.n_substeps == round(0.002 / config.mechanism.sim_dt) > 1
    assert (plain.max_episode_steps, plain.sensed) == (250, False)
    assert plain.action_filter_alpha == 1.0

"""The contract of each registered env id, pinned: what a learner sees and is scored on.

An id's contract is its resolved config (the default arm, reference, timing, reset noise,
observation options, reward form and weights: EnvConfig.to_dict, with ``observe`` written as
the four flags it replaced, tendon2r_gym.task.observation.as_flags, so that an id whose
behaviour did not change keeps its hash), its observation layout, its
reward terms with their default weights, its action space, its episode length and a short
seeded rollout's observations and rewards (six significant digits): the behaviour, not only
the settings.  ``tendon2r_gym/data/contracts.yaml`` holds each id's hash; tests/test_contract.py
fails when a contract changes until the id's version is raised (tendon2r_gym.VERSIONS) and
CHANGELOG.md says what changed.
"""

from __future__ import annotations

import functools
import warnings
from typing import Any

import gymnasium as gym
import numpy as np

from tendon2r_gym.policies.registry import contract_hash
from tendon2r_gym.presets import DATA_DIR, load_yaml
from tendon2r_gym.task import observation
from tendon2r_gym.task.rewards import TERMS

CONTRACTS = DATA_DIR / "contracts.yaml"
#: The fingerprint rollout: steps, seed and the action at step k, a slow sweep of the range.
STEPS, SEED = 50, 0


def _sig(values: Any) -> list[float]:
    return [float(f"{x:.6g}") for x in np.ravel(values)]


def env_contract(env_id: str) -> dict[str, Any]:
    """Returns the contract of a registered id (module docstring)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Gymnasium's "out of date" warning for older ids
        env = gym.make(env_id)
    config = env.unwrapped.config
    obs, _ = env.reset(seed=SEED)
    seen, rewards = [_sig(obs)], []
    n = env.action_space.shape[0]
    for k in range(STEPS):
        action = np.sin(0.1 * k + np.arange(n)).astype(env.action_space.dtype)
        obs, reward, *_ = env.step(action)
        seen.append(_sig(obs))
        rewards.append(float(f"{reward:.6g}"))
    env.close()
    return {
        "config": observation.as_flags(config.to_dict()),
        "observation": config.observation.layout(),
        "reward_terms": {name: weight for name, (weight, _) in TERMS.items()},
        "action_space": [_sig(env.action_space.low), _sig(env.action_space.high)],
        "max_episode_steps": env.spec.max_episode_steps,
        "rollout": {"observations": seen, "rewards": rewards},
    }


def env_contract_hash(env_id: str) -> str:
    """Returns the hash of the id's contract (tendon2r_gym.policies.registry.contract_hash)."""
    import json

    return contract_hash(json.loads(json.dumps(env_contract(env_id))))


@functools.cache
def pinned() -> dict[str, str]:
    """Returns the pinned hash of each id (tendon2r_gym/data/contracts.yaml)."""
    return {str(k): str(v) for k, v in load_yaml(CONTRACTS).items()}

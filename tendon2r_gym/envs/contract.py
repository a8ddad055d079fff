"""The contract of each registered env id, pinned: what a learner sees and is scored on.

An id's contract is its resolved config (the default arm, reference, timing, reset noise,
observation options, reward form and weights: EnvConfig.to_dict, with ``observe`` written as
the four flags it replaced, tendon2r_gym.task.observation.as_flags, so that an id whose
behaviour did not change keeps its hash), its observation layout, its
reward terms with their default weights, its action space, its episode length, what its entry
point adds around the env (``wrapper``: a residual id's PD and the correction's scale) and a short
seeded rollout's observations and rewards (six significant digits): the behaviour, not only
the settings.  ``tendon2r_gym/data/contracts.yaml`` holds each id's hash; tests/test_contract.py
fails when a contract changes until the id's version is raised (tendon2r_gym.VERSIONS) and
CHANGELOG.md says what changed.

A contract may grow: ``tendon2r_gym/data/contracts/<hash>.json`` holds each pinned contract
whole, and a contract that keeps every pinned value (`changes` is empty) and only adds
keys is the same contract.  A new option at the value that leaves the env as it was (a reward
term of weight 0, a mechanism field that is off) then needs no new version: the pinned
rollout shows that the behaviour did not change.
"""

from __future__ import annotations

import functools
import hashlib
import json
import warnings
from typing import Any

import gymnasium as gym
import numpy as np

from tendon2r_gym.envs.env_config import arguments
from tendon2r_gym.presets import DATA_DIR, load_yaml
from tendon2r_gym.task import observation
from tendon2r_gym.task.rewards import TERMS

CONTRACTS = DATA_DIR / "contracts.yaml"
#: The pinned contracts, whole, one file per hash.
PINNED_DIR = DATA_DIR / "contracts"
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
    # What the entry point takes besides the env's own arguments (a residual id's PD wrapper).
    wrapper = {k: v for k, v in gym.spec(env_id).kwargs.items() if k not in arguments()}
    return {
        **({"wrapper": wrapper} if wrapper else {}),
        "config": observation.as_flags(config.to_dict()),
        "observation": config.observation.layout(),
        "reward_terms": {name: weight for name, (weight, _) in TERMS.items()},
        "action_space": [_sig(env.action_space.low), _sig(env.action_space.high)],
        "max_episode_steps": env.spec.max_episode_steps,
        "rollout": {"observations": seen, "rewards": rewards},
    }


def contract_hash(env_config: dict[str, Any]) -> str:
    """Returns the hash of an env contract: SHA-256 of its canonical JSON, 12 hex digits (an
    id's contract, or the env config a shipped model's runs recorded: the registry's
    ``contract``)."""
    text = json.dumps(env_config, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def env_contract_hash(env_id: str) -> str:
    """Returns the hash of the id's contract (`contract_hash`)."""
    return contract_hash(json.loads(json.dumps(env_contract(env_id))))


@functools.cache
def pinned() -> dict[str, str]:
    """Returns the pinned hash of each id (tendon2r_gym/data/contracts.yaml)."""
    return {str(k): str(v) for k, v in load_yaml(CONTRACTS).items()}


def pinned_contract(env_id: str) -> dict[str, Any]:
    """Returns the id's pinned contract (``PINNED_DIR/<hash>.json``), or raises if the file
    is missing or does not hash to the pinned hash."""
    digest = pinned()[env_id]
    path = PINNED_DIR / f"{digest}.json"
    contract = json.loads(path.read_text())
    if contract_hash(contract) != digest:
        raise ValueError(f"{path} does not hash to {digest}: restore it from the repository")
    return contract


def leaves(value: Any, path: str = "") -> dict[str, Any]:
    """Returns a contract's values by path ("config.mechanism.R1"): mappings are walked,
    anything else (a number, a list such as the rollout) is one value."""
    if not isinstance(value, dict):
        return {path: value}
    out: dict[str, Any] = {}
    for key, item in value.items():
        out.update(leaves(item, f"{path}.{key}" if path else str(key)))
    return out


def changes(pinned_: dict[str, Any], current: dict[str, Any]) -> list[str]:
    """Returns the paths of ``pinned_`` that ``current`` lost or holds another value at (added
    paths are not changes: the contract grew)."""
    ours = leaves(current)
    return [k for k, v in leaves(pinned_).items() if k not in ours or ours[k] != v]

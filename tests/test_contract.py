"""Each registered env id's contract is pinned (tendon2r_gym.policies.contract): changing the env's
defaults, observation, reward, actions, reset or episode length fails here until the id's
version is raised and CHANGELOG.md says what changed."""

import re
from pathlib import Path

import gymnasium as gym
import pytest

import tendon2r_gym
from tendon2r_gym.policies.contract import env_contract, env_contract_hash, pinned

IDS = sorted(i for i in gym.registry if re.fullmatch(r"Tendon2R(Residual)?-v\d+", i))
CHANGELOG = Path(__file__).resolve().parents[1] / "CHANGELOG.md"


def test_every_registered_id_is_pinned_and_every_pinned_id_registered():
    assert IDS == sorted(pinned())
    assert tendon2r_gym.LATEST in IDS
    versions = {i.rsplit("-", 1)[1] for i in IDS}
    assert versions == set(tendon2r_gym.VERSIONS)


@pytest.mark.parametrize("env_id", IDS)
def test_the_contract_is_the_pinned_one(env_id):
    assert env_contract_hash(env_id) == pinned()[env_id], (
        f"{env_id}'s contract changed: register a new version (tendon2r_gym.VERSIONS), pin it "
        "in tendon2r_gym/data/contracts.yaml and say what changed in CHANGELOG.md"
    )


@pytest.mark.parametrize("env_id", IDS)
def test_the_changelog_describes_each_id(env_id):
    headings = [line for line in CHANGELOG.read_text().splitlines() if line.startswith("## ")]
    assert any(re.search(rf"\b{re.escape(env_id)}\b", h) for h in headings), env_id


def test_the_contract_sees_a_changed_default_and_a_changed_behaviour(monkeypatch):
    base = env_contract("Tendon2R-v1")
    assert env_contract("Tendon2R-v1") == base, "deterministic"
    gym.register(id="Tendon2RTest-v9", entry_point="tendon2r_gym.envs.registration:make_env",
                 kwargs={**tendon2r_gym.VERSIONS["v1"], "reset_noise_scale": 0.03})  # fmt: skip
    try:
        changed = env_contract("Tendon2RTest-v9")
    finally:
        del gym.registry["Tendon2RTest-v9"]
    assert changed["config"] != base["config"] and changed["rollout"] != base["rollout"]
    from tendon2r_gym.task import rewards as task

    monkeypatch.setitem(task.TERMS, "ctrl", (0.002, task.TERMS["ctrl"][1]))
    assert env_contract("Tendon2R-v1")["reward_terms"] != base["reward_terms"]

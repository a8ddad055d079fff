"""Each registered env id's contract is pinned (tendon2r_gym.envs.contract): changing the env's
defaults, observation, reward, actions, reset or episode length fails here until the id's
version is raised and CHANGELOG.md says what changed."""

import json
import re
from pathlib import Path

import gymnasium as gym
import pytest

import tendon2r_gym
from tendon2r_gym.envs.contract import changes, env_contract, pinned, pinned_contract

IDS = sorted(i for i in gym.registry if re.fullmatch(r"Tendon2R(Residual)?-v\d+", i))
CHANGELOG = Path(__file__).resolve().parents[1] / "CHANGELOG.md"


def test_every_registered_id_is_pinned_and_every_pinned_id_registered():
    assert IDS == sorted(pinned())
    assert tendon2r_gym.LATEST in IDS
    versions = {i.rsplit("-", 1)[1] for i in IDS}
    assert versions == set(tendon2r_gym.VERSIONS)


@pytest.mark.parametrize("env_id", IDS)
def test_the_contract_keeps_every_pinned_value(env_id):
    changed = changes(pinned_contract(env_id), json.loads(json.dumps(env_contract(env_id))))
    assert not changed, (
        f"{env_id}'s contract changed at {changed[:5]}: register a new version "
        "(tendon2r_gym.VERSIONS), pin it in tendon2r_gym/data/contracts.yaml (and its whole "
        "contract in tendon2r_gym/data/contracts/) and say what changed in CHANGELOG.md"
    )


def test_an_option_added_at_its_off_value_keeps_the_contract(monkeypatch):
    """A new reward term of weight 0 adds paths and changes no pinned value: the same
    contract; a changed default weight is a change, named by its path."""
    from tendon2r_gym.task import rewards

    pinned_v1 = pinned_contract("Tendon2R-v1")
    monkeypatch.setitem(rewards.TERMS, "new_term", (0.0, "a term nobody weighs"))
    monkeypatch.setitem(rewards.REWARD_SCALES, "new_term", 0.0)
    grown = json.loads(json.dumps(env_contract("Tendon2R-v1")))
    assert "new_term" in grown["reward_terms"] and changes(pinned_v1, grown) == []
    monkeypatch.setitem(rewards.TERMS, "ctrl", (0.002, rewards.TERMS["ctrl"][1]))
    monkeypatch.setitem(rewards.REWARD_SCALES, "ctrl", 0.002)
    changed = changes(pinned_v1, json.loads(json.dumps(env_contract("Tendon2R-v1"))))
    assert "reward_terms.ctrl" in changed and "config.reward_scales.ctrl" in changed


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

"""The registry of shipped models (tendon2r_gym/data/shipped.yaml) against the bundles: every
bundle registered, every line true of its bundle, and each bundle re-trainable from its entry."""

import json
import shlex

import pytest

from tendon2r_gym.artifacts.bundle import bundle_meta, bundle_names, bundled_model
from tendon2r_gym.artifacts.registry import GROUPS, names, shipped
from tendon2r_gym.artifacts.runs import RunFolder, stem_of
from tendon2r_gym.envs.contract import contract_hash
from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.task import observation
from tendon2r_gym.training import Hyperparams


def test_every_bundle_is_registered_and_every_registered_model_is_bundled():
    assert sorted(names()) == bundle_names()
    assert {s.group for s in shipped().values()} <= set(GROUPS)


def _subset_differences(recorded, now, where=""):
    """The keys of ``recorded`` (recursively) where ``now`` differs: a key added to the env
    since a run was recorded is not a difference if the run's env behaved as its default."""
    if isinstance(recorded, dict) and isinstance(now, dict):
        return [d for k, v in recorded.items()
                for d in _subset_differences(v, now.get(k), f"{where}.{k}")]  # fmt: skip
    return [] if recorded == now else [where]


@pytest.mark.parametrize("name", names())
def test_each_line_is_true_of_its_bundle(name):
    """Seeds, primary seed, contract hash, preset and entry are what the bundle's files say;
    its recorded command trains the entry; every seed's config.yaml is the entry's resolved
    hyperparameters and its recorded env contract is what the entry builds today."""
    line, meta = shipped()[name], bundle_meta(name)
    assert list(line.seeds) == meta["seeds"] and line.primary_seed == meta["primary_seed"]
    command = shlex.split(meta["train_command"])
    assert command[0] == "tendon2r-train" and command[command.index("--hyperparams") + 1] == (
        line.entry
    ), "the recorded command re-trains the entry"
    entry = Hyperparams.from_entry(line.entry)
    assert entry.env_kwargs.get("preset", "default") == line.env
    contract = EnvConfig.make(**entry.env_kwargs)
    built = {**contract.to_dict(), "observation": contract.observation.layout()}
    built = json.loads(json.dumps(built))  # tuples as lists, as run.json holds them
    for seed in line.seeds:
        run = RunFolder(stem_of(bundled_model(name, seed)).parent)
        record = run.read_json("run.json")
        assert contract_hash(record["env_config"]) == line.contract, f"seed {seed}"
        recorded_config = observation.from_flags(record["env_config"])  # an older record's flags
        assert not _subset_differences(recorded_config, built), f"seed {seed}"
        recorded = Hyperparams.from_dict(run.read_config()).to_dict()
        ours = entry.to_dict()
        differ = [k for k in ours if k != "env_kwargs" and ours[k] != recorded[k]]
        assert not differ, f"seed {seed}: {differ}"


def test_the_contract_hash_changes_with_any_field():
    record = {"a": 1, "b": {"c": [1.0, 2.0]}}
    assert contract_hash(record) == contract_hash({"b": {"c": [1.0, 2.0]}, "a": 1})
    assert contract_hash(record) != contract_hash({"a": 1, "b": {"c": [1.0, 2.5]}})

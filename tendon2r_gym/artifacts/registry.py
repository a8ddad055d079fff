"""The registry of shipped models (``tendon2r_gym/data/shipped.yaml``): one line per model.

Each line gives the model's role, its training entry (``tendon2r_gym/data/ppo.yaml``), the
preset it was trained on, its bundled seeds (the first is the primary one) and the hash of the
env contract it needs: the env config its runs recorded (run.json ``env_config``: every env
argument, resolved, and the observation layout), as tendon2r_gym.envs.contract.contract_hash
computes it.  Its ``group`` says where the benchmark runs it: ``preset`` (the preset's own
table), ``generalist`` (zero-shot on your arm), ``realism`` (the perturbed arms) or
``references`` (held-out references).

Promoting a model is its bundle folder (``tendon2r-bundle``) and one line there; the benchmark,
the CLI, the tests and the docs read the rest from here.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

from tendon2r_gym.presets import DATA_DIR, load_yaml
from tendon2r_gym.validation import check_keys, invalid

REGISTRY = DATA_DIR / "shipped.yaml"
GROUPS = ("preset", "generalist", "realism", "references")


@dataclass(frozen=True)
class Shipped:
    """One shipped model (see the module docstring)."""

    name: str
    role: str
    entry: str
    env: str
    seeds: tuple[int, ...]
    contract: str
    group: str

    @property
    def primary_seed(self) -> int:
        return self.seeds[0]


@functools.cache
def shipped() -> dict[str, Shipped]:
    """Returns the registry: name -> Shipped, in the file's order."""
    out = {}
    for name, line in load_yaml(REGISTRY).items():
        where = f"{REGISTRY.name}: {name}"
        if not isinstance(line, dict):
            raise invalid(where, line, "a mapping of role, entry, env, seeds, contract, group")
        check_keys(where, line, ("role", "entry", "env", "seeds", "contract", "group"))
        if line.get("group") not in GROUPS:
            raise invalid(f"{where}.group", line.get("group"), f"one of {GROUPS}")
        out[name] = Shipped(name=name, **{**line, "seeds": tuple(line["seeds"])})
    return out


def names(group: str | None = None) -> list[str]:
    """Returns the shipped models' names (of one group)."""
    return [n for n, s in shipped().items() if group is None or s.group == group]

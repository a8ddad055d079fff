"""Import shim: the env contract lives in :mod:`tendon2r_gym.envs.contract`.  This path stays
because shipped text names it: the header of the pinned hashes (tendon2r_gym/data/contracts.yaml,
package data that is never edited), the env's Version History and a dated research note."""

from tendon2r_gym.envs.contract import (
    CONTRACTS,
    PINNED_DIR,
    changes,
    contract_hash,
    env_contract,
    env_contract_hash,
    leaves,
    pinned,
    pinned_contract,
)

__all__ = [
    "CONTRACTS",
    "PINNED_DIR",
    "changes",
    "contract_hash",
    "env_contract",
    "env_contract_hash",
    "leaves",
    "pinned",
    "pinned_contract",
]

"""Pins the contract of new env ids (tendon2r_gym.envs.contract).

    python scripts/pin_contract.py Tendon2R-v2 Tendon2RResidual-v2

Writes each id's whole contract to tendon2r_gym/data/contracts/<hash>.json and its hash to
tendon2r_gym/data/contracts.yaml.  An id that is pinned already is refused: a pinned contract
never changes (register a new version instead, and say what changed in CHANGELOG.md).
"""

from __future__ import annotations

import json
import sys

import tendon2r_gym  # noqa: F401  (registers the ids)
from tendon2r_gym.envs.contract import CONTRACTS, PINNED_DIR, contract_hash, env_contract, pinned


def main(ids: list[str]) -> int:
    table = dict(pinned())
    for env_id in ids:
        if env_id in table:
            print(f"error: {env_id} is pinned already ({table[env_id]}); a pinned contract "
                  "never changes: register a new version", file=sys.stderr)  # fmt: skip
            return 2
        contract = json.loads(json.dumps(env_contract(env_id)))
        digest = contract_hash(contract)
        path = PINNED_DIR / f"{digest}.json"
        if not path.exists():
            path.write_text(json.dumps(contract, indent=1, sort_keys=True) + "\n")
        table[env_id] = digest
        print(f"{env_id}: {digest}")
    lines = [line for line in CONTRACTS.read_text().splitlines() if line.startswith("#")]
    body = "".join(f"{k}: '{v}'\n" for k, v in table.items())  # quoted: a hash is a string
    CONTRACTS.write_text("\n".join(lines) + "\n" + body)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

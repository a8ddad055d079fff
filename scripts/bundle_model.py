"""Copy finished training runs into models/<preset>/ (the bundled PPO models).

    python scripts/bundle_model.py --preset default runs/default/seed_0 runs/default/seed_1

The first run is the primary model (used by ``evaluate.py --policy ppo``); the others give the
spread over training seeds.  ``train_ppo.py --bundle`` does the same right after training.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from tendon2r_gym.bundle import bundle_runs


def main(argv: list[str] | None = None) -> Path:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--preset", required=True, help="bundle name, e.g. default")
    p.add_argument("runs", nargs="+", type=Path, help="run folders written by train_ppo.py")
    args = p.parse_args(argv)
    command = shlex.join(
        ["python", "scripts/bundle_model.py", *(sys.argv[1:] if argv is None else argv)]
    )
    dest = bundle_runs(args.runs, args.preset, command)
    print("bundled", len(args.runs), "run(s) into", dest)
    return dest


if __name__ == "__main__":
    main()

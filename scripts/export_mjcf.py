"""Write the MJCF XML of a preset's mechanism (loads with MjModel.from_xml_path and the viewer).

python scripts/export_mjcf.py --preset default --out build/default.xml
"""

from __future__ import annotations

import argparse
from pathlib import Path

from tendon2r_gym.config import list_presets, load_preset
from tendon2r_gym.mechanism import Mechanism
from tendon2r_gym.model import to_xml


def main(argv: list[str] | None = None) -> Path:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--preset", default="default", help=f"one of {list_presets()} or a YAML path")
    p.add_argument("--out", default=None, help="output file (default build/<preset>.xml)")
    args = p.parse_args(argv)
    mech = Mechanism.from_dict(load_preset(args.preset)["mechanism"])
    out = Path(args.out or f"build/{Path(args.preset).stem}.xml")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(to_xml(mech))
    print("wrote", out)
    return out


if __name__ == "__main__":
    main()

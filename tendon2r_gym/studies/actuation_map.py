"""Heat map of log10 cond(J) over the joint range, one panel per routing, with the preset's
reference trajectory on top: why mirror-image routings cannot drive both joints.

    python scripts/actuation_map.py --env-config default --out results/actuation_map.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from tendon2r_gym.actuation import ActuationAnalysis  # noqa: E402
from tendon2r_gym.env_config import EnvConfig  # noqa: E402
from tendon2r_gym.mechanism import ROUTINGS  # noqa: E402
from tendon2r_gym.model import build_model  # noqa: E402


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--env-config", default="default", help="preset name or experiment file")
    p.add_argument("--out", default="results/actuation_map.png")
    p.add_argument("--grid", type=int, default=91)
    args = p.parse_args(argv)
    config = EnvConfig.make(args.env_config)
    mech, ref = config.mechanism, config.reference
    traj = np.degrees(ref.q(np.arange(0, 2.0, 1e-3)))
    q = np.linspace(*mech.joint_range_rad, args.grid)
    fig, axes = plt.subplots(1, len(ROUTINGS), figsize=(5 * len(ROUTINGS), 4.4), sharey=True)
    summary = {}
    for ax, routing in zip(axes, ROUTINGS, strict=True):
        analysis = ActuationAnalysis(build_model(mech.replace(routing=routing)))
        cond = analysis.condition_map(q, q)
        along = [analysis.condition_number(np.radians(x)) for x in traj[::10]]
        summary[routing] = {
            "grid_max_cond": float(np.max(cond)),
            "grid_median_cond": float(np.median(cond)),
            "reference_max_cond": float(np.max(along)),
        }
        im = ax.pcolormesh(
            np.degrees(q),
            np.degrees(q),
            np.log10(np.minimum(cond, 1e17)).T,
            vmin=0,
            vmax=6,
            cmap="viridis",
            shading="auto",
        )
        ax.plot(traj[:, 0], traj[:, 1], "w-", lw=0.8, label="reference")
        ax.set(title=f"{routing}: max cond on path {max(along):.3g}", xlabel="q_A (deg)")
        ax.legend(loc="lower right")
    axes[0].set_ylabel("q_B (deg)")
    fig.colorbar(im, ax=axes, label="log10 cond(J)  (clipped at 6)")
    fig.suptitle(f"Moment-arm conditioning, {args.env_config}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print("wrote", args.out)
    print(json.dumps(summary, indent=1))
    return summary


if __name__ == "__main__":
    main()

"""Actuation map: per routing, log10 cond(J) and the positive-span margin over the joint range,
with the preset's reference path on top.  Why mirror-image routings cannot drive both joints,
and why pull-only tendons need three.

    python -m research.studies.actuation_map --env-config default \
        --out research/results/actuation_map.png

cond(J) near 1 means the tendons drive both joints equally well.  The margin (deg) is pi minus
the largest angular gap between the moment-arm rows: > 0 where pull-only tendons can produce
any joint torque (tendon2r_gym.simulation.routing.positive_span); two tendons never reach it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from tendon2r_gym.app.args import arg, parse  # noqa: E402
from tendon2r_gym.envs.env_config import EnvConfig  # noqa: E402
from tendon2r_gym.simulation.actuation import ActuationAnalysis  # noqa: E402
from tendon2r_gym.simulation.model import build_model  # noqa: E402
from tendon2r_gym.simulation.routing import ROUTINGS  # noqa: E402


@dataclass
class Args:
    """The actuation map's flags."""

    env_config: Annotated[str, arg("preset name or experiment file")] = "default"
    out: Annotated[str, arg("the figure (PNG); its numbers go next to it as .json")] = (
        "research/results/actuation_map.png"
    )
    grid: Annotated[int, arg("joint angles per joint")] = 61


def main(argv: list[str] | None = None) -> dict:
    args = parse(Args, argv, __doc__)
    config = EnvConfig.make(args.env_config)
    mech, ref = config.mechanism.replace(pull_only=False), config.reference
    traj = np.degrees(ref.q(np.arange(0, 2.0, 1e-3)))
    q = np.linspace(*mech.joint_range_rad, args.grid)
    n = len(ROUTINGS)
    fig, axes = plt.subplots(
        2, n, figsize=(4.6 * n, 8), sharex=True, sharey=True, constrained_layout=True
    )
    summary = {}
    for col, routing in enumerate(ROUTINGS):
        analysis = ActuationAnalysis(build_model(mech.replace(routing=routing)))
        cond = analysis.grid(q, q, analysis.condition_number)
        margin = np.degrees(analysis.grid(q, q, analysis.span_margin))
        along = [analysis.condition_number(np.radians(x)) for x in traj[::10]]
        summary[routing] = {
            "tendons": len(ROUTINGS[routing]),
            "grid_max_cond": float(np.max(cond)),
            "reference_max_cond": float(np.max(along)),
            "grid_min_span_margin_deg": float(np.min(margin)),
        }
        log_cond = np.log10(np.minimum(cond, 1e17))
        panels = (
            (log_cond, 0, 6, "viridis", f"max cond on path {max(along):.3g}"),
            (margin, -90, 90, "RdBu", f"min span margin {np.min(margin):.1f} deg"),
        )
        for row, (data, lo, hi, cmap, label) in enumerate(panels):
            ax = axes[row, col]
            im = ax.pcolormesh(
                np.degrees(q), np.degrees(q), data.T, vmin=lo, vmax=hi, cmap=cmap, shading="auto"
            )
            ax.plot(traj[:, 0], traj[:, 1], "k-", lw=0.8, label="reference")
            ax.set_title(f"{routing} ({len(ROUTINGS[routing])} tendons)\n{label}", fontsize=10)
            if row == 1:
                ax.set_xlabel("q_A (deg)")
            fig.colorbar(im, ax=ax, label="log10 cond(J)" if row == 0 else "span margin (deg)")
    for row in range(2):
        axes[row, 0].set_ylabel("q_B (deg)")
    fig.suptitle(f"Moment arms over the joint range, {args.env_config}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=90)
    print("wrote", args.out)
    print(json.dumps(summary, indent=1))
    Path(args.out).with_suffix(".json").write_text(json.dumps(summary, indent=1) + "\n")
    return summary


if __name__ == "__main__":
    main()

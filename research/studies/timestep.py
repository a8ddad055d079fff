"""Integrator / time-step study under PD control, against a fine RK4 reference.

    python -m research.studies.timestep        # writes research/results/timestep_study.md and .json

For each preset, integrator and sim_dt: the max joint-angle deviation (deg) from RK4 at
sim_dt = 2e-5 s over one episode with the same PD policy, and the physics cost per simulated
second.  The cheapest setting under 0.01 deg on every preset is the recommended default.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import gymnasium as gym
import mujoco
import numpy as np

import tendon2r_gym  # noqa: F401
from tendon2r_gym.app.args import arg, parse
from tendon2r_gym.policies.baselines import PDPolicy
from tendon2r_gym.task.observation import Q

PRESETS = ("default", "report_002")
INTEGRATORS = ("RK4", "implicitfast", "Euler")
SIM_DTS = (1e-4, 2e-4, 5e-4, 1e-3)
REFERENCE = ("RK4", 2e-5)
TOLERANCE_DEG = 0.01


def trajectory(preset: str, integrator: str, sim_dt: float, seconds: float = 2.0):
    env = gym.make(
        "Tendon2R-v0",
        preset=preset,
        mechanism={"integrator": integrator, "sim_dt": sim_dt},
        episode_duration=seconds,
    )
    pd = PDPolicy.from_env(env)
    obs, _ = env.reset(seed=0)
    qs, done = [], False
    while not done:
        obs, _, term, trunc, _ = env.step(pd.predict(obs)[0])
        qs.append(obs[Q].copy())
        done = term or trunc
    env = env.unwrapped
    # Physics cost: mj_step with nstep = substeps, no Python per substep.
    n = 2000
    start = time.perf_counter()
    for _ in range(n // 10):
        mujoco.mj_step(env.model, env.data, nstep=env.frame_skip * 10)
    cost = (time.perf_counter() - start) / (n * env.dt)  # s of CPU per simulated second
    return np.degrees(np.array(qs)), cost


@dataclass
class Args:
    """The time-step study's flags."""

    out: Annotated[str, arg("folder for timestep_study.md and .json")] = "research/results"


def main(argv: list[str] | None = None) -> dict:
    args = parse(Args, argv, __doc__)
    rows = []
    for preset in PRESETS:
        ref, _ = trajectory(preset, *REFERENCE)
        for integrator in INTEGRATORS:
            for dt in SIM_DTS:
                q, cost = trajectory(preset, integrator, dt)
                dev = float(np.max(np.abs(q - ref))) if np.isfinite(q).all() else float("inf")
                rows.append(
                    {
                        "preset": preset,
                        "integrator": integrator,
                        "sim_dt": dt,
                        "max_dev_deg": dev,
                        "cost_ms_per_sim_s": 1e3 * cost,
                    }
                )
                print(rows[-1], flush=True)
    ok = {}
    for r in rows:
        key = (r["integrator"], r["sim_dt"])
        ok.setdefault(key, []).append(r)
    passing = [
        (max(x["cost_ms_per_sim_s"] for x in v), k)
        for k, v in ok.items()
        if all(x["max_dev_deg"] < TOLERANCE_DEG for x in v)
    ]
    best = min(passing)[1] if passing else ("RK4", 1e-4)
    lines = [
        "# Time-step study",
        "",
        "Produced by `python -m research.studies.timestep`. Max "
        f"joint deviation from RK4 at {REFERENCE[1]} s over a 2 s PD episode; cost of "
        "`mj_step` per simulated second on this machine.",
        "",
        "| preset | integrator | sim_dt (s) | max deviation (deg) | cost (ms CPU / s simulated) |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['preset']} | {r['integrator']} | {r['sim_dt']:g} | "
            f"{r['max_dev_deg']:.2e} | {r['cost_ms_per_sim_s']:.1f} |"
        )
    lines += [
        "",
        f"Cheapest setting under {TOLERANCE_DEG} deg on every preset: "
        f"**{best[0]} at sim_dt = {best[1]:g} s**.",
    ]
    folder = Path(args.out)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "timestep_study.md").write_text("\n".join(lines) + "\n")
    out = {"rows": rows, "recommended": {"integrator": best[0], "sim_dt": best[1]}}
    (folder / "timestep_study.json").write_text(json.dumps(out, indent=1))
    print("recommended", best)
    return out


if __name__ == "__main__":
    main()

"""How much ordinary exploration undoes PD: PD plus a residual of white N(0, 1) noise.

    python -m research.studies.residual_noise      # research/results/residual_noise.md and .json

An untrained policy with SB3's default ``log_std_init`` 0 explores with standard deviation 1
around a mean near 0.  On a residual env that noise is added to PD's command at the residual's
scale.  This study measures PD's RMS tracking error under it, on the ``default`` arm with
Tendon2R-v2's defaults, for two ways of scaling the residual: as a fraction of each command's
range (``residual_units: command``, tension commands, the v1 residual's units) and as a
multiple of each joint's torque need (``residual_units: need``, joint-torque commands,
``Tendon2RResidual-v2``).  Seeds 10000 and 10001, one noise stream per seed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from research.studies import joints, save_json

SCALES = (0.05, 0.1, 0.2, 0.5, 1.0)
SEEDS = (10000, 10001)
UNITS = {"command": {"action_mode": "tension"}, "need": {"action_mode": "joint_torque"}}


def noisy_pd(units: str, scale: float, seeds: tuple[int, ...] = SEEDS) -> list[float]:
    """Returns PD's RMS error per joint (deg) with N(0, 1) noise as its residual."""
    import gymnasium as gym

    import tendon2r_gym  # noqa: F401  (registers the ids)
    from tendon2r_gym.policies.residual import ResidualPDWrapper

    errors = []
    for seed in seeds:
        base = gym.make("Tendon2R-v2", action_filter_tau=0.0, **UNITS[units]).unwrapped
        env = ResidualPDWrapper(base, scale, residual_units=units)
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        for _ in range(base.timing.max_episode_steps):
            *_, terminated, _, info = env.step(rng.normal(size=2).astype(np.float32))
            errors.append(info["tracking_error_deg"])
            if terminated:
                break
    return np.sqrt(np.mean(np.square(errors), axis=0)).tolist()


def main(out: str = "research/results") -> dict[str, Any]:
    rows = [{"units": u, "scale": s, "rms_deg": noisy_pd(u, s)} for u in UNITS for s in SCALES]
    pd = noisy_pd("command", 0.0 + 1e-12)
    result = {"seeds": list(SEEDS), "pd_rms_deg": pd, "rows": rows}
    save_json(Path(out), "residual_noise", result)
    lines = [
        "# PD under ordinary exploration's noise",
        "",
        "Produced by `python -m research.studies.residual_noise`: PD on the `default` arm "
        "(Tendon2R-v2's defaults, no command filter) with N(0, 1) noise as its residual, "
        f"seeds {list(SEEDS)}.  PD alone: {joints(pd, 4)} deg.",
        "",
        "| residual units | scale | RMS A / B (deg) | x PD's A / B |",
        "|---|---|---|---|",
    ]
    for r in rows:
        ratio = [a / b for a, b in zip(r["rms_deg"], pd, strict=True)]
        lines.append(f"| {r['units']} | {r['scale']:g} | {joints(r['rms_deg'], 4)} | "
                     f"{joints(ratio, 2)} |")  # fmt: skip
    (Path(out) / "residual_noise.md").write_text("\n".join(lines) + "\n")
    return result


if __name__ == "__main__":
    main()

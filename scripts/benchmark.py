"""The main job: PD vs computed torque vs PPO on the same seeds, on `default` and `report_002`.

    python scripts/benchmark.py                        # bundled PPO models, 3 episodes each
    python scripts/benchmark.py --train-report-002     # also train a PPO for report_002 first

Writes results/benchmark.md, results/benchmark.json and plots in results/plots/.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

import tendon2r_gym  # noqa: E402, F401
from tendon2r_gym.evaluation import BUNDLED_DIR, evaluate  # noqa: E402
from tendon2r_gym.plots import plot_trace  # noqa: E402

PRESETS = ("default", "report_002")
#: Figures quoted from the lab reports (their own measurements), shown for comparison only.
REPORT_ROWS = {
    "default": (
        "report 001 (position actuators on the joints, not tendons)",
        [0.92, 1.15],
        [1.85, 2.34],
    ),
    "report_002": ("report 002 (open-loop tendon commands)", [37.5, 35.8], [60.0, 70.0]),
}
#: Held-out references for the generalization check (the random-reference PPO never saw these
#: exact sinusoids; they lie inside its training ranges, configs/ppo.yaml random_reference).
HELD_OUT = [
    {
        "amp_deg": [12.0, 18.0],
        "freq_hz": [1.3, 2.2],
        "bias_deg": [5.0, -8.0],
        "phase_deg": [30.0, 200.0],
    },
    {
        "amp_deg": [22.0, 7.0],
        "freq_hz": [2.8, 0.9],
        "bias_deg": [-6.0, 2.0],
        "phase_deg": [90.0, 0.0],
    },
    {
        "amp_deg": [8.0, 14.0],
        "freq_hz": [0.7, 2.6],
        "bias_deg": [0.0, -12.0],
        "phase_deg": [270.0, 45.0],
    },
]


def _fmt(pair: list[float] | None, digits: int = 4) -> str:
    return "-" if pair is None else " / ".join(f"{v:.{digits}f}" for v in pair)


def run_presets(episodes: int, out: Path) -> list[dict]:
    rows = []
    seeds = list(range(episodes))
    for preset in PRESETS:
        for policy in ("pd", "ct", "ppo"):
            model = BUNDLED_DIR / preset / "best_model.zip"
            row = {"preset": preset, "policy": policy}
            if policy == "ppo" and not model.is_file():
                rows.append({**row, "missing": f"no bundled model {model}"})
                continue
            start = time.perf_counter()
            metrics, traces = evaluate(
                policy, {"preset": preset}, seeds, model if policy == "ppo" else None
            )
            row.update(metrics, eval_s=round(time.perf_counter() - start, 1))
            if policy == "ppo":
                summary = BUNDLED_DIR / preset / "summary.json"
                if summary.is_file():
                    s = json.loads(summary.read_text())
                    row["train_steps"], row["train_wall_s"] = s["timesteps"], s["wall_time_s"]
                seeds_file = BUNDLED_DIR / preset / "seeds_summary.json"
                if seeds_file.is_file():
                    s = json.loads(seeds_file.read_text())
                    row["seeds_rms_mean"], row["seeds_rms_std"] = (
                        s["rms_deg_mean"],
                        s["rms_deg_std"],
                    )
                    row["n_training_seeds"] = len(s["seeds"])
            plot_trace(traces[0], out / "plots" / preset / policy, f"{policy.upper()} on {preset}")
            rows.append(row)
            print(
                f"{preset:11s} {policy:4s} RMS {_fmt(row['rms_deg'])} deg  max "
                f"{_fmt(row['max_deg'], 3)} deg  RMS force {_fmt(row['rms_force_N'])} N",
                flush=True,
            )
    return rows


def run_held_out(out: Path) -> list[dict]:
    model = BUNDLED_DIR / "random_reference" / "best_model.zip"
    rows = []
    for policy in ("pd", "ppo"):
        if policy == "ppo" and not model.is_file():
            rows.append({"policy": policy, "missing": f"no bundled model {model}"})
            continue
        errs = []
        for i, ref in enumerate(HELD_OUT):
            metrics, _ = evaluate(
                policy,
                {"preset": "default"},
                [i],
                model if policy == "ppo" else None,
                options={"reference": ref},
            )
            errs.append(metrics["rms_deg"])
        rows.append(
            {
                "policy": policy,
                "rms_deg_per_reference": errs,
                "rms_deg_mean": np.mean(errs, axis=0).tolist(),
            }
        )
        print(f"held-out {policy:4s} mean RMS {_fmt(rows[-1]['rms_deg_mean'])} deg", flush=True)
    return rows


def write_markdown(rows: list[dict], held: list[dict], path: Path, command: str) -> None:
    lines = [
        "# Benchmark: PD vs computed torque vs PPO on Tendon2R-v0",
        "",
        f"Produced by `{command}`; every figure below comes from that run except the rows",
        "marked *quoted*, which are the lab reports' own figures.",
        "",
        "Per joint (A / B): RMS and max tracking error over all steps of all episodes (same",
        "seeds for every policy), RMS tendon force per tendon, saturated-step fraction.",
        "",
        "| preset | policy | RMS error (deg) | max error (deg) | RMS force (N) | saturated | "
        "PPO training steps | PPO wall time (s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for preset in PRESETS:
        for r in (r for r in rows if r["preset"] == preset):
            if "missing" in r:
                lines.append(f"| {preset} | {r['policy']} | {r['missing']} | | | | | |")
                continue
            lines.append(
                f"| {preset} | {r['policy']} | {_fmt(r['rms_deg'])} | {_fmt(r['max_deg'], 3)} | "
                f"{_fmt(r['rms_force_N'])} | {_fmt(r['saturated_fraction'], 3)} | "
                f"{r.get('train_steps', '')} | {r.get('train_wall_s', '')} |"
            )
        name, rms, mx = REPORT_ROWS[preset]
        lines.append(f"| {preset} | *quoted: {name}* | {_fmt(rms, 2)} | {_fmt(mx, 2)} | | | | |")
    seeds = [r for r in rows if "seeds_rms_mean" in r]
    if seeds:
        lines += [
            "",
            "PPO over training seeds (best model of each seed, same evaluation seeds "
            "as during training):",
            "",
        ]
        for r in seeds:
            lines.append(
                f"- {r['preset']}: RMS {_fmt(r['seeds_rms_mean'])} ± "
                f"{_fmt(r['seeds_rms_std'])} deg over {r['n_training_seeds']} seeds"
            )
    lines += [
        "",
        "## Held-out references (generalization)",
        "",
        "PPO trained on random references (configs/ppo.yaml `random_reference`) and PD, "
        "on fixed references PPO never trained on (scripts/benchmark.py HELD_OUT):",
        "",
        "| policy | mean RMS error A / B (deg) |",
        "|---|---|",
    ]
    for r in held:
        lines.append(f"| {r['policy']} | {r.get('missing') or _fmt(r['rms_deg_mean'])} |")
    path.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--episodes", type=int, default=3)
    p.add_argument("--out", default="results")
    p.add_argument(
        "--train-report-002",
        action="store_true",
        help="train PPO for report_002 (configs/ppo.yaml) into models/report_002",
    )
    args = p.parse_args(argv)
    if args.episodes < 1:
        p.error(f"--episodes {args.episodes} is invalid; allowed: >= 1")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.train_report_002:
        import subprocess
        import sys

        subprocess.run(
            [
                sys.executable,
                str(Path(__file__).with_name("train_ppo.py")),
                "--preset",
                "report_002",
                "--run-dir",
                str(BUNDLED_DIR / "report_002"),
            ],
            check=True,
        )
    command = "python scripts/benchmark.py" + (
        f" --episodes {args.episodes}" if args.episodes != 3 else ""
    )
    rows = run_presets(args.episodes, out)
    held = run_held_out(out)
    result = {"command": command, "presets": rows, "held_out": held}
    (out / "benchmark.json").write_text(json.dumps(result, indent=1))
    write_markdown(rows, held, out / "benchmark.md", command)
    print("wrote", out / "benchmark.md")
    return result


if __name__ == "__main__":
    main()

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
from tendon2r_gym.bundle import bundle_meta, bundled_model, training_summary  # noqa: E402
from tendon2r_gym.evaluation import evaluate  # noqa: E402
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
        meta = bundle_meta(preset)
        for policy in ("pd", "ct", "ppo"):
            row = {"preset": preset, "policy": policy}
            if policy == "ppo" and meta is None:
                rows.append({**row, "missing": f"no bundled model in models/{preset}/"})
                continue
            model = bundled_model(preset) if policy == "ppo" else None
            start = time.perf_counter()
            metrics, traces = evaluate(policy, {"preset": preset}, seeds, model)
            row.update(metrics, eval_s=round(time.perf_counter() - start, 1))
            if model is not None:
                s = training_summary(model)
                row.update(
                    seed=meta["primary_seed"],
                    train_steps=s["timesteps"],
                    train_wall_s=s["wall_time_s"],
                )
            plot_trace(traces[0], out / "plots" / preset / policy, f"{policy.upper()} on {preset}")
            rows.append(row)
            _print_row(row)
        if meta is not None and len(meta["seeds"]) > 1:
            rows.append(_seed_spread(preset, meta, seeds, primary=rows[-1]))
    return rows


def _seed_spread(preset: str, meta: dict, seeds: list[int], primary: dict) -> dict:
    """Evaluates every bundled training seed on the benchmark seeds (not the seeds that chose
    each best model): mean and std over training seeds.  ``primary`` is the row already
    measured for the primary seed."""
    rms, mx, walls, steps = [], [], [], []
    for seed in meta["seeds"]:
        model = bundled_model(preset, seed)
        if seed == primary["seed"]:
            metrics = primary
        else:
            metrics, _ = evaluate("ppo", {"preset": preset}, seeds, model)
        rms.append(metrics["rms_deg"])
        mx.append(metrics["max_deg"])
        s = training_summary(model)
        walls.append(s["wall_time_s"])
        steps.append(s["timesteps"])
    row = {
        "preset": preset,
        "policy": f"ppo ({len(meta['seeds'])} seeds)",
        "training_seeds": meta["seeds"],
        "rms_deg_per_seed": rms,
        "rms_deg": np.mean(rms, axis=0).tolist(),
        "rms_deg_std": np.std(rms, axis=0).tolist(),
        "max_deg": np.mean(mx, axis=0).tolist(),
        "train_steps": int(np.mean(steps)),
        "train_wall_s": round(float(np.mean(walls)), 1),
        "train_wall_s_max": max(walls),
    }
    _print_row(row)
    return row


def _print_row(row: dict) -> None:
    std = f" +- {_fmt(row['rms_deg_std'])}" if "rms_deg_std" in row else ""
    force = f"  RMS force {_fmt(row['rms_force_N'])} N" if "rms_force_N" in row else ""
    print(
        f"{row['preset']:11s} {row['policy']:14s} RMS {_fmt(row['rms_deg'])}{std} deg  max "
        f"{_fmt(row['max_deg'], 3)} deg{force}",
        flush=True,
    )


def verdicts(rows: list[dict]) -> list[str]:
    """Returns, per preset, whether PPO's RMS error is <= PD's on both joints (issue target)."""
    lines = []
    for preset in PRESETS:
        by = {r["policy"]: r for r in rows if r["preset"] == preset and "rms_deg" in r}
        if "pd" not in by:
            continue
        for name, r in by.items():
            if not name.startswith("ppo"):
                continue
            wins = all(p <= d for p, d in zip(r["rms_deg"], by["pd"]["rms_deg"], strict=True))
            lines.append(
                f"- {preset}, {name}: RMS {_fmt(r['rms_deg'])} vs PD {_fmt(by['pd']['rms_deg'])}"
                f" deg: PPO {'<=' if wins else 'is WORSE than'} PD on "
                f"{'both joints' if wins else 'at least one joint'}; "
                f"trained {r['train_steps']} steps in {r['train_wall_s']} s"
                + (f" (slowest seed {r['train_wall_s_max']} s)" if "train_wall_s_max" in r else "")
            )
    return lines


def run_held_out(out: Path) -> list[dict]:
    meta = bundle_meta("random_reference")
    model = bundled_model("random_reference") if meta is not None else None
    rows = []
    for policy in ("pd", "ppo"):
        if policy == "ppo" and model is None:
            rows.append(
                {"policy": policy, "missing": "no bundled model in models/random_reference/"}
            )
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
            std = f" ± {_fmt(r['rms_deg_std'])}" if "rms_deg_std" in r else ""
            lines.append(
                f"| {preset} | {r['policy']} | {_fmt(r['rms_deg'])}{std} | "
                f"{_fmt(r['max_deg'], 3)} | {_fmt(r.get('rms_force_N'))} | "
                f"{_fmt(r.get('saturated_fraction'), 3)} | "
                f"{r.get('train_steps', '')} | {r.get('train_wall_s', '')} |"
            )
        name, rms, mx = REPORT_ROWS[preset]
        lines.append(f"| {preset} | *quoted: {name}* | {_fmt(rms, 2)} | {_fmt(mx, 2)} | | | | |")
    lines += [
        "",
        "`ppo` is the bundled primary model (training seed chosen before training); "
        "`ppo (N seeds)` is the mean ± std (ddof = 0) over the bundled training seeds, each "
        "evaluated on the benchmark seeds above (not on the seeds that selected its best "
        "checkpoint); its max error is the mean of the per-seed maxima. Wall time: one "
        "training run on 2 CPU cores (mean over seeds for the seeds row).",
        "",
        "Target (PPO RMS <= PD RMS on both joints):",
        "",
        *verdicts(rows),
        "",
        "Bundled models and the commands that trained them (models/<preset>/bundle.json):",
        "",
        *(
            f"- {name}: seeds {m['seeds']}, trained by `{m['train_command']}`, bundled by "
            f"`{m['command']}`"
            for name in (*PRESETS, "random_reference")
            if (m := bundle_meta(name)) is not None
        ),
    ]
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
        help="first train PPO for report_002 (configs/ppo.yaml) and bundle it into "
        "models/report_002",
    )
    p.add_argument(
        "--train-seeds",
        type=int,
        nargs="+",
        default=[0],
        help="training seeds for --train-report-002 (default: 0)",
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
                "--seeds",
                *map(str, args.train_seeds),
                "--run-dir",
                "runs/report_002",
                "--bundle",
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

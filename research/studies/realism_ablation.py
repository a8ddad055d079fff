"""What the randomized residual sees, its network and its PD: finished real-arm runs on the
realism study's arms (research.studies.realism).

    python -m research.studies.realism_ablation \
        --runs runs/real_arm/seed_0 runs/real_arm_blind/seed_0
    # research/results/realism_ablation.md and .json

Each run (a folder written by ``tendon2r-train``, e.g. of the configs/ppo.yaml entries
``real_arm``, ``real_arm_scheduled``, ``real_arm_oracle``, ``real_arm_history``,
``real_arm_blind``, ``real_arm_frame_stack`` and ``real_arm_gains``) gives its training record
(best evaluation, its effort, steps and wall time) and its best model's (``--model last``: its
last model's) RMS error on the arms of the realism study
(research.studies.realism.realism_arms), against PD on the same episodes, as that section scores
the shipped bundle: a run trained on drawn PD gains on the gains tendon2r-tune-pd finds on each
arm (research.studies.realism.on_its_pd).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np

from research.studies import joints, one_or_more, save_json
from research.studies.realism import TUNE_EPISODES, on_its_pd, realism_arms
from tendon2r_gym.app.args import arg, parse
from tendon2r_gym.artifacts.model_env import trained_on_drawn_gains
from tendon2r_gym.artifacts.runs import BEST_METRICS, CONFIG, SUMMARY, RunFolder, command_line
from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.evaluation.evaluator import evaluate
from tendon2r_gym.evaluation.metrics import beats, worst_ratio
from tendon2r_gym.evaluation.tuning import tune_pd
from tendon2r_gym.formatting import pair
from tendon2r_gym.task import observation
from tendon2r_gym.task.arms import CONTROLLER, GAIN_UNITS, MechanismRanges
from tendon2r_gym.task.gains import gains_of, true_phase_per_hz
from tendon2r_gym.validation import invalid


def _record(run: RunFolder) -> dict[str, Any]:
    """Returns the run's training record; raises if ``run`` is not a run folder."""
    config = run.read_config()
    if config is None:
        raise invalid("--runs", str(run.path), f"run folders (seed_<n>, with a {CONFIG})")
    best, summary = run.read_json(BEST_METRICS), run.read_json(SUMMARY)
    return {
        "run": str(run.path),
        "command": run.train_command(),
        "env_kwargs": config.get("env_kwargs", {}),
        "hide_from_actor": config.get("hide_from_actor", []),
        "frame_stack": config.get("frame_stack", 1),
        "frame_stride": config.get("frame_stride", 1),
        "net_arch": config.get("policy_kwargs", {}).get("net_arch"),
        "timesteps": summary["timesteps"],
        "wall_time_s": summary["wall_time_s"],
        "best_timesteps": best["timesteps"],
        "best_rms_deg": best["rms_deg"],
        "best_rms_tension_N": best["rms_tension_N"],
        "best_rms_tension_rate_N_per_s": best["rms_tension_rate_N_per_s"],
    }


@dataclass
class Args:
    """The realism ablation's flags."""

    runs: Annotated[list[str], arg("run folders (seed_<n>)")]
    episodes: Annotated[int, arg("per arm, as the realism study")] = 3
    model: Annotated[
        Literal["best", "last"],
        arg("each run's best model (by its training evaluations) or its last"),
    ] = "best"
    out: Annotated[str, arg("folder for realism_ablation.md and .json")] = "research/results"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse(Args, argv, __doc__)
    one_or_more("--runs", args.runs, "one or more run folders (seed_<n>)")
    command = command_line(argv, "python -m research.studies.realism_ablation")
    runs = [RunFolder(Path(r)) for r in args.runs]
    records = [_record(run) for run in runs]  # every folder checked before any evaluation
    seeds = list(range(args.episodes))
    arms = []
    models = [getattr(run, args.model).with_suffix(".zip") for run in runs]
    needs_tuning = any(map(trained_on_drawn_gains, models))
    for name, kwargs in realism_arms():
        pd, _ = evaluate("pd", kwargs, seeds)
        row = {"arm": name, "pd": pd["rms_deg"], "runs": []}
        tuned = None  # the arm with its tuned PD gains, for runs trained on drawn gains
        if needs_tuning:
            tuned = {**kwargs, "pd_gains": tune_pd(kwargs, TUNE_EPISODES).gains.to_dict()}
            row["tuned_pd"] = _tuned_pd(tuned)
        for model in models:
            metrics, _ = evaluate("ppo", on_its_pd(kwargs, tuned, model), seeds, model)
            row["runs"].append(metrics["rms_deg"])
        arms.append(row)
        print(name, joints(pd["rms_deg"]), *(joints(r) for r in row["runs"]), flush=True)
    for i, record in enumerate(records):
        ratios = [worst_ratio(a["runs"][i], a["pd"]) for a in arms]
        record.update(
            arms_le_pd=sum(beats(a["runs"][i], a["pd"]) for a in arms),
            median_worst_ratio=float(np.median(ratios)),
            max_worst_ratio=float(np.max(ratios)),
            lost_to_pd=[a["arm"] for a, r in zip(arms, ratios, strict=True) if r > 1.0],
        )
    result = {
        "command": command,
        "episodes": args.episodes,
        "model": args.model,
        "runs": records,
        "arms": arms,
    }
    write(result, Path(args.out))
    return result


def _tuned_pd(tuned: dict[str, Any]) -> dict[str, float]:
    """Returns the tuned PD's bandwidth (Hz) on the arm and the phase the arm's true loop
    delay takes at it (what MechanismRanges' tuned_phase draws: tendon2r_gym.task.gains)."""
    arm = EnvConfig.make(**tuned)
    f = arm.pd_gains.bandwidth_hz
    per_hz = true_phase_per_hz(arm.mechanism, arm.observation_delay, arm.ctrl_dt)
    return {"bandwidth_hz": f, "true_loop_phase_rad": f * per_hz}


def _sees(record: dict[str, Any]) -> str:
    kwargs = observation.from_flags(record["env_kwargs"])  # a record of 0.2 holds flags
    if "arm" not in kwargs.get("observe", ()):
        seen = "no arm features"
    elif record["hide_from_actor"]:
        seen = f"the drawn arm; the actor not {', '.join(record['hide_from_actor'])}"
    else:
        seen = "the drawn arm"
    stack, stride = record["frame_stack"], record["frame_stride"]
    if stack == 1:
        return seen
    return (
        seen
        + f"; its last {stack} observations"
        + (f", {stride} steps apart" if stride > 1 else "")
    )


def _network_and_pd(record: dict[str, Any]) -> str:
    """Returns the run's hidden layers and its PD's gains (a bandwidth, scheduled on each
    arm's loop delay: tendon2r_gym.task.gains, or drawn per episode in training and tuned per arm
    when deployed)."""
    net = record["net_arch"]
    layers = " x ".join(map(str, net)) if isinstance(net, list) else "SB3's default"
    kwargs = record["env_kwargs"]
    gains = gains_of(kwargs.get("pd_gains"))
    drawn = kwargs.get("mechanism_ranges")
    ranges = MechanismRanges.from_value(drawn).ranges if drawn else ()
    gain_ranges = [
        f"{lo:.3g} to {hi:.3g} {GAIN_UNITS[name]}"
        for name, (lo, hi) in ranges
        if name in CONTROLLER
    ]
    if gain_ranges:
        tied = MechanismRanges.from_value(drawn).tuned_phase
        how = f" at {tied[0]:.3g} to {tied[1]:.3g} rad of the arm's true loop" if tied else ""
        pd = f"tuned per arm (trained on {', '.join(gain_ranges)} drawn per episode{how})"
    elif gains.max_delay_phase is None:
        pd = f"{gains.bandwidth_hz:g} Hz"
    else:
        pd = f"{gains.max_delay_phase:.3g} rad / loop delay, <= {gains.bandwidth_hz:g} Hz"
    return f"{layers}; PD {pd}"


def write(result: dict[str, Any], out: Path) -> None:
    """Writes realism_ablation.json and realism_ablation.md."""
    save_json(out, "realism_ablation", result)
    n = len(result["arms"])
    lines = [
        "# Realism ablation: what the randomized residual sees",
        "",
        f"Produced by `{result['command']}`. Training: each run's best evaluation (its "
        "`best_metrics.json`, on the entry's evaluation seeds: random arms from its ranges). "
        f"Realism arms: the {n} arms of the realism study (research.studies.realism), "
        f"{result['episodes']} episodes each, the run's {result.get('model', 'best')} model "
        "against PD on the same "
        "episodes; ratio: the worse joint's RMS as a multiple of PD's. Tensions per tendon.",
        "",
        "| # | run | sees | network; PD | steps (best at) | wall (s) | training RMS A / B (deg) "
        "| RMS tension (N) | RMS tension rate (N/s) | <= PD on both joints | median ratio "
        "| worst ratio | loses to PD on |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for i, r in enumerate(result["runs"], 1):
        tension = pair(r["best_rms_tension_N"], ".2f")
        rate = pair(r["best_rms_tension_rate_N_per_s"], ".1f")
        lines.append(
            f"| {i} | `{r['command']}` | {_sees(r)} | {_network_and_pd(r)} | "
            f"{r['timesteps']:,} ({r['best_timesteps']:,}) | {r['wall_time_s']:.0f} | "
            f"{joints(r['best_rms_deg'])} | {tension} | {rate} | "
            f"{r['arms_le_pd']} of {n} | {r['median_worst_ratio']:.2f} | "
            f"{r['max_worst_ratio']:.2f} | {', '.join(r['lost_to_pd']) or 'none'} |"
        )
    lines += ["", "Per arm, RMS A / B (deg):", ""]
    numbers = range(1, len(result["runs"]) + 1)
    tuned = all("tuned_pd" in a for a in result["arms"])
    if tuned:
        lines[-1] += (
            " tuned PD: the bandwidth tendon2r-tune-pd finds on the arm, and the phase the "
            "arm's true loop delay takes at it (2 pi f tau / sqrt(density_scale), "
            "tendon2r_gym.task.gains.true_phase_per_hz)."
        )
        lines.append("")
    head = "| arm | PD | " + ("tuned PD | " if tuned else "")
    lines.append(head + " | ".join(f"run {i}" for i in numbers) + " |")
    lines.append("|---|---|" + ("---|" if tuned else "") + "---|" * len(result["runs"]))
    for a in result["arms"]:
        cells = [f"{joints(x)} ({worst_ratio(x, a['pd']):.2f}x)" for x in a["runs"]]
        if tuned:
            t = a["tuned_pd"]
            cells.insert(0, f"{t['bandwidth_hz']:.3g} Hz, {t['true_loop_phase_rad']:.2f} rad")
        lines.append(f"| {a['arm']} | {joints(a['pd'])} | " + " | ".join(cells) + " |")
    (out / "realism_ablation.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines), flush=True)


if __name__ == "__main__":
    main()

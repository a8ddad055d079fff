"""Where a residual's RMS comes from: the reset's transient, in the RMS and in the reward.

On the arm sweep's arms that a bundle covers (research/results/arm_sweep.json, as the generalist
study takes them), the bundle runs the study's evaluation episodes. Per arm: the share of each
episode's first SETTLE_S (tendon2r_gym.evaluation.metrics), the steps that close the reset's
offset, in the
squared tracking error (what the RMS adds up), in the bundle's own tracking reward (its run's
``tracking_form`` and ``tracking_sigma_deg``) and in the registered one (the sweep's specialists
trained on it). A reward that weighs those steps far less than the RMS does trains a policy that
settles precisely but closes the offset slowly.

    python -m research.studies.transient [--bundle generalist] [--out results]
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np

from research.studies import joints, save_json
from research.studies.generalist import action_mode_of, model_of, sweep_arms
from tendon2r_gym.app.args import arg, parse
from tendon2r_gym.artifacts.model_env import in_model_settings
from tendon2r_gym.artifacts.runs import command_line, training_record
from tendon2r_gym.envs.env_config import EnvConfig, resolve
from tendon2r_gym.envs.formulas import RAD_PER_DEG, Formulas
from tendon2r_gym.evaluation.evaluator import evaluate
from tendon2r_gym.evaluation.metrics import SETTLE_S, settled, smoothness_x_pd
from tendon2r_gym.evaluation.rollout import Trace
from tendon2r_gym.ops import BATCH

#: What a reward's tracking term is read from: the fields of an env config that shape it.
REWARD_FIELDS = ("tracking_form", "tracking_sigma_deg")


def tracking_cost(task: Formulas, trace: Trace) -> np.ndarray:
    """Returns minus the task's unscaled tracking term at each step of an episode."""
    e = trace.error_deg * RAD_PER_DEG
    none: list[Any] = []
    terms = task.reward_terms(BATCH, e[:, 0], e[:, 1], none, none, none, np.zeros(len(e), bool))
    return -np.asarray(terms["tracking"])


def transient_share(traces: list[Trace], costs: dict[str, Formulas]) -> dict[str, float]:
    """Returns the share of the episodes' first SETTLE_S in their squared error and in each
    task's tracking cost."""
    head = [~settled(t) for t in traces]
    sq = [np.sum(t.error_deg**2, axis=1) for t in traces]
    out = {"squared_error": _share(sq, head)}
    for name, task in costs.items():
        out[name] = _share([tracking_cost(task, t) for t in traces], head)
    return out


def _share(per_step: list[np.ndarray], head: list[np.ndarray]) -> float:
    total = sum(float(x.sum()) for x in per_step)
    return sum(float(x[h].sum()) for x, h in zip(per_step, head, strict=True)) / total


def tracking_reward_of(model: Path) -> dict[str, Any]:
    """Returns the tracking-reward fields the model's run trained on."""
    config = training_record(model)["env_config"]
    return {k: config[k] for k in REWARD_FIELDS}


@dataclass
class Args:
    """The transient study's flags."""

    bundle: Annotated[str, arg("a bundle, or NAME@SEED")] = "generalist"
    episodes: Annotated[int, arg("evaluation seeds 0..N-1 per arm")] = 3
    sweep: Annotated[str, arg("the arm sweep's results")] = "research/results/arm_sweep.json"
    out: Annotated[str, arg("folder for transient.md and .json")] = "research/results"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse(Args, argv, __doc__)
    model = model_of(args.bundle)
    own = tracking_reward_of(model)
    seeds = list(range(args.episodes))
    result: dict[str, Any] = {
        "command": command_line(argv, "python -m research.studies.transient"),
        "bundle": args.bundle,
        "seeds": seeds,
        "settle_s": SETTLE_S,
        "reward": own,
        "registered_reward": {k: getattr(EnvConfig, k) for k in REWARD_FIELDS},
        "arms": {},
    }
    mode = action_mode_of(args.bundle)
    for name, arm in sweep_arms(Path(args.sweep)).items():
        kwargs = in_model_settings(model, arm["env_kwargs"])
        try:
            metrics, traces = evaluate("ppo", kwargs, seeds, model)
        except ValueError:  # outside the bundle's ranges
            continue
        tasks = {
            "own_reward": Formulas(resolve({**arm["env_kwargs"], **own})),
            "registered_reward": Formulas(resolve(arm["env_kwargs"])),
        }
        pd_metrics, _ = evaluate("pd", arm["env_kwargs"], seeds)
        tension_x_pd, rate_x_pd = smoothness_x_pd(metrics, pd_metrics)
        result["arms"][name] = {
            "share": transient_share(traces, tasks),
            "rms_deg": metrics["rms_deg"],
            "settled_rms_deg": metrics["settled_rms_deg"],
            "tension_x_pd": tension_x_pd,
            "tension_rate_x_pd": rate_x_pd,
            "specialist_rms_deg": arm["specialist_rms_deg"].get(mode),
        }
    write(result, Path(args.out))
    return result


def write(result: dict[str, Any], out: Path) -> None:
    save_json(out, "transient", result)
    own, registered = result["reward"], result["registered_reward"]
    ms = round(result["settle_s"] * 1000)
    lines = [
        "# The reset's transient: its share of the RMS and of the reward",
        "",
        f"`{result['command']}`",
        "",
        f"Bundle `{result['bundle']}` on the arm sweep's arms it covers, evaluation seeds "
        f"{result['seeds']}. Share of each "
        f"episode's first {ms} ms in: the squared tracking error (the RMS metric's sum), the "
        f"bundle's own tracking reward ({own['tracking_form']}, sigma {own['tracking_sigma_deg']:g}"
        f" deg) and the registered one ({registered['tracking_form']}, sigma "
        f"{registered['tracking_sigma_deg']:g} deg, the specialists'). RMS in deg, "
        "joint A / B; the specialist's over whole episodes, all the sweep records. The "
        "bundle's RMS tension and RMS tension rate as multiples of PD's on the same episodes.",
        "",
        f"| arm | first {ms} ms: share of squared error | of own reward | of registered reward "
        f"| RMS | after {ms} ms | specialist | tension, tension rate x PD |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, a in result["arms"].items():
        s = a["share"]
        spec = joints(a["specialist_rms_deg"], 4) if a["specialist_rms_deg"] else "-"
        lines.append(
            f"| {name} | {s['squared_error']:.2f} | {s['own_reward']:.3f} | "
            f"{s['registered_reward']:.3f} | {joints(a['rms_deg'], 4)} | "
            f"{joints(a['settled_rms_deg'], 4)} | {spec} | "
            f"{a['tension_x_pd']:.2f}, {a['tension_rate_x_pd']:.2f} |"
        )
    (out / "transient.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()

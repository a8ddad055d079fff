"""The shipped residuals on real cables, motors and sensors: PD, PD tuned per arm, CT and the
ideal-trained and randomized residuals on the ``real_arm`` preset and its seeded perturbations.

    python -m research.studies.realism   # research/results/realism.md and .json

Every figure is evaluated as ``make benchmark`` evaluates its rows, with its reproducibility
(tendon2r_gym.evaluation.evaluator.reproducible_to).

Each arm is one job (``realism_arm``) of an executor (tendon2r_gym.training.executors):
``--workers N`` runs N arms at once in local processes, ``--cluster auto`` (or HOST:PORT) on a
Ray cluster.  An arm's row depends only on the arm, the policies and the episodes, so the
results are the same on every executor.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np

from tendon2r_gym.app.args import arg, parse
from tendon2r_gym.app.report import fmt, unsure
from tendon2r_gym.artifacts.bundle import bundle_meta, bundled_model
from tendon2r_gym.artifacts.model_env import trained_on_drawn_gains
from tendon2r_gym.artifacts.runs import command_line
from tendon2r_gym.evaluation.evaluator import evaluate, jittered_rms, reproducible_to
from tendon2r_gym.evaluation.metrics import smoothness_x_pd, worst_ratio
from tendon2r_gym.evaluation.tuning import tune_pd

#: The arms: the real_arm preset, then REALISM_ARMS arms of
#: perturbed_arms (REALISM_SEED); REALISM_BUNDLE is the residual trained
#: on the ideal arm of the same geometry.
REALISM_BASE, REALISM_ARMS, REALISM_SEED, REALISM_BUNDLE = "real_arm", 16, 0, "pull_only"
#: The residual trained with per-episode random cables and motors (configs/ppo.yaml real_arm).
RANDOMIZED_BUNDLE = "real_arm"
#: Held-out episodes PD is tuned on per arm (tendon2r_gym.evaluation.tuning).
TUNE_EPISODES = 2
#: The policies: (key, label, policy, bundle or None).
REALISM_POLICIES = (
    ("pd", "PD", "pd", None),
    ("ct", "CT", "ct", None),
    ("ppo", "residual (ideal-trained)", "ppo", REALISM_BUNDLE),
    ("randomized", "residual (randomized)", "ppo", RANDOMIZED_BUNDLE),
)


def perturbed_arms(preset: str, n: int, seed: int) -> list[dict[str, Any]]:
    """Returns the env kwargs (experiment-file content) of ``n`` arms: ``preset`` with every
    PERTURBATIONS value drawn from ``np.random.default_rng(seed)`` as a randomized env draws
    them (tendon2r_gym.task.arms.draw_episode_arm with ``mechanism_ranges: real_arm``)."""
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.simulation.realism import PERTURBATIONS
    from tendon2r_gym.task.arms import draw_episode_arm

    randomized = EnvConfig.make(preset, mechanism_ranges="real_arm")
    rng = np.random.default_rng(seed)
    arms = []
    for _ in range(n):
        arm = draw_episode_arm(randomized, rng, randomized.reference)
        drawn = arm.to_dict()
        arms.append(
            {
                "preset": preset,
                "mechanism": {k: v for k, v in drawn["mechanism"].items() if k in PERTURBATIONS},
                "observation_noise": drawn["observation_noise"],
                "observation_delay": drawn["observation_delay"],
            }
        )
    return arms


def realism_arms() -> list[tuple[str, dict[str, Any]]]:
    """Returns the study's arms as (name, env kwargs): the real arm, then its
    seeded perturbations."""
    perturbed = perturbed_arms(REALISM_BASE, REALISM_ARMS, REALISM_SEED)
    return [("real_arm", {"preset": REALISM_BASE})] + [
        (f"perturbed {i}", kw) for i, kw in enumerate(perturbed)
    ]


def realism(episodes: int, executor: Any = None) -> list[dict[str, Any]]:
    """PD, CT (nominal model), the ideal-trained residual and the randomized residual on the
    real arm and its seeded perturbations: one row per arm, RMS per joint and tension rate
    per policy (a policy without its bundle is left out).  ``executor``: runs each arm as one
    job (None: one after another in this process)."""
    from research.studies.realism import realism_arm  # by name, also under python -m

    policies = [p for p in REALISM_POLICIES if p[3] is None or bundle_meta(p[3])]
    jobs = [ArmJob(name, kwargs, policies, list(range(episodes)))
            for name, kwargs in realism_arms()]  # fmt: skip
    if executor is None:
        return [realism_arm(job) for job in jobs]
    return executor.map(realism_arm, jobs, [f"arm {job.name}" for job in jobs])


@dataclass(frozen=True)
class ArmJob:
    """One arm of the study: its name, env kwargs, the policies (REALISM_POLICIES' tuples)
    and the evaluation seeds."""

    name: str
    kwargs: dict[str, Any]
    policies: list[tuple[str, str, str, str | None]]
    seeds: list[int]


def realism_arm(job: ArmJob) -> dict[str, Any]:
    """An executor's job: one arm's row (realism)."""
    name, kwargs, policies, seeds = job.name, job.kwargs, job.policies, job.seeds
    row: dict[str, Any] = {"arm": name, "env_kwargs": kwargs}
    # PD as a user would tune it on this arm (tendon2r-tune-pd, held-out episodes)
    scan = tune_pd(kwargs, TUNE_EPISODES)
    tuned = {**kwargs, "pd_gains": scan.gains.to_dict()}
    for key, _, policy, bundle in policies:
        model = bundled_model(bundle) if bundle else None
        on = on_its_pd(kwargs, tuned, model)
        metrics, _ = evaluate(policy, on, seeds, model)
        row[key] = {k: metrics[k] for k in ("rms_deg", "rms_tension_N", "rms_tension_rate_N_per_s")}
        row[key]["reproducible_to"] = reproducible_to(
            metrics["rms_deg"], jittered_rms(policy, on, seeds, model)
        )
    metrics, _ = evaluate("pd", tuned, seeds)
    row["pd_tuned"] = {
        "rms_deg": metrics["rms_deg"],
        "rms_tension_rate_N_per_s": metrics["rms_tension_rate_N_per_s"],
        "bandwidth_hz": scan.chosen,
        "reproducible_to": reproducible_to(
            metrics["rms_deg"], jittered_rms("pd", tuned, seeds, None)
        ),
    }
    shown = "  ".join(f"{k} {fmt(row[k]['rms_deg'])}" for k in [p[0] for p in policies])
    print(f"realism {name:12s} {shown}  pd_tuned {fmt(metrics['rms_deg'])} deg", flush=True)
    return row


def on_its_pd(kwargs: dict[str, Any], tuned: dict[str, Any], model: Path | None) -> dict[str, Any]:
    """Returns the env kwargs a policy runs on an arm with: the arm's ``kwargs``, or for a
    residual trained on drawn PD gains (learned.trained_on_drawn_gains) ``tuned``, the arm
    with the gains tendon2r-tune-pd finds on it, which its PD then uses."""
    return tuned if model is not None and trained_on_drawn_gains(model) else kwargs


def realism_lines(rows: list[dict[str, Any]]) -> list[str]:
    """Returns realism.md's title and body."""
    learned = [p for p in REALISM_POLICIES if p[3] and all(p[0] in r for r in rows)]
    lines = [
        "## Real tendons, motors and sensors",
        "",
        f"The `{REALISM_BASE}` preset (elastic pull-only cables on motor spools, pulley "
        "friction, motor lag and delay, sensor noise and delay: "
        "tendon2r_gym.simulation.realism) and "
        f"{REALISM_ARMS} arms drawn from tendon2r_gym.simulation.realism.PERTURBATIONS with seed "
        f"{REALISM_SEED}: cables, motors, delays, sensor noise, and the model's errors in "
        "mass (density_scale) and joint damping (extra_joint_damping). PD and CT keep the "
        "nominal (ideal) model: no stretch, lag or friction, the nominal mass and damping. "
        "Residual (ideal-trained): "
        f"the `{REALISM_BUNDLE}` bundle's primary model, trained on the ideal arm; residual "
        f"(randomized): the `{RANDOMIZED_BUNDLE}` bundle's, trained on `{REALISM_BASE}` with "
        "every one of these drawn anew every episode from the same ranges "
        "(`mechanism_ranges: real_arm`); its actor sees each arm's drawn cables, motors and "
        "sensors, which a user knows of their arm (`observe: [arm]`), and only its critic the "
        "model's errors (`hide_from_actor`); in training, on a PD whose bandwidth is drawn "
        "each episode as a tuning would pick it on the drawn arm, which it sees "
        "(`pd_tuned_phase`), and here on the gains `tendon2r-tune-pd` finds on each arm "
        "(PD (tuned)). PD (tuned): PD with the gains `tendon2r-tune-pd` finds on that arm "
        f"({TUNE_EPISODES} held-out episodes; its bandwidth in Hz). RMS error A / B (deg); for "
        "a residual, (its worst joint as a multiple of PD's); *to x / y*: the figure changes "
        "by up to x / y deg in reruns with its policy's commands perturbed in their last "
        "bits (tendon2r_gym.app.report.NOTES); a figure without it keeps its printed digits.",
        "",
        "| arm | PD | PD (tuned) | CT | " + " | ".join(p[1] for p in learned) + " |",
        "|---|---|---|---|" + "---|" * len(learned),
    ]
    worst = lambda r, key, base: worst_ratio(r[key]["rms_deg"], r[base]["rms_deg"])  # noqa: E731
    for r in rows:
        cells = [
            f"{fmt(r[k]['rms_deg'])}{unsure(r[k])} ({worst(r, k, 'pd'):.2f}x)" for k, *_ in learned
        ]
        tuned = r["pd_tuned"]
        lines.append(
            f"| {r['arm']} | {fmt(r['pd']['rms_deg'])}{unsure(r['pd'])} | "
            f"{fmt(tuned['rms_deg'])}{unsure(tuned)} ({tuned['bandwidth_hz']:.3g} Hz) | "
            f"{fmt(r['ct']['rms_deg'])}{unsure(r['ct'])} | " + " | ".join(cells) + " |"
        )
    lines.append("")
    for key, label, *_ in learned:
        for base, name in (("pd", "PD"), ("pd_tuned", "PD tuned per arm")):
            x = [worst(r, key, base) for r in rows]
            lines.append(
                f"- {label}: <= {name} on both joints on {sum(v <= 1.0 for v in x)} of "
                f"{len(rows)} arms; median worst-joint ratio {np.median(x):.2f}."
            )
        effort, rate = zip(*(smoothness_x_pd(r[key], r["pd"]) for r in rows), strict=True)
        lines.append(
            f"- {label}: RMS tension {np.median(effort):.2f}x PD's, RMS tension rate "
            f"{np.median(rate):.2f}x PD's (medians over the arms)."
        )
    return lines


@dataclass
class Args:
    """The realism study's flags."""

    episodes: Annotated[int, arg("evaluation episodes per arm (seeds 0 .. N-1)")] = 3
    out: Annotated[str, arg("folder for realism.md and realism.json")] = "research/results"
    workers: Annotated[int, arg("evaluate this many arms at once in local worker processes")] = 1
    cluster: Annotated[
        str | None, arg("evaluate the arms on a Ray cluster: auto (or RAY_ADDRESS) or HOST:PORT")
    ] = None


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from tendon2r_gym.training.executors import entered, make_executor, without_executor_flags

    args = parse(Args, argv, __doc__)
    executor = make_executor(args.workers, args.cluster, 1)  # --workers, --cluster checked
    # the same results, and the same command recorded, on every executor
    command = command_line(without_executor_flags(sys.argv[1:] if argv is None else argv),
                           "python -m research.studies.realism")  # fmt: skip
    with entered(executor) as ex:
        rows = realism(args.episodes, ex)
    result = {"command": command, "episodes": args.episodes, "rows": rows}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "realism.json").write_text(json.dumps(result, indent=1))
    page = ["# " + realism_lines(result["rows"])[0][3:], "", f"Produced by `{command}`."]
    page += realism_lines(result["rows"])[1:]
    (out / "realism.md").write_text("\n".join(page) + "\n")
    print("wrote", out / "realism.md")
    return result


if __name__ == "__main__":
    main()

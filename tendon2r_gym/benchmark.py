"""The benchmark: PD, computed torque and PPO (from scratch and residual on PD), same seeds.

- :func:`benchmark_bundled` (``tendon2r-benchmark``, ``make benchmark``): the bundled presets
  with their bundled models, plus held-out references for the random-reference model.
- :func:`benchmark_own_arm` (``tendon2r-benchmark --env-config my_arm.yaml``): trains both PPO
  variants on the user's experiment file, then compares all four on it.

Every learned row is evaluated on the benchmark seeds (0, 1, ...), never on the seeds that
chose its checkpoint (configs/ppo.yaml eval_seeds).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tendon2r_gym.bundle import bundle_meta, bundle_names, bundled_model
from tendon2r_gym.env import make as make_env
from tendon2r_gym.evaluation import BASELINE, JITTER, evaluate, names
from tendon2r_gym.learned import (
    MODEL_SETTINGS,
    in_model_settings,
    settings_on,
    trained_on_drawn_gains,
)
from tendon2r_gym.metrics import beats, smoothness_x_pd, worst_ratio
from tendon2r_gym.plots import plot_trace
from tendon2r_gym.presets import DATA_DIR
from tendon2r_gym.runs import model_files, training_record, training_summary
from tendon2r_gym.tuning import tune_pd
from tendon2r_gym.validation import invalid

#: Learned variants: label -> (bundle suffix, hyperparameter entry used to train on your arm).
LEARNED = {
    "ppo scratch": ("_scratch", "default_scratch"),
    "ppo residual": ("", "default"),
}
PRESETS = ("default", "report_002", "pull_only")
#: Figures quoted from the lab reports (their own measurements), shown for comparison only.
REPORT_ROWS = {
    "default": ("report 001 (position actuators on the joints)", [0.92, 1.15], [1.85, 2.34]),
    "report_002": ("report 002 (open-loop tendon commands)", [37.5, 35.8], [60.0, 70.0]),
}
#: Held-out references for the generalization check (inside the training ranges of
#: configs/ppo.yaml random_reference, never drawn exactly).
HELD_OUT = [
    {"amp_deg": [12.0, 18.0], "freq_hz": [1.3, 2.2], "bias_deg": [5.0, -8.0],
     "phase_deg": [30.0, 200.0]},
    {"amp_deg": [22.0, 7.0], "freq_hz": [2.8, 0.9], "bias_deg": [-6.0, 2.0],
     "phase_deg": [90.0, 0.0]},
    {"amp_deg": [8.0, 14.0], "freq_hz": [0.7, 2.6], "bias_deg": [0.0, -12.0],
     "phase_deg": [270.0, 45.0]},
]  # fmt: skip


def _fmt(pair: list[float] | None, digits: int = 4) -> str:
    return "-" if pair is None else " / ".join(f"{v:.{digits}f}" for v in pair)


#: Re-evaluations of every row with its policy's commands perturbed in their last float32 bits
#: (evaluation.Jittered, seeds 1 .. REPRO_RUNS): a row's ``reproducible_to`` is, per joint,
#: the largest change of its RMS error among them.
REPRO_RUNS = 2
#: A figure printed to 4 decimals keeps its digits (to a unit of the last) when it changes
#: by less than this.
PRINTED = 5e-5


def jittered_rms(
    policy: str,
    env_kwargs: dict[str, Any],
    seeds: list[int],
    model: Path | None,
    options: dict[str, Any] | None = None,
) -> list[list[float]]:
    """Returns the RMS error per joint of each of the REPRO_RUNS re-evaluations of a row with
    jittered observations."""
    return [
        evaluate(policy, env_kwargs, seeds, model, options, jitter=k)[0]["rms_deg"]
        for k in range(1, REPRO_RUNS + 1)
    ]


def reproducible_to(rms_deg: list[float], jittered: list[list[float]]) -> list[float]:
    """Returns per joint the largest change of ``rms_deg`` among its jittered
    re-evaluations (0 without any)."""
    if not jittered:
        return [0.0] * len(rms_deg)
    return np.max(np.abs(np.subtract(jittered, rms_deg)), axis=0).tolist()


def _tol(pair: list[float] | None) -> str:
    return "-" if pair is None else " / ".join(f"{v:.2g}" for v in pair)


def compare(
    name: str,
    env_kwargs: dict[str, Any],
    learned: dict[str, list[Path]],
    seeds: list[int],
    plots: Path | None,
    progress: Any = None,
) -> list[dict[str, Any]]:
    """Returns the rows of one env: PD, CT, and per learned label its primary model and the
    mean +- std (ddof 0) over all its training seeds."""
    rows = []
    for policy in names(BASELINE):
        rows.append(_row(name, policy, policy, env_kwargs, seeds, None, plots))
        _tick(progress)
    for label, models in learned.items():
        if not models:
            rows.append({"env": name, "policy": label, "missing": "no trained model"})
            continue
        # A model runs in the settings it was trained in (its action mode, timing...: the
        # same arm, reference and episodes as PD's), and its rows name those that differ.
        tag = settings_on(models[0], env_kwargs)
        kwargs = {**env_kwargs, **tag}
        per_seed = []
        for i, model in enumerate(models):
            row = _row(name, label, "ppo", kwargs, seeds, model, plots if i == 0 else None)
            per_seed.append({**row, **tag})
            _tick(progress)
        rows.append(per_seed[0])
        if len(per_seed) > 1:
            rows.append({**_spread(name, label, per_seed), **tag})
    for row in rows:
        _print(row)
    return rows


#: The generalist bundles (configs/ppo.yaml entries of the same names): trained across random
#: arms, run zero-shot on a user's arm when it lies inside their training ranges.
GENERALISTS = ("generalist", "generalist_scratch", "generalist_pull_only")


#: Fine-tuning a generalist on a user's arm: row label -> configs/ppo.yaml entry (its
#: ``init_from`` names the bundle it starts from).
FINETUNED = {"generalist fine-tuned": "generalist_finetune"}


def not_covered(bundle: str, env_kwargs: dict[str, Any]) -> str | None:
    """Returns why the bundle's primary model cannot run on this arm (outside its training
    ranges, another observation...), or None if it can."""
    from tendon2r_gym.learned import trained_model

    model = bundled_model(bundle)
    kwargs = in_model_settings(model, env_kwargs)
    try:
        trained_model(model, make_env(**kwargs), bundle)
    except ValueError as e:
        return str(e)
    return None


def generalist_rows(name: str, env_kwargs: dict[str, Any], seeds: list[int]) -> list[dict]:
    """Returns a row per shipped generalist bundle on this arm: zero-shot (no training on it),
    or ``missing`` with the reason when the arm is outside its training ranges."""
    rows = []
    for bundle in (b for b in GENERALISTS if b in bundle_names()):
        label, model = f"{bundle} zero-shot", bundled_model(bundle)
        reason = not_covered(bundle, env_kwargs)
        if reason is not None:
            rows.append({"env": name, "policy": label, "missing": reason})
            continue
        tag = settings_on(model, env_kwargs)  # as compare: the settings it trained in
        row = _row(name, label, "ppo", {**env_kwargs, **tag}, seeds, model, None)
        rows.append({**row, **tag})
        _print(rows[-1])
    return rows


def _row(
    name: str,
    label: str,
    policy: str,
    env_kwargs: dict[str, Any],
    seeds: list[int],
    model: Path | None,
    plots: Path | None,
) -> dict[str, Any]:
    start = time.perf_counter()
    metrics, traces = evaluate(policy, env_kwargs, seeds, model)
    jittered = jittered_rms(policy, env_kwargs, seeds, model)
    row = {
        **metrics,
        "reproducible_to": reproducible_to(metrics["rms_deg"], jittered),
        "rms_deg_jittered": jittered,
        "env": name,
        "policy": label,
        "eval_s": round(time.perf_counter() - start, 1),
    }
    if model is not None:
        s = training_summary(model)
        row.update(
            model=shown_path(model),
            train_seed=s["seed"],
            train_steps=s["timesteps"],
            train_wall_s=s["wall_time_s"],
            first_beat_pd=s.get("first_beat_pd"),
        )
    if plots is not None:
        plot_trace(traces[0], plots / name / label.replace(" ", "_"), f"{label} on {name}")
    return row


def shown_path(path: Path) -> str:
    """Returns a model path as recorded in benchmark.json: relative to the package for a
    bundled model (``tendon2r_gym/data/models/...``), else relative to the working folder when
    it is inside it, else absolute; never the machine's absolute path of the package."""
    path = Path(path).resolve()
    for root, prefix in ((DATA_DIR.parent, "tendon2r_gym"), (Path.cwd(), ".")):
        if path.is_relative_to(root):
            return str(Path(prefix) / path.relative_to(root))
    return str(path)


def _spread(name: str, label: str, per_seed: list[dict[str, Any]]) -> dict[str, Any]:
    rms = [r["rms_deg"] for r in per_seed]
    beat = [r["first_beat_pd"] for r in per_seed]
    mean = np.mean(rms, axis=0).tolist()
    jittered = np.mean([r["rms_deg_jittered"] for r in per_seed], axis=0).tolist()
    return {
        "env": name,
        "policy": f"{label} ({len(per_seed)} seeds)",
        "training_seeds": [r["train_seed"] for r in per_seed],
        "rms_deg_per_seed": rms,
        "rms_deg": mean,
        "reproducible_to": reproducible_to(mean, jittered),
        "rms_deg_std": np.std(rms, axis=0).tolist(),
        "max_deg": np.mean([r["max_deg"] for r in per_seed], axis=0).tolist(),
        "train_steps": int(np.mean([r["train_steps"] for r in per_seed])),
        "train_wall_s": round(float(np.mean([r["train_wall_s"] for r in per_seed])), 1),
        "train_wall_s_max": max(r["train_wall_s"] for r in per_seed),
        "first_beat_pd": beat,
    }


def _print(row: dict[str, Any]) -> None:
    if "missing" in row:
        print(f"{row['env']:11s} {row['policy']:24s} {row['missing']}", flush=True)
        return
    std = f" +- {_fmt(row['rms_deg_std'])}" if "rms_deg_std" in row else ""
    print(
        f"{row['env']:11s} {row['policy']:24s} RMS {_fmt(row['rms_deg'])}{std} deg  "
        f"max {_fmt(row['max_deg'], 3)} deg  reproducible to {_tol(row.get('reproducible_to'))}",
        flush=True,
    )


def _tick(progress: Any) -> None:
    if progress is not None:
        progress.update(1)


def verdicts(rows: list[dict[str, Any]]) -> list[str]:
    """Returns, per env and learned row, whether its RMS is <= PD's on both joints, and its
    worst-joint ratio to every other baseline of the registry."""
    lines = []
    baselines = names(BASELINE)
    for name in dict.fromkeys(r["env"] for r in rows):
        by = {r["policy"]: r for r in rows if r["env"] == name and "rms_deg" in r}
        if "pd" not in by:
            continue
        for label, r in by.items():
            if label in baselines:
                continue
            pd = by["pd"]["rms_deg"]
            wins = beats(r["rms_deg"], pd)
            ratios = "".join(
                f"; {max(p / c for p, c in zip(r['rms_deg'], by[b]['rms_deg'], strict=True)):.1f}x"
                f" {b.upper()}"
                for b in baselines
                if b != "pd" and b in by
            )
            smooth = ""
            if "rms_tension_N" in r and "rms_tension_N" in by["pd"]:
                tension, rate = smoothness_x_pd(r, by["pd"])
                smooth = f"; tension {tension:.1f}x PD's, tension rate {rate:.1f}x PD's"
            lines.append(
                f"- {name}, {shown_policy(r)}: RMS {_fmt(r['rms_deg'])} vs PD {_fmt(pd)}"
                f" deg: {'<= PD on both joints' if wins else 'WORSE than PD on at least one joint'}"
                f"{ratios}{smooth}; trained {r['train_steps']} steps in {r['train_wall_s']} s"
                + (f" (slowest seed {r['train_wall_s_max']} s)" if "train_wall_s_max" in r else "")
            )
    return lines


def shown_policy(row: dict[str, Any]) -> str:
    """Returns a row's policy label, with the model settings (learned.MODEL_SETTINGS) it ran
    in where they differ from the env's: "residual (joint-torque mode)"."""
    shown = [
        f"{row[k].replace('_', '-')} mode" if k == "action_mode" else f"{k} {row[k]}"
        for k in MODEL_SETTINGS
        if k in row
    ]
    return row["policy"] + (f" ({', '.join(shown)})" if shown else "")


def _beat(value: Any) -> str:
    if isinstance(value, list):
        return ", ".join(_beat(v) for v in value)
    return "never" if value is None else f"{value['timesteps']} / {value['wall_time_s']} s"


def table(rows: list[dict[str, Any]], quoted: dict[str, tuple] | None = None) -> list[str]:
    """Returns the markdown table of benchmark rows."""
    lines = [
        "| env | policy | RMS error A / B (deg) | reproducible to (deg) | max error (deg) | RMS "
        "tension (N) | peak tension (N) | RMS tension rate (N/s) | steps pushing | saturated | "
        "train steps | train wall (s) | first beat PD (steps / wall) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in dict.fromkeys(r["env"] for r in rows):
        for r in (r for r in rows if r["env"] == name):
            if "missing" in r:
                lines.append(f"| {name} | {r['policy']} | {r['missing']} |" + " |" * 10)
                continue
            std = f" ± {_fmt(r['rms_deg_std'])}" if "rms_deg_std" in r else ""
            learned = "train_steps" in r
            lines.append(
                f"| {name} | {shown_policy(r)} | {_fmt(r['rms_deg'])}{std} | "
                f"{_tol(r.get('reproducible_to'))} | {_fmt(r['max_deg'], 3)} "
                f"| {_fmt(r.get('rms_tension_N'))} | {_fmt(r.get('max_tension_N'))} | "
                f"{_fmt(r.get('rms_tension_rate_N_per_s'), 2)} | "
                f"{r.get('negative_tension_steps', '')} | {_fmt(r.get('saturated_fraction'), 3)} | "
                f"{r.get('train_steps', '')} | {r.get('train_wall_s', '')} | "
                f"{_beat(r.get('first_beat_pd')) if learned else ''} |"
            )
        if quoted and name in quoted:
            label, rms, mx = quoted[name]
            lines.append(
                f"| {name} | *quoted: {label}* | {_fmt(rms, 2)} | | {_fmt(mx, 2)} |" + " |" * 8
            )
    return lines


NOTES = [
    "Per joint (A / B): RMS and max tracking error over all steps of all episodes (the same",
    "seeds for every policy). Per tendon: RMS and peak tension (N, positive pulling), and the",
    "RMS rate of change of each tension (N/s: smoothness, what a motor must follow), the",
    "steps where some tendon pushed (negative tension); then the fraction of saturated steps.",
    "`ppo scratch` is plain PPO driving the motors (residual_scale 0); `ppo residual` adds",
    "its action to the PD command. The row without a seed count is the primary training",
    "seed (fixed before training); `(N seeds)` is the mean ± std (ddof 0) over training",
    "seeds, each evaluated on the benchmark seeds, not on the seeds that chose its",
    "checkpoint. Train wall time: one run on 2 CPU cores. First beat PD: the first",
    "evaluation during training (on the eval seeds) whose RMS was <= PD's on both joints.",
    "Reproducible to: per joint, the largest change of the row's RMS error among "
    f"{REPRO_RUNS} reruns in",
    f"which every command of its policy is scaled by 1 +- 2^{math.log2(JITTER):.0f} (float32's "
    "rounding: what",
    "another CPU's float32 kernels changed in a network's action); below "
    f"{PRINTED:g} deg the figures",
    "keep their printed digits, above it the closed loop amplifies the last bits of its",
    "arithmetic. A learned policy's network runs in float64 in a fixed order of operations",
    "(tendon2r_gym.inference): the same bits whatever the CPU and torch's threads.",
]


def _bundle_models(name: str) -> list[Path]:
    meta = bundle_meta(name)
    return [] if meta is None else [bundled_model(name, s) for s in meta["seeds"]]


def benchmark_bundled(episodes: int, out: Path, command: str) -> dict[str, Any]:
    """The bundled presets with their bundled models -> out/benchmark.md, .json, plots/."""
    out.mkdir(parents=True, exist_ok=True)
    seeds = list(range(episodes))
    rows = []
    for preset in PRESETS:
        learned = {label: _bundle_models(preset + suffix) for label, (suffix, _) in LEARNED.items()}
        rows += compare(preset, {"preset": preset}, learned, seeds, out / "plots")
    held = held_out()
    real = realism(episodes)
    result = {"command": command, "rows": rows, "held_out": held, "realism": real}
    tension = tension_comparison(rows)
    bundles = [
        f"- {n}: seeds {m['seeds']}, trained by `{m['train_command']}`, bundled by `{m['command']}`"
        for n in sorted(
            {p + s for p in PRESETS for s, _ in LEARNED.values()} | {"random_reference"}
        )
        if (m := bundle_meta(n)) is not None
    ]
    lines = [
        "# Benchmark: PD vs computed torque vs PPO on Tendon2R-v0",
        "",
        f"Produced by `{command}`; every figure comes from that run except the rows marked",
        "*quoted*, which are the lab reports' own figures.",
        "",
        *NOTES,
        "",
        *table(rows, REPORT_ROWS),
        "",
        "Learned rows against PD (RMS <= PD on both joints?) and against computed torque:",
        "",
        *verdicts(rows),
        "",
        "## Pull-only tendons (preset `pull_only`, routing n_plus_1) against push-pull `default`",
        "",
        *tension,
        "",
        "Bundled models and the commands that made them (tendon2r_gym/data/models/):",
        "",
        *bundles,
        "",
        "## Held-out references (generalization)",
        "",
        "PPO residual trained on random references (configs/ppo.yaml `random_reference`) and",
        "PD, on fixed references the model never trained on (tendon2r_gym.benchmark.HELD_OUT):",
        "",
        "| policy | mean RMS error A / B (deg) | reproducible to (deg) |",
        "|---|---|---|",
        *(
            f"| {r['policy']} | {r.get('missing') or _fmt(r['rms_deg_mean'])} | "
            f"{_tol(r.get('reproducible_to'))} |"
            for r in held
        ),
        "",
        *realism_lines(real),
    ]
    return _write(out, result, lines)


def _write(out: Path, result: dict[str, Any], lines: list[str]) -> dict[str, Any]:
    """Writes out/benchmark.json and out/benchmark.md; returns the result."""
    (out / "benchmark.json").write_text(json.dumps(result, indent=1))
    (out / "benchmark.md").write_text("\n".join(lines) + "\n")
    print("wrote", out / "benchmark.md")
    return result


def tension_comparison(rows: list[dict[str, Any]]) -> list[str]:
    """Returns lines comparing the pull-only preset's tensions and steps with a pushing tendon
    with the push-pull default's, per policy, and the pull-only targets."""
    by = {(r["env"], r["policy"]): r for r in rows if "rms_deg" in r and "rms_tension_N" in r}
    lines = []
    for (env, policy), r in by.items():
        if env != "pull_only" or (base := by.get(("default", policy))) is None:
            continue
        lines.append(
            f"- {policy}: RMS tension {_fmt(r['rms_tension_N'], 3)} N (peak "
            f"{max(r['max_tension_N']):.3f} N, least {min(r['min_tension_N']):.3f} N, "
            f"{r['negative_tension_steps']} steps with a pushing tendon) against push-pull "
            f"{_fmt(base['rms_tension_N'], 3)} N (peak {max(base['max_tension_N']):.3f} N, "
            f"{base['negative_tension_steps']} of {base['steps']} steps pushing)."
        )
    limits = {"pd": 0.3, "ct": 0.02}
    for policy, limit in limits.items():
        if (r := by.get(("pull_only", policy))) is not None:
            ok = max(r["rms_deg"]) <= limit and r["negative_tension_steps"] == 0
            lines.append(
                f"- Target {policy.upper()} <= {limit} deg RMS per joint with no pushing "
                f"tendon: **{'met' if ok else 'MISSED'}** ({_fmt(r['rms_deg'])} deg)."
            )
    return lines


#: The realism section: the real_arm preset, then REALISM_ARMS arms of
#: perturbed_arms (REALISM_SEED); REALISM_BUNDLE is the residual trained
#: on the ideal arm of the same geometry.
REALISM_BASE, REALISM_ARMS, REALISM_SEED, REALISM_BUNDLE = "real_arm", 16, 0, "pull_only"
#: The residual trained with per-episode random cables and motors (configs/ppo.yaml real_arm).
RANDOMIZED_BUNDLE = "real_arm"
#: Held-out episodes PD is tuned on per arm (tendon2r_gym.tuning) in the realism section.
TUNE_EPISODES = 2
#: The realism section's policies: (key, label, policy, bundle or None).
REALISM_POLICIES = (
    ("pd", "PD", "pd", None),
    ("ct", "CT", "ct", None),
    ("ppo", "residual (ideal-trained)", "ppo", REALISM_BUNDLE),
    ("randomized", "residual (randomized)", "ppo", RANDOMIZED_BUNDLE),
)


def perturbed_arms(preset: str, n: int, seed: int) -> list[dict[str, Any]]:
    """Returns the env kwargs (experiment-file content) of ``n`` arms: ``preset`` with every
    PERTURBATIONS value drawn from ``np.random.default_rng(seed)`` as a randomized env draws
    them (EnvConfig.draw_arm with ``mechanism_ranges: real_arm``)."""
    from tendon2r_gym.env_config import EnvConfig
    from tendon2r_gym.realism import PERTURBATIONS

    randomized = EnvConfig.make(preset, mechanism_ranges="real_arm")
    rng = np.random.default_rng(seed)
    arms = []
    for _ in range(n):
        arm = randomized.draw_arm(rng, randomized.reference)
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
    """Returns the realism section's arms as (name, env kwargs): the real arm, then its
    seeded perturbations."""
    perturbed = perturbed_arms(REALISM_BASE, REALISM_ARMS, REALISM_SEED)
    return [("real_arm", {"preset": REALISM_BASE})] + [
        (f"perturbed {i}", kw) for i, kw in enumerate(perturbed)
    ]


def realism(episodes: int) -> list[dict[str, Any]]:
    """PD, CT (nominal model), the ideal-trained residual and the randomized residual on the
    real arm and its seeded perturbations: one row per arm, RMS per joint and tension rate
    per policy (a policy without its bundle is left out)."""
    arms = realism_arms()
    policies = [p for p in REALISM_POLICIES if p[3] is None or bundle_meta(p[3])]
    seeds = list(range(episodes))
    rows = []
    for name, kwargs in arms:
        row: dict[str, Any] = {"arm": name, "env_kwargs": kwargs}
        # PD as a user would tune it on this arm (tendon2r-tune-pd, held-out episodes)
        scan = tune_pd(kwargs, TUNE_EPISODES)
        tuned = {**kwargs, "pd_gains": scan.gains.to_dict()}
        for key, _, policy, bundle in policies:
            model = bundled_model(bundle) if bundle else None
            on = on_its_pd(kwargs, tuned, model)
            metrics, _ = evaluate(policy, on, seeds, model)
            row[key] = {
                k: metrics[k] for k in ("rms_deg", "rms_tension_N", "rms_tension_rate_N_per_s")
            }
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
        rows.append(row)
        shown = "  ".join(f"{k} {_fmt(row[k]['rms_deg'])}" for k in [p[0] for p in policies])
        print(f"realism {name:12s} {shown}  pd_tuned {_fmt(metrics['rms_deg'])} deg", flush=True)
    return rows


def on_its_pd(kwargs: dict[str, Any], tuned: dict[str, Any], model: Path | None) -> dict[str, Any]:
    """Returns the env kwargs a policy runs on an arm with: the arm's ``kwargs``, or for a
    residual trained on drawn PD gains (learned.trained_on_drawn_gains) ``tuned``, the arm
    with the gains tendon2r-tune-pd finds on it, which its PD then uses."""
    return tuned if model is not None and trained_on_drawn_gains(model) else kwargs


def realism_lines(rows: list[dict[str, Any]]) -> list[str]:
    """Returns the realism section of benchmark.md."""
    learned = [p for p in REALISM_POLICIES if p[3] and all(p[0] in r for r in rows)]
    lines = [
        "## Real tendons, motors and sensors",
        "",
        f"The `{REALISM_BASE}` preset (elastic pull-only cables on motor spools, pulley "
        "friction, motor lag and delay, sensor noise and delay: tendon2r_gym.realism) and "
        f"{REALISM_ARMS} arms drawn from tendon2r_gym.realism.PERTURBATIONS with seed "
        f"{REALISM_SEED}: cables, motors, delays, sensor noise, and the model's errors in "
        "mass (density_scale) and joint damping (extra_joint_damping). PD and CT keep the "
        "nominal (ideal) model: no stretch, lag or friction, the nominal mass and damping. "
        "Residual (ideal-trained): "
        f"the `{REALISM_BUNDLE}` bundle's primary model, trained on the ideal arm; residual "
        f"(randomized): the `{RANDOMIZED_BUNDLE}` bundle's, trained on `{REALISM_BASE}` with "
        "every one of these drawn anew every episode from the same ranges "
        "(`mechanism_ranges: real_arm`); its actor sees each arm's drawn cables, motors and "
        "sensors, which a user knows of their arm (`observe_arm`), and only its critic the "
        "model's errors (`hide_from_actor`); in training, on a PD whose bandwidth is drawn "
        "each episode as a tuning would pick it on the drawn arm, which it sees "
        "(`pd_tuned_phase`), and here on the gains `tendon2r-tune-pd` finds on each arm "
        "(PD (tuned)). PD (tuned): PD with the gains `tendon2r-tune-pd` finds on that arm "
        f"({TUNE_EPISODES} held-out episodes; its bandwidth in Hz). RMS error A / B (deg); for "
        "a residual, (its worst joint as a multiple of PD's); *to x / y*: the figure changes "
        "by up to x / y deg in reruns with its policy's commands perturbed in their last "
        "bits (reproducible to, above); a figure without it keeps its printed digits.",
        "",
        "| arm | PD | PD (tuned) | CT | " + " | ".join(p[1] for p in learned) + " |",
        "|---|---|---|---|" + "---|" * len(learned),
    ]
    worst = lambda r, key, base: worst_ratio(r[key]["rms_deg"], r[base]["rms_deg"])  # noqa: E731
    for r in rows:
        cells = [
            f"{_fmt(r[k]['rms_deg'])}{_unsure(r[k])} ({worst(r, k, 'pd'):.2f}x)"
            for k, *_ in learned
        ]
        tuned = r["pd_tuned"]
        lines.append(
            f"| {r['arm']} | {_fmt(r['pd']['rms_deg'])}{_unsure(r['pd'])} | "
            f"{_fmt(tuned['rms_deg'])}{_unsure(tuned)} ({tuned['bandwidth_hz']:.3g} Hz) | "
            f"{_fmt(r['ct']['rms_deg'])}{_unsure(r['ct'])} | " + " | ".join(cells) + " |"
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


def _unsure(cell: dict[str, Any]) -> str:
    """Returns " *to x / y*" for a figure whose reruns change its printed digits, else ""."""
    tol = cell.get("reproducible_to")
    return f" *to {_tol(tol)}*" if tol is not None and max(tol) >= PRINTED else ""


def held_out() -> list[dict[str, Any]]:
    """PD and the random-reference PPO on HELD_OUT, with the env the model trained on."""
    meta = bundle_meta("random_reference")
    if meta is None:
        return [{"policy": "ppo", "missing": "no bundled random_reference model"}]
    model = bundled_model("random_reference")
    env_kwargs = training_record(model)["env_kwargs"]
    rows = []
    for policy in ("pd", "ppo"):  # PD is the baseline that needs no knowledge of the reference
        learned = model if policy == "ppo" else None
        errs, jittered = [], []
        for i, ref in enumerate(HELD_OUT):
            options = {"reference": ref}
            errs.append(evaluate(policy, env_kwargs, [i], learned, options)[0]["rms_deg"])
            jittered.append(jittered_rms(policy, env_kwargs, [i], learned, options))
        mean = np.mean(errs, axis=0).tolist()
        rows.append(
            {"policy": policy, "rms_deg_per_reference": errs, "rms_deg_mean": mean,
             "reproducible_to": reproducible_to(mean, np.mean(jittered, axis=0).tolist())}
        )  # fmt: skip
        print(f"held-out {policy:4s} mean RMS {_fmt(rows[-1]['rms_deg_mean'])} deg", flush=True)
    return rows


def benchmark_own_arm(
    env_config: str,
    train_steps: int | None,
    seeds: list[int],
    episodes: int,
    out: Path,
    run_dir: Path,
    command: str,
    labels: Sequence[str] | None = None,
) -> dict[str, Any]:
    """Trains both PPO variants on ``env_config`` (one run per seed), then compares PD, CT and
    them on the same evaluation seeds -> out/benchmark.md, .json, plots/.  ``labels``: train
    only these learned rows (of LEARNED and FINETUNED; None: every one)."""
    from tqdm.auto import tqdm

    from tendon2r_gym.env_config import EnvConfig
    from tendon2r_gym.training import Experiment, Hyperparams

    env_kwargs = {"preset": env_config}
    config = EnvConfig.make(env_config)  # every error before any training
    entries = {label: entry for label, (_, entry) in LEARNED.items()} | FINETUNED
    if labels is not None:
        if unknown := set(labels) - set(entries):
            raise invalid("labels", sorted(unknown), f"some of {list(entries)}")
        entries = {k: v for k, v in entries.items() if k in labels}
    cfgs = {k: Hyperparams.from_entry(e, env_config=env_config) for k, e in entries.items()}
    uncovered = {}
    for label in [k for k in FINETUNED if k in cfgs]:  # only where the generalist covers the arm
        source = cfgs[label].init_from
        if source not in bundle_names():
            uncovered[label] = f"bundle {source} is not installed"
        elif (reason := not_covered(source, env_kwargs)) is not None:
            uncovered[label] = reason
        if label in uncovered:
            del cfgs[label]
    if train_steps is not None:
        cfgs = {k: hp.replace(total_timesteps=train_steps) for k, hp in cfgs.items()}
    out.mkdir(parents=True, exist_ok=True)
    learned: dict[str, list[Path]] = {}
    with tqdm(total=len(cfgs) * len(seeds) * 2 + 2, desc="benchmark", unit="task") as bar:
        for label, hp in cfgs.items():
            folder = run_dir / label.replace(" ", "_")
            exp = Experiment.start_or_continue(hp, folder, seeds, command)
            bar.set_postfix_str(f"training {label}")
            exp.train(resume=True)
            learned[label] = [model_files(exp.run_folder(s).best)[0] for s in seeds]
            bar.update(len(seeds))
        bar.set_postfix_str("evaluating")
        name = Path(env_config).stem
        rows = compare(name, env_kwargs, learned, list(range(episodes)), out / "plots", bar)
        rows += generalist_rows(name, env_kwargs, list(range(episodes)))
        rows += [{"env": name, "policy": k, "missing": v} for k, v in uncovered.items()]
    result = {
        "command": command,
        "env_config": config.to_dict(),
        "force_need_N": config.force_need,
        "rows": rows,
    }
    lines = [
        f"# Benchmark on {env_config}",
        "",
        f"Produced by `{command}`.",
        f"Force limit {config.mechanism.max_tendon_force} N; inverse dynamics of the reference "
        f"needs {config.force_need:.3g} N.",
        "",
        *NOTES,
        "",
        *table(rows),
        "",
        *verdicts(rows),
    ]
    return _write(out, result, lines)

"""Hyperparameter sensitivity: does plain PPO still beat PD with settings nobody tuned for us?

    python -m research.studies.sensitivity     # research/results/sensitivity.md and .json
    python -m research.studies.sensitivity --steps 2048 --variants defaults --out runs/x   # smoke

Each variant is the shipped plain-PPO entry (configs/ppo.yaml ``default_scratch``) with one
knob changed, trained on the ``default`` preset with one seed and the entry's budget.  A
variant passes if its best model is <= PD on both joints (on the eval seeds); each row also
gives its smoothness on those seeds started on the reference, where training judged it
(evaluations.json), and whether it kept plain PPO's smoothness limits there.
"""

from __future__ import annotations

import multiprocessing
import tempfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

from research.studies import joints, one_or_more, save_json
from tendon2r_gym.app.args import arg, parse

ENTRY = "default_scratch"


def _policy(**kw: Any) -> Any:
    return lambda h: {"policy_kwargs": {**h.policy_kwargs, **kw}}


def _ppo(**kw: Any) -> Any:
    return lambda h: {"ppo": {**h.ppo, **kw}}


def _scaled_int(key: str, factor: float) -> Any:
    return lambda h: {"ppo": {**h.ppo, key: int(h.ppo[key] * factor)}}


def _scaled_rate(factor: float) -> Any:
    from tendon2r_gym.training.hyperparams import scaled_schedule

    return lambda h: {
        "ppo": {**h.ppo, "learning_rate": scaled_schedule(h.ppo["learning_rate"], factor)}
    }


def _normalize(**kw: Any) -> Any:
    return lambda h: {"normalize": {**h.normalize, **kw}}


#: Variant -> (what changes, function of the entry -> changed fields).
VARIANTS: dict[str, tuple[str, Any]] = {
    "defaults": ("the shipped entry", lambda h: {}),
    "log_std_-1.5": ("log_std_init -1.5", _policy(log_std_init=-1.5)),
    "log_std_-0.5": ("log_std_init -0.5", _policy(log_std_init=-0.5)),
    "log_std_0": ("log_std_init 0", _policy(log_std_init=0.0)),
    "norm_reward_on": ("reward normalization on", _normalize(norm_reward=True)),
    "norm_reward_off": ("reward normalization off", _normalize(norm_reward=False)),
    "8x512": ("8 envs x 512 steps", lambda h: {"n_envs": 8, "ppo": {**h.ppo, "n_steps": 512}}),
    "64x64": ("64 envs x 64 steps", lambda h: {"n_envs": 64, "ppo": {**h.ppo, "n_steps": 64}}),
    "batch_x0.25": ("batch size x 0.25", _scaled_int("batch_size", 0.25)),
    "batch_x4": ("batch size x 4", _scaled_int("batch_size", 4)),
    "epochs_5": ("n_epochs 5", _ppo(n_epochs=5)),
    "epochs_20": ("n_epochs 20", _ppo(n_epochs=20)),
    "lr_x0.3": ("learning rate x 0.3", _scaled_rate(0.3)),
    "lr_x3": ("learning rate x 3", _scaled_rate(3.0)),
    "gamma_0.95": ("gamma 0.95", _ppo(gamma=0.95)),
    "gamma_0.99": ("gamma 0.99", _ppo(gamma=0.99)),
    "net_64": ("network 64 x 64", _policy(net_arch=[64, 64])),
    "net_256": ("network 256 x 256", _policy(net_arch=[256, 256])),
}
Variant = Literal[tuple(VARIANTS)]  # type: ignore[valid-type]


def variant(name: str, steps: int | None) -> Any:
    """Returns the hyperparameters of a variant; None if it equals the shipped entry (a knob
    already at that value)."""
    from tendon2r_gym.training import Hyperparams

    base = Hyperparams.from_entry(ENTRY)
    hp = base.replace(**VARIANTS[name][1](base))
    if name != "defaults" and hp == base:
        return None
    if steps is not None:
        hp = hp.replace(total_timesteps=steps, eval_freq=max(steps // 10, hp.rollout_steps))
    return hp


def _run(name: str, steps: int | None, root: str) -> dict[str, Any]:
    """Trains a variant in ``root/<name>`` (continuing or reusing a run found there)."""
    from tendon2r_gym.artifacts.runs import SUMMARY
    from tendon2r_gym.training import Experiment

    exp = Experiment(variant(name, steps), Path(root) / name, [0], f"sensitivity {name}")
    exp.train(resume=True)
    run = exp.run_folder(0)
    summary = run.read_json(SUMMARY)
    row = run.best_evaluation() or {}
    smooth = {k: row.get(k) for k in ("tension_x_pd", "tension_rate_x_pd", "within_limits")}
    return {
        "variant": name,
        **{k: v for k, v in summary.items() if k != "segments"},
        "best_on_reference": smooth,
    }


@dataclass
class Args:
    """The sensitivity study's flags."""

    steps: Annotated[int | None, arg("default: the entry's budget")] = None
    variants: Annotated[list[Variant], arg("the hyperparameter changes to train")] = field(
        default_factory=lambda: list(VARIANTS)
    )
    jobs: Annotated[int, arg("runs in parallel (one per core)")] = 2
    out: Annotated[str, arg("folder for sensitivity.md and .json")] = "research/results"
    run_dir: Annotated[
        str | None,
        arg("keep the runs here (default: a temp dir); a rerun continues or reuses them"),
    ] = None


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from tendon2r_gym.artifacts.runs import command_line

    args = parse(Args, argv, __doc__)
    one_or_more("--variants", args.variants, f"one or more of {list(VARIANTS)}")
    command = command_line(argv, "python -m research.studies.sensitivity")
    names = [n for n in args.variants if variant(n, args.steps) is not None]
    skipped = [n for n in args.variants if n not in names]
    with tempfile.TemporaryDirectory() as tmp:
        root = args.run_dir or tmp
        with ProcessPoolExecutor(
            args.jobs, mp_context=multiprocessing.get_context("spawn")
        ) as pool:
            runs = list(pool.map(_run, names, [args.steps] * len(names), [root] * len(names)))
    result = {
        "command": command,
        "entry": ENTRY,
        "runs": runs,
        "same_as_shipped": skipped,
        "pd_tension_rate_N_per_s": pd_tension_rate(),
    }
    write(result, Path(args.out))
    return result


def pd_tension_rate() -> list[float]:
    """Returns PD's RMS tension rate (N/s, per tendon) on the episodes the variants' best
    models were chosen and measured on: the entry's env and evaluation seeds."""
    from tendon2r_gym.evaluation.evaluator import evaluate
    from tendon2r_gym.training import Hyperparams

    hp = Hyperparams.from_entry(ENTRY)
    return evaluate("pd", hp.env_kwargs, list(hp.eval_seeds))[0]["rms_tension_rate_N_per_s"]


def write(result: dict[str, Any], out: Path) -> None:
    """Writes sensitivity.json and sensitivity.md."""
    from tendon2r_gym.evaluation.metrics import (
        RATE_LIMIT_X_PD,
        TENSION_LIMIT_X_PD,
        beats,
        rms_ratio,
    )

    save_json(out, "sensitivity", result)
    fmt = joints
    rows = []
    passed = smooth = 0
    variants = [r for r in result["runs"] if r["variant"] != "defaults"]
    pd_rate = result["pd_tension_rate_N_per_s"]
    for r in result["runs"]:
        ok = beats(r["best_rms_deg"], r["pd_eval_rms_deg"])
        on_ref = r.get("best_on_reference") or {}
        kept = on_ref.get("within_limits")
        passed += ok and r["variant"] != "defaults"
        smooth += bool(ok and kept) and r["variant"] != "defaults"
        rate = r["best_tension_rate_N_per_s"]
        on_ref_cell = (
            "-"
            if kept is None
            else f"{on_ref['tension_x_pd']:.1f}x / {on_ref['tension_rate_x_pd']:.1f}x "
            f"({'within' if kept else '**over**'})"
        )
        rows.append(
            f"| {r['variant']} | {VARIANTS[r['variant']][0]} | {fmt(r['best_rms_deg'])} | "
            f"{fmt(r['pd_eval_rms_deg'])} | {'yes' if ok else '**no**'} | "
            f"{fmt(rate, 2)} ({rms_ratio(rate, pd_rate):.1f}x) | {on_ref_cell} | "
            f"{r['timesteps']} | {r['wall_time_s']:.0f} |"
        )
    lines = [
        "# Hyperparameter sensitivity of plain PPO",
        "",
        f"Produced by `{result['command']}`: the `{result['entry']}` entry with one knob "
        "changed per row, the `default` preset, seed 0; best RMS on the eval seeds (started "
        "off the reference by the entry's reset noise), and the best model's RMS tension "
        "rate there (N/s per tendon; x PD's on the same episodes, "
        f"{fmt(pd_rate, 2)} N/s). On the reference: the best model's RMS tension and "
        "tension rate as multiples of PD's on the same seeds started on the reference, where "
        f"training judges smoothness (plain PPO's limits: {TENSION_LIMIT_X_PD:g}x and "
        f"{RATE_LIMIT_X_PD['plain']:g}x).",
        "",
        "| variant | change | best RMS A / B (deg) | PD (deg) | beats PD | tension rate (N/s) | "
        "on the reference: tension / rate x PD | steps | wall (s) |",
        "|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
        f"Variants that beat PD on both joints: **{passed} of {len(variants)}** "
        f"({100 * passed / max(len(variants), 1):.0f}%; target >= 80%); within the "
        f"smoothness limits too: {smooth} of {len(variants)}.",
    ]
    if result["same_as_shipped"]:
        lines.append(
            f"Not run, equal to the shipped entry: {', '.join(result['same_as_shipped'])}."
        )
    (out / "sensitivity.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines), flush=True)


if __name__ == "__main__":
    main()

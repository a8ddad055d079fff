"""Learnability study: which env defaults make plain PPO (no PD inside) learn from scratch.

    python -m research.studies.learnability    # research/results/learnability.md and .json
    python -m research.studies.learnability --steps 2048 --seeds 0 --rows defaults --out x  # smoke

Each row is the ``default_scratch`` entry of configs/ppo.yaml (which uses the registered env's
defaults) with one change: the landed value of one choice.  Every row trains one run per seed
with the same step budget, and reports the best tracking RMS on the eval seeds and the first
evaluation that beat PD.  The table therefore shows what each choice costs.
"""

from __future__ import annotations

import json
import multiprocessing
import shlex
import tempfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

if TYPE_CHECKING:
    from tendon2r_gym.training import Hyperparams

import numpy as np

from research.studies import joints, one_or_more, save_json
from tendon2r_gym.app.args import arg, parse

#: Row name -> (what changes, env kwargs, hyperparameter changes).  Rows start from
#: ``default_scratch`` unless their hyperparameter changes name another ``entry``.
ROWS: dict[str, tuple[str, dict[str, Any], dict[str, Any]]] = {
    "defaults": ("the new defaults (registered env, default_scratch)", {}, {}),
    "landed_reward": (
        "landed reward: quadratic in deg^2, scales 1 / 0.01 / 1000, VecNormalize rewards",
        {
            "tracking_form": "quadratic",
            "reward_scales": {"tracking": 1.0, "ctrl": 0.01, "divergence": 1000.0},
        },
        {"normalize": {"norm_reward": True}},
    ),
    "landed_exploration": ("landed exploration: log_std_init -1.5", {}, {"log_std_init": -1.5}),
    "landed_reset": ("landed reset noise 0.001 (training starts on the reference)",
                     {"reset_noise_scale": 0.001}, {}),
    "ctrl_dt_2ms": ("control period 2 ms (the prototype's)", {"ctrl_dt": 0.002}, {}),
    "gamma_0.99": ("gamma 0.99", {}, {"gamma": 0.99}),
    "net_256": ("network 256 x 256", {}, {"net_arch": [256, 256]}),
    "multiscale_plain": ("plain PPO, the multiscale reward", {"tracking_form": "multiscale"},
                         {}),
    "multiscale_residual": ("residual PPO (entry `default`), the multiscale reward, "
                            "normalized", {"tracking_form": "multiscale", "reward_scales": {}},
                            {"entry": "default"}),
    "multiscale_residual_raw": ("residual PPO (entry `default`), the multiscale reward, "
                                "not normalized",
                                {"tracking_form": "multiscale", "reward_scales": {}},
                                {"entry": "default", "normalize": {"norm_reward": False}}),
    "residual_quadratic": ("residual PPO (entry `default`): quadratic reward, normalized", {},
                           {"entry": "default"}),
    "residual_log": ("residual PPO with the bounded log reward of the env's defaults",
                     {"tracking_form": "log", "reward_scales": {}}, {"entry": "default"}),
    "plain_sigma_0.1": ("plain PPO, log reward with sigma 0.1 deg",
                        {"tracking_sigma_deg": 0.1}, {}),
    "plain_sigma_0.01": ("plain PPO, log reward with sigma 0.01 deg",
                         {"tracking_sigma_deg": 0.01}, {}),
    "residual_sigma_0.1": ("residual PPO (entry `default`), the registered reward with sigma "
                           "0.1 deg", {"tracking_form": "log", "reward_scales": {},
                                       "tracking_sigma_deg": 0.1}, {"entry": "default"}),
    "residual_sigma_0.01": ("residual PPO (entry `default`), the registered reward with sigma "
                            "0.01 deg", {"tracking_form": "log", "reward_scales": {},
                                         "tracking_sigma_deg": 0.01}, {"entry": "default"}),
    "plain_no_rate": ("plain PPO without the action-rate term",
                      {"reward_scales": {"action_rate": 0.0}}, {}),
    "plain_rate_0.1": ("plain PPO, action-rate weight 0.1",
                       {"reward_scales": {"action_rate": 0.1}}, {}),
    "residual_log_ctrl0": ("residual PPO (entry `default`), the registered reward without the "
                           "ctrl term", {"tracking_form": "log", "reward_scales": {"ctrl": 0.0}},
                           {"entry": "default"}),
    "residual_log_ctrl0_rate0": ("residual PPO (entry `default`), the registered reward "
                                 "without the ctrl and action-rate terms",
                                 {"tracking_form": "log",
                                  "reward_scales": {"ctrl": 0.0, "action_rate": 0.0}},
                                 {"entry": "default"}),
    "residual_registered": ("residual PPO (entry `default`) on the registered env",
                            {"tracking_form": "log", "reward_scales": {}}, {"entry": "default"}),
    "plain_norm_reward": ("plain PPO with reward normalization", {},
                          {"normalize": {"norm_reward": True}}),
    "plain_div100": ("plain PPO, divergence weight 100", {"reward_scales": {"divergence": 100.0}},
                     {}),
    "plain_div100_norm": ("plain PPO, divergence weight 100, reward normalization",
                          {"reward_scales": {"divergence": 100.0}},
                          {"normalize": {"norm_reward": True}}),
    "plain_div100_registered": ("plain PPO, divergence weight 100, reset noise 0.001",
                                {"reward_scales": {"divergence": 100.0},
                                 "reset_noise_scale": 0.001}, {}),
    "residual_div100": ("residual PPO (entry `default`), divergence weight 100",
                        {"tracking_form": "log", "reward_scales": {"divergence": 100.0}},
                        {"entry": "default"}),
    "plain_filter": ("plain PPO, action filter 10 ms", {"action_filter_tau": 0.01}, {}),
    "plain_filter_rate0": ("plain PPO, action filter 10 ms, no action-rate term",
                           {"action_filter_tau": 0.01, "reward_scales": {"action_rate": 0.0}},
                           {}),
    "residual_filter": ("residual PPO (entry `default`), action filter 10 ms",
                        {"action_filter_tau": 0.01}, {"entry": "default"}),
    "plain_ctrl0": ("plain PPO without the ctrl term", {"reward_scales": {"ctrl": 0.0}}, {}),
}  # fmt: skip
Row = Literal[tuple(ROWS)]  # type: ignore[valid-type]


def row_config(name: str, steps: int) -> Hyperparams:
    """Returns the hyperparameters of a study row."""
    from tendon2r_gym.training import Hyperparams

    _, env_kwargs, knobs = ROWS[name]
    knobs = dict(knobs)
    base = Hyperparams.from_entry(knobs.pop("entry", "default_scratch"))
    changes: dict[str, Any] = {
        "env_kwargs": {**base.env_kwargs, **env_kwargs},
        "total_timesteps": steps,
        # ten evaluations, at most one per rollout
        "eval_freq": max(steps // 10, base.rollout_steps),
        "policy_kwargs": dict(base.policy_kwargs),
        "normalize": dict(base.normalize),
        "ppo": dict(base.ppo),
    }
    for key, value in knobs.items():
        if key in ("log_std_init", "net_arch"):
            changes["policy_kwargs"][key] = value
        elif key == "normalize":
            changes["normalize"].update(value)
        else:
            changes["ppo"][key] = value
    return base.replace(**changes)


def _run(name: str, seed: int, steps: int, root: str) -> dict[str, Any]:
    from tendon2r_gym.artifacts.runs import RunFolder, seed_dir
    from tendon2r_gym.training import train_run

    run = RunFolder(seed_dir(Path(root) / name, seed))
    summary = train_run(row_config(name, steps), run, seed, command=f"learnability {name}")
    return {"row": name, **{k: v for k, v in summary.items() if k != "segments"}}


@dataclass
class Args:
    """The learnability study's flags."""

    steps: Annotated[int, arg("PPO steps per run")] = 150_000
    seeds: Annotated[list[int], arg("one run per row and seed")] = field(
        default_factory=lambda: [0, 1, 2]
    )
    rows: Annotated[list[Row], arg("the study's rows")] = field(default_factory=lambda: list(ROWS))
    jobs: Annotated[int, arg("runs in parallel (one per core; 1: in this process)")] = 2
    out: Annotated[str, arg("folder for learnability.md and .json")] = "research/results"
    run_dir: Annotated[str | None, arg("keep the runs here (default: a temp dir)")] = None
    render: Annotated[str | None, arg("only re-render the tables of this JSON")] = None


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse(Args, argv, __doc__)
    one_or_more("--seeds", args.seeds, "one or more seeds")
    one_or_more("--rows", args.rows, "one or more of the rows --help lists")
    from tendon2r_gym.artifacts.runs import command_line

    command = command_line(argv, "python -m research.studies.learnability")
    if args.render:  # re-render the tables of an earlier run's JSON (no training)
        old = json.loads(Path(args.render).read_text())
        program, *rest = shlex.split(old["command"])  # its program name, unquoted
        old["command"] = command_line(rest, program)
        write(old, Path(args.out))
        return old
    with tempfile.TemporaryDirectory() as tmp:
        root = args.run_dir or tmp
        jobs = [(r, s) for r in args.rows for s in args.seeds]
        if args.jobs == 1:  # in this process
            runs = [_run(r, s, args.steps, root) for r, s in jobs]
        else:
            # spawn: a forked child of a process that already loaded torch can hang in OpenMP.
            with ProcessPoolExecutor(
                args.jobs, mp_context=multiprocessing.get_context("spawn")
            ) as pool:
                futures = [pool.submit(_run, r, s, args.steps, root) for r, s in jobs]
                runs = [f.result() for f in futures]
    result = summarize(runs, args.rows, args.seeds, args.steps, command)
    base = row_config(args.rows[0], args.steps)
    result["pd_tension_rate_N_per_s"] = pd_tension_rate(base.env_kwargs, list(base.eval_seeds))
    write(result, Path(args.out))
    return result


def summarize(
    runs: list[dict[str, Any]], names: list[str], seeds: list[int], steps: int, command: str
) -> dict[str, Any]:
    """Returns the study's result: per row, mean +- std over seeds and the wins over PD."""
    rows = []
    for name in names:
        mine = [r for r in runs if r["row"] == name]
        rms = np.array([r["best_rms_deg"] for r in mine], dtype=float)
        beat = [r["first_beat_pd"] for r in mine]
        rows.append(
            {
                "row": name,
                "change": ROWS[name][0],
                "rms_deg_mean": rms.mean(0).tolist(),
                "rms_deg_std": rms.std(0).tolist(),
                "rms_deg_per_seed": rms.tolist(),
                "beat_pd_seeds": sum(b is not None for b in beat),
                "first_beat_pd": beat,
                "wall_time_s_mean": float(np.mean([r["wall_time_s"] for r in mine])),
                "tension_rate_N_per_s_mean": _mean_rate(mine),
                "pd_rms_deg": mine[0]["pd_eval_rms_deg"],
            }
        )
    return {"command": command, "steps": steps, "seeds": seeds, "rows": rows, "runs": runs}


def _rate_ratio(row: dict[str, Any], result: dict[str, Any]) -> str:
    """Returns the row's RMS tension rate over PD's (the `default` preset), or "-"."""
    rate, pd = row.get("tension_rate_N_per_s_mean"), result.get("pd_tension_rate_N_per_s")
    return "-" if rate is None or pd is None else f"{rate / pd:.1f}x"


def _mean_rate(runs: list[dict[str, Any]]) -> float | None:
    """Returns the RMS tension rate (N/s) of the best models, over tendons and seeds."""
    rates = [r.get("best_tension_rate_N_per_s") for r in runs]
    if any(r is None for r in rates):
        return None
    return float(np.sqrt(np.mean(np.square(rates))))


def pd_tension_rate(env_kwargs: dict[str, Any], seeds: list[int]) -> float:
    """Returns PD's RMS tension rate (N/s) over tendons on the eval seeds."""
    from tendon2r_gym.evaluation.evaluator import evaluate

    metrics, _ = evaluate("pd", env_kwargs, seeds)
    return float(np.sqrt(np.mean(np.square(metrics["rms_tension_rate_N_per_s"]))))


def write(result: dict[str, Any], out: Path) -> None:
    """Writes learnability.json and learnability.md."""
    rows, seeds = result["rows"], result["seeds"]
    save_json(out, "learnability", result)
    fmt = joints
    lines = [
        "# Learnability study: plain PPO from scratch",
        "",
        f"Produced by `{result['command']}`: {result['steps']} PPO steps per run, seeds "
        f"{seeds}, the `default` preset. Best tracking RMS on the eval seeds (mean ± std over "
        f"seeds, ddof 0); PD on the same seeds: {fmt(rows[0]['pd_rms_deg'])} deg. Each row "
        "changes one choice of `default_scratch` back to its landed value (or to an "
        "alternative); the residual rows start from the `default` entry instead.",
        "",
        "| row | change | best RMS A / B (deg) | ± std | seeds that beat PD | tension rate "
        "/ PD's | wall (s) |",
        "|---|---|---|---|---|---|---|",
        *(
            f"| {r['row']} | {r['change']} | {fmt(r['rms_deg_mean'])} | "
            f"{fmt(r['rms_deg_std'])} | {r['beat_pd_seeds']} / {len(seeds)} | "
            f"{_rate_ratio(r, result)} | {r['wall_time_s_mean']:.0f} |"
            for r in rows
        ),
    ]
    (out / "learnability.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

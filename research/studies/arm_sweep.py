"""Arm sweep: does learning hold off the presets it was tuned on?

    python -m research.studies.arm_sweep                  # research/results/arm_sweep.md and .json
    python -m research.studies.arm_sweep --arms default --train-steps 2048 --out runs/x   # smoke

Arms: the bundled presets, the example arm (configs/examples/my_arm.yaml) and ``--n-random``
arms drawn with ``--arm-seed`` from the course's ranges by tendon2r_gym.task.arms.draw_arms.  Each
arm is written as an experiment file and run through the same code path as
``tendon2r-benchmark --env-config ARM.yaml``: plain and residual PPO trained with the shipped
hyperparameters (one seed, no per-arm tuning), then PD, CT and both on the same episodes.
Every arm runs in each ``--action-modes`` (the experiment file's ``action_mode``).

``--only scratch`` (or ``residual``) trains and measures only that PPO row, after its entry
changed; the other row's cells stay those of ``--out``'s arm_sweep.json (the same arms, its
command kept beside them).  Training is deterministic, so rerunning that row with the same
entry and code would repeat it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml

from research.studies import joints, one_or_more, save_json
from tendon2r_gym.app.args import arg, parse
from tendon2r_gym.app.benchmark import benchmark_own_arm
from tendon2r_gym.artifacts.runs import command_line
from tendon2r_gym.envs.env_config import ACTION_MODES, EnvConfig
from tendon2r_gym.evaluation.metrics import (
    RATE_LIMIT_X_PD,
    TENSION_LIMIT_X_PD,
    beats,
    smoothness_x_pd,
    within_limits,
)
from tendon2r_gym.presets import load_yaml, preset_path
from tendon2r_gym.task.arms import draw_arms
from tendon2r_gym.validation import invalid

PRESETS = ("default", "report_002", "pull_only")
#: The sweep's learned rows (tendon2r_gym.app.benchmark.LEARNED labels), by --only's names.
ROWS = {"scratch": "ppo scratch", "residual": "ppo residual"}
Row = Literal[tuple(ROWS)]  # type: ignore[valid-type]
ActionMode = Literal[ACTION_MODES]  # type: ignore[valid-type]
EXAMPLE = Path(__file__).resolve().parents[2] / "configs" / "examples" / "my_arm.yaml"


def arm_files(
    folder: Path, n_random: int, arm_seed: int, modes: tuple[str, ...] = ("tension",)
) -> dict[tuple[str, str], Path]:
    """Writes every arm of the sweep in every action mode as an experiment file; returns
    (arm, mode) -> path."""
    folder.mkdir(parents=True, exist_ok=True)
    arms: dict[str, dict[str, Any]] = {p: load_yaml(preset_path(p)) for p in PRESETS}
    if EXAMPLE.is_file():
        arms["my_arm"] = load_yaml(EXAMPLE)
    for i, arm in enumerate(draw_arms(arm_seed, n_random)):
        arms[f"course_{i}"] = arm
    paths = {}
    for name, content in arms.items():
        for mode in modes:
            path = folder / f"{name}_{mode}.yaml"
            path.write_text(yaml.safe_dump({**content, "action_mode": mode}, sort_keys=False))
            paths[name, mode] = path
    return paths


def _verdict(rows: list[dict[str, Any]]) -> dict[str, Any]:
    by = {r["policy"]: r for r in rows if "rms_deg" in r}
    pd = by["pd"]["rms_deg"]
    out = {"pd": pd, "ct": by["ct"]["rms_deg"]}
    for label in ("ppo scratch", "ppo residual"):
        r = by.get(label)
        if r is None:
            out[label] = None
            continue
        tension, rate = smoothness_x_pd(r, by["pd"])
        out[label] = {
            "rms_deg": r["rms_deg"],
            "beats_pd": beats(r["rms_deg"], pd),
            "tension_x_pd": tension,
            "tension_rate_x_pd": rate,
        }
    return out


@dataclass
class Args:
    """The arm sweep's flags."""

    n_random: Annotated[int, arg("random course arms")] = 8
    arm_seed: Annotated[int, arg("seed of the random arms")] = 2027
    arms: Annotated[list[str] | None, arg("only these arms (names)")] = None
    train_steps: Annotated[int | None, arg("default: the entries' own")] = None
    episodes: Annotated[int, arg("evaluation episodes per arm")] = 3
    action_modes: Annotated[list[ActionMode], arg("the env's action modes to sweep")] = field(
        default_factory=lambda: list(ACTION_MODES)
    )
    out: Annotated[str, arg("folder for arm_sweep.md and .json")] = "research/results"
    run_dir: Annotated[str, arg("the arms' files, training runs and reports")] = "runs/arm_sweep"
    only: Annotated[
        Row | None,
        arg("train only this PPO row; the other's cells come from --out's arm_sweep.json"),
    ] = None


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse(Args, argv, __doc__)
    one_or_more("--action-modes", args.action_modes, f"one or more of {ACTION_MODES}")
    command = command_line(argv, "python -m research.studies.arm_sweep")
    out, runs = Path(args.out), Path(args.run_dir)
    earlier = _earlier(out, args.only)
    paths = arm_files(runs / "arms", args.n_random, args.arm_seed, tuple(args.action_modes))
    if args.arms:
        paths = {k: v for k, v in paths.items() if k[0] in args.arms}
    commands = {label: command for label in ROWS.values()}
    if earlier is not None:
        commands |= {k: v for k, v in earlier["commands"].items() if k != ROWS[args.only]}
    result: dict[str, Any] = {
        "command": command, "commands": commands, "modes": args.action_modes, "arms": {},
    }  # fmt: skip
    labels, kept = None, {}
    if earlier is not None:  # every arm checked before any training
        labels = [ROWS[args.only]]
        kept = {
            f"{name}_{mode}": _kept(earlier, f"{name}_{mode}", path, labels[0])
            for (name, mode), path in paths.items()
        }
    for (name, mode), path in paths.items():
        key = f"{name}_{mode}"
        bench = benchmark_own_arm(
            str(path), args.train_steps, [0], args.episodes, runs / "reports" / key,
            runs / key, command, labels,
        )  # fmt: skip
        arm = {"arm": name, "action_mode": mode, "env_config": bench["env_config"]}
        result["arms"][key] = arm | _verdict(bench["rows"]) | kept.get(key, {})
        write(result, out)
    return result


def _earlier(out: Path, only: str | None) -> dict[str, Any] | None:
    """Returns the earlier sweep that ``--only`` keeps the other rows of (None without --only),
    with the command of each row (a sweep from before per-row commands: its one command)."""
    if only is None:
        return None
    path = out / "arm_sweep.json"
    if not path.is_file():
        raise invalid("--only", only, f"no --only without an earlier sweep at {path}")
    earlier = json.loads(path.read_text())
    earlier.setdefault("commands", {label: earlier["command"] for label in ROWS.values()})
    return earlier


def _kept(earlier: dict[str, Any], key: str, path: Path, retrained: str) -> dict[str, Any]:
    """Returns the earlier sweep's cells of arm ``key`` (experiment file ``path``) for every
    learned row but ``retrained``; raises if that sweep lacks the arm or ran another config."""
    arm = earlier["arms"].get(key)  # its config read back: a field added since, its default
    if arm is None or EnvConfig.from_kwargs(arm["env_config"]) != EnvConfig.make(str(path)):
        found = None if arm is None else "another config of it"
        raise invalid(f"earlier arm_sweep.json arm {key!r}", found, "the same arm as this sweep")
    return {label: arm[label] for label in ROWS.values() if label != retrained}


def _smooth(cell: dict[str, Any], label: str) -> bool:
    """Returns whether a learned row's cell keeps the smoothness limits (metrics)."""
    return within_limits(cell["tension_x_pd"], cell["tension_rate_x_pd"], label == "ppo residual")


def _produced_by(result: dict[str, Any]) -> list[str]:
    """Returns the line that names the command of each learned row (--only keeps the other
    row from an earlier sweep)."""
    shown = {"ppo scratch": "plain PPO", "ppo residual": "residual PPO"}
    kept = {k: v for k, v in result.get("commands", {}).items() if v != result["command"]}
    line = f"Produced by `{result['command']}`"
    for label, command in kept.items():
        line += f"; the {shown[label]} cells are kept from `{command}`"
    return [line + "."]


def write(result: dict[str, Any], out: Path) -> None:
    """Writes arm_sweep.json and arm_sweep.md."""
    save_json(out, "arm_sweep", result)
    fmt = joints

    def cell(v: dict[str, Any] | None, label: str) -> str:
        if v is None:
            return "-"
        mark = "<= PD" if v["beats_pd"] else "**WORSE**"
        over = "" if _smooth(v, label) else ", **over the limits**"
        return (
            f"{fmt(v['rms_deg'])} ({mark}; tension {v['tension_x_pd']:.1f}x, "
            f"rate {v['tension_rate_x_pd']:.1f}x PD{over})"
        )

    arms = result["arms"]
    lines = [
        "# Arm sweep: PD, CT, plain and residual PPO on every arm",
        "",
        *_produced_by(result),
        "One training seed per arm, the shipped "
        "hyperparameters (configs/ppo.yaml `default_scratch` and `default`), no per-arm tuning;",
        "RMS tracking error (deg, joint A / B) on evaluation seeds 0-2; `tension` and `rate`: the",
        "RMS tendon tension and its RMS rate of change, over the tendons, as multiples of PD's (in",
        f"the same action mode); the limits: tension {TENSION_LIMIT_X_PD:g}x, rate "
        f"{RATE_LIMIT_X_PD['plain']:g}x (plain) and {RATE_LIMIT_X_PD['residual']:g}x (residual).",
        "",
        "| arm | action mode | PD | CT | plain PPO | residual PPO |",
        "|---|---|---|---|---|---|",
        *(
            f"| {a['arm']} | {a['action_mode']} | {fmt(a['pd'])} | {fmt(a['ct'])} | "
            f"{cell(a['ppo scratch'], 'ppo scratch')} | {cell(a['ppo residual'], 'ppo residual')} |"
            for a in arms.values()
        ),
        "",
    ]
    for label in ("ppo scratch", "ppo residual"):
        for mode in result["modes"]:
            done = [
                a[label] for a in arms.values() if a[label] is not None and a["action_mode"] == mode
            ]
            wins = sum(v["beats_pd"] for v in done)
            smooth = sum(v["beats_pd"] and _smooth(v, label) for v in done)
            lines.append(
                f"- {label}, {mode}: <= PD on both joints on {wins} of {len(done)} arms; "
                f"<= PD within the smoothness limits on {smooth}."
            )
    names = {a["arm"] for a in arms.values()}
    either = sum(
        any(
            a["ppo scratch"] is not None and a["ppo scratch"]["beats_pd"]
            for a in arms.values()
            if a["arm"] == n
        )
        for n in names
    )
    lines.append(
        f"- ppo scratch: <= PD in at least one action mode on {either} of {len(names)} arms."
    )
    push_pull = [
        a["ppo scratch"]
        for a in arms.values()
        if a["action_mode"] == "tension"
        and not a["env_config"]["mechanism"]["pull_only"]
        and a["ppo scratch"] is not None
    ]
    if push_pull:
        wins = sum(v["beats_pd"] for v in push_pull)
        lines.append(
            f"- ppo scratch, tension mode, push-pull arms: <= PD on {wins} of {len(push_pull)}."
        )
    (out / "arm_sweep.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines), flush=True)


if __name__ == "__main__":
    main()

"""Ten training seeds of the default preset's two learned recipes (issue 81's 10-seed result):
plain PPO (`default_scratch`) and residual PPO (`default`), each trained for its entry's full
budget on 10 seeds through the executor, then compared with PD and computed torque on the
benchmark's evaluation episodes, as `tendon2r-benchmark` compares the shipped models.

    python -m research.studies.ten_seeds --workers 2   # research/results/ten_seeds.md and .json

Training writes into ``--run-dir`` (one folder per entry, ``seed_<n>/`` in each) and is
resumed there: a command stopped by Ctrl-C or a crash continues where it stopped, and seeds
already trained are only evaluated.  Each row over several seeds carries the IQM of the RMS
error per joint with its 95% stratified bootstrap interval, the mean +- std, the share of seeds
that beat PD on both joints with its Wilson interval, and each seed's worst-joint ratio to PD
(`tendon2r-benchmark`'s ``statistics``).  Only the primary seeds (0-2) ship as models; the
others are kept as these results only.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from tendon2r_gym.app.args import arg, parse

OUT = Path("research/results")
#: The preset, and the benchmark's rows: label -> configs/ppo.yaml entry.
PRESET = "default"
ENTRIES = {"ppo scratch": "default_scratch", "ppo residual": "default"}
#: The benchmark's evaluation episodes (reset seeds), as results/benchmark.json's rows.
EPISODES = [0, 1, 2]


@dataclass
class Args:
    """Ten seeds of the default preset's recipes (module docstring)."""

    seeds: Annotated[list[int], arg("the training seeds of each entry")] = field(
        default_factory=lambda: list(range(10))
    )
    run_dir: Annotated[str, arg("the training runs, one folder per entry (resumed)")] = (
        "runs/ten_seeds"
    )
    workers: Annotated[int, arg("train this many seeds at once in local worker processes")] = 1
    cluster: Annotated[str | None, arg("train the seeds on a Ray cluster: auto or HOST:PORT")] = (
        None
    )
    steps: Annotated[int | None, arg("training steps per seed (default: the entry's)")] = None
    config: Annotated[str | None, arg("hyperparameter file (default: configs/ppo.yaml)")] = None
    out: Annotated[str, arg("folder of ten_seeds.md and ten_seeds.json")] = str(OUT)
    only_report: Annotated[bool, arg("rewrite the .md from the .json")] = False


def train(args: Args, command: str) -> dict[str, list[Path]]:
    """Trains (or resumes) each entry's seeds; returns label -> the seeds' best-model paths."""
    from tendon2r_gym.artifacts.runs import model_files
    from tendon2r_gym.training import Experiment, Hyperparams
    from tendon2r_gym.training.executors import entered, make_executor
    from tendon2r_gym.training.jobs import train_experiment

    path = {} if args.config is None else {"path": args.config}
    cfgs = {label: Hyperparams.from_entry(entry, **path) for label, entry in ENTRIES.items()}
    if args.steps is not None:
        cfgs = {k: hp.replace(total_timesteps=args.steps) for k, hp in cfgs.items()}
    threads = max(hp.torch_threads for hp in cfgs.values())
    executor = make_executor(args.workers, args.cluster, threads)  # flags checked here
    learned = {}
    with entered(executor) as ex:  # an unreachable cluster: refused before training
        for label, hp in cfgs.items():
            folder = Path(args.run_dir) / ENTRIES[label]
            exp = Experiment.start_or_continue(hp, folder, args.seeds, command)
            train_experiment(exp, resume=True, executor=ex)
            learned[label] = [model_files(exp.run_folder(s).best)[0] for s in args.seeds]
    return learned


def lines(result: dict[str, Any]) -> list[str]:
    """Returns ten_seeds.md."""
    from tendon2r_gym.app import report

    steps = result.get("steps")
    budget = "its entry's full budget" if steps is None else f"{steps:,} steps"
    return [
        "# Ten training seeds",
        "",
        f"Produced by `{result['command']}` (research/studies/ten_seeds.py): the "
        f"`{result['preset']}` preset's plain and residual PPO recipes, each trained on seeds "
        f"{', '.join(map(str, result['seeds']))} for {budget}, evaluated on "
        f"episodes {result['episodes']} beside PD and computed torque. The rows named after a "
        "policy alone are its first seed.",
        "",
        *report.tables(result["rows"]),
    ]


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from research.studies import computed_or_read, seeds_flag
    from tendon2r_gym.app.benchmark import compare
    from tendon2r_gym.artifacts.runs import command_line
    from tendon2r_gym.validation import integer

    args = parse(Args, argv, __doc__)
    command = command_line(sys.argv[1:] if argv is None else argv,
                           "python -m research.studies.ten_seeds")  # fmt: skip
    out = Path(args.out)

    def compute() -> dict[str, Any]:
        seeds_flag("--seeds", args.seeds)
        if args.steps is not None:
            integer("--steps", args.steps, 1, 10**9)
        learned = train(args, command)
        rows = compare(PRESET, {"preset": PRESET}, learned, EPISODES, None)
        return {"command": command, "preset": PRESET, "entries": ENTRIES, "seeds": args.seeds,
                "steps": args.steps, "episodes": EPISODES, "rows": rows}  # fmt: skip

    result = computed_or_read(out, "ten_seeds", args.only_report, compute)
    (out / "ten_seeds.md").write_text("\n".join(lines(result)) + "\n")
    print("wrote", out / "ten_seeds.md")
    return result


if __name__ == "__main__":
    main()

"""Scale-up of the executors (issue 81's targets): wall times of the same seeds trained in one
process, on two local workers and on a two-node Ray cluster on this machine, and whether each
seed trains to the same bits on every executor.

    python -m research.studies.scale_up   # research/results/scale_up.md and scale_up.json

The modes (``--modes``), each training ``--seeds`` of the ``--hyperparams`` entry for
``--steps`` steps into a fresh run folder, as ``tendon2r-train`` does:

- ``workers_1``: ``--workers 1``, the seeds one after another in this process (the reference);
- ``workers_2``: ``--workers 2``, two local worker processes;
- ``cluster``: ``--cluster HOST:PORT`` of a Ray cluster of two one-CPU nodes started here by
  ``ray.cluster_utils.Cluster``, every node on 127.0.0.1 (nothing sent to any other address;
  Ray's usage statistics off), stopped after its training.  Its start is not timed.

Reported per mode: the training's wall time, its ratio to ``workers_1``'s (the targets: at
most TARGET for ``workers_2`` on 2 cores and for the cluster), and per seed whether its
``evaluations.json`` (wall times aside) and its best model's weights and observation
statistics are bit-identical to ``workers_1``'s.  The load average before each mode is
recorded: other jobs on the machine lengthen every wall time.
"""

from __future__ import annotations

import contextlib
import io
import os
import shutil
import sys
import tempfile
import time
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from tendon2r_gym.app.args import arg, parse

OUT = Path("research/results")
#: The modes, in the order they run.
MODES = ("workers_1", "workers_2", "cluster")
#: The targets: a mode's wall time at most this multiple of workers_1's.
TARGET = 0.6


def _check(args: Args) -> None:
    """Raises a ValueError naming the first bad flag."""
    from research.studies import one_or_more, seeds_flag
    from tendon2r_gym.validation import integer, invalid

    integer("--steps", args.steps, 1, 10**9)
    seeds_flag("--seeds", args.seeds)
    for mode in one_or_more("--modes", args.modes, f"one or more of {MODES}"):
        if mode not in MODES:
            raise invalid("--modes", mode, f"one of {MODES}")


@contextlib.contextmanager
def loopback_cluster(nodes: int = 2, cpus: int = 1) -> Iterator[Any]:
    """Yields a Ray cluster of ``nodes`` nodes of ``cpus`` CPUs each on this machine (Ray's
    ``ray.cluster_utils.Cluster``), every node on 127.0.0.1 and Ray's usage statistics off;
    stops only what it started."""
    from tendon2r_gym.training.executors import _import_ray

    _import_ray()  # a ValueError naming the cluster extra if Ray is missing
    import ray._private.ray_constants as constants
    from ray.cluster_utils import Cluster

    old_env = {k: os.environ.get(k) for k in ("RAY_USAGE_STATS_ENABLED",
                                              "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER")}  # fmt: skip
    old_flag = constants.ENABLE_RAY_CLUSTER
    os.environ.update({"RAY_USAGE_STATS_ENABLED": "0", "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"})
    constants.ENABLE_RAY_CLUSTER = False  # this process: 127.0.0.1
    cluster = None
    try:
        head = {"num_cpus": cpus, "include_dashboard": False, "node_ip_address": "127.0.0.1"}
        cluster = Cluster(initialize_head=True, head_node_args=head)
        for _ in range(nodes - 1):
            cluster.add_node(num_cpus=cpus, node_ip_address="127.0.0.1")
        cluster.wait_for_nodes()
        yield cluster
    finally:
        if cluster is not None:
            cluster.shutdown()
        constants.ENABLE_RAY_CLUSTER = old_flag
        for k, v in old_env.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def bits(run: Path) -> dict[str, Any]:
    """What a seed's training decides, as plain data: its evaluations (wall times aside), and
    its best model's weights and observation statistics."""
    import numpy as np
    import torch

    from tendon2r_gym.artifacts.runs import RunFolder

    folder = RunFolder(run)
    rows = [{k: v for k, v in r.items() if k != "wall_time_s"}
            for r in folder.read_json("evaluations.json")]  # fmt: skip
    with zipfile.ZipFile(folder.file("best_model.zip")) as z:
        weights = torch.load(io.BytesIO(z.read("policy.pth")), weights_only=True)
    with np.load(folder.file("best_model_vecnormalize.npz")) as stats:
        statistics = {k: stats[k].tobytes() for k in stats.files}
    return {
        "evaluations": rows,
        "best_model": {"weights": {k: v.numpy().tobytes() for k, v in weights.items()},
                       "statistics": statistics},
    }  # fmt: skip


def train(args: Args, mode: str, run: Path) -> float:
    """Trains ``args.seeds`` in ``mode`` into ``run``; returns the training's wall time (s)."""
    from tendon2r_gym.app.cli import train_main

    argv = ["--hyperparams", args.hyperparams, "--run-dir", str(run),
            "--total-timesteps", str(args.steps), "--seeds", *map(str, args.seeds)]  # fmt: skip
    if args.config is not None:
        argv += ["--config", args.config]
    with contextlib.ExitStack() as stack:
        if mode == "cluster":
            cluster = stack.enter_context(loopback_cluster())
            argv += ["--cluster", cluster.address]
        elif mode == "workers_2":
            argv += ["--workers", "2"]
        start = time.perf_counter()
        train_main(argv)
        return time.perf_counter() - start


def measure(args: Args, runs: Path) -> dict[str, Any]:
    """Runs each mode of ``args.modes`` (module docstring) under ``runs``; returns the
    results."""
    modes: dict[str, Any] = {}
    seen: dict[str, dict[int, dict[str, Any]]] = {}
    for mode in [m for m in MODES if m in args.modes]:
        load = os.getloadavg()[0]
        print(f"scale_up: {mode}, seeds {args.seeds}, {args.steps} steps", flush=True)
        wall = train(args, mode, runs / mode)
        seen[mode] = {seed: bits(runs / mode / f"seed_{seed}") for seed in args.seeds}
        modes[mode] = {"wall_s": wall, "load_before": load}
        print(f"scale_up: {mode} took {wall:.1f} s", flush=True)
    reference = next(iter(seen))
    for mode, row in modes.items():
        one = modes.get("workers_1")
        row["ratio_to_workers_1"] = row["wall_s"] / one["wall_s"] if one else None
        row["identical_to"] = reference
        row["identical"] = {
            str(seed): {part: seen[mode][seed][part] == seen[reference][seed][part]
                        for part in ("evaluations", "best_model")}
            for seed in args.seeds
        }  # fmt: skip
        row["all_identical"] = all(all(v.values()) for v in row["identical"].values())
        if mode != "workers_1" and row["ratio_to_workers_1"] is not None:
            row["target"] = TARGET
            row["met"] = row["ratio_to_workers_1"] <= TARGET
    return modes


def lines(result: dict[str, Any]) -> list[str]:
    """Returns scale_up.md."""
    out = [
        "# Scale-up of the executors",
        "",
        f"Produced by `{result['command']}` (research/studies/scale_up.py): seeds "
        f"{result['seeds']} of the `{result['hyperparams']}` entry, {result['steps']:,} steps "
        f"each, on a machine of {result['cpus']} CPUs. Wall time of the training alone (a "
        "cluster's start aside); the ratio to one worker (`--workers 1`, the seeds one after "
        f"another in one process), against the target of at most {TARGET}; and the seeds "
        f"whose `evaluations.json` (wall times aside) and best model (weights and observation "
        "statistics) are bit-identical to the reference mode's. The load average before each "
        "mode tells how busy the machine was with other jobs.",
        "",
        "| mode | wall time (s) | ratio to one worker | target | met | bit-identical seeds "
        "| load before |",
        "|---|---|---|---|---|---|---|",
    ]
    for mode, row in result["modes"].items():
        ratio = row.get("ratio_to_workers_1")
        same = sum(all(v.values()) for v in row["identical"].values())
        target = f"<= {row['target']}" if "target" in row else "-"
        met = ("yes" if row["met"] else "no") if "met" in row else "-"
        shown = f"{ratio:.3f}" if ratio is not None else "-"
        out.append(f"| {mode} | {row['wall_s']:.1f} | {shown} | {target} | {met} | "
                   f"{same} of {len(row['identical'])} (vs {row['identical_to']}) | "
                   f"{row['load_before']:.2f} |")  # fmt: skip
    differ = [f"{mode}: seed {seed} ({', '.join(k for k, v in parts.items() if not v)})"
              for mode, row in result["modes"].items()
              for seed, parts in row["identical"].items() if not all(parts.values())]  # fmt: skip
    if differ:
        out += ["", "Seeds that differ from the reference: " + "; ".join(differ) + "."]
    out += ["", "Modes: `workers_2` is `tendon2r-train --workers 2`; `cluster` is "
            "`tendon2r-train --cluster HOST:PORT` on a Ray cluster of two one-CPU nodes on "
            "127.0.0.1 (`ray.cluster_utils.Cluster`)."]  # fmt: skip
    return out


@dataclass
class Args:
    """The scale-up measurement (module docstring)."""

    steps: Annotated[int, arg("training steps per seed")] = 300_000
    seeds: Annotated[list[int], arg("the seeds each mode trains")] = field(
        default_factory=lambda: [0, 1, 2, 3]
    )
    modes: Annotated[list[str], arg(f"which of {', '.join(MODES)} to run")] = field(
        default_factory=lambda: list(MODES)
    )
    hyperparams: Annotated[str, arg("entry of the hyperparameter file")] = "default"
    config: Annotated[str | None, arg("hyperparameter file (default: configs/ppo.yaml)")] = None
    out: Annotated[str, arg("folder of scale_up.md and scale_up.json")] = str(OUT)
    run_dir: Annotated[
        str | None, arg("keep the run folders here, one per mode (default: a temporary folder)")
    ] = None
    only_report: Annotated[bool, arg("rewrite the .md from the .json")] = False


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from research.studies import computed_or_read
    from tendon2r_gym.artifacts.runs import command_line
    from tendon2r_gym.validation import invalid

    args = parse(Args, argv, __doc__)
    command = command_line(sys.argv[1:] if argv is None else argv,
                           "python -m research.studies.scale_up")  # fmt: skip
    out = Path(args.out)

    def compute() -> dict[str, Any]:
        _check(args)
        if args.run_dir is not None:
            runs = Path(args.run_dir)
            if runs.exists() and any(runs.iterdir()):
                raise invalid("--run-dir", args.run_dir, "a folder that is missing or empty")
            modes = measure(args, runs)
        else:
            tmp = tempfile.mkdtemp(prefix="tendon2r-scale-up-")
            try:
                modes = measure(args, Path(tmp))
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
        return {"command": command, "hyperparams": args.hyperparams, "config": args.config,
                "steps": args.steps, "seeds": args.seeds, "cpus": os.cpu_count(),
                "target": TARGET, "modes": modes}  # fmt: skip

    result = computed_or_read(out, "scale_up", args.only_report, compute)
    (out / "scale_up.md").write_text("\n".join(lines(result)) + "\n")
    print("wrote", out / "scale_up.md")
    return result


if __name__ == "__main__":
    main()

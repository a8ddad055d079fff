"""A small rl_zoo3 Optuna search with workers sharing one study through a storage.

    python -m research.studies.optuna_search --workers 2 --trials 4 --steps 30000

starts ``--workers`` copies of the zoo's own command on this machine:

    python -m rl_zoo3.train --algo ppo --env Tendon2R-v1 --gym-packages tendon2r_gym \\
        --conf-file configs/rl_zoo3/ppo.yml -optimize --storage STORAGE --study-name NAME ...

and then writes the study's best trial to research/results/optuna.md and .json.  Optuna
coordinates the workers through the storage (a journal file here); nothing here schedules
trials.  On many machines, run that same zoo command on each of them with a shared database URL as
``--storage`` (for example ``postgresql://user@host/optuna``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from tendon2r_gym.app.args import arg, parse

#: The zoo hyperparameter file, relative to the repository (run from its root, as README does).
ZOO_CONF = "configs/rl_zoo3/ppo.yml"


@dataclass
class Args:
    """The Optuna search's flags."""

    workers: Annotated[int, arg("zoo processes sharing the study")] = 2
    trials: Annotated[int, arg("trials per worker")] = 4
    steps: Annotated[int, arg("PPO steps per trial")] = 30000
    env: Annotated[str, arg("the Gymnasium id to tune on")] = "Tendon2R-v1"
    conf_file: Annotated[str, arg("the zoo hyperparameter file")] = ZOO_CONF
    storage: Annotated[str, arg("the study's Optuna journal file")] = "runs/optuna/tendon2r_ppo.log"
    study_name: Annotated[str, arg("the study's name in the storage")] = "tendon2r_ppo"
    log_folder: Annotated[str, arg("the zoo's log folder")] = "runs/optuna"
    out: Annotated[str, arg("folder for optuna.md and .json")] = "research/results"


def zoo_command(args: Args, seed: int) -> list[str]:
    """Returns one worker's rl_zoo3 command."""
    return [
        sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", args.env,
        "--gym-packages", "tendon2r_gym", "--conf-file", str(args.conf_file), "-optimize",
        "--storage", args.storage, "--study-name", args.study_name, "--n-trials",
        str(args.trials), "--n-jobs", "1", "-n", str(args.steps), "--n-evaluations", "2",
        "--eval-episodes", "3", "--sampler", "tpe", "--pruner", "median",
        "--n-startup-trials", "2", "--log-folder", args.log_folder, "--seed", str(seed),
        "--device", "cpu",
    ]  # fmt: skip


def main(argv: list[str] | None = None) -> dict:
    args = parse(Args, argv, __doc__)
    from tendon2r_gym.artifacts.runs import command_line

    command = command_line(argv, "python -m research.studies.optuna_search")
    Path(args.storage).parent.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "MUJOCO_GL": "egl", "OMP_NUM_THREADS": "1"}
    workers = [subprocess.Popen(zoo_command(args, seed), env=env) for seed in range(args.workers)]
    codes = [w.wait() for w in workers]
    if any(codes):
        raise RuntimeError(f"rl_zoo3 workers exited with {codes}")
    import optuna

    storage = optuna.storages.JournalStorage(
        optuna.storages.journal.JournalFileBackend(args.storage)
    )
    study = optuna.load_study(study_name=args.study_name, storage=storage)
    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    best = study.best_trial
    result = {
        "command": command,
        "worker_command": " ".join(["python", *zoo_command(args, 0)[1:]]).replace(
            "--seed 0", "--seed <worker>"
        ),
        "trials": len(study.trials),
        "complete": len(done),
        "pruned": sum(t.state == optuna.trial.TrialState.PRUNED for t in study.trials),
        "best_value": best.value,
        "best_params": best.params,
        "best_user_attrs": best.user_attrs,
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "optuna.json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [
        "# rl_zoo3 Optuna search",
        "",
        f"Produced by `{command}`: {args.workers} workers on this machine sharing one study "
        f"through `{args.storage}` (Optuna's journal storage), {args.trials} trials each of "
        f"{args.steps} PPO steps. Each worker ran:",
        "",
        f"    {result['worker_command']}",
        "",
        f"{result['trials']} trials ({result['complete']} complete, {result['pruned']} pruned). "
        f"Best mean evaluation reward (the zoo's objective, episode return of the env's "
        f"reward): **{best.value:.1f}**, trial {best.number}:",
        "",
        "| parameter | value |",
        "|---|---|",
        *(f"| {k} | {v} |" for k, v in {**best.params, **best.user_attrs}.items()),
    ]
    (out / "optuna.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return result


if __name__ == "__main__":
    main()

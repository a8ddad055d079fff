"""What a user's own PPO learns on each env version: rl_zoo3 with its ordinary MuJoCo settings.

    python -m research.studies.zoo_defaults --steps 500000 --seeds 0   # results/zoo_defaults.*
    python -m research.studies.zoo_defaults --steps 256 --out x         # smoke

For each env id (its own defaults, no env_kwargs), trains PPO with ``python -m rl_zoo3.train``
on a hyperparameter file this study writes: one entry of rl_zoo3's own shipped
``hyperparams/ppo.yml`` (default ``Reacher-v2``, the zoo's entry for its MuJoCo two-link arm),
copied from the installed file, with ``n_timesteps`` set to the budget.  Then evaluates the
model rl_zoo3 saved at the end (with its VecNormalize statistics) deterministically on the
eval seeds of the same id, and PD on the same episodes.
"""

from __future__ import annotations

import importlib.metadata
import importlib.resources
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml

from research.studies import joints, save_json
from tendon2r_gym.app.args import arg, parse
from tendon2r_gym.artifacts.runs import command_line
from tendon2r_gym.evaluation.metrics import SETTLE_S
from tendon2r_gym.validation import integer, invalid

ENV_IDS = ("Tendon2R-v0", "Tendon2R-v1")
#: The rl_zoo3 entry copied by default: the zoo's MuJoCo two-link arm (tuned, normalize: true).
ZOO_ENTRY = "Reacher-v2"


def zoo_file() -> Path:
    """Returns rl_zoo3's installed PPO hyperparameter file."""
    return Path(str(importlib.resources.files("rl_zoo3") / "hyperparams" / "ppo.yml"))


def zoo_hyperparams(entry: str, steps: int) -> dict[str, Any]:
    """Returns entry ``entry`` of rl_zoo3's shipped ppo.yml (anchors merged), with
    ``n_timesteps`` = ``steps``."""
    table = yaml.safe_load(zoo_file().read_text())
    if entry not in table or not isinstance(table[entry], dict):
        raise invalid("zoo_entry", entry, f"an entry of {zoo_file()}, e.g. {ZOO_ENTRY!r}")
    return {**table[entry], "n_timesteps": steps}


def train(
    env_id: str, seed: int, steps: int, hyperparams: dict[str, Any], root: Path, threads: int
) -> dict[str, Any]:
    """Trains one rl_zoo3 run into ``root/<env_id>/seed_<seed>``; returns its folder, model,
    VecNormalize file and wall time (s, the whole rl_zoo3 process)."""
    log = root / env_id / f"seed_{seed}"
    run = log / "ppo" / f"{env_id}_1"
    if run.exists():  # rl_zoo3 would number a new folder; refuse instead of guessing
        raise invalid("run_dir", str(root), f"a folder without an earlier run of {env_id} "
                      f"seed {seed} (found {run})")  # fmt: skip
    log.mkdir(parents=True, exist_ok=True)
    conf = log / "ppo.yml"
    conf.write_text(yaml.safe_dump({env_id: hyperparams}, sort_keys=False))
    cmd = [sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", env_id,
           "--gym-packages", "tendon2r_gym", "-n", str(steps), "--seed", str(seed),
           "--log-folder", str(log), "--eval-freq", "-1", "--conf-file", str(conf),
           "--num-threads", str(threads)]  # fmt: skip
    start = time.perf_counter()
    proc = subprocess.run(
        cmd, capture_output=True, text=True, env={"MUJOCO_GL": "egl", **os.environ}
    )
    wall = time.perf_counter() - start
    (log / "train.log").write_text(proc.stdout + proc.stderr)
    if proc.returncode != 0:
        raise RuntimeError(f"rl_zoo3 failed on {env_id} seed {seed}: {proc.stderr[-2000:]}")
    return {
        "env_id": env_id,
        "seed": seed,
        "run": str(run),
        "model": str(run / f"{env_id}.zip"),
        "vecnormalize": str(run / env_id / "vecnormalize.pkl"),
        "wall_time_s": wall,
        "command": " ".join(["python", *cmd[1:]]),
    }


def env_kwargs(env_id: str) -> dict[str, Any]:
    """Returns the defaults the id registers (what rl_zoo3's ``gym.make(env_id)`` gets)."""
    import gymnasium as gym

    import tendon2r_gym  # noqa: F401  (registers the ids)

    return dict(gym.spec(env_id).kwargs)


def evaluate_zoo_model(
    model: str | Path, stats: str | Path, env_id: str, seeds: list[int], threads: int = 1
) -> dict[str, Any]:
    """Returns the tracking metrics of an rl_zoo3 model (deterministic, observations
    normalized by its VecNormalize statistics) on the id's episodes of ``seeds``, with
    ``threads`` torch threads (one step's small batch is many times faster on one thread than
    on two busy cores)."""
    import gymnasium as gym

    from tendon2r_gym.llvm import load_triton

    load_triton()  # before torch: tendon2r_gym.llvm
    import torch
    from stable_baselines3.common.vec_env import DummyVecEnv

    from tendon2r_gym.artifacts.files import load_model, load_vecnormalize
    from tendon2r_gym.evaluation.metrics import tracking_metrics
    from tendon2r_gym.evaluation.rollout import rollouts
    from tendon2r_gym.policies.learned import PPOPolicy
    from tendon2r_gym.policies.residual import NO_RESIDUAL

    kwargs = env_kwargs(env_id)
    probe = gym.make(env_id)
    try:
        # rl_zoo3 writes pickles: this study's own files, trusted
        vecnorm = load_vecnormalize(stats, DummyVecEnv([lambda: probe]), env_id, trust_pickle=True)
        vecnorm.training, vecnorm.norm_reward = False, False
        policy = PPOPolicy(load_model(model, device="cpu", trust_pickle=True), vecnorm, NO_RESIDUAL)
        before = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            return tracking_metrics(rollouts(policy, kwargs, seeds))
        finally:
            torch.set_num_threads(before)
    finally:
        probe.close()


def env_defaults(env_id: str) -> dict[str, Any]:
    """Returns the settings the env versions differ in (tendon2r_gym.VERSIONS), as the id's
    env has them."""
    import gymnasium as gym

    from tendon2r_gym import VERSIONS

    versioned = sorted({k for defaults in VERSIONS.values() for k in defaults})
    env = gym.make(env_id)
    try:
        return {k: getattr(env.unwrapped.config, k) for k in versioned}
    finally:
        env.close()


def pd_metrics(env_id: str, seeds: list[int]) -> dict[str, Any]:
    """Returns PD's tracking metrics on the id's episodes of ``seeds``."""
    from tendon2r_gym.evaluation.evaluator import evaluate

    metrics, _ = evaluate("pd", env_kwargs(env_id), seeds)
    return metrics


EnvId = Literal[ENV_IDS]  # type: ignore[valid-type]

#: Metrics kept per run (tendon2r_gym.evaluation.metrics.tracking_metrics).
KEPT = ("rms_deg", "settled_rms_deg", "max_deg", "diverged_episodes", "episodes", "steps")


@dataclass
class Args:
    """The study's arguments (module docstring)."""

    steps: Annotated[int, arg("PPO steps per run")] = 500_000
    seeds: Annotated[list[int], arg("training seeds")] = field(default_factory=lambda: [0])
    env_ids: Annotated[list[EnvId], arg("env ids to train on")] = field(
        default_factory=lambda: list(ENV_IDS)
    )
    eval_seeds: Annotated[list[int], arg("evaluation episodes' seeds")] = field(
        default_factory=lambda: [0, 1, 2]
    )
    zoo_entry: Annotated[str, arg("the entry of rl_zoo3's ppo.yml")] = ZOO_ENTRY
    threads: Annotated[int, arg("torch threads (rl_zoo3 --num-threads)")] = 1
    out: Annotated[str, arg("folder for zoo_defaults.md and .json")] = "research/results"
    run_dir: Annotated[str | None, arg("keep the runs here (default: a temp dir)")] = None


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse(Args, argv, __doc__)
    integer("steps", args.steps, 1, 10**9)
    integer("threads", args.threads, 1, 256)
    hyperparams = zoo_hyperparams(args.zoo_entry, args.steps)
    command = command_line(argv, "python -m research.studies.zoo_defaults")
    ids = args.env_ids
    result: dict[str, Any] = {
        "command": command,
        "steps": args.steps,
        "seeds": args.seeds,
        "eval_seeds": args.eval_seeds,
        "zoo_entry": args.zoo_entry,
        "zoo_file": "rl_zoo3/hyperparams/ppo.yml (installed)",
        "rl_zoo3_version": importlib.metadata.version("rl_zoo3"),
        "hyperparams": hyperparams,
        "env_kwargs": {env_id: env_kwargs(env_id) for env_id in ids},
        "env_defaults": {env_id: env_defaults(env_id) for env_id in ids},
        "settle_s": SETTLE_S,
        "pd": {env_id: _kept(pd_metrics(env_id, args.eval_seeds)) for env_id in ids},
        "runs": [],
        # seed by seed, one run at a time; the files are rewritten after each run
        "pending": [[env_id, seed] for seed in args.seeds for env_id in ids],
    }
    out = Path(args.out)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.run_dir or tmp)
        while result["pending"]:
            env_id, seed = result["pending"][0]
            run = train(env_id, seed, args.steps, hyperparams, root, args.threads)
            metrics = evaluate_zoo_model(
                run["model"], run["vecnormalize"], env_id, args.eval_seeds, args.threads
            )
            if not args.run_dir:  # the runs' paths die with the temp dir
                run = {k: v for k, v in run.items() if k not in ("run", "model", "vecnormalize")}
            result["runs"].append({**run, **_kept(metrics)})
            result["pending"].pop(0)
            write(result, out)
    return result


def _kept(metrics: dict[str, Any]) -> dict[str, Any]:
    """Returns the metrics the study keeps (KEPT)."""
    return {k: v for k, v in metrics.items() if k in KEPT}


def write(result: dict[str, Any], out: Path) -> None:
    """Writes zoo_defaults.json and zoo_defaults.md."""
    save_json(out, "zoo_defaults", result)
    hp = ", ".join(f"{k} {v}" for k, v in result["hyperparams"].items())
    lines = [
        "# rl_zoo3's ordinary MuJoCo PPO on each env version",
        "",
        f"Produced by `{result['command']}`: rl_zoo3 {result['rl_zoo3_version']}, its shipped "
        f"`{result['zoo_entry']}` entry of hyperparams/ppo.yml ({hp}), each id's own defaults "
        f"(no env_kwargs), {result['steps']} steps per run. The model rl_zoo3 saves at the "
        f"end, deterministic, on eval seeds {result['eval_seeds']}; PD on the same episodes. "
        f"Settled: after each episode's first {result['settle_s'] * 1000:g} ms. Wall: the whole "
        "rl_zoo3 process.",
        "",
        "| env id | its defaults | seed | RMS A / B (deg) | settled A / B (deg) | PD RMS A / B "
        "(deg) | PD settled A / B (deg) | diverged episodes | wall (s) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for run in result["runs"]:
        env_id = run["env_id"]
        pd = result["pd"][env_id]
        lines.append(
            f"| {env_id} | {defaults(result['env_defaults'][env_id])} | {run['seed']} | "
            f"{joints(run['rms_deg'])} | {joints(run['settled_rms_deg'])} | "
            f"{joints(pd['rms_deg'])} | {joints(pd['settled_rms_deg'])} | "
            f"{run['diverged_episodes']} / {run['episodes']} | {run['wall_time_s']:.0f} |"
        )
    if result["pending"]:
        lines += ["", f"Not run yet: {', '.join(f'{i} seed {s}' for i, s in result['pending'])}."]
    (out / "zoo_defaults.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def defaults(settings: dict[str, Any]) -> str:
    """Returns an id's versioned settings as the table shows them."""
    return ", ".join(f"{k} {v}" for k, v in settings.items())


if __name__ == "__main__":
    main()

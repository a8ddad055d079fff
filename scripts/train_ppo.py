"""Train SB3 PPO on Tendon2R-v0.

    python scripts/train_ppo.py --preset default                        # configs/ppo.yaml
    python scripts/train_ppo.py --preset default --seeds 0 1 2          # mean +- std over seeds
    python scripts/train_ppo.py --run-dir runs/x --resume               # after Ctrl-C or a crash
    python scripts/train_ppo.py --preset default --seeds 0 1 2 --bundle # and copy to models/

Each run folder keeps config.yaml (resolved), command.txt, TensorBoard logs, checkpoints/ (model
and VecNormalize), best_model.zip (+ _vecnormalize.pkl, chosen by tracking RMS on fixed seeds),
last_model.zip and summary.json.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import shlex
import sys
import time
from dataclasses import dataclass, field, fields
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import torch  # noqa: E402
import yaml  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback  # noqa: E402
from stable_baselines3.common.env_util import make_vec_env  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize  # noqa: E402

import tendon2r_gym  # noqa: E402, F401  (registers Tendon2R-v0)
from tendon2r_gym.bundle import bundle_runs  # noqa: E402
from tendon2r_gym.config import CONFIG_DIR, load_yaml  # noqa: E402
from tendon2r_gym.learned import make_training_env  # noqa: E402
from tendon2r_gym.training import (  # noqa: E402
    TrackingEvalCallback,
    TrackingLogCallback,
    save_model,
)


@dataclass
class Args:
    preset: str = "default"  # key in configs/ppo.yaml
    config: str = str(CONFIG_DIR / "ppo.yaml")
    total_timesteps: int | None = None  # overrides the config
    n_envs: int | None = None
    seed: int = 0
    seeds: list[int] = field(default_factory=list)  # several seeds, one run folder each
    run_dir: str | None = None  # default runs/<preset>/seed_<seed>
    resume: bool = False  # continue from the newest of last_model and checkpoints/ in run_dir
    progress_bar: bool = False  # also on whenever stderr is a terminal
    bundle: bool = False  # copy the best model(s) to models/<preset>/ (tendon2r_gym.bundle)


def parse_args(argv: list[str] | None = None) -> Args:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    for f in fields(Args):
        flag = "--" + f.name.replace("_", "-")
        if f.type == "bool":
            parser.add_argument(flag, action="store_true")
        elif f.name == "seeds":
            parser.add_argument(flag, type=int, nargs="+", default=[])
        else:
            kind = int if "int" in str(f.type) else str
            parser.add_argument(flag, type=kind, default=f.default)
    return Args(**vars(parser.parse_args(argv)))


def resolve_config(args: Args) -> dict:
    table = load_yaml(args.config)
    if args.preset not in table:
        raise ValueError(f"preset {args.preset!r} not in {args.config}; allowed: {sorted(table)}")
    cfg = copy.deepcopy(table[args.preset])
    if args.total_timesteps is not None:
        cfg["total_timesteps"] = args.total_timesteps
    if args.n_envs is not None:
        cfg["n_envs"] = args.n_envs
    for key in ("total_timesteps", "n_envs"):
        if not isinstance(cfg[key], int) or cfg[key] < 1:
            raise ValueError(f"{key} = {cfg[key]!r} is invalid; allowed: an integer >= 1")
    cfg["seed"] = args.seed
    return cfg


def command_line() -> str:
    """Returns this process's command as `python <script relative to cwd> args...`."""
    script = Path(sys.argv[0])
    try:
        script = script.resolve().relative_to(Path.cwd())
    except ValueError:
        pass
    return shlex.join(["python", str(script), *sys.argv[1:]])


def latest_state(run: Path) -> tuple[Path, Path]:
    """Returns the newest saved (model zip, VecNormalize pkl) of a run: last_model (written on
    Ctrl-C and at the end) or, after a crash that skipped it, the newest checkpoint."""
    candidates = []
    if (run / "last_model.zip").is_file():
        candidates.append((run / "last_model.zip", run / "last_model_vecnormalize.pkl"))
    for zip_path in (run / "checkpoints").glob("rl_model_*_steps.zip"):
        steps = zip_path.stem.removeprefix("rl_model_")
        candidates.append((zip_path, zip_path.with_name(f"rl_model_vecnormalize_{steps}.pkl")))
    candidates = [c for c in candidates if c[1].is_file()]
    if not candidates:
        raise FileNotFoundError(f"--resume: no last_model or checkpoint in {run}")
    return max(candidates, key=lambda c: c[0].stat().st_mtime_ns)


def train(args: Args) -> dict:
    cfg = resolve_config(args)
    run = Path(args.run_dir or f"runs/{args.preset}/seed_{args.seed}")
    run.mkdir(parents=True, exist_ok=True)
    (run / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    (run / "command.txt").write_text(f"{command_line()}\n# interpreter: {sys.executable}\n")
    torch.set_num_threads(cfg["torch_threads"])

    # Environments: subprocesses when n_envs > 1, normalized observations and rewards.
    env_kwargs, residual = cfg["env_kwargs"], float(cfg["residual_scale"])
    venv = make_vec_env(
        make_training_env,
        n_envs=cfg["n_envs"],
        seed=args.seed,
        env_kwargs={"env_kwargs": env_kwargs, "residual_scale": residual},
        vec_env_cls=SubprocVecEnv if cfg["n_envs"] > 1 else DummyVecEnv,
    )
    last = run / "last_model"
    if args.resume:
        state, stats = latest_state(run)
        print(f"resuming from {state}", flush=True)
        venv = VecNormalize.load(str(stats), venv)
        model = PPO.load(state, env=venv, device="cpu")
    else:
        venv = VecNormalize(venv, gamma=cfg["ppo"]["gamma"], **cfg["normalize"])
        model = PPO(
            "MlpPolicy",
            venv,
            seed=args.seed,
            device="cpu",
            verbose=0,
            tensorboard_log=str(run / "tb"),
            policy_kwargs=cfg["policy_kwargs"],
            **cfg["ppo"],
        )

    # Callbacks: tracking-error logs, best model by tracking RMS, periodic checkpoints.
    eval_cb = TrackingEvalCallback(
        env_kwargs, cfg["eval_seeds"], cfg["eval_freq"], run / "best_model", residual
    )
    best_file = run / "best_metrics.json"
    if args.resume and best_file.is_file():  # a resumed run only replaces a better best model
        eval_cb.best_rms = float(np.mean(json.loads(best_file.read_text())["rms_deg"]))
    checkpoints = CheckpointCallback(
        max(cfg["checkpoint_freq"] // cfg["n_envs"], 1),
        str(run / "checkpoints"),
        save_vecnormalize=True,
    )
    remaining = cfg["total_timesteps"] - model.num_timesteps
    start = time.perf_counter()
    interrupted = False
    try:
        if remaining > 0:
            model.learn(
                remaining,
                callback=CallbackList([TrackingLogCallback(), eval_cb, checkpoints]),
                reset_num_timesteps=not args.resume,
                progress_bar=args.progress_bar or sys.stderr.isatty(),
                tb_log_name="ppo",
            )
    except KeyboardInterrupt:
        interrupted = True
        print(f"interrupted at {model.num_timesteps} steps; resume with --resume", flush=True)
    finally:
        save_model(model, last, residual)  # Ctrl-C or a crash keeps the last state
        venv.close()
    wall = time.perf_counter() - start
    best = (
        json.loads((run / "best_metrics.json").read_text())
        if (run / "best_metrics.json").is_file()
        else {}
    )
    summary = {
        "preset": args.preset,
        "seed": args.seed,
        "timesteps": int(model.num_timesteps),
        "wall_time_s": round(wall, 1),
        "steps_per_s": round(max(remaining, 0) / wall, 1),
        "interrupted": interrupted,
        "best_rms_deg": best.get("rms_deg"),
        "best_timesteps": best.get("timesteps"),
    }
    (run / "summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary), flush=True)
    return summary


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    command = (
        command_line() if argv is None else shlex.join(["python", "scripts/train_ppo.py", *argv])
    )
    if not args.seeds:
        train(args)
        if args.bundle:
            run = Path(args.run_dir or f"runs/{args.preset}/seed_{args.seed}")
            print("bundled into", bundle_runs([run], args.preset, command), flush=True)
        return
    base = Path(args.run_dir or f"runs/{args.preset}")
    results, runs = [], []
    for seed in args.seeds:
        one = Args(
            **{
                **vars(args),
                "seed": seed,
                "seeds": [],
                "bundle": False,
                "run_dir": str(base / f"seed_{seed}"),
            }
        )
        results.append(train(one))
        runs.append(Path(one.run_dir))
    rms = np.array([r["best_rms_deg"] for r in results], dtype=float)
    agg = {
        "preset": args.preset,
        "seeds": args.seeds,
        "runs": results,
        "rms_deg_mean": rms.mean(0).tolist(),
        "rms_deg_std": rms.std(0).tolist(),
        "wall_time_s_mean": float(np.mean([r["wall_time_s"] for r in results])),
    }
    (base / "seeds_summary.json").write_text(json.dumps(agg, indent=1))
    print(json.dumps({k: v for k, v in agg.items() if k != "runs"}), flush=True)
    if args.bundle:
        print("bundled into", bundle_runs(runs, args.preset, command), flush=True)


if __name__ == "__main__":
    main()

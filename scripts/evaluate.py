"""Evaluate a policy on Tendon2R-v0: RMS / max tracking error, forces and saturation.

python scripts/evaluate.py --policy pd --preset default --episodes 3 --json out.json
python scripts/evaluate.py --policy ppo                    # the bundled model of the preset
python scripts/evaluate.py --policy ct --env-config my_arm.yaml --plots figs --video run.mp4
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import dataclass, fields
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym  # noqa: E402

import tendon2r_gym  # noqa: E402, F401
from tendon2r_gym.evaluation import POLICIES, env_kwargs_for, evaluate, make_policy  # noqa: E402
from tendon2r_gym.plots import plot_trace, save_video  # noqa: E402
from tendon2r_gym.rollout import rollout  # noqa: E402


@dataclass
class Args:
    policy: str = "pd"  # pd, ct or ppo
    model: str | None = None  # PPO zip (default: the bundled model of the preset)
    preset: str = "default"
    env_config: str | None = None  # YAML with the preset keys (mechanism, reference)
    episodes: int = 3
    seed: int = 0  # episodes use seeds seed, seed + 1, ...
    episode_duration: float | None = None
    json: str | None = None
    plots: str | None = None  # folder for the PNGs of the first episode
    video: str | None = None  # mp4 or gif of the first episode


def parse_args(argv: list[str] | None = None) -> Args:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    for f in fields(Args):
        kind = {"int": int, "float": float}.get(str(f.type).split(" ")[0], str)
        kw = {"choices": POLICIES} if f.name == "policy" else {}
        p.add_argument("--" + f.name.replace("_", "-"), type=kind, default=f.default, **kw)
    args = Args(**vars(p.parse_args(argv)))
    if args.episodes < 1:
        p.error(f"--episodes {args.episodes} is invalid; allowed: >= 1")
    return args


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    extra = {} if args.episode_duration is None else {"episode_duration": args.episode_duration}
    env_kwargs = env_kwargs_for(args.preset, args.env_config, **extra)
    seeds = list(range(args.seed, args.seed + args.episodes))
    metrics, traces = evaluate(args.policy, env_kwargs, seeds, args.model)
    metrics["env_kwargs"] = env_kwargs
    print(
        json.dumps(
            {
                k: metrics[k]
                for k in ("policy", "rms_deg", "max_deg", "rms_force_N", "saturated_fraction")
            }
        )
    )
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(metrics, indent=1))
    title = f"{args.policy.upper()} on {Path(str(env_kwargs['preset'])).stem}"
    if args.plots:
        for path in plot_trace(traces[0], args.plots, title):
            print("wrote", path)
    if args.video:
        env = gym.make("Tendon2R-v0", render_mode="rgb_array", width=480, height=360, **env_kwargs)
        trace = rollout(
            make_policy(args.policy, env, args.model, args.preset), env, seeds[0], render=True
        )
        every = max(1, round(1 / 30 / env.unwrapped.ctrl_dt))  # ~30 fps of real time
        print("wrote", save_video(trace.frames[::every], args.video, fps=30))
        env.close()
    return metrics


if __name__ == "__main__":
    main()

"""Speed benchmark (not a test): raw physics vs env.step, against Gymnasium's Reacher-v5 in the
same run; vector envs; PPO training throughput; peak memory.

    python scripts/bench_speed.py            # writes results/speed.md and results/speed.json
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import threading
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

import tendon2r_gym  # noqa: E402, F401
from tendon2r_gym.runs import command_line  # noqa: E402


def time_raw_physics(env: gym.Env, n: int) -> float:
    """Returns seconds per env step of mj_step(nstep=frame_skip) alone on the env's model."""
    u = env.unwrapped
    data = mujoco.MjData(u.model)
    start = time.perf_counter()
    for _ in range(n):
        mujoco.mj_step(u.model, data, nstep=u.frame_skip)
    return (time.perf_counter() - start) / n


def time_env_step(env: gym.Env, n: int) -> float:
    """Returns seconds per env.step (unwrapped, fixed zero action, resets excluded)."""
    u = env.unwrapped
    action = np.zeros(u.action_space.shape, dtype=np.float32)
    u.reset(seed=0)
    total, steps = 0.0, 0
    while steps < n:
        start = time.perf_counter()
        for _ in range(min(500, n - steps)):
            u.step(action)
        total += time.perf_counter() - start
        steps += min(500, n - steps)
        u.reset()
    return total / n


def best_of(fn, *args, repeats: int = 3) -> float:
    return min(fn(*args) for _ in range(repeats))


def vector_throughput(num_envs: int, mode: str, seconds: float = 1.5) -> float:
    envs = gym.make_vec("Tendon2R-v0", num_envs=num_envs, vectorization_mode=mode)
    envs.reset(seed=0)
    action = np.zeros((num_envs, 2), dtype=np.float32)
    for _ in range(50):
        envs.step(action)
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        envs.step(action)
        steps += num_envs
    rate = steps / (time.perf_counter() - start)
    envs.close()
    return rate


def _descendants(pid: int) -> list[int]:
    """Returns pid and all its descendant pids (Linux /proc)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            children = Path(f"/proc/{p}/task/{p}/children").read_text().split()
        except OSError:
            continue
        todo += [int(c) for c in children]
    return out


def _pss_mb(pids: list[int]) -> float:
    """Returns the summed proportional set size (MB) of pids: shared pages counted once."""
    total = 0
    for p in pids:
        try:
            for line in Path(f"/proc/{p}/smaps_rollup").read_text().splitlines():
                if line.startswith("Pss:"):
                    total += int(line.split()[1])
        except OSError:
            pass
    return total / 1024


class PeakMemory:
    """Samples the summed PSS of this process and its children in a thread; ``peak_mb``."""

    def __init__(self, period_s: float = 0.5) -> None:
        self.period_s, self.peak_mb = period_s, 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak_mb = max(self.peak_mb, _pss_mb(_descendants(os.getpid())))
            self._stop.wait(self.period_s)

    def __enter__(self) -> PeakMemory:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def ppo_throughput(timesteps: int) -> dict:
    import tempfile

    from tendon2r_gym.runs import RunFolder
    from tendon2r_gym.training import TrainSpec, load_hyperparams, train

    cfg = {**load_hyperparams("default"), "total_timesteps": timesteps}
    with tempfile.TemporaryDirectory() as tmp, PeakMemory() as mem:
        start = time.perf_counter()
        summary = train(TrainSpec(cfg, RunFolder(tmp), command="bench_speed"))
        wall = time.perf_counter() - start
    return {
        "timesteps": summary["timesteps"],
        "wall_s": round(wall, 1),
        "env_steps_per_s": round(summary["timesteps"] / wall, 1),
        "n_envs": cfg["n_envs"],
        "n_steps": cfg["ppo"]["n_steps"],
        "torch_threads": cfg["torch_threads"],
        "peak_pss_mb_all_processes": round(mem.peak_mb, 1),
        "note": "includes start-up of the env subprocesses, the tracking evaluation at the "
        "end of training and the checkpoints of the config",
    }


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--steps", type=int, default=20000)
    p.add_argument("--ppo-timesteps", type=int, default=102400)
    p.add_argument("--vector-seconds", type=float, default=1.5, help="per vector-env setting")
    p.add_argument("--out", default="results", help="folder for speed.md and speed.json")
    args = p.parse_args(argv)
    command = command_line(argv, "python scripts/bench_speed.py")
    result: dict = {"mujoco": mujoco.__version__, "gymnasium": gym.__version__}
    for env_id, kwargs in (("Tendon2R-v0", {}), ("Reacher-v5", {})):
        env = gym.make(env_id, **kwargs)
        raw = best_of(time_raw_physics, env, args.steps)
        step = best_of(time_env_step, env, args.steps)
        result[env_id] = {
            "substeps": env.unwrapped.frame_skip,
            "raw_physics_us": 1e6 * raw,
            "env_step_us": 1e6 * step,
            "overhead_us": 1e6 * (step - raw),
            "env_steps_per_s": 1 / step,
        }
        env.close()
        print(env_id, result[env_id], flush=True)
    ours, ref = result["Tendon2R-v0"]["overhead_us"], result["Reacher-v5"]["overhead_us"]
    result["overhead_ratio"] = ours / ref
    result["vector"] = {
        f"{mode}_{n}": vector_throughput(n, mode, args.vector_seconds)
        for mode in ("sync", "async")
        for n in (1, 2, 4, 8)
    }
    print("vector", result["vector"], flush=True)
    result["ppo"] = ppo_throughput(args.ppo_timesteps)
    print("ppo", result["ppo"], flush=True)
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    result["peak_rss_mb"] = {"main_process": round(own, 1), "largest_child": round(kids, 1)}

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "speed.json").write_text(json.dumps(result, indent=1))
    t, r = result["Tendon2R-v0"], result["Reacher-v5"]
    lines = [
        "# Speed",
        "",
        f"Produced by `{command}` (one run, 2 CPU cores; best "
        "of 3 repeats; unwrapped envs, zero action).",
        "",
        "| env | substeps | raw mj_step (us) | env.step (us) | overhead (us) | steps/s |",
        "|---|---|---|---|---|---|",
        *(
            f"| {k} | {v['substeps']} | {v['raw_physics_us']:.1f} | {v['env_step_us']:.1f} | "
            f"{v['overhead_us']:.1f} | {v['env_steps_per_s']:.0f} |"
            for k, v in (("Tendon2R-v0", t), ("Reacher-v5", r))
        ),
        "",
        f"Overhead ratio Tendon2R-v0 / Reacher-v5: **{result['overhead_ratio']:.2f}** "
        f"(target <= 1: **{'met' if result['overhead_ratio'] <= 1 else 'MISSED'}**). "
        "Overhead = env.step minus the raw mj_step of the same substeps; Reacher-v5's also "
        "includes its mj_rnePostConstraint call.",
        "",
        "## gym.make_vec (env steps/s, all envs together)",
        "",
        "| envs | sync | async |",
        "|---|---|---|",
        *(
            f"| {n} | {result['vector'][f'sync_{n}']:.0f} | {result['vector'][f'async_{n}']:.0f} |"
            for n in (1, 2, 4, 8)
        ),
        "",
        "## PPO training (configs/ppo.yaml default)",
        "",
        f"{result['ppo']['env_steps_per_s']:.0f} env steps/s over {result['ppo']['timesteps']} "
        f"steps, n_envs = {result['ppo']['n_envs']}, torch threads = "
        f"{result['ppo']['torch_threads']} ({result['ppo']['note']}); target >= 2000: "
        f"**{'met' if result['ppo']['env_steps_per_s'] >= 2000 else 'MISSED'}**.",
        "",
        "## Peak memory",
        "",
        f"- PPO training, all processes together (summed PSS, shared pages counted once, "
        f"sampled every 0.5 s): {result['ppo']['peak_pss_mb_all_processes']} MB.",
        f"- Peak RSS of this benchmark's main process {result['peak_rss_mb']['main_process']} "
        f"MB; of its largest child {result['peak_rss_mb']['largest_child']} MB (RSS counts the "
        "pages that forkserver children share).",
    ]
    (out / "speed.md").write_text("\n".join(lines) + "\n")
    print("wrote", out / "speed.md")
    return result


if __name__ == "__main__":
    main()

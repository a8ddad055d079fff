"""Speed benchmark (not a test): raw physics vs env.step, against Gymnasium's Reacher-v5 in the
same run; vector envs; PPO training throughput; peak memory.

    python -m research.studies.speed   # writes research/results/speed.md and speed.json
"""

from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

import tendon2r_gym  # noqa: E402, F401
from research.studies import joints, one_or_more  # noqa: E402
from tendon2r_gym.app.args import arg, parse  # noqa: E402
from tendon2r_gym.artifacts.runs import command_line  # noqa: E402
from tendon2r_gym.envs.vector_env import ARMS_PER_THREAD  # noqa: E402

#: The single env with every effect of tendon2r_gym.simulation.realism on, and the same arm without
#: them (real_arm is the pull_only arm with real cables, motors and sensors).
REAL = "Tendon2R-v0 real_arm"
REAL_IDEAL = "Tendon2R-v0 pull_only"


def time_raw_physics(env: gym.Env, n: int) -> float:
    """Returns seconds per env step of mj_step(nstep=frame_skip) alone on the env's model, on
    the states the env steps through in ``time_env_step``: from the env's reset state
    (seed 0), with the zero action's controls (the env writes its action to ``ctrl``), for
    episodes of 500 steps.  (From a fresh MjData instead, the cables of an elastic arm start
    off their rest stretch, and the physics of other states would count as overhead.)"""
    u = env.unwrapped
    u.reset(seed=0)
    start_state, data = u.data, mujoco.MjData(u.model)
    total, steps = 0.0, 0
    while steps < n:
        mujoco.mj_copyData(data, u.model, start_state)
        data.ctrl[:] = 0.0
        start = time.perf_counter()
        for _ in range(min(500, n - steps)):
            mujoco.mj_step(u.model, data, nstep=u.frame_skip)
        total += time.perf_counter() - start
        steps += min(500, n - steps)
    return total / n


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


def _checkout_child(steps: int, num_envs: int, seconds: float) -> dict[str, float]:
    """Runs in a child whose ``tendon2r_gym`` is another checkout's: the single env's overhead
    and the native vector env's steps/s at ``num_envs`` arms, timed by this module's code."""

    env = gym.make("Tendon2R-v0")
    raw, step = time_raw_physics(env, steps), time_env_step(env, steps)
    reacher = gym.make("Reacher-v5")  # in the same process: the ratio resists machine load
    ref_overhead = time_env_step(reacher, steps) - time_raw_physics(reacher, steps)
    envs = gym.make_vec("Tendon2R-v0", num_envs=num_envs, vectorization_mode="vector_entry_point")
    envs.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = [rng.uniform(-1, 1, envs.action_space.shape) for _ in range(64)]
    count, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        envs.step(actions[count % 64])
        count += 1
    rate = count * num_envs / (time.perf_counter() - start)
    return {
        "overhead_us": 1e6 * (step - raw),
        "env_step_us": 1e6 * step,
        "reacher_overhead_us": 1e6 * ref_overhead,
        "overhead_ratio": (step - raw) / ref_overhead,
        "native_steps_per_s": rate,
    }


def compare_checkouts(
    checkouts: dict[str, str], steps: int, num_envs: int, seconds: float, repeats: int
) -> dict[str, dict[str, float]]:
    """Times each checkout (label -> source folder holding its tendon2r_gym) in fresh child
    processes, in rounds; per figure, the best of ``repeats``."""
    code = "\n".join(
        [
            "from __future__ import annotations",
            "import json, sys, time",
            "import gymnasium as gym, mujoco, numpy as np",
            "import tendon2r_gym  # the checkout under test registers the env",
            inspect.getsource(time_raw_physics),
            inspect.getsource(time_env_step),
            inspect.getsource(_checkout_child),
            f"print(json.dumps(_checkout_child({steps}, {num_envs}, {seconds})))",
        ]
    )
    best: dict[str, dict[str, float]] = {}
    for _ in range(repeats):
        for label, src in checkouts.items():
            env = {**os.environ, "PYTHONPATH": str(Path(src).resolve())}
            out = subprocess.run(
                [sys.executable, "-c", code],
                env=env,
                cwd=src,
                capture_output=True,
                text=True,
                check=True,
            ).stdout
            run = json.loads(out.strip().splitlines()[-1])
            mine = best.setdefault(label, {})
            for key, value in run.items():
                better = max if key == "native_steps_per_s" else min  # best of each figure
                mine[key] = better(mine.get(key, value), value)
            print("checkout", label, run, flush=True)
    return best


#: Vector-env backends: (name, factory(num_envs) -> object with reset/step, SB3-style?).
def _make_backend(name: str, num_envs: int) -> Any:
    if name.startswith("native"):  # native: default threads; native_<k>thread(s): k
        kwargs = {"nthread": NATIVE_THREADS[name]} if name in NATIVE_THREADS else {}
        return gym.make_vec(
            "Tendon2R-v0", num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs
        )
    if name in ("sync", "async"):
        return gym.make_vec("Tendon2R-v0", num_envs=num_envs, vectorization_mode=name)
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    cls = DummyVecEnv if name == "sb3_dummy" else SubprocVecEnv
    # The module prefix registers the env in worker processes too.
    return make_vec_env("tendon2r_gym:Tendon2R-v0", n_envs=num_envs, vec_env_cls=cls)


NATIVE_THREADS = {"native_1thread": 1, "native_2threads": 2}  # fixed MuJoCo thread counts
BACKENDS = ("native", *NATIVE_THREADS, "sync", "async", "sb3_dummy", "sb3_subproc")
PROCESS_BACKENDS = ("async", "sb3_subproc")  # one process per env


class _TimedBatch:
    """Stands in for a native env's mujoco.batch.Batch and adds up the seconds spent in its
    ``step`` (the MuJoCo physics, on the env's threads)."""

    def __init__(self, batch: Any) -> None:
        self._batch, self.seconds = batch, 0.0

    def __getattr__(self, name: str) -> Any:
        return getattr(self._batch, name)

    def step(self, *args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return self._batch.step(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - start


def vector_throughput(name: str, num_envs: int, seconds: float) -> dict[str, float]:
    """Returns env steps/s (all envs together) of a backend, random actions, autoreset on; for
    the native env also ``physics_steps_per_s``: the same steps over the seconds spent in
    MuJoCo alone, the rate no Python-side work could exceed."""
    envs = _make_backend(name, num_envs)
    sb3 = name.startswith("sb3")
    envs.reset() if sb3 else envs.reset(seed=0)
    timed = None
    if name.startswith("native"):
        timed = envs.unwrapped.batch = _TimedBatch(envs.unwrapped.batch)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (64, num_envs, envs.action_space.shape[-1])).astype(np.float32)
    for k in range(20):
        envs.step(actions[k % 64])
    if timed is not None:
        timed.seconds = 0.0
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        envs.step(actions[steps // num_envs % 64])
        steps += num_envs
    out = {"steps_per_s": steps / (time.perf_counter() - start)}
    if timed is not None:
        out["physics_steps_per_s"] = steps / timed.seconds
    envs.close()
    return out


#: What a training process cannot do without, each timed alone in a fresh process: PyPI's
#: torch (a CUDA build), and torch with one optimizer (creating one imports torch._dynamo).
FLOORS = {
    "import torch": "import torch",
    "torch + one Adam optimizer": (
        "import torch; torch.optim.Adam([torch.zeros(1, requires_grad=True)])"
    ),
    "import tendon2r_gym.training": "import tendon2r_gym.training",
}


def fresh_process_pss_mb(code: str) -> float:
    """Returns the PSS (MB) of a fresh Python process once it has run ``code``."""
    import subprocess

    wait = "\nimport sys; print('ready', flush=True); sys.stdin.read()"
    with subprocess.Popen(
        [sys.executable, "-c", code + wait], stdin=subprocess.PIPE, stdout=subprocess.PIPE
    ) as proc:
        if proc.stdout.readline().strip() != b"ready":
            raise RuntimeError(f"{code!r} failed in a fresh process")
        mb = _pss_mb([proc.pid])
        proc.communicate(b"")
    return mb


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
    """Samples the summed PSS of a process tree in a thread; ``peak_mb``."""

    def __init__(self, pid: int, period_s: float = 0.25) -> None:
        self.pid, self.period_s, self.peak_mb = pid, period_s, 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak_mb = max(self.peak_mb, _pss_mb(_descendants(self.pid)))
            self._stop.wait(self.period_s)

    def __enter__(self) -> PeakMemory:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


#: PPO set-ups compared in one run: the landed path (8 SubprocVecEnv workers x 512 steps) and
#: the native vector env with its own n_envs / n_steps from configs/ppo.yaml.
PPO_SETUPS = {
    "subproc (landed: 8 x 512)": {
        "vec_env": "subproc", "n_envs": 8, "n_steps": 512, "batch_size": 512,
    },
    "dummy (landed, one process)": {
        "vec_env": "dummy", "n_envs": 8, "n_steps": 512, "batch_size": 512,
    },
    "native (configs/ppo.yaml)": {},
}  # fmt: skip


def ppo_throughput(setup: dict[str, Any], timesteps: int, eval_freq: int) -> dict[str, Any]:
    """Trains residual PPO (configs/ppo.yaml `default`, with ``setup``) in a fresh process and
    returns its env steps/s, peak summed PSS of its process tree and its first win over PD."""
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        code = (
            "import json, sys; from research.studies.speed import _train_child; "
            "_train_child(json.loads(sys.argv[1]))"
        )
        arg = json.dumps({"setup": setup, "timesteps": timesteps, "eval_freq": eval_freq,
                          "run": tmp})  # fmt: skip
        start = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c", code, arg], stdout=subprocess.PIPE)
        with PeakMemory(proc.pid) as mem:
            out, _ = proc.communicate()
        wall = time.perf_counter() - start
        if proc.returncode != 0:
            raise RuntimeError(f"PPO child failed: {out.decode()[-2000:]}")
        summary = json.loads(out.decode().strip().splitlines()[-1])
    return {
        **summary,
        "process_wall_s": round(wall, 1),
        "env_steps_per_s_with_startup": round(summary["timesteps"] / wall, 1),
        "peak_pss_mb": round(mem.peak_mb, 1),
    }


def _train_child(spec: dict[str, Any]) -> None:
    """Runs in the child process of ppo_throughput: trains and prints the summary as JSON."""
    from tendon2r_gym.artifacts.runs import RunFolder
    from tendon2r_gym.training import Hyperparams, train_run

    hp = Hyperparams.from_entry("default")
    setup = dict(spec["setup"])
    ppo = dict(hp.ppo)
    for key in ("n_steps", "batch_size"):
        if key in setup:
            ppo[key] = setup.pop(key)
    changes = {**setup, "ppo": ppo, "total_timesteps": spec["timesteps"]}
    if spec["eval_freq"]:
        changes["eval_freq"] = spec["eval_freq"]
    hp = hp.replace(**changes)
    summary = train_run(hp, RunFolder(spec["run"]), command="bench_speed")
    keep = ("timesteps", "wall_time_s", "steps_per_s", "first_beat_pd", "best_rms_deg")
    out = {k: summary[k] for k in keep}
    out.update(
        n_envs=hp.n_envs,
        n_steps=hp.ppo["n_steps"],
        batch_size=hp.ppo["batch_size"],
        vec_env=hp.vec_env,
        eval_freq=hp.eval_freq,
    )
    print(json.dumps(out), flush=True)


def targets(result: dict[str, Any], num_envs: list[int]) -> list[str]:
    """Returns the issue's speed targets as met / MISSED lines, from one run's figures."""
    ppo = result["ppo"]
    landed, native = ppo["subproc (landed: 8 x 512)"], ppo["native (configs/ppo.yaml)"]
    speedup = native["steps_per_s"] / landed["steps_per_s"]
    lines = [
        f"- PPO training: native {native['steps_per_s']:.0f} vs landed subproc "
        f"{landed['steps_per_s']:.0f} env steps/s = **{speedup:.1f}x** (target >= 4x: "
        f"**{'met' if speedup >= 4 else 'MISSED'}**).",
        f"- Peak memory of the native training: **{native['peak_pss_mb']:.0f} MB** summed PSS "
        f"(target <= 600 MB: **{'met' if native['peak_pss_mb'] <= 600 else 'MISSED'}**; landed "
        f"subproc {landed['peak_pss_mb']:.0f} MB).",
    ]
    if result["parent_maps_torch"]:
        lines.append("  (This run's own process mapped torch: every PSS figure is understated.)")
    lines.append(
        "  Each alone, in a fresh process: "
        + "; ".join(f"{k}: {v:.0f} MB" for k, v in result["floor_pss_mb"].items())
        + "."
    )
    vec = result["vector"]
    if "native_64" in vec and "sync_64" in vec:
        native, sync = vec["native_64"], vec["sync_64"]["steps_per_s"]
        ratio = native["steps_per_s"] / sync
        # Per step of all 64 arms (us): the whole step, MuJoCo's share, and the step that 5x
        # sync allows; the rest of a step is the Python-side work.
        arms_us = 64 * 1e6
        step_us = arms_us / native["steps_per_s"]
        physics_us = arms_us / native["physics_steps_per_s"]
        allowed_us = arms_us / (5 * sync)
        lines += [
            f"- Native vector env at N = 64: **{ratio:.1f}x** gym.make_vec sync (target >= 5x: "
            f"**{'met' if ratio >= 5 else 'MISSED'}**).",
            f"  MuJoCo alone, on the native env's threads, stepped those arms at "
            f"{native['physics_steps_per_s']:.0f} steps/s = "
            f"{native['physics_steps_per_s'] / sync:.1f}x sync: the ceiling for any "
            f"Python-side work.  Per step of the 64 arms: MuJoCo {physics_us:.0f} us, the "
            f"Python-side work {step_us - physics_us:.0f} us; "
            + (
                f"5x sync leaves it {allowed_us - physics_us:.0f} us."
                if allowed_us > physics_us
                else f"5x sync allows {allowed_us:.0f} us in all, less than MuJoCo alone takes."
            ),
        ]
    beat = result["first_win"]["first_beat_pd"]
    wall = beat["wall_time_s"] if beat else None
    lines.append(
        "- Moonshot, residual PPO beats PD on `default` in under 30 s: "
        + (
            f"after **{wall} s** ({beat['timesteps']} steps): "
            f"**{'met' if wall < 30 else 'MISSED'}**."
            if beat
            else "**MISSED** (never in this run)."
        )
    )
    return lines


@dataclass
class Args:
    """The speed benchmark's flags."""

    steps: Annotated[int, arg("per single-env timing")] = 5000
    single_rounds: Annotated[
        int,
        arg("best of, per single-env timing (this machine's speed drifts by 1.5x for seconds "
            "at a time: many short rounds over all envs catch each env at full speed)"),
    ] = 15  # fmt: skip
    ppo_timesteps: Annotated[int, arg("PPO steps per training-throughput setting")] = 200_000
    eval_freq: Annotated[
        int, arg("evaluation period (steps) of the run that times the first win over PD")
    ] = 4096
    first_win_timesteps: Annotated[int, arg("PPO steps of that run")] = 49152
    vector_seconds: Annotated[float, arg("per vector-env setting")] = 1.5
    repeats: Annotated[int, arg("best of, per timing")] = 3
    num_envs: Annotated[list[int], arg("vector-env sizes N")] = field(
        default_factory=lambda: [1, 8, 16, 64, 256]
    )
    max_processes: Annotated[int, arg("largest N for async/subproc")] = 8
    out: Annotated[str, arg("folder for speed.md and speed.json")] = "research/results"
    compare: Annotated[
        list[str],
        arg("LABEL=SRC ...: also time other checkouts (a folder holding their tendon2r_gym, e.g. "
            "a git worktree) against this one, in the same run: single-env overhead and native "
            "N = 64"),
    ] = field(default_factory=list)  # fmt: skip
    only_compare: Annotated[bool, arg("skip every other measurement")] = False


def main(argv: list[str] | None = None) -> dict:
    args = parse(Args, argv, __doc__)
    one_or_more("--num-envs", args.num_envs, "one or more vector-env sizes")
    if args.compare or args.only_compare:
        here = str(Path(__file__).resolve().parents[2])
        checkouts = dict(item.split("=", 1) for item in args.compare)
        checkouts["this checkout"] = here
        cmp = compare_checkouts(checkouts, args.steps, 64, args.vector_seconds, args.repeats)
        lines = [
            "| checkout | env.step (us) | overhead (us) | Reacher-v5 overhead (us) | ratio | "
            "native N = 64 (steps/s) |",
            "|---|---|---|---|---|---|",
            *(
                f"| {k} | {v['env_step_us']:.1f} | {v['overhead_us']:.1f} | "
                f"{v['reacher_overhead_us']:.1f} | {v['overhead_ratio']:.2f} | "
                f"{v['native_steps_per_s']:.0f} |"
                for k, v in cmp.items()
            ),
            "",
            "Overhead: env.step minus the raw mj_step of its substeps; ratio: ours over "
            "Reacher-v5's, measured in the same child process (best of each).",
        ]
        print("\n".join(lines), flush=True)
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        command = command_line(argv, "python -m research.studies.speed")
        (out / "speed_compare.json").write_text(json.dumps({"command": command, **cmp}, indent=1))
        (out / "speed_compare.md").write_text(
            f"# Speed of checkouts\n\nProduced by `{command}` (best of {args.repeats}, "
            "taken in rounds, each in a fresh process).\n\n" + "\n".join(lines) + "\n"
        )
        if args.only_compare:
            return cmp
    command = command_line(argv, "python -m research.studies.speed")
    result: dict = {"mujoco": mujoco.__version__, "gymnasium": gym.__version__}
    # Every timing is the best of --repeats, taken in rounds over all the settings, so that a
    # burst of load from elsewhere costs one repeat of each setting, not every repeat of one.
    envs = {env_id: gym.make(env_id) for env_id in ("Tendon2R-v0", "Reacher-v5")}
    envs[REAL] = gym.make("Tendon2R-v0", preset="real_arm")  # every realism effect on
    envs[REAL_IDEAL] = gym.make("Tendon2R-v0", preset="pull_only")  # the same arm, ideal
    raw: dict[str, float] = {}
    step: dict[str, float] = {}
    for _ in range(args.single_rounds):
        for env_id, env in envs.items():
            raw[env_id] = min(raw.get(env_id, np.inf), time_raw_physics(env, args.steps))
            step[env_id] = min(step.get(env_id, np.inf), time_env_step(env, args.steps))
    for env_id, env in envs.items():
        result[env_id] = {
            "substeps": env.unwrapped.frame_skip,
            "raw_physics_us": 1e6 * raw[env_id],
            "env_step_us": 1e6 * step[env_id],
            "overhead_us": 1e6 * (step[env_id] - raw[env_id]),
            "env_steps_per_s": 1 / step[env_id],
        }
        env.close()
        print(env_id, result[env_id], flush=True)
    ours, ref = result["Tendon2R-v0"]["overhead_us"], result["Reacher-v5"]["overhead_us"]
    result["overhead_ratio"] = ours / ref
    result["realism_overhead_ratio"] = result[REAL]["overhead_us"] / ours
    result["realism_same_arm_ratio"] = (
        result[REAL]["overhead_us"] / result[REAL_IDEAL]["overhead_us"]
    )
    # Memory first, while this process maps no torch: PSS splits a shared page among every
    # process that maps it, so a parent holding torch would halve the children's figures.
    result["parent_maps_torch"] = "torch" in sys.modules  # True only when run inside pytest
    result["floor_pss_mb"] = {k: fresh_process_pss_mb(c) for k, c in FLOORS.items()}
    print("floors, PSS (MB)", result["floor_pss_mb"], flush=True)
    result["ppo"] = {}
    for label, setup in PPO_SETUPS.items():  # each with its entry's evaluation period
        result["ppo"][label] = ppo_throughput(setup, args.ppo_timesteps, 0)
        print("ppo", label, result["ppo"][label], flush=True)
    # Time to beat PD: the native set-up again, evaluated every --eval-freq steps.
    result["first_win"] = ppo_throughput({}, args.first_win_timesteps, args.eval_freq)
    print("first win", result["first_win"], flush=True)
    vec: dict[str, dict[str, float]] = {}
    for _ in range(args.repeats):  # in rounds, as above
        for name in BACKENDS:
            for n in args.num_envs:
                if name in PROCESS_BACKENDS and n > args.max_processes:
                    continue  # one process per env: N processes on 2 cores
                run, key = vector_throughput(name, n, args.vector_seconds), f"{name}_{n}"
                if key not in vec or run["steps_per_s"] > vec[key]["steps_per_s"]:
                    vec[key] = run
                print(name, n, run, flush=True)
    result["vector"] = vec

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "speed.json").write_text(json.dumps(result, indent=1))
    t, r = result["Tendon2R-v0"], result["Reacher-v5"]
    lines = [
        "# Speed",
        "",
        f"Produced by `{command}` (one run, 2 CPU cores; single envs: best of "
        f"{args.single_rounds} rounds of {args.steps} steps; other timings: best of "
        f"{args.repeats} repeats; taken in rounds over all settings; unwrapped envs, zero "
        "action; raw physics on the states the env steps through).",
        "",
        "| env | substeps | raw mj_step (us) | env.step (us) | overhead (us) | steps/s |",
        "|---|---|---|---|---|---|",
        *(
            f"| {k} | {v['substeps']} | {v['raw_physics_us']:.1f} | {v['env_step_us']:.1f} | "
            f"{v['overhead_us']:.1f} | {v['env_steps_per_s']:.0f} |"
            for k, v in (
                ("Tendon2R-v0", t),
                (REAL, result[REAL]),
                (REAL_IDEAL, result[REAL_IDEAL]),
                ("Reacher-v5", r),
            )
        ),
        "",
        f"Overhead with every realism effect on ({REAL}) / the ideal env's: "
        f"**{result['realism_overhead_ratio']:.2f}** (target <= 1.5: "
        f"**{'met' if result['realism_overhead_ratio'] <= 1.5 else 'MISSED'}**); its raw "
        "physics also steps the spools' degrees of freedom. Against the same arm without the "
        f"effects ({REAL_IDEAL}, three cables): **{result['realism_same_arm_ratio']:.2f}**.",
        "",
        f"Overhead ratio Tendon2R-v0 / Reacher-v5: **{result['overhead_ratio']:.2f}** "
        f"(target <= 1: **{'met' if result['overhead_ratio'] <= 1 else 'MISSED'}**). "
        "Overhead = env.step minus the raw mj_step of the same substeps; Reacher-v5's also "
        "includes its mj_rnePostConstraint call.",
        "",
        "## Vector envs (env steps/s, all envs together, random actions, autoreset; best of "
        f"{args.repeats} runs of {args.vector_seconds} s)",
        "",
        '`native` is gym.make_vec(..., vectorization_mode="vector_entry_point") '
        "(tendon2r_gym.envs.vector_env: mujoco.batch, one process); `sync` / `async` are "
        "Gymnasium's, `sb3_dummy` / `sb3_subproc` SB3's.  Process-based backends run only "
        f"up to N = {args.max_processes} (one process per env on 2 cores).  `native` uses its "
        f"default MuJoCo threads (one per {ARMS_PER_THREAD} arms, up to the CPUs), "
        "`native_1thread` / `native_2threads` one / two; "
        "`native, MuJoCo alone` divides native's steps by the seconds spent inside "
        "mujoco.batch's step.",
        "",
        "| N | " + " | ".join(BACKENDS) + " | native, MuJoCo alone |",
        "|---|" + "---|" * (len(BACKENDS) + 1),
        *(
            f"| {n} | "
            + " | ".join(
                f"{result['vector'][f'{b}_{n}']['steps_per_s']:.0f}"
                if f"{b}_{n}" in result["vector"]
                else "-"
                for b in BACKENDS
            )
            + f" | {result['vector'][f'native_{n}']['physics_steps_per_s']:.0f} |"
            for n in args.num_envs
        ),
        "",
        "## PPO training (residual PPO, configs/ppo.yaml `default`, each in a fresh process)",
        "",
        f"{args.ppo_timesteps} steps each, evaluated every `eval_freq` steps of the entry.",
        "",
        "| set-up | n_envs x n_steps, batch | env steps/s (training) | env steps/s (with "
        "start-up) | peak PSS, whole process tree (MB) | best RMS A / B (deg) |",
        "|---|---|---|---|---|---|",
        *(
            f"| {label} | {r['n_envs']} x {r['n_steps']}, {r['batch_size']} | "
            f"{r['steps_per_s']:.0f} | {r['env_steps_per_s_with_startup']:.0f} | "
            f"{r['peak_pss_mb']:.0f} | {joints(r['best_rms_deg'], 4)} |"
            for label, r in result["ppo"].items()
        ),
        "",
        "Targets, from this run:",
        "",
        *targets(result, args.num_envs),
        "",
        "The first win over PD comes from a separate native run of "
        f"{args.first_win_timesteps} steps evaluated every {args.eval_freq} steps (on the eval "
        "seeds): the first evaluation whose RMS is <= PD's on both joints. Its wall time counts "
        "the evaluations themselves.",
    ]
    (out / "speed.md").write_text("\n".join(lines) + "\n")
    print("wrote", out / "speed.md")
    return result


if __name__ == "__main__":
    main()

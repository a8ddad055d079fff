"""Console commands (``[project.scripts]``): each is a typed Args dataclass, parsed one way
(tendon2r_gym.app.args).

    tendon2r-train      train PPO (one run, or one per seed), resume, bundle
    tendon2r-evaluate   RMS / max tracking error of PD, CT or PPO, plots and video
    tendon2r-benchmark  PD vs CT vs PPO table; on your own arm with --env-config
    tendon2r-tune-pd    PD's bandwidth for your arm (a lagging one needs lower gains)

The model tools (tendon2r-view, tendon2r-export, tendon2r-bundle) are tendon2r_gym.app.tools.
Ctrl-C during a command exits with code 130 after saving what it was doing.
"""

from __future__ import annotations

import json
import sys
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

from tendon2r_gym.app.args import arg, env_help, parse, run
from tendon2r_gym.artifacts.files import TRUST_HELP, trusting_pickle
from tendon2r_gym.evaluation.evaluator import names as policy_names
from tendon2r_gym.evaluation.tuning import SCANS
from tendon2r_gym.training.hyperparams import VEC_ENVS

if typing.TYPE_CHECKING:
    from tendon2r_gym.training import Experiment

VecEnvName = Literal[VEC_ENVS]  # type: ignore[valid-type]
ScanName = Literal[SCANS]  # type: ignore[valid-type]


# -- tendon2r-train ------------------------------------------------------------------------------
@dataclass
class TrainArgs:
    """Train SB3 PPO on Tendon2R-v0 with an entry of configs/ppo.yaml.

    tendon2r-train --hyperparams default --seeds 0 1 2 --bundle default
    tendon2r-train --env-config my_arm.yaml --hyperparams default_scratch
    tendon2r-train --run-dir runs/default --resume      # after Ctrl-C or a crash
    tendon2r-train --env-config my_arm.yaml --init-from generalist --total-timesteps 300000

    --resume continues the run recorded in --run-dir: its config.yaml (budget and overrides
    included) with only this command's override flags on top; --hyperparams, --config and
    --env-config choose the hyperparameters of a new run only.

    --bundle NAME copies the finished runs into the bundled models as tendon2r-bundle does; the
    name is checked before training starts, and a bundle of that name is replaced only with
    --replace-bundle.

    --workers N trains N seeds at once in local processes; --cluster auto (or HOST:PORT) on a
    Ray cluster (the cluster extra).  Each seed's run is the same on every executor.
    """

    hyperparams: Annotated[str, arg("entry of the hyperparameter file (a new run)")] = "default"
    config: Annotated[str | None, arg("hyperparameter file (default: configs/ppo.yaml)")] = None
    env_config: Annotated[str | None, env_help("preset", "the env to train on")] = None
    total_timesteps: Annotated[int | None, arg("overrides the entry (or the resumed run)")] = None
    n_envs: Annotated[int | None, arg("overrides the entry (or the resumed run)")] = None
    vec_env: Annotated[VecEnvName | None, arg("overrides the entry (or the resumed run)")] = None
    seeds: Annotated[
        list[int] | None, arg("one run folder per seed (default 0, or the resumed ones)")
    ] = None
    run_dir: Annotated[str | None, arg("default runs/<hyperparams>; seeds go in seed_<n>/")] = None
    resume: Annotated[bool, arg("continue the recorded run from its newest readable state")] = False
    bundle: Annotated[
        str | None, arg("copy the best models into the bundled models under NAME")
    ] = None
    replace_bundle: Annotated[bool, arg("with --bundle: replace the bundle of that name")] = False
    init_from: Annotated[
        str | None, arg("start from a bundle's (or model zip's) weights: fine-tune")
    ] = None
    progress_bar: Annotated[bool, arg("also on whenever stderr is a terminal")] = False
    workers: Annotated[
        int, arg("train this many seeds at once in local worker processes (1: in this one)")
    ] = 1
    cluster: Annotated[
        str | None,
        arg("train the seeds on a Ray cluster: auto (ray start's, or RAY_ADDRESS) or HOST:PORT"),
    ] = None
    trust_pickle: Annotated[bool, arg(TRUST_HELP)] = False


def experiment(args: TrainArgs, command: str = "") -> Experiment:
    """Returns the experiment of a train command: a new one from the entry, or the recorded
    one under --run-dir with --resume."""
    from tendon2r_gym.presets import PPO_CONFIG
    from tendon2r_gym.training import Experiment, Hyperparams

    base = Path(args.run_dir or f"runs/{args.hyperparams}")
    overrides = {
        k: getattr(args, k)
        for k in ("total_timesteps", "n_envs", "vec_env", "init_from")
        if getattr(args, k) is not None
    }
    progress = args.progress_bar or sys.stderr.isatty()
    if args.resume:  # a folder without a run is refused, naming it
        return Experiment.resume(base, args.seeds, command, progress, **overrides)
    hp = Hyperparams.from_entry(args.hyperparams, args.config or PPO_CONFIG, args.env_config)
    if overrides:
        hp = hp.replace(**overrides)
    return Experiment(hp, base, args.seeds or [0], command, progress)


def train_main(argv: list[str] | None = None) -> dict[str, Any]:
    from tendon2r_gym.artifacts.bundle import bundle_runs, check_destination
    from tendon2r_gym.artifacts.runs import command_line

    args = parse(TrainArgs, argv)
    if args.bundle is not None:  # refused before training, not after it
        check_destination(args.bundle, args.replace_bundle, field="--bundle",
                          flag="--replace-bundle")  # fmt: skip
    command = command_line(argv, "tendon2r-train")
    exp = experiment(args, command)
    from tendon2r_gym.training.executors import entered, make_executor
    from tendon2r_gym.training.jobs import train_experiment

    # --trust-pickle: --init-from, or --resume of an earlier version's run; a cluster that
    # cannot be reached, or has no CPU to give, is refused here, before training
    executor = make_executor(args.workers, args.cluster, exp.hyperparams.torch_threads)
    with trusting_pickle(args.trust_pickle), entered(executor) as ex:
        agg = train_experiment(exp, args.resume, ex)
    print(json.dumps({k: v for k, v in agg.items() if k != "runs"}), flush=True)
    if args.bundle is not None:
        runs = [exp.run_folder(s).path for s in exp.seeds]
        dest = bundle_runs(runs, args.bundle, command, replace=args.replace_bundle,
                           trust_pickle=args.trust_pickle)  # fmt: skip
        print("bundled into", dest, flush=True)
    return agg


# -- tendon2r-evaluate ---------------------------------------------------------------------------
@dataclass
class EvaluateArgs:
    """Evaluate a policy on Tendon2R-v0: RMS / max tracking error, forces and saturation.

    tendon2r-evaluate --policy pd --env-config default --episodes 3 --json out.json
    tendon2r-evaluate --policy ppo                        # the bundled model of the preset
    tendon2r-evaluate --policy ct --env-config my_arm.yaml --plots figs --video run.mp4
    """

    policy: Annotated[str, arg(f"policy to run: one of {policy_names()} (the registry's)")] = "pd"
    model: Annotated[
        str | None, arg("PPO model zip (default: the bundle named like the preset)")
    ] = None
    bundle: Annotated[str | None, arg("bundled PPO to use instead of --model")] = None
    env_config: Annotated[str, env_help("preset")] = "default"
    episodes: Annotated[int, arg("episodes, seeds seed .. seed + episodes - 1")] = 3
    seed: Annotated[int, arg("first episode seed")] = 0
    episode_duration: Annotated[
        float | None, env_help("episode_duration", "overrides the env config")
    ] = None
    json: Annotated[str | None, arg("write all metrics here")] = None
    plots: Annotated[str | None, arg("folder for the PNGs of the first episode")] = None
    video: Annotated[str | None, arg("mp4 or gif of the first episode")] = None
    trust_pickle: Annotated[bool, arg(TRUST_HELP)] = False


def evaluate_main(argv: list[str] | None = None) -> dict[str, Any]:

    import tendon2r_gym  # noqa: F401  (registers Tendon2R-v0)
    from tendon2r_gym.envs.env_config import resolve
    from tendon2r_gym.evaluation.evaluator import evaluate, make_policy, resolve_model
    from tendon2r_gym.evaluation.rollout import rollout
    from tendon2r_gym.validation import choice, integer

    args = parse(EvaluateArgs, argv)
    choice("--policy", args.policy, policy_names())  # the registry's names, now
    integer("--episodes", args.episodes, 1, 10**6)
    env_kwargs: dict[str, Any] = {"preset": args.env_config}
    if args.episode_duration is not None:
        env_kwargs["episode_duration"] = args.episode_duration
    model = resolve_model(args.policy, args.model, args.bundle, env_kwargs)
    if model is not None:  # a model runs in the settings it trained in (e.g. its action mode)
        from tendon2r_gym.artifacts.model_env import in_model_settings

        env_kwargs = in_model_settings(model, env_kwargs)
    seeds = list(range(args.seed, args.seed + args.episodes))
    config = resolve(env_kwargs)  # once: the evaluation and the video
    with trusting_pickle(args.trust_pickle):  # --model of an earlier version
        metrics, traces = evaluate(args.policy, config, seeds, model)
    metrics["env_kwargs"], metrics["model"] = env_kwargs, None if model is None else str(model)
    keys = ("policy", "rms_deg", "max_deg", "rms_tension_N", "saturated_fraction", "steps")
    print(json.dumps({k: metrics[k] for k in keys}))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(metrics, indent=1))
    title = f"{args.policy.upper()} on {Path(args.env_config).stem}"
    if args.plots or args.video:  # the plots extra
        from tendon2r_gym.app.plots import plot_trace, save_video
    if args.plots:
        for path in plot_trace(traces[0], args.plots, title):
            print("wrote", path)
    if args.video:
        from tendon2r_gym.envs.registration import make as make_env_as_given

        env = make_env_as_given(preset=config, render_mode="rgb_array", width=480, height=360)
        with trusting_pickle(args.trust_pickle):
            trace = rollout(make_policy(args.policy, env, model), env, seeds[0], render=True)
        every = max(1, round(1 / 30 / env.unwrapped.ctrl_dt))  # ~30 fps of real time
        print("wrote", save_video(trace.frames[::every], args.video, fps=30))
        env.close()
    return metrics


# -- tendon2r-benchmark --------------------------------------------------------------------------
@dataclass
class BenchmarkArgs:
    """PD vs computed torque vs PPO (from scratch and residual) on the same seeds.

    tendon2r-benchmark                                   # bundled presets -> results/
    tendon2r-benchmark --env-config my_arm.yaml --train-steps 300000 --seeds 0 1 2 --out DIR
    tendon2r-benchmark --env-config my_arm_identified.yaml --no-train --out DIR
    tendon2r-benchmark --env-config my_arm.yaml --seeds 0 1 2 3 4 5 6 7 8 9 --workers 2

    With --env-config, --workers N trains N of a row's seeds at once in local processes, and
    --cluster auto (or HOST:PORT) on a Ray cluster (the cluster extra), as tendon2r-train does;
    each seed's run is the same on every executor.  A learned row of several seeds records, in
    benchmark.json, its per-joint IQM with a 95% bootstrap interval, mean +- std and its
    probability of beating PD (tendon2r_gym.evaluation.statistics).
    """

    env_config: Annotated[
        str | None, env_help("preset", "your arm: train PPO on it, then compare")
    ] = None
    train_steps: Annotated[int | None, arg("PPO steps per run (default: the entries' own)")] = None
    seeds: Annotated[list[int], arg("PPO training seeds (with --env-config)")] = field(
        default_factory=lambda: [0]
    )
    episodes: Annotated[int, arg("evaluation episodes per policy (seeds 0 ..)")] = 3
    out: Annotated[str, arg("folder for benchmark.md, benchmark.json and plots/")] = "results"
    run_dir: Annotated[str | None, arg("training runs (default runs/<env-config name>)")] = None
    train: Annotated[
        bool, arg("with --env-config: train PPO on the arm (--no-train: PD, CT, zero-shot rows)")
    ] = True
    workers: Annotated[
        int, arg("with --env-config: train this many seeds at once in local worker processes")
    ] = 1
    cluster: Annotated[
        str | None,
        arg("with --env-config: train the seeds on a Ray cluster: auto or HOST:PORT"),
    ] = None


def benchmark_main(argv: list[str] | None = None) -> dict[str, Any]:
    from tendon2r_gym.app.benchmark import benchmark_bundled, benchmark_own_arm
    from tendon2r_gym.artifacts.runs import command_line
    from tendon2r_gym.validation import integer, invalid

    args = parse(BenchmarkArgs, argv)
    integer("--episodes", args.episodes, 1, 10**6)
    if args.train_steps is not None:
        integer("--train-steps", args.train_steps, 1, 10**10)
    command = command_line(argv, "tendon2r-benchmark")
    if args.env_config is None and not args.train:
        raise invalid("--no-train", True, "only with --env-config (the bundled one trains nothing)")
    if args.env_config is None:
        if args.workers != 1:
            raise invalid("--workers", args.workers, "1 without --env-config (the bundled "
                          "benchmark trains nothing)")  # fmt: skip
        if args.cluster is not None:
            raise invalid("--cluster", args.cluster, "only with --env-config (the bundled "
                          "benchmark trains nothing)")  # fmt: skip
        return benchmark_bundled(args.episodes, Path(args.out), command)
    return benchmark_own_arm(
        args.env_config,
        args.train_steps,
        args.seeds,
        args.episodes,
        Path(args.out),
        Path(args.run_dir or f"runs/{Path(args.env_config).stem}"),
        command,
        None if args.train else [],
        args.workers,
        args.cluster,
    )


# -- tendon2r-tune-pd ----------------------------------------------------------------------------
@dataclass
class TunePDArgs:
    """Scan PD's closed-loop bandwidth on held-out episodes of your arm and keep the best one
    with a gain margin (tendon2r_gym.evaluation.tuning); write your experiment file with its
    pd_gains.

    tendon2r-tune-pd --env-config my_arm.yaml --out my_arm_tuned.yaml
    tendon2r-evaluate --policy pd --env-config my_arm_tuned.yaml
    tendon2r-tune-pd --hyperparams real_arm --episodes 16 --scan max_delay_phase
    tendon2r-tune-pd --hyperparams generalist_real --episodes 32 --workers 2

    --workers N rolls N grid points out at once in local processes; --cluster auto (or
    HOST:PORT) on a Ray cluster (the cluster extra).  The scan is the same on every executor.
    """

    env_config: Annotated[str, env_help("preset")] = "default"
    hyperparams: Annotated[str | None, arg("tune on this ppo.yaml entry's env instead")] = None
    episodes: Annotated[
        int, arg("tuning episodes (seeds 1000 ..; more for an env that draws arms)")
    ] = 3
    out: Annotated[str | None, arg("write the experiment file with the tuned pd_gains here")] = None
    scan: Annotated[
        ScanName,
        arg("the gain to scan (max_delay_phase: gains scheduled on each arm's loop delay)"),
    ] = "bandwidth_hz"
    workers: Annotated[
        int, arg("roll this many grid points out at once in local worker processes")
    ] = 1
    cluster: Annotated[
        str | None,
        arg(
            "roll the grid points out on a Ray cluster: auto (ray start's, or RAY_ADDRESS) or "
            "HOST:PORT"
        ),
    ] = None


def tune_pd_main(argv: list[str] | None = None) -> dict[str, Any]:
    import yaml

    from tendon2r_gym.artifacts.runs import command_line
    from tendon2r_gym.evaluation.tuning import tune_pd
    from tendon2r_gym.presets import PPO_CONFIG, load_yaml, preset_path
    from tendon2r_gym.training import Hyperparams
    from tendon2r_gym.training.executors import entered, make_executor
    from tendon2r_gym.validation import integer

    args = parse(TunePDArgs, argv)
    integer("--episodes", args.episodes, 1, 10**4)
    env_kwargs: dict[str, Any] = {"preset": args.env_config}
    if args.hyperparams is not None:
        env_kwargs = Hyperparams.from_entry(args.hyperparams, PPO_CONFIG).env_kwargs
    # --workers and --cluster checked, and a cluster that cannot be reached refused, first
    executor = make_executor(args.workers, args.cluster, 1)
    with entered(executor) as ex:
        scan = tune_pd(env_kwargs, args.episodes, args.scan, ex)
    print("\n".join(scan.lines()))
    result = {"pd_gains": scan.gains.to_dict(), "scan": scan.field, "values": list(scan.values),
              "worst_deg": [list(w) for w in scan.worst_deg]}  # fmt: skip
    if args.out:
        data = {**load_yaml(preset_path(args.env_config)), "pd_gains": scan.gains.to_dict()}
        header = f"# {command_line(argv, 'tendon2r-tune-pd')}: pd_gains tuned\n"
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(header + yaml.safe_dump(data, sort_keys=False))
        print("wrote", args.out)
    return result


train = run(train_main)
evaluate = run(evaluate_main)
benchmark = run(benchmark_main)
tune_pd = run(tune_pd_main)

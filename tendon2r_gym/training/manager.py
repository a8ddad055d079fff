"""The run owner (rl_zoo3's ExperimentManager): one training command, its seeds and folders.

``Experiment`` trains one run per seed in ``base/seed_<n>/`` (names from
tendon2r_gym.artifacts.runs) and survives interruption:
- Ctrl-C (or SIGTERM) stops training at the next env step (StopOnSignal), saves
  ``last_model`` and the summary, then raises KeyboardInterrupt, so a multi-seed command stops
  as a whole (exit code 130) after writing the summary of the seeds that finished;
- checkpoints are taken every ``checkpoint_freq`` steps and every ``checkpoint_minutes``;
- ``Experiment.resume`` continues the run that was started: the hyperparameters recorded
  in its folder (budget and overrides included), never the entry's current defaults, from the
  newest readable saved state (a corrupt one is skipped with a warning);
- a new run never overwrites one that was started: without ``resume``, a folder that holds a
  run is refused (rl_zoo3 numbers its folders instead; here ``--run-dir`` names the run);
- a command that can be run again (the own-arm benchmark, the studies) trains through
  ``Experiment.start_or_continue``: its runs continue as they were recorded, and runs of
  other hyperparameters in its folder are refused;
- ``summary.json`` adds up steps and wall time over every segment, recorded at each
  checkpoint too (a killed segment counts up to its last checkpoint), and command.txt keeps
  the original command with one line per resume;
- a run is checked before anything is written (``plan_run``): a refused start leaves its
  folder as it was;
- a folder in training is held by its process (records.training_lock): a second command on it
  (a --resume while it trains) is refused, not run beside it;
- a run folder that cannot be written (read-only, a full disk) stops training with one
  ``RunWriteError`` line, after keeping the last state it can.
"""

from __future__ import annotations

import contextlib
import json
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym

from tendon2r_gym.artifacts.runs import (
    BEST_METRICS,
    CONFIG,
    EVALUATIONS,
    PD_EVAL,
    RUN_META,
    SEEDS_SUMMARY,
    SUMMARY,
    RunFolder,
    seed_dir,
    seed_dirs,
)
from tendon2r_gym.envs.env_config import EnvConfig, resolve
from tendon2r_gym.envs.registration import make as make_env
from tendon2r_gym.policies.residual import NO_RESIDUAL, Residual, ResidualPDWrapper
from tendon2r_gym.training.callbacks import (
    StopOnSignal,
    TimedCheckpointCallback,
    TrackingEvalCallback,
    TrackingLogCallback,
    quiet_writer_threads,
    save_model,
)
from tendon2r_gym.training.frame_stack import stacked
from tendon2r_gym.training.hyperparams import Hyperparams
from tendon2r_gym.training.init_from import fine_tune, initial_model, load_initial
from tendon2r_gym.training.records import (
    RunWriteError,
    Segment,
    attempt_write,
    is_write_error,
    seeds_summary,
    training_lock,
    write_failure,
)
from tendon2r_gym.validation import integer, invalid


@dataclass
class Experiment:
    """One training command: hyperparameters, the seeds, their base folder, the command."""

    hyperparams: Hyperparams
    base: Path
    seeds: list[int]
    command: str = ""
    progress_bar: bool = False

    @classmethod
    def resume(
        cls,
        base: str | Path,
        seeds: list[int] | None = None,
        command: str = "",
        progress_bar: bool = False,
        **overrides: Any,
    ) -> Experiment:
        """Returns the experiment recorded in ``base``: the hyperparameters of its seed
        folders' config.yaml, with only the ``overrides`` given now on top (its seeds, unless
        ``seeds``)."""
        recorded = seed_dirs(base)
        if not recorded:
            raise invalid(
                "run_dir",
                str(base),
                "a folder that holds a run to resume (seed_<n>/config.yaml); it holds none: "
                "without --resume, the command starts a new run there",
            )
        hp = recorded_hyperparams(RunFolder(recorded[0]))
        if overrides:
            hp = hp.replace(**overrides)
        seeds = seeds if seeds is not None else [RunFolder(p).seed for p in recorded]
        return cls(hp, Path(base), list(seeds), command, progress_bar)

    @classmethod
    def start_or_continue(
        cls, hp: Hyperparams, base: str | Path, seeds: list[int], command: str = ""
    ) -> Experiment:
        """Returns the experiment of a command that can be run again (the own-arm benchmark,
        the studies) to train ``hp`` in ``base``, for ``train(resume=True)``: where runs were
        started there, with their recorded hyperparameters (a fine-tune's include what it took
        from its source model) and ``hp``'s budget.  Runs started with other hyperparameters
        (another entry, or a fine-tune of another source) are refused, naming the folder and
        the fields: they are not this command's to continue or report."""
        recorded = seed_dirs(base)
        if not recorded:
            return cls(hp, Path(base), list(seeds), command)
        new = fine_tune(hp).to_dict()
        for path in recorded:
            old = recorded_hyperparams(RunFolder(path)).to_dict()
            if differ := sorted(k for k in new if k != "total_timesteps" and new[k] != old.get(k)):
                raise invalid(
                    "run_dir",
                    str(base),
                    f"a folder without runs of other hyperparameters ({path} differs in "
                    f"{differ}: remove it, or use another run folder)",
                )
        return cls.resume(base, list(seeds), command, total_timesteps=hp.total_timesteps)

    def run_folder(self, seed: int) -> RunFolder:
        return RunFolder(seed_dir(self.base, seed))

    def train(self, resume: bool = False) -> dict[str, Any]:
        """Trains one run per seed in this process, one after another (continuing those with a
        saved state if ``resume``) and writes SEEDS_SUMMARY.  Every seed's run is checked
        before any is written (``plan``).  A Ctrl-C stops them all: the summary of the
        finished seeds is written, then it re-raises.  (Local workers or a Ray cluster train
        the seeds at once: tendon2r_gym.training.jobs.train_experiment.)"""
        plans = self.plan(resume)
        results: list[dict[str, Any]] = []
        # the seed folders that exist are held before anything is written; a new one from the
        # start of its training (a seed that never starts leaves no folder)
        held = {plan.run.path for plan in plans if plan.run.path.is_dir()}
        with (
            training_lock([plan.run for plan in plans if plan.run.path in held]),
            contextlib.ExitStack() as new,
        ):
            try:
                for plan in plans:
                    if plan.run.path not in held:
                        new.enter_context(training_lock([plan.run]))
                    results.append(train_planned(plan, self.command, self.progress_bar))
            except BaseException:
                self.record_seeds(results, failing=True)
                raise
        return self.record_seeds(results)

    def plan(self, resume: bool = False) -> list[RunPlan]:
        """Returns the plan of every seed's run, each checked before anything is written: the
        seeds (distinct, each one numpy takes), a folder that holds a run refused unless
        ``resume``, and all that each run reads (``plan_run``)."""
        check_seeds(self.seeds)
        runs = [self.run_folder(seed) for seed in self.seeds]
        started = [str(run.path) for run in runs if run.read_config() is not None]
        if not resume and started:
            raise invalid(
                "run_dir",
                str(self.base),
                f"a folder without runs (it holds {started}: --resume continues them; a new "
                "run needs another --run-dir)",
            )
        return [
            plan_run(self.hyperparams, run, seed, resume and bool(run.checkpoint_candidates()))
            for seed, run in zip(self.seeds, runs, strict=True)
        ]

    def record_seeds(self, results: list[dict[str, Any]], failing: bool = False) -> dict:
        """Writes and returns SEEDS_SUMMARY of the finished seeds' summaries ``results``.  While
        an error is in flight (``failing``), a failed write is ignored: that error is the one
        to report."""
        agg = seeds_summary(self.seeds, results)
        try:
            RunFolder(self.base).write_json(SEEDS_SUMMARY, agg)
        except OSError as e:
            if failing:
                return agg
            raise RunWriteError(
                f"writing {self.base / SEEDS_SUMMARY} failed ({e}); the runs are saved in "
                "their seed folders"
            ) from e
        return agg


def check_seeds(seeds: list[int]) -> list[int]:
    """Returns ``seeds`` if each is a seed numpy takes and none repeats (one folder each)."""
    for seed in seeds:
        integer("seeds", seed, 0, 2**32 - 1)
    if len(set(seeds)) != len(seeds):
        raise invalid("seeds", list(seeds), "distinct seeds (one run folder each)")
    return list(seeds)


def recorded_hyperparams(run: RunFolder) -> Hyperparams:
    """Returns the hyperparameters a run was started with (its config.yaml)."""
    values = run.read_config()  # a mapping, or a ValueError naming the file
    if values is None:
        raise invalid("run folder", str(run.path), f"a run folder with a {CONFIG}")
    values.pop("seed", None)  # older runs recorded it there (run.json has it)
    try:
        return Hyperparams.from_dict(values, CONFIG)
    except ValueError as e:  # edited, or naming a file that moved (an experiment file)
        raise ValueError(
            f"{run.file(CONFIG)}: its hyperparameters are invalid ({e}); to recover: put back a "
            "file they name that moved (env_kwargs.preset), or restore it from a copy (a bundle "
            "keeps one)"
        ) from None


# -- one run -----------------------------------------------------------------------------------
def make_training_env(
    env_kwargs: EnvConfig | Mapping[str, Any], residual: Residual = NO_RESIDUAL
) -> gym.Env:
    """Returns Tendon2R-v0 of ``env_kwargs`` (an EnvConfig, or env kwargs: resolved once),
    wrapped for residual learning if ``residual`` is active."""
    env = make_env(preset=resolve(env_kwargs))
    if not residual.active:
        return env
    return ResidualPDWrapper(env, **residual.to_record())


def make_vec_env(hp: Hyperparams, seed: int) -> Any:
    """Returns the training VecEnv: the native vector env (one process, batched physics and PD)
    with SB3's VecMonitor, or SB3's make_vec_env with Subproc/Dummy."""
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if hp.vec_env == "native":
        from tendon2r_gym.training.vector_env_sb3 import make_native

        return make_native(hp.n_envs, hp.env_config, hp.residual, seed)
    subproc = hp.vec_env == "subproc" and hp.n_envs > 1
    return sb3_make_vec_env(
        make_training_env,
        n_envs=hp.n_envs,
        seed=seed,
        env_kwargs={"env_kwargs": hp.env_config, "residual": hp.residual},
        vec_env_cls=SubprocVecEnv if subproc else DummyVecEnv,
    )


def _load_newest(run: RunFolder, venv: Any, hp: Hyperparams) -> tuple[Any, Any]:
    """Returns (PPO, VecNormalize) from the newest readable saved state of the run, read
    without unpickling (files.load_ppo; an earlier version's pickled statistics only with
    the trust option, else the error names it); a corrupt one is skipped with a warning."""
    from tendon2r_gym.artifacts.files import PickleRefused, load_ppo, load_vecnormalize

    candidates = run.checkpoint_candidates()
    if not candidates:
        raise FileNotFoundError(f"resume: no last_model or checkpoint in {run.path}")
    for zip_path, stats in candidates:
        try:
            vecnorm = load_vecnormalize(stats, venv)
            env = stacked(vecnorm, hp.frame_stack, hp.frame_stride)
            model = load_ppo(zip_path, env, hp.ppo_kwargs(), tensorboard_log=str(run.tensorboard))
        except PickleRefused:
            raise
        except Exception as e:  # noqa: BLE001 (any unreadable file: try the one before)
            warnings.warn(f"resume: skipping unreadable {zip_path.name} ({e!r})", stacklevel=2)
            continue
        print(f"resuming from {zip_path} at {model.num_timesteps} steps", flush=True)
        return model, vecnorm
    raise FileNotFoundError(f"resume: every saved state in {run.path} is unreadable")


@dataclass(frozen=True)
class RunPlan:
    """One run as checked before anything is written: what it trains, and from what."""

    hp: Hyperparams  # a new fine-tune's with its source's settings (fine_tune)
    run: RunFolder
    seed: int
    resume: bool
    env_config: EnvConfig
    previous: dict[str, Any] | None  # the summary of the earlier segments (a resume)
    source: tuple[Path, Path] | None  # init_from's model zip and statistics (a new fine-tune)


def plan_run(hp: Hyperparams, run: RunFolder, seed: int = 0, resume: bool = False) -> RunPlan:
    """Returns the plan of one run after checking all it reads (the env, init_from's model,
    the run's records), writing nothing: a refused run leaves its folder as it was."""
    if not resume:  # a resumed run keeps the env kwargs it recorded
        hp = fine_tune(hp)
    env_config = hp.env_config  # resolved once, by Hyperparams
    for name in (EVALUATIONS, BEST_METRICS, PD_EVAL):  # read by the eval callback
        run.read_json(name)
    previous = run.read_json(SUMMARY) if resume else None
    source = initial_model(hp) if not resume and hp.init_from is not None else None
    return RunPlan(hp, run, seed, resume, env_config, previous, source)


def train_run(
    hp: Hyperparams,
    run: RunFolder,
    seed: int = 0,
    resume: bool = False,
    command: str = "",
    progress_bar: bool = False,
) -> dict[str, Any]:
    """Trains one run; returns its summary (``plan_run``, then ``train_planned``)."""
    plan = plan_run(hp, run, seed, resume)
    with training_lock([run]):
        return train_planned(plan, command, progress_bar)


def train_planned(plan: RunPlan, command: str = "", progress_bar: bool = False) -> dict[str, Any]:
    """Trains one planned run; returns its summary.  Ctrl-C saves, writes the summary,
    re-raises.  If writing to the run folder fails (read-only, a full disk), training stops
    with a ``RunWriteError``, after keeping the last state it can (last_model, else the
    newest checkpoint stays)."""
    import torch
    from stable_baselines3.common.callbacks import CallbackList

    hp, run = plan.hp, plan.run
    torch.set_num_threads(hp.torch_threads)
    model, vecnorm = _model(plan)
    segment = Segment(run, plan.seed, command, plan.previous, int(model.num_timesteps))
    stop = StopOnSignal()
    error: BaseException | None = None
    with quiet_writer_threads():
        try:
            _write_records(plan, command)
            callbacks = [
                stop,
                TrackingLogCallback(),
                TrackingEvalCallback(
                    hp.env_kwargs,
                    hp.eval_seeds,
                    hp.eval_freq,
                    run,
                    hp.residual,
                    hp.frame_stack,
                    hp.frame_stride,
                    wall_offset_s=segment.wall_offset_s,
                ),
                TimedCheckpointCallback(
                    max(hp.checkpoint_freq // hp.n_envs, 1),
                    str(run.checkpoints),
                    hp.checkpoint_minutes,
                    on_save=lambda: segment.checkpoint(model.num_timesteps),
                ),
            ]
            remaining = hp.total_timesteps - segment.start_steps
            with stop:
                if remaining > 0 and not stop.stopped:
                    model.learn(
                        remaining,
                        callback=CallbackList(callbacks),
                        reset_num_timesteps=not plan.resume,
                        progress_bar=progress_bar,
                        tb_log_name="ppo",
                    )
            if stop.stopped:
                raise KeyboardInterrupt("signal")
        except KeyboardInterrupt as e:
            print(f"interrupted at {model.num_timesteps} steps; resume with --resume", flush=True)
            error = e
        except BaseException as e:  # noqa: BLE001 (saved below, then raised)
            error = e
        # Ctrl-C or a crash keeps the last state; each write is tried even if one fails.
        failed = [error] if error is not None and is_write_error(error, run) else []
        failed += attempt_write(lambda: save_model(model, run.last))
        failed += attempt_write(lambda: _close_logger(model))
        _close(vecnorm)
        summary: dict[str, Any] = {}
        failed += attempt_write(
            lambda: summary.update(segment.end(model.num_timesteps, error is not None))
        )
    if summary:
        print(json.dumps({k: v for k, v in summary.items() if k != "segments"}), flush=True)
    if error is not None and not is_write_error(error, run):
        raise error
    if failed:
        raise RunWriteError(write_failure(run, model.num_timesteps, failed)) from failed[0]
    return summary


def _model(plan: RunPlan) -> tuple[Any, Any]:
    """Returns (PPO, VecNormalize) of a planned run on its training envs: resumed, started
    from init_from's weights, or new; the envs are closed if that fails."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    hp, run = plan.hp, plan.run
    venv = make_vec_env(hp, plan.seed)
    try:
        if plan.resume:
            return _load_newest(run, venv, hp)
        if plan.source is not None:
            return load_initial(hp, plan.source, venv, plan.seed, run)
        vecnorm = VecNormalize(venv, gamma=hp.gamma, **hp.normalize)
        policy, policy_kwargs = hp.policy(plan.env_config)
        model = PPO(
            policy,
            stacked(vecnorm, hp.frame_stack, hp.frame_stride),
            seed=plan.seed,
            device="cpu",
            verbose=0,
            tensorboard_log=str(run.tensorboard),
            policy_kwargs=policy_kwargs,
            **hp.ppo_kwargs(),
        )
        return model, vecnorm
    except BaseException:
        _close(venv)
        raise


def _write_records(plan: RunPlan, command: str) -> None:
    """Writes config.yaml, command.txt and run.json of a planned run."""
    hp, run, env_config = plan.hp, plan.run, plan.env_config
    run.write_config(hp.to_dict())
    run.record_command(command, plan.resume)
    run.write_json(
        RUN_META,
        {
            **hp.residual.to_record(),
            "frame_stack": hp.frame_stack,
            "frame_stride": hp.frame_stride,
            "seed": plan.seed,
            "env_kwargs": hp.env_kwargs,
            "env_config": {
                **env_config.to_dict(),
                "observation": env_config.observation.layout(),
            },
        },
    )


def _close_logger(model: Any) -> None:
    """Closes SB3's logger (it flushes the TensorBoard events), if training started one."""
    logger = getattr(model, "_logger", None)
    if logger is not None:
        logger.close()


def _close(vecnorm: Any) -> None:
    try:
        vecnorm.close()
    except (BrokenPipeError, EOFError, ConnectionResetError):  # workers already gone (Ctrl-C)
        pass

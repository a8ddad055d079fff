"""The SB3 callbacks of a training run: tracking logs, evaluation by tracking RMS (the best
model), timed checkpoints, and a clean stop on Ctrl-C or SIGTERM."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback

from tendon2r_gym.artifacts.files import NormStats
from tendon2r_gym.artifacts.runs import (
    BEST_METRICS,
    CHECKPOINT_PREFIX,
    PD_EVAL,
    RunFolder,
    stats_files,
)
from tendon2r_gym.envs.registration import make as make_env
from tendon2r_gym.evaluation.metrics import (
    beats,
    selection_rank,
    smoothness_x_pd,
    tracking_metrics,
    within_limits,
)
from tendon2r_gym.evaluation.rollout import rollouts
from tendon2r_gym.formatting import pair
from tendon2r_gym.policies.baselines import PDPolicy
from tendon2r_gym.policies.learned import PPOPolicy
from tendon2r_gym.policies.residual import Residual
from tendon2r_gym.training.executors import STOP_REQUESTED

#: pd_eval.json's key of PD's metrics on the eval seeds started on the reference.
ON_REFERENCE = "on_reference"


class TrackingLogCallback(BaseCallback):
    """Logs the training envs' absolute tracking errors (deg) to TensorBoard."""

    def _on_step(self) -> bool:
        errs = [info["tracking_error_deg"] for info in self.locals["infos"]]
        e = np.abs(np.asarray(errs))
        self.logger.record_mean("train/abs_error_deg_A", float(e[:, 0].mean()))
        self.logger.record_mean("train/abs_error_deg_B", float(e[:, 1].mean()))
        return True


class TimedCheckpointCallback(CheckpointCallback):
    """SB3's CheckpointCallback (its file names; model + VecNormalize every ``save_freq``
    calls), also every ``minutes`` of wall time, each written by ``save_pair``, so that a
    SIGKILL loses little and never leaves a torn checkpoint."""

    def __init__(
        self,
        save_freq: int,
        save_path: str,
        minutes: float,
        on_save: Callable[[], None] | None = None,
    ) -> None:
        super().__init__(
            save_freq, save_path, name_prefix=CHECKPOINT_PREFIX, save_vecnormalize=True
        )
        self.period_s = 60.0 * minutes
        self.on_save = on_save  # after each checkpoint (the run records its progress)
        self._last_save = time.monotonic()

    def _on_step(self) -> bool:
        due = time.monotonic() - self._last_save >= self.period_s
        if due or self.n_calls % self.save_freq == 0:
            self._last_save = time.monotonic()
            zip_path = Path(self._checkpoint_path(extension="zip"))
            save_pair(self.model, zip_path, Path(self._checkpoint_path("vecnormalize_", "npz")))
            if self.on_save is not None:
                self.on_save()
        return True


class TrackingEvalCallback(BaseCallback):
    """At every multiple of ``eval_freq`` of the run's env steps (a resumed run's too) and at
    the end, rolls the deterministic policy out on fixed seeds and keeps the best model by
    ``tendon2r_gym.evaluation.metrics.selection_rank``: the lowest mean tracking RMS (over
    joints)
    among the evaluations <= PD on both joints within the smoothness limits, else the lowest
    overall.  Each evaluation is appended to evaluations.json with the
    cumulative wall time, whether it beats PD on both joints, and its RMS tension and tension
    rate as multiples of PD's.

    The smoothness is measured on the same seeds started on the reference, as the benchmark's
    episodes are: the training env's start noise (an entry's ``reset_noise_scale``) raises PD's
    and the policy's tension rates alike while each pulls the arm onto the reference, and masks
    a policy that chatters once there.

    SB3's EvalCallback ranks by mean episode reward, which mixes in the control cost, and does
    not save the VecNormalize statistics with the best model; this one ranks by the benchmark's
    own metrics and saves both."""

    def __init__(
        self,
        env_kwargs: dict[str, Any],
        seeds: list[int],
        eval_freq: int,
        run: RunFolder,
        residual: Residual,
        frame_stack: int = 1,
        frame_stride: int = 1,
        wall_offset_s: float = 0.0,
        verbose: int = 1,
    ) -> None:
        super().__init__(verbose)
        self.env_kwargs, self.seeds, self.eval_freq = env_kwargs, seeds, eval_freq
        self.on_reference = {k: v for k, v in env_kwargs.items() if k != "reset_noise_scale"}
        self.run, self.residual = run, residual
        self.frame_stack, self.frame_stride = frame_stack, frame_stride  # as PPOPolicy takes them
        self._last_eval = 0
        self._start = time.perf_counter() - wall_offset_s
        # One env, built once: its mechanism and control period define the PD baseline and
        # the PD inside a residual policy (the rollouts run on the vector env).
        self._env = make_env(**self.env_kwargs)
        self.pd = run.read_json(PD_EVAL)
        if not isinstance(self.pd, dict) or ON_REFERENCE not in self.pd:  # none yet, or older
            self.pd = self.measure(PDPolicy.from_env(self._env))
            run.write_json(PD_EVAL, self.pd)
        self.pd_rms = self.pd["rms_deg"]
        # On resume, the saved best model's rank.  An evaluation recorded before evaluations
        # kept their smoothness (no within_limits) ranks after any that beats PD within them.
        best, row = run.read_json(BEST_METRICS), run.best_evaluation()
        if best is None:
            self.best_rank = (2, float("inf"))
        elif row is not None:
            self.best_rank = selection_rank(row)
        else:
            self.best_rank = (1, float(np.mean(best["rms_deg"])))

    def measure(self, policy: Any) -> dict[str, Any]:
        """Returns a policy's tracking metrics on the eval seeds, with, under ON_REFERENCE, its
        metrics on the same seeds started on the reference (the same, without start noise)."""
        metrics = tracking_metrics(rollouts(policy, self.env_kwargs, self.seeds))
        if self.on_reference == self.env_kwargs:
            return {**metrics, ON_REFERENCE: metrics}
        return {
            **metrics,
            ON_REFERENCE: tracking_metrics(rollouts(policy, self.on_reference, self.seeds)),
        }

    def _on_training_start(self) -> None:
        self._last_eval = self.num_timesteps

    def _on_step(self) -> bool:
        if self.num_timesteps // self.eval_freq > self._last_eval // self.eval_freq:
            self._last_eval = self.num_timesteps
            self.evaluate()
        return True

    def _on_training_end(self) -> None:
        if self.num_timesteps > self._last_eval:
            self.evaluate()

    def evaluate(self) -> dict[str, Any]:
        config = self._env.unwrapped.config
        policy = PPOPolicy(
            self.model,
            self.model.get_vec_normalize_env(),
            self.residual,
            self._env,
            config.pd_gains,  # the PD the residual trains on
            frame_stack=self.frame_stack,
            frame_stride=self.frame_stride,
        )
        measured = self.measure(policy)
        metrics = {k: v for k, v in measured.items() if k != ON_REFERENCE}
        tension_x_pd, rate_x_pd = smoothness_x_pd(measured[ON_REFERENCE], self.pd[ON_REFERENCE])
        row = {
            "timesteps": self.num_timesteps,
            "wall_time_s": round(time.perf_counter() - self._start, 1),
            "rms_deg": metrics["rms_deg"],
            "beats_pd": beats(metrics["rms_deg"], self.pd_rms),
            "tension_x_pd": tension_x_pd,
            "tension_rate_x_pd": rate_x_pd,
            "within_limits": within_limits(tension_x_pd, rate_x_pd, self.residual.active),
        }
        rank = selection_rank(row)
        self.logger.record("eval/rms_deg_A", metrics["rms_deg"][0])
        self.logger.record("eval/rms_deg_B", metrics["rms_deg"][1])
        self.logger.record("eval/rms_deg_mean", rank[1])
        self.logger.record("eval/tension_rate_x_pd", rate_x_pd)
        self.run.append_evaluation(row)
        if rank < self.best_rank:
            self.best_rank = rank
            save_model(self.model, self.run.best)
            self.run.write_json(BEST_METRICS, {"timesteps": self.num_timesteps, **metrics})
        if self.verbose:
            smooth = "" if self.best_rank[0] == 0 else ", none yet <= PD within the limits"
            print(
                f"[eval] {self.num_timesteps} steps, {row['wall_time_s']} s: "
                f"RMS {_fmt(metrics['rms_deg'])} deg, tension rate {rate_x_pd:.1f}x PD's "
                f"(PD {_fmt(self.pd_rms)}; best mean {self.best_rank[1]:.4f}{smooth})",
                flush=True,
            )
        return metrics


def _fmt(values: list[float]) -> str:
    return pair(values, ".4f")


class StopOnSignal(BaseCallback):
    """Ctrl-C (SIGINT) or SIGTERM during ``learn`` asks training to stop at the next env step,
    so that no signal lands inside torch or MuJoCo; a second signal interrupts at once.  A
    stop requested earlier (executors.STOP_REQUESTED: a local worker's SIGINT during its job's
    set-up) holds from the start."""

    def __init__(self) -> None:
        super().__init__()
        self.stopped = False
        self._old: dict[int, Any] = {}

    def _request(self, signum: int, frame: Any) -> None:
        self.stopped = True
        for sig, old in self._old.items():  # a second signal acts at once
            signal.signal(sig, old)

    def __enter__(self) -> StopOnSignal:
        self.stopped = self.stopped or STOP_REQUESTED.is_set()
        try:
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._request)
        except ValueError:  # not the main thread: signals stay as they are
            self._old.clear()
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)

    def _on_step(self) -> bool:
        return not self.stopped


def save_pair(model: Any, zip_path: Path, stats_path: Path) -> None:
    """Saves the model and its VecNormalize statistics so that a kill at any moment leaves no
    torn file: each is written under a hidden temporary name and renamed into place, the
    statistics first, so a model zip never appears before its statistics.  Where a save
    replaces an earlier pair (last_model, best_model), a kill between the renames leaves the
    new statistics beside the previous zip.

    The statistics are the plain arrays of ``stats_path`` (an npz: files.NormStats, what
    this package reads), and beside it SB3's own pickle of them (``.pkl``, for SB3's
    VecNormalize.load; read here only with the trust option)."""
    zip_path.parent.mkdir(parents=True, exist_ok=True)
    venv = model.get_vec_normalize_env()
    if venv is not None:
        stats = NormStats.of(venv)
        pkl = stats_path.with_suffix(".pkl")
        for path, write in ((stats_path, stats.save), (pkl, lambda p: venv.save(str(p)))):
            part = path.with_name(f".{path.name}.part")
            with _removed_on_error(part):
                write(part)
                os.replace(part, path)
    part = zip_path.with_name(f".{zip_path.stem}.part.zip")
    with _removed_on_error(part):
        model.save(part)
        os.replace(part, zip_path)


@contextlib.contextmanager
def _removed_on_error(part: Path) -> Iterator[None]:
    """Removes the partial file ``part`` if writing it fails (e.g. on a full disk)."""
    try:
        yield
    except BaseException:
        with contextlib.suppress(OSError):
            part.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def quiet_writer_threads() -> Iterator[None]:
    """Keeps the OSError of TensorBoard's writer thread (a read-only run folder, a full disk)
    from printing its traceback: the thread keeps it, and SB3's logger raises it in the
    training loop at its next write, which reports it once."""
    previous = threading.excepthook

    def hook(args: threading.ExceptHookArgs) -> None:
        module = type(args.thread).__module__ if args.thread is not None else ""
        if not (issubclass(args.exc_type, OSError) and module.startswith("tensorboard.")):
            previous(args)

    threading.excepthook = hook
    try:
        yield
    finally:
        threading.excepthook = previous


def save_model(model: Any, stem: Path) -> None:
    """Saves ``stem.zip`` and its statistics ``stem_vecnormalize.npz`` (see
    ``save_pair``)."""
    save_pair(model, stem.with_name(stem.name + ".zip"), stats_files(stem)[0])

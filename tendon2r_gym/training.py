"""PPO training: hyperparameters, the training loop, resume, several seeds, and its callbacks.

``train(TrainSpec)`` owns one run from config to saved models (the run folder's layout belongs to
tendon2r_gym.runs).  It survives interruption:
- Ctrl-C (or SIGTERM) stops training at the next env step (StopOnSignal), saves
  ``last_model`` and the summary, then raises KeyboardInterrupt, so a multi-seed command stops
  as a whole (exit code 130) after writing the summary of the seeds that finished;
- checkpoints are taken every ``checkpoint_freq`` steps and every ``checkpoint_minutes``;
- ``resume`` continues from the newest readable saved state, skipping a corrupt one with a
  warning;
- ``summary.json`` adds up steps and wall time over every segment, and command.txt keeps the
  original command with one line per resume.
"""

from __future__ import annotations

import copy
import json
import signal
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback
from stable_baselines3.common.vec_env import VecEnv

from tendon2r_gym import observation
from tendon2r_gym.env_config import EnvConfig
from tendon2r_gym.learned import (
    PPOPolicy,
    make_training_env,
    observation_layout,
    residual_command,
)
from tendon2r_gym.metrics import tracking_metrics
from tendon2r_gym.policies import PDPolicy
from tendon2r_gym.presets import PPO_CONFIG, load_yaml
from tendon2r_gym.rollout import rollouts
from tendon2r_gym.runs import CHECKPOINT_PREFIX, RUN_META, RunFolder, model_files
from tendon2r_gym.validation import check_keys, integer, invalid, mapping, number

#: Keys of one entry of the hyperparameter file (configs/ppo.yaml).
HYPERPARAM_KEYS = (
    "env_kwargs",
    "residual_scale",
    "total_timesteps",
    "n_envs",
    "vec_env",
    "torch_threads",
    "ppo",
    "policy_kwargs",
    "normalize",
    "eval_seeds",
    "eval_freq",
    "checkpoint_freq",
    "checkpoint_minutes",
    "zero_obs",  # observation entries to blank out (ablations)
)
VEC_ENVS = ("native", "subproc", "dummy")


def load_hyperparams(
    name: str = "default", path: str | Path = PPO_CONFIG, env_config: str | None = None
) -> dict[str, Any]:
    """Returns entry ``name`` of a hyperparameter file, validated.  ``env_config`` (a preset
    name or experiment-file path) replaces the entry's env preset, keeping its other env
    kwargs."""
    table = load_yaml(path)
    if name not in table:
        raise invalid("hyperparams", name, f"an entry of {path}: {sorted(table)}")
    cfg = copy.deepcopy(mapping(f"{path}: {name}", table[name]))
    check_keys(f"{path}: {name}", cfg, HYPERPARAM_KEYS)
    cfg.setdefault("vec_env", "subproc")
    cfg.setdefault("checkpoint_minutes", 2.0)
    cfg["env_kwargs"] = mapping("env_kwargs", cfg.get("env_kwargs"))
    if env_config is not None:
        cfg["env_kwargs"]["preset"] = str(env_config)
    return cfg


def check_hyperparams(cfg: dict[str, Any]) -> None:
    """Raises a ValueError naming the first bad value of a resolved entry."""
    integer("total_timesteps", cfg["total_timesteps"], 1, 10**10)
    integer("n_envs", cfg["n_envs"], 1, 1024)
    integer("torch_threads", cfg["torch_threads"], 1, 256)
    number("residual_scale", cfg["residual_scale"], 0.0, 2.0)
    integer("eval_freq", cfg["eval_freq"], 1, 10**10)
    integer("checkpoint_freq", cfg["checkpoint_freq"], 1, 10**10)
    number("checkpoint_minutes", cfg["checkpoint_minutes"], 0.0, lo_open=True)
    check_keys("zero_obs", cfg.get("zero_obs", ()), observation.SLICES)
    if cfg["vec_env"] not in VEC_ENVS:
        raise invalid("vec_env", cfg["vec_env"], f"one of {VEC_ENVS}")
    EnvConfig.make(**cfg["env_kwargs"])  # the env kwargs, before any worker starts


@dataclass
class TrainSpec:
    """One run: resolved hyperparameters, its folder, its seed and the command to record."""

    cfg: dict[str, Any]
    run: RunFolder
    seed: int = 0
    resume: bool = False
    command: str = ""
    progress_bar: bool = False


# -- callbacks ---------------------------------------------------------------------------------
class TrackingLogCallback(BaseCallback):
    """Logs the training envs' absolute tracking errors (deg) to TensorBoard."""

    def _on_step(self) -> bool:
        errs = [info["tracking_error_deg"] for info in self.locals["infos"]]
        e = np.abs(np.asarray(errs))
        self.logger.record_mean("train/abs_error_deg_A", float(e[:, 0].mean()))
        self.logger.record_mean("train/abs_error_deg_B", float(e[:, 1].mean()))
        return True


class TimedCheckpointCallback(CheckpointCallback):
    """SB3's CheckpointCallback (model + VecNormalize every ``save_freq`` calls), also every
    ``minutes`` of wall time, so that a SIGKILL loses little."""

    def __init__(self, save_freq: int, save_path: str, minutes: float) -> None:
        super().__init__(
            save_freq, save_path, name_prefix=CHECKPOINT_PREFIX, save_vecnormalize=True
        )
        self.period_s = 60.0 * minutes
        self._last_save = time.monotonic()

    def _on_step(self) -> bool:
        due = time.monotonic() - self._last_save >= self.period_s
        if due or self.n_calls % self.save_freq == 0:
            self._last_save = time.monotonic()
            self.n_calls, saved = self.save_freq, self.n_calls  # makes the parent save now
            super()._on_step()
            self.n_calls = saved
        return True


class TrackingEvalCallback(BaseCallback):
    """Every ``eval_freq`` env steps, rolls the deterministic policy out on fixed seeds and keeps
    the model with the lowest mean tracking RMS (over joints) as ``best_model``.  Each
    evaluation is appended to evaluations.json with the cumulative wall time, and the first
    one that beats PD on both joints is noted.

    SB3's EvalCallback ranks by mean episode reward, which mixes in the control cost, and does
    not save the VecNormalize statistics with the best model; this one ranks by the benchmark's
    own metric and saves both."""

    def __init__(
        self,
        env_kwargs: dict[str, Any],
        seeds: list[int],
        eval_freq: int,
        run: RunFolder,
        residual_scale: float,
        wall_offset_s: float = 0.0,
        verbose: int = 1,
    ) -> None:
        super().__init__(verbose)
        self.env_kwargs, self.seeds, self.eval_freq = env_kwargs, seeds, eval_freq
        self.run, self.residual_scale = run, residual_scale
        best = run.read_json("best_metrics.json")
        self.best_rms = float(np.mean(best["rms_deg"])) if best else float("inf")
        self._last_eval = 0
        self._start = time.perf_counter() - wall_offset_s
        # One env, built once: its mechanism and control period define the PD baseline and
        # the PD inside a residual policy (the rollouts run on the vector env).
        self._env = gym.make("Tendon2R-v0", **self.env_kwargs)
        self.pd_rms = run.read_json("pd_eval.json")
        if self.pd_rms is None:
            pd_metrics = tracking_metrics(
                rollouts(PDPolicy.from_env(self._env), self.env_kwargs, seeds)
            )
            self.pd_rms = pd_metrics["rms_deg"]
            run.write_json("pd_eval.json", self.pd_rms)

    def _on_training_start(self) -> None:
        self._last_eval = self.num_timesteps

    def _on_step(self) -> bool:
        if self.num_timesteps - self._last_eval >= self.eval_freq:
            self._last_eval = self.num_timesteps
            self.evaluate()
        return True

    def _on_training_end(self) -> None:
        if self.num_timesteps > self._last_eval:
            self.evaluate()

    def evaluate(self) -> dict[str, Any]:
        policy = PPOPolicy(
            self.model, self.model.get_vec_normalize_env(), self.residual_scale, self._env
        )
        metrics = tracking_metrics(rollouts(policy, self.env_kwargs, self.seeds))
        rms = float(np.mean(metrics["rms_deg"]))
        self.logger.record("eval/rms_deg_A", metrics["rms_deg"][0])
        self.logger.record("eval/rms_deg_B", metrics["rms_deg"][1])
        self.logger.record("eval/rms_deg_mean", rms)
        wall = round(time.perf_counter() - self._start, 1)
        beats = all(p <= d for p, d in zip(metrics["rms_deg"], self.pd_rms, strict=True))
        self.run.append_evaluation(
            {
                "timesteps": self.num_timesteps,
                "wall_time_s": wall,
                "rms_deg": metrics["rms_deg"],
                "beats_pd": beats,
            }
        )
        if rms < self.best_rms:
            self.best_rms = rms
            save_model(self.model, self.run.best)
            self.run.write_json("best_metrics.json", {"timesteps": self.num_timesteps, **metrics})
        if self.verbose:
            print(
                f"[eval] {self.num_timesteps} steps, {wall} s: RMS {_fmt(metrics['rms_deg'])} "
                f"deg (PD {_fmt(self.pd_rms)}; best mean {self.best_rms:.4f})",
                flush=True,
            )
        return metrics


def _fmt(pair: list[float]) -> str:
    return " / ".join(f"{v:.4f}" for v in pair)


def save_model(model: Any, stem: Path) -> None:
    """Saves ``stem.zip`` and ``stem_vecnormalize.pkl``."""
    zip_path, stats = model_files(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    model.save(zip_path)
    venv = model.get_vec_normalize_env()
    if venv is not None:
        venv.save(str(stats))


def first_beat_pd(run: RunFolder) -> dict[str, Any] | None:
    """Returns the first evaluation of a run that beat PD on both joints, or None."""
    for row in run.read_json("evaluations.json") or []:
        if row["beats_pd"]:
            return {"timesteps": row["timesteps"], "wall_time_s": row["wall_time_s"]}
    return None


# -- the training loop ---------------------------------------------------------------------------
def _load_newest(run: RunFolder, venv: Any) -> tuple[Any, Any]:
    """Returns (PPO, VecNormalize) from the newest readable saved state of the run; a corrupt
    one is skipped with a warning."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    candidates = run.checkpoint_candidates()
    if not candidates:
        raise FileNotFoundError(f"resume: no last_model or checkpoint in {run.path}")
    for zip_path, stats in candidates:
        try:
            vecnorm = VecNormalize.load(str(stats), venv)
            model = PPO.load(zip_path, env=vecnorm, device="cpu")
        except Exception as e:  # noqa: BLE001 (any unreadable file: try the one before)
            warnings.warn(f"resume: skipping unreadable {zip_path.name} ({e!r})", stacklevel=2)
            continue
        print(f"resuming from {zip_path} at {model.num_timesteps} steps", flush=True)
        return model, vecnorm
    raise FileNotFoundError(f"resume: every saved state in {run.path} is unreadable")


class SB3VecEnv(VecEnv):
    """Stable-Baselines3's VecEnv API over the native vector env (tendon2r_gym.vector_env) in
    Gymnasium's SAME_STEP autoreset mode: ``terminal_observation`` and ``TimeLimit.truncated``
    go in each env's info, as SB3's own VecEnvs put them.  With ``residual_scale > 0`` it
    also adds the agent's action to a batched PD command (one numpy call for all arms)."""

    def __init__(
        self, venv: Any, residual_scale: float = 0.0, zero_obs: tuple[str, ...] = ()
    ) -> None:
        from gymnasium.vector import AutoresetMode

        if venv.autoreset_mode != AutoresetMode.SAME_STEP:
            raise invalid("autoreset_mode", venv.autoreset_mode, "SAME_STEP for SB3")
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self.venv, self.residual_scale = venv, residual_scale
        self.pd = PDPolicy(venv.mechanism, venv.ctrl_dt) if residual_scale > 0 else None
        self._mask = observation.mask(zero_obs, venv.single_observation_space.shape[0])
        self._raw: np.ndarray | None = None
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        seeds = list(self._seeds)
        self._raw, _ = self.venv.reset(seed=seeds if any(s is not None for s in seeds) else None)
        self._reset_seeds()
        self._reset_options()
        return self._raw * self._mask

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        actions = self._actions
        if self.pd is not None:
            base, _ = self.pd.predict(self._raw)
            actions = residual_command(base, actions, self.residual_scale)
        obs, rewards, terminated, truncated, info = self.venv.step(actions)
        dones = terminated | truncated
        keys = [k for k in info if not k.startswith("_") and k != "final_obs"]
        infos: list[dict[str, Any]] = [{k: info[k][i] for k in keys} for i in range(self.num_envs)]
        for i in range(self.num_envs):  # as SB3's DummyVecEnv: on every step
            infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
        for i in np.flatnonzero(dones):
            infos[i]["terminal_observation"] = info["final_obs"][i] * self._mask
        self._raw = obs
        return obs * self._mask, rewards.astype(np.float32), dones, infos

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [getattr(self.venv, attr_name)] * len(self._get_indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *args: Any, indices: Any = None, **kw: Any) -> list:
        return [getattr(self.venv, method_name)(*args, **kw)] * len(self._get_indices(indices))

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False] * len(self._get_indices(indices))


def make_vec_env(cfg: dict[str, Any], seed: int) -> Any:
    """Returns the training VecEnv of a resolved entry: the native vector env (one process,
    batched physics and PD) with SB3's VecMonitor, or SB3's make_vec_env with Subproc/Dummy."""
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    if cfg["vec_env"] == "native":
        from tendon2r_gym.vector_env import Tendon2RVectorEnv

        native = Tendon2RVectorEnv(
            cfg["n_envs"], autoreset_mode="SameStep", stagger=True, **cfg["env_kwargs"]
        )
        venv = SB3VecEnv(native, cfg["residual_scale"], tuple(cfg.get("zero_obs", ())))
        venv.seed(seed)
        return VecMonitor(venv)
    subproc = cfg["vec_env"] == "subproc" and cfg["n_envs"] > 1
    return sb3_make_vec_env(
        make_training_env,
        n_envs=cfg["n_envs"],
        seed=seed,
        env_kwargs={
            "env_kwargs": cfg["env_kwargs"],
            "residual_scale": cfg["residual_scale"],
            "zero_obs": tuple(cfg.get("zero_obs", ())),
        },
        vec_env_cls=SubprocVecEnv if subproc else DummyVecEnv,
    )


def train(spec: TrainSpec) -> dict[str, Any]:
    """Trains one run; returns its summary.  Ctrl-C saves, writes the summary, re-raises."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.vec_env import VecNormalize

    cfg, run = spec.cfg, spec.run
    check_hyperparams(cfg)
    env_config = EnvConfig.make(**cfg["env_kwargs"])
    previous = run.read_json("summary.json") if spec.resume else None
    run.write_config({**cfg, "seed": spec.seed})
    run.record_command(spec.command, spec.resume)
    run.write_json(
        RUN_META,
        {
            "residual_scale": float(cfg["residual_scale"]),
            "seed": spec.seed,
            "env_kwargs": cfg["env_kwargs"],
            "env_config": {
                **env_config.to_dict(),
                "observation": observation_layout(env_config.preview_steps),
            },
        },
    )
    torch.set_num_threads(cfg["torch_threads"])
    venv = make_vec_env(cfg, spec.seed)
    if spec.resume:
        model, vecnorm = _load_newest(run, venv)
    else:
        vecnorm = VecNormalize(venv, gamma=cfg["ppo"].get("gamma", 0.99), **cfg["normalize"])
        model = PPO(
            "MlpPolicy",
            vecnorm,
            seed=spec.seed,
            device="cpu",
            verbose=0,
            tensorboard_log=str(run.file("tb")),
            policy_kwargs=cfg["policy_kwargs"],
            **cfg["ppo"],
        )
    prior_wall = previous["wall_time_s"] if previous else 0.0
    callbacks = [
        TrackingLogCallback(),
        TrackingEvalCallback(
            cfg["env_kwargs"],
            cfg["eval_seeds"],
            cfg["eval_freq"],
            run,
            float(cfg["residual_scale"]),
            wall_offset_s=prior_wall,
        ),
        TimedCheckpointCallback(
            max(cfg["checkpoint_freq"] // cfg["n_envs"], 1),
            str(run.checkpoints),
            cfg["checkpoint_minutes"],
        ),
    ]
    start_steps = int(model.num_timesteps)
    remaining = cfg["total_timesteps"] - start_steps
    start = time.perf_counter()
    interrupted = False
    stop = StopOnSignal()
    try:
        with stop:
            if remaining > 0:
                model.learn(
                    remaining,
                    callback=CallbackList([stop, *callbacks]),
                    reset_num_timesteps=not spec.resume,
                    progress_bar=spec.progress_bar,
                    tb_log_name="ppo",
                )
        if stop.stopped:
            raise KeyboardInterrupt("signal")
    except KeyboardInterrupt:
        interrupted = True
        print(f"interrupted at {model.num_timesteps} steps; resume with --resume", flush=True)
        raise
    finally:
        save_model(model, run.last)  # Ctrl-C or a crash keeps the last state
        _close(vecnorm)
        summary = _write_summary(spec, previous, start_steps, model, start, interrupted)
    return summary


def _write_summary(
    spec: TrainSpec,
    previous: dict[str, Any] | None,
    start_steps: int,
    model: Any,
    start: float,
    interrupted: bool,
) -> dict[str, Any]:
    """Writes summary.json: this segment appended to the earlier ones, totals summed."""
    run = spec.run
    wall = time.perf_counter() - start
    steps = int(model.num_timesteps)
    segment = {
        "command": spec.command,
        "start_timesteps": start_steps,
        "end_timesteps": steps,
        "wall_time_s": round(wall, 1),
        "interrupted": interrupted,
    }
    segments = [*(previous or {}).get("segments", []), segment]
    total_wall = round(sum(s["wall_time_s"] for s in segments), 1)
    best = run.read_json("best_metrics.json") or {}
    summary = {
        "seed": spec.seed,
        "timesteps": steps,
        "wall_time_s": total_wall,
        "steps_per_s": round(
            sum(s["end_timesteps"] - s["start_timesteps"] for s in segments)
            / max(total_wall, 1e-9),
            1,
        ),
        "interrupted": interrupted,
        "best_rms_deg": best.get("rms_deg"),
        "best_timesteps": best.get("timesteps"),
        "pd_eval_rms_deg": run.read_json("pd_eval.json"),
        "first_beat_pd": first_beat_pd(run),
        "segments": segments,
    }
    run.write_json("summary.json", summary)
    print(json.dumps({k: v for k, v in summary.items() if k != "segments"}), flush=True)
    return summary


def _close(vecnorm: Any) -> None:
    try:
        vecnorm.close()
    except (BrokenPipeError, EOFError, ConnectionResetError):  # workers already gone (Ctrl-C)
        pass


class StopOnSignal(BaseCallback):
    """Ctrl-C (SIGINT) or SIGTERM during ``learn`` asks training to stop at the next env step,
    so that no signal lands inside torch or MuJoCo; a second signal interrupts at once."""

    def __init__(self) -> None:
        super().__init__()
        self.stopped = False
        self._old: dict[int, Any] = {}

    def _request(self, signum: int, frame: Any) -> None:
        self.stopped = True
        for sig, old in self._old.items():  # a second signal acts at once
            signal.signal(sig, old)

    def __enter__(self) -> StopOnSignal:
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


def train_seeds(
    cfg: dict[str, Any],
    base: Path,
    seeds: list[int],
    command: str,
    resume: bool = False,
    progress_bar: bool = False,
) -> dict[str, Any]:
    """Trains one run per seed in ``base/seed_<n>`` and writes base/seeds_summary.json.  A
    Ctrl-C stops them all: the summary of the finished seeds is written, then it re-raises."""
    results: list[dict[str, Any]] = []
    try:
        for seed in seeds:
            run = RunFolder(base / f"seed_{seed}")
            resume_this = resume and bool(run.checkpoint_candidates())
            results.append(train(TrainSpec(cfg, run, seed, resume_this, command, progress_bar)))
    finally:
        agg = seeds_summary(seeds, results)
        RunFolder(base).write_json("seeds_summary.json", agg)
    return agg


def seeds_summary(seeds: list[int], results: list[dict[str, Any]]) -> dict[str, Any]:
    """Returns mean +- std (ddof 0) of the finished runs' best RMS."""
    done = [r for r in results if r.get("best_rms_deg") is not None]
    out: dict[str, Any] = {"seeds": seeds, "finished": [r["seed"] for r in done], "runs": results}
    if done:
        rms = np.array([r["best_rms_deg"] for r in done], dtype=float)
        out.update(
            rms_deg_mean=rms.mean(0).tolist(),
            rms_deg_std=rms.std(0).tolist(),
            wall_time_s_mean=float(np.mean([r["wall_time_s"] for r in done])),
        )
    return out

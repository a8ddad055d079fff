"""SB3 training helpers: tracking-error logging and model selection by tracking RMS."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from tendon2r_gym.learned import RUN_META, PPOPolicy
from tendon2r_gym.metrics import tracking_metrics
from tendon2r_gym.rollout import rollouts


def save_model(model: Any, path: Path, residual_scale: float) -> None:
    """Saves ``path.zip``, ``path_vecnormalize.pkl`` and policy.json beside them."""
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path.with_suffix(".zip"))
    venv = model.get_vec_normalize_env()
    if venv is not None:
        venv.save(str(path.parent / f"{path.name}_vecnormalize.pkl"))
    (path.parent / RUN_META).write_text(json.dumps({"residual_scale": residual_scale}))


class TrackingLogCallback(BaseCallback):
    """Logs the training envs' absolute tracking errors (deg) to TensorBoard."""

    def _on_step(self) -> bool:
        errs = [info["tracking_error_deg"] for info in self.locals["infos"]]
        e = np.abs(np.asarray(errs))
        self.logger.record_mean("train/abs_error_deg_A", float(e[:, 0].mean()))
        self.logger.record_mean("train/abs_error_deg_B", float(e[:, 1].mean()))
        return True


class TrackingEvalCallback(BaseCallback):
    """Every ``eval_freq`` env steps, rolls the deterministic policy out on fixed seeds and keeps
    the model with the lowest mean tracking RMS (over joints) as ``best_model``.

    SB3's EvalCallback ranks by mean episode reward, which mixes in the control cost, and does
    not save the VecNormalize statistics with the best model; this one ranks by the benchmark's
    own metric and saves both."""

    def __init__(
        self,
        env_kwargs: dict[str, Any],
        seeds: list[int],
        eval_freq: int,
        best_path: Path,
        residual_scale: float,
        verbose: int = 1,
    ) -> None:
        super().__init__(verbose)
        self.env_kwargs, self.seeds, self.eval_freq = env_kwargs, seeds, eval_freq
        self.best_path, self.residual_scale = best_path, residual_scale
        self.best_rms = float("inf")
        self._last_eval = 0

    def _on_step(self) -> bool:
        if self.num_timesteps - self._last_eval >= self.eval_freq:
            self._last_eval = self.num_timesteps
            self.evaluate()
        return True

    def _on_training_end(self) -> None:
        self.evaluate()

    def evaluate(self) -> dict[str, Any]:
        venv = self.model.get_vec_normalize_env()
        make = lambda: gym.make("Tendon2R-v0", **self.env_kwargs)  # noqa: E731
        env = make()
        policy = PPOPolicy(
            self.model,
            venv.obs_rms if venv else None,
            venv.clip_obs if venv else 10.0,
            venv.epsilon if venv else 1e-8,
            self.residual_scale,
            env,
        )
        metrics = tracking_metrics(rollouts(policy, make, self.seeds))
        rms = float(np.mean(metrics["rms_deg"]))
        self.logger.record("eval/rms_deg_A", metrics["rms_deg"][0])
        self.logger.record("eval/rms_deg_B", metrics["rms_deg"][1])
        self.logger.record("eval/rms_deg_mean", rms)
        if rms < self.best_rms:
            self.best_rms = rms
            save_model(self.model, self.best_path, self.residual_scale)
            (self.best_path.parent / "best_metrics.json").write_text(
                json.dumps({"timesteps": self.num_timesteps, **metrics}, indent=1)
            )
        if self.verbose:
            print(
                f"[eval] {self.num_timesteps} steps: RMS {metrics['rms_deg']} deg "
                f"(best mean {self.best_rms:.4f})",
                flush=True,
            )
        return metrics

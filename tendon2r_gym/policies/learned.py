"""Trained PPO policies: a run's model, loaded for the env it runs in.

A trained model only meets the env it was trained for: `PPOPolicy.load` compares the env
config recorded in the run (``run.json``) with the env's (tendon2r_gym.artifacts.model_env) and
refuses another mechanism, reference set or observation layout, and its model zip and
VecNormalize statistics when unreadable or made for another observation or action size
(tendon2r_gym.artifacts.files).  Neither file is unpickled: the policy is built from the zip's
plain JSON and weights, the statistics read from plain arrays; an earlier version's pickled
statistics load only with the trust option (files.TRUST_HELP).  A residual model adds its
action to PD's command (tendon2r_gym.policies.residual).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from tendon2r_gym.artifacts.files import (
    check_model_spaces,
    check_stats_shape,
    load_policy,
    load_vecnormalize,
    model_data,
    read_stats,
)
from tendon2r_gym.artifacts.model_env import arm_features, check_model_env, deployed_gains
from tendon2r_gym.artifacts.runs import RUN_META, model_files, stem_of, training_record
from tendon2r_gym.llvm import load_triton
from tendon2r_gym.policies import inference
from tendon2r_gym.policies.baselines import PDPolicy
from tendon2r_gym.policies.residual import Residual, ResidualFilter, residual_command
from tendon2r_gym.task.gains import Gains, gains_of


def trained_model(
    model_path: str | Path, env: gym.Env, field: str = "model", trust_pickle: bool | None = None
) -> tuple[Path, Path, dict[str, Any]]:
    """Returns (``<name>.zip``, its statistics ``<name>_vecnormalize.npz``, or an earlier
    version's ``.pkl``, the run's run.json) of a model that tendon2r-train wrote, after checking
    that it was trained for ``env`` (`check_model_env`; a ValueError naming ``field``
    otherwise) and that both files are readable without pickle (or with ``trust_pickle``) and
    made for it (`check_model_files`; a ValueError naming the file)."""
    zip_path, stats = model_files(stem_of(model_path))
    if zip_path.is_dir() or not zip_path.is_file():
        raise ValueError(
            f"{field} = {str(model_path)!r} is invalid; allowed: an existing SB3 model file "
            f"(<name>.zip, here {zip_path}) written by tendon2r-train"
        )
    for needed in (stats, zip_path.parent / RUN_META):
        if not needed.is_file():
            raise ValueError(
                f"{field} = {str(model_path)!r} is invalid: {needed.name} is missing beside "
                "it; allowed: a model from a tendon2r-train run folder or bundle"
            )
    meta = training_record(zip_path)
    check_model_env(meta["env_config"], env, f"{field} {zip_path}")
    check_model_files(zip_path, stats, meta, env, trust_pickle)
    return zip_path, stats, meta


def check_model_files(
    zip_path: Path,
    stats: Path,
    meta: dict[str, Any],
    env: gym.Env,
    trust_pickle: bool | None = None,
) -> None:
    """Raises a ValueError naming the file if the model zip or its VecNormalize statistics
    are unreadable (a pickle without ``trust_pickle``: files.read_stats), or made for another
    observation or action size than ``env`` (whose config matches the run's ``meta``,
    `check_model_env`) gives it: the model sees the env's observation (with its
    `arm_features` appended), ``frame_stack`` times."""
    arm = arm_features(meta["env_config"], env)
    seen = env.observation_space.shape[0] + (0 if arm is None else arm.size)
    stack = int(meta.get("frame_stack", 1))
    where = f"the env it is loaded on (that of its {RUN_META})"
    data = model_data(zip_path)
    check_model_spaces(zip_path, data, (stack * seen,), env.action_space.shape, where)
    check_stats_shape(stats, read_stats(stats, trust_pickle), (seen,), where)


class PPOPolicy:
    """A trained PPO (+ its VecNormalize statistics) behind the SB3 ``predict`` interface,
    acting on raw observations of the unwrapped env: normalizes them with VecNormalize's own
    ``normalize_obs``, and adds PD if it was residual: the PD of its training env's gains
    (``pd_gains``), whatever the env's are, except gains drawn in training, which are the
    env's (`deployed_gains`), and the residual at the scale and through the filter it
    trained with (``residual_scale``, ``residual_filter_tau``)."""

    def __init__(
        self,
        model: Any,
        vecnormalize: Any,
        residual: Residual,
        env: gym.Env | None = None,
        pd_gains: Gains | dict[str, float] | None = None,
        arm: np.ndarray | None = None,
        frame_stack: int = 1,
        frame_stride: int = 1,
    ) -> None:
        self.model = model
        self.vecnormalize = vecnormalize
        self.residual = residual
        #: The ``arm`` slice appended to each observation (`arm_features`), or None.
        self.arm = arm
        #: The model sees its last frame_stack normalized observations, frame_stride control
        #: steps apart, oldest first, as in training (tendon2r_gym.policies.history).
        self.frame_stack, self.frame_stride = frame_stack, frame_stride
        self._history = None
        if frame_stack > 1:
            from tendon2r_gym.policies.history import FrameHistory

            self._history = FrameHistory(frame_stack, frame_stride)
        self.pd, self.filter = None, None
        if residual.active and env is not None:  # the PD it was trained on: its gains
            self.pd = PDPolicy.from_env(env, gains=gains_of(pd_gains))
            self.filter = ResidualFilter(residual.filter_tau, env.unwrapped.config.ctrl_dt)

    @classmethod
    def load(
        cls, model_path: str | Path, env: gym.Env, trust_pickle: bool | None = None
    ) -> PPOPolicy:
        """Loads ``<name>.zip`` with its statistics (``<name>_vecnormalize.npz``) and the
        run's run.json, without unpickling (an earlier version's ``.pkl`` statistics only with
        ``trust_pickle``, or inside files.trusting_pickle); raises if the env is not the one
        the model was trained on, or a file is corrupt or made for another observation size
        (`trained_model`)."""
        load_triton()  # torch's triton after a GL context's LLVM segfaults: tendon2r_gym.llvm
        from stable_baselines3.common.vec_env import DummyVecEnv

        zip_path, stats, meta = trained_model(model_path, env, trust_pickle=trust_pickle)
        model = load_policy(zip_path)
        arm = arm_features(meta["env_config"], env)
        seen = env if arm is None else _with_arm(env, arm)
        venv = DummyVecEnv([lambda: seen])
        vecnorm = load_vecnormalize(stats, venv, trust_pickle=trust_pickle)
        vecnorm.training, vecnorm.norm_reward = False, False
        gains = deployed_gains(meta["env_config"], env)
        history = int(meta.get("frame_stack", 1)), int(meta.get("frame_stride", 1))
        return cls(model, vecnorm, Residual.from_record(meta), env, gains, arm, *history)

    def reset(self, info: dict[str, Any]) -> None:
        """Follows the episode's arm with the PD inside a residual policy (the rollouts call
        it with each reset's info), and starts the stack of observations and the residual's
        filter anew."""
        if self._history is not None:
            self._history.clear()
        if self.pd is not None:
            self.pd.reset(info)
            self.filter.clear()

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        obs = np.asarray(observation, dtype=np.float64)
        seen = obs
        if self.arm is not None:  # one observation or a batch of them
            arm = np.broadcast_to(self.arm, (*obs.shape[:-1], self.arm.size))
            seen = np.concatenate([obs, arm], axis=-1)
        norm = self.vecnormalize.normalize_obs(seen) if self.vecnormalize is not None else seen
        if self._history is not None:  # emptied first where an episode starts
            norm = self._history.push(norm, episode_start)
        action, state = inference.predict(self.model, norm, state, episode_start, deterministic)
        if self.pd is None:
            return np.clip(action, -1.0, 1.0).astype(np.float32), state
        base, _ = self.pd.predict(obs)
        command = residual_command(base, action, self.residual.scale, self.filter, episode_start)
        return command.astype(np.float32), state


def _with_arm(env: gym.Env, arm: np.ndarray) -> gym.Env:
    """Returns ``env`` observed with the constant ``arm`` slice appended (what a model that
    observed ``arm`` saw in training)."""
    space = env.observation_space
    box = gym.spaces.Box(
        np.concatenate([space.low, np.full(arm.size, -np.inf)]),
        np.concatenate([space.high, np.full(arm.size, np.inf)]),
        dtype=space.dtype,
    )
    return gym.wrappers.TransformObservation(env, lambda o: np.concatenate([o, arm]), box)

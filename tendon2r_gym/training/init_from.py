"""Starting a run from a trained model (init_from): the source model checked against the
run's env and residual, the env kwargs and residual the run inherits from it, and PPO
loaded from its weights and observation statistics, without unpickling either (an earlier
version's pickled statistics only with the trust option: tendon2r_gym.artifacts.files)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tendon2r_gym.artifacts.model_env import (
    feature_ranges,
    in_model_settings,
    observes_arm,
)
from tendon2r_gym.artifacts.runs import (
    RunFolder,
    model_files,
    stem_of,
    training_record,
)
from tendon2r_gym.envs.env_config import resolve
from tendon2r_gym.envs.registration import make as make_env
from tendon2r_gym.training.frame_stack import stacked
from tendon2r_gym.training.hyperparams import LOG_STD_RANGE, Hyperparams
from tendon2r_gym.validation import invalid


def initial_model(hp: Hyperparams) -> tuple[Path, Path]:
    """Returns (model zip, statistics) of ``hp.init_from`` (a bundle's primary seed, or a
    model file) after checking that it covers the run's env and residual scale."""

    from tendon2r_gym.artifacts.bundle import model_path
    from tendon2r_gym.policies.learned import trained_model
    from tendon2r_gym.policies.residual import Residual

    source = hp.init_from
    env = make_env(preset=hp.env_config)
    zip_path, stats, meta = trained_model(model_path(source), env, "init_from")
    if Residual.from_record(meta).active != hp.residual.active:
        kind = "a residual model (residual_scale > 0)" if hp.residual.active else "a plain model"
        raise invalid(
            "init_from",
            source,
            f"{kind} for this entry (the model has residual_scale {meta['residual_scale']})",
        )
    n = int(np.prod(env.action_space.shape))  # the model's actions: it was trained for env
    if isinstance(hp.init_log_std, list) and len(hp.init_log_std) != n:
        lo, hi = LOG_STD_RANGE
        raise invalid(
            "init_log_std",
            hp.init_log_std,
            f"one number in [{lo:g}, {hi:g}], or {n} (the model's actions)",
        )
    return zip_path, stats


def fine_tune(hp: Hyperparams) -> Hyperparams:
    """Returns the hyperparameters of a run that starts from ``hp.init_from``: its env kwargs
    take the source model's settings and arm slice (`fine_tune_env_kwargs`), and its
    residual the source's scale and filter (``residual_scale``, ``residual_filter_tau``), so
    that every env of the run, its run.json and its deployment see what the model saw and its
    actions mean what they meant; ``hp`` itself without init_from.  A plain entry does not
    fine-tune a residual model, nor the reverse (initial_model refuses it)."""
    from tendon2r_gym.artifacts.bundle import model_path
    from tendon2r_gym.policies.residual import Residual

    source = None if hp.init_from is None else model_path(hp.init_from)
    if source is None or not model_files(stem_of(source))[0].is_file():
        return hp  # (a missing source is refused by initial_model, naming init_from)
    residual = Residual.from_record(training_record(source))
    env_kwargs = fine_tune_env_kwargs(source, hp.env_kwargs)
    if not hp.residual.active or not residual.active:
        return hp.replace(env_kwargs=env_kwargs)
    return hp.replace(env_kwargs=env_kwargs, **residual.to_record())


def fine_tune_env_kwargs(model_path: str | Path, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """Returns the env kwargs on which a run fine-tunes the model (``init_from``) on the env
    of ``env_kwargs``: with the model's settings (what its actions mean, its timing:
    tendon2r_gym.artifacts.model_env.model_settings), and, if it observed its arm, the arm slice
    over the model's ranges (observe ``arm``, ``arm_feature_ranges``), so that the run's every
    env, its record and its deployment see the arm as the model did."""
    out = in_model_settings(model_path, env_kwargs)
    recorded = (training_record(model_path) or {}).get("env_config", {})
    if observes_arm(recorded):  # the observe list of the run's own experiment (``out``)
        observe = [n for n in resolve(out).observe if n != "arm"] + ["arm"]
        out.update(observe=observe, arm_feature_ranges=feature_ranges(recorded).to_dict())
    return out


def load_initial(
    hp: Hyperparams, source: tuple[Path, Path], venv: Any, seed: int, run: RunFolder
) -> tuple[Any, Any]:
    """Returns (PPO, VecNormalize) started from the weights and observation statistics of
    ``source`` (``initial_model``), training on ``venv`` with the run's PPO settings and
    the source's policy (its class and policy_kwargs: files.load_ppo)."""
    from tendon2r_gym.artifacts.files import load_ppo, load_vecnormalize

    zip_path, stats = source
    vecnorm = load_vecnormalize(stats, venv)
    vecnorm.training = True
    vecnorm.norm_reward = bool(hp.normalize.get("norm_reward", True))
    env = stacked(vecnorm, hp.frame_stack, hp.frame_stride)
    model = load_ppo(zip_path, env, hp.ppo_kwargs(), seed, str(run.tensorboard))
    model.num_timesteps = 0  # a fine-tune counts its own steps (the zip holds the source's)
    if hp.init_log_std is not None:
        reset_log_std(model.policy.log_std, hp.init_log_std)
    print(f"initialized from {zip_path}", flush=True)
    return model, vecnorm


def reset_log_std(log_std: Any, value: float | list[float]) -> None:
    """Sets the policy's log std (``init_log_std``): one value for every action, or one per
    action (``initial_model`` checked their number)."""
    import torch

    values = torch.as_tensor(value, dtype=log_std.dtype).expand(log_std.shape)
    with torch.no_grad():
        log_std.copy_(values)

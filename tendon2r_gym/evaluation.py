"""Evaluation: build a policy by name and measure it on seeded episodes (same seeds for all)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym

from tendon2r_gym.bundle import bundled_model
from tendon2r_gym.config import CONFIG_DIR, load_preset, preset_path
from tendon2r_gym.metrics import tracking_metrics
from tendon2r_gym.policies import ComputedTorquePolicy, PDPolicy
from tendon2r_gym.rollout import Policy, Trace, rollouts

POLICIES = ("pd", "ct", "ppo")


def env_kwargs_for(
    preset: str | None = None, env_config: str | None = None, **extra: Any
) -> dict[str, Any]:
    """Returns gym.make kwargs for a preset name or a YAML file with the preset's keys."""
    if env_config is not None:
        path = str(preset_path(env_config))
        load_preset(path)  # validates the sections early
        return {"preset": path, **extra}
    return {"preset": preset or "default", **extra}


def make_policy(
    name: str, env: gym.Env, model: str | Path | None = None, preset: str = "default"
) -> Policy:
    """Returns the policy ``name`` (pd, ct or ppo) for ``env``."""
    if name == "pd":
        return PDPolicy.from_env(env)
    if name == "ct":
        return ComputedTorquePolicy.from_env(env)
    if name == "ppo":
        from tendon2r_gym.learned import PPOPolicy

        return PPOPolicy.load(model or bundled_model(preset), env)
    raise ValueError(f"policy {name!r} is invalid; allowed: {POLICIES}")


def evaluate(
    name: str,
    env_kwargs: dict[str, Any],
    seeds: list[int],
    model: str | Path | None = None,
    options: dict[str, Any] | None = None,
) -> tuple[dict[str, Any], list[Trace]]:
    """Rolls policy ``name`` out on ``seeds``; returns (metrics, traces)."""
    make = lambda: gym.make("Tendon2R-v0", **env_kwargs)  # noqa: E731
    probe = make()
    preset = Path(str(env_kwargs.get("preset", "default"))).stem
    policy = make_policy(name, probe, model, preset)
    traces = rollouts(policy, make, seeds, options)
    return {"policy": name, **tracking_metrics(traces)}, traces


__all__ = ["CONFIG_DIR", "POLICIES", "bundled_model", "env_kwargs_for", "evaluate", "make_policy"]

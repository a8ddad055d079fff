"""Evaluation: build a policy by name and measure it on seeded episodes (same seeds for all)."""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from tendon2r_gym.artifacts.bundle import bundle_names, bundled_model
from tendon2r_gym.envs.env_config import EnvConfig, resolve
from tendon2r_gym.envs.registration import make as make_env
from tendon2r_gym.evaluation.metrics import tracking_metrics
from tendon2r_gym.evaluation.rollout import Policy, Trace, rollouts
from tendon2r_gym.policies.baselines import ComputedTorquePolicy, PDPolicy
from tendon2r_gym.validation import invalid


def _ppo(env: gym.Env, model: str | Path | None) -> Policy:
    from tendon2r_gym.policies.learned import PPOPolicy

    return PPOPolicy.load(model, env)


BASELINE, LEARNED = "baseline", "learned"


@dataclass(frozen=True)
class PolicyEntry:
    """One policy of the registry: its label in tables, its kind (a model-based baseline, or a
    learned policy that the benchmark compares with the baselines), and its factory."""

    label: str
    kind: str
    factory: Callable[[gym.Env, Any], Policy]  # (env, model file or None) -> policy
    takes_model: bool = False


#: The policy registry: the CLI's choices, the benchmark's rows and its verdicts derive from it.
#: A new baseline is its class (tendon2r_gym.policies.baselines) and one line here.
POLICIES: dict[str, PolicyEntry] = {
    "pd": PolicyEntry("PD", BASELINE, lambda env, _: PDPolicy.from_env(env)),
    "ct": PolicyEntry("CT", BASELINE, lambda env, _: ComputedTorquePolicy.from_env(env)),
    "ppo": PolicyEntry("PPO", LEARNED, _ppo, takes_model=True),
}


def names(kind: str | None = None) -> list[str]:
    """Returns the registered policy names (of one kind), in registry order."""
    return [k for k, v in POLICIES.items() if kind is None or v.kind == kind]


def resolve_model(
    policy: str, model: str | os.PathLike | None, bundle: str | None, env_kwargs: dict[str, Any]
) -> Path | None:
    """Returns the model file a policy needs: ``model``, or the primary seed of ``bundle``, or
    of the bundle named like the env's preset.  Raises for a model given to a policy that
    takes none."""
    if not _entry(policy).takes_model:
        if model is not None or bundle is not None:
            raise invalid(
                "model" if model is not None else "bundle",
                str(model or bundle),
                f"nothing: policy {policy!r} uses no model (only "
                f"{[k for k, v in POLICIES.items() if v.takes_model]} do)",
            )
        return None
    if model is not None:
        return Path(model)
    name = bundle or Path(str(env_kwargs.get("preset", "default"))).stem
    if name not in bundle_names():
        raise invalid("bundle", name, f"one of {bundle_names()}, or pass a model file with --model")
    return bundled_model(name)


def make_policy(name: str, env: gym.Env, model: str | Path | None = None) -> Policy:
    """Returns the policy ``name`` for ``env`` (a learned one loads ``model``)."""
    return _entry(name).factory(env, model)


def _entry(name: str) -> PolicyEntry:
    """Returns the POLICIES entry of ``name``, or raises naming the allowed ones."""
    if name not in POLICIES:
        raise invalid("policy", name, f"one of {sorted(POLICIES)}")
    return POLICIES[name]


#: The relative size of `Jittered`'s perturbations: float32's rounding (2**-24).
JITTER = 2.0**-24


class Jittered:
    """``policy`` with every entry of each command it returns scaled by 1 + JITTER or
    1 - JITTER (drawn per entry and step from ``seed``): its command with other last float32
    bits, as another CPU's float32 kernels would give.  Where the closed loop amplifies such
    bits, the rollouts' figures change; elsewhere they stay."""

    def __init__(self, policy: Policy, seed: int) -> None:
        self.policy, self.rng = policy, np.random.default_rng(seed)

    def reset(self, info: dict[str, Any]) -> None:
        reset = getattr(self.policy, "reset", None)
        if callable(reset):
            reset(info)

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        action, state = self.policy.predict(observation, state, episode_start, deterministic)
        action = np.asarray(action, dtype=np.float64)
        sign = self.rng.choice([-1.0, 1.0], size=action.shape)
        return action * (1.0 + sign * JITTER), state


def evaluate(
    name: str,
    env: EnvConfig | Mapping[str, Any],
    seeds: list[int],
    model: str | Path | None = None,
    options: dict[str, Any] | None = None,
    jitter: int | None = None,
) -> tuple[dict[str, Any], list[Trace]]:
    """Rolls policy ``name`` out on ``seeds`` of the env ``env`` (an EnvConfig, or env kwargs:
    resolved once); returns (metrics, traces).  ``jitter``: the policy is `Jittered` with
    that seed."""
    config = resolve(env)
    probe = make_env(preset=config)
    policy = make_policy(name, probe, model)
    probe.close()
    if jitter is not None:
        policy = Jittered(policy, jitter)
    traces = rollouts(policy, config, seeds, options)
    return {"policy": name, **tracking_metrics(traces)}, traces


#: Re-evaluations of a figure with its policy's commands perturbed in their last float32 bits
#: (`Jittered`, seeds 1 .. REPRO_RUNS): its ``reproducible_to`` is, per joint, the
#: largest change of its RMS error among them.
REPRO_RUNS = 2


def jittered_rms(
    policy: str,
    env: EnvConfig | Mapping[str, Any],
    seeds: list[int],
    model: str | Path | None,
    options: dict[str, Any] | None = None,
) -> list[list[float]]:
    """Returns the RMS error per joint of each of the REPRO_RUNS jittered re-evaluations (of
    the env ``env``, resolved once)."""
    config = resolve(env)
    return [
        evaluate(policy, config, seeds, model, options, jitter=k)[0]["rms_deg"]
        for k in range(1, REPRO_RUNS + 1)
    ]


def reproducible_to(rms_deg: list[float], jittered: list[list[float]]) -> list[float]:
    """Returns per joint the largest change of ``rms_deg`` among its jittered
    re-evaluations (0 without any)."""
    if not jittered:
        return [0.0] * len(rms_deg)
    return np.max(np.abs(np.subtract(jittered, rms_deg)), axis=0).tolist()

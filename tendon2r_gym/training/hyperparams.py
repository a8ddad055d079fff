"""The hyperparameters of one training run: a typed dataclass, validated once.

An entry of the hyperparameter file (``configs/ppo.yaml``, package data) is read with
``Hyperparams.from_entry``; a run folder's ``config.yaml`` with ``Hyperparams.from_dict``.
Both go through the same validation, and ``Hyperparams.replace`` validates overrides again,
so nothing downstream checks a value twice.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tendon2r_gym.envs.env_config import EnvConfig, resolve
from tendon2r_gym.policies.residual import Residual
from tendon2r_gym.presets import PPO_CONFIG, load_yaml
from tendon2r_gym.validation import check_keys, integer, invalid, mapping, number

VEC_ENVS = ("native", "subproc", "dummy")
MAX_FRAME_STACK = 64
MAX_FRAME_STRIDE = 1000
#: The range of init_log_std (SB3's log std of an action).
LOG_STD_RANGE = (-20.0, 2.0)
#: PPO settings that may be a schedule, as rl_zoo3 writes one: ``lin_<v>`` decays linearly from
#: v at the start of training to 0 at its end (SB3's progress_remaining times v).
SCHEDULES = ("learning_rate", "clip_range", "clip_range_vf")
LINEAR = "lin_"


#: An entry's key naming the entry it starts from (in its own file, else in PPO_CONFIG).
BASE = "base"


def merged(base: dict[str, Any], changes: dict[str, Any]) -> dict[str, Any]:
    """Returns ``base`` with ``changes`` on top: a mapping merges into the base's mapping
    (recursively), a null removes the key (its default), any other value replaces."""
    out = copy.deepcopy(base)
    for key, value in changes.items():
        if value is None:
            out.pop(key, None)
        elif isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merged(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def entry_values(name: str, path: str | Path = PPO_CONFIG, seen: tuple[str, ...] = ()) -> dict:
    """Returns entry ``name`` of the hyperparameter file ``path`` with its ``base`` resolved: the
    named entry (of the same file, else of the shipped file PPO_CONFIG) with this one's values
    on top (``merged``)."""
    table = load_yaml(path)
    if name not in table:
        if Path(path).resolve() != PPO_CONFIG.resolve() and name in load_yaml(PPO_CONFIG):
            return entry_values(name, PPO_CONFIG, seen)
        raise invalid("hyperparams", name, f"an entry of {path}: {sorted(table)}")
    if name in seen:
        raise invalid(f"{path}: {name}.{BASE}", name, f"no cycle (through {list(seen)})")
    values = mapping(f"{path}: {name}", table[name])
    base = values.pop(BASE, None)
    if base is None:
        return values
    if not isinstance(base, str):
        raise invalid(f"{path}: {name}.{BASE}", base, "the name of another entry")
    return merged(entry_values(base, path, (*seen, name)), values)


@dataclass(frozen=True)
class Hyperparams:
    """One entry of configs/ppo.yaml (see the comments there for each field)."""

    env_kwargs: dict[str, Any]  # Tendon2R-v0 kwargs (a preset or experiment file and overrides)
    total_timesteps: int
    n_envs: int
    eval_seeds: list[int]
    eval_freq: int  # env steps between evaluations
    checkpoint_freq: int  # env steps between checkpoints
    residual_scale: float = 0.0  # > 0: residual on PD (command = PD + scale * action)
    # With residual_scale > 0: the time constant (s) of a first-order low-pass on the residual
    # alone, PD's command unfiltered (tendon2r_gym.policies.residual.ResidualFilter).  0: none.
    residual_filter_tau: float = 0.0
    vec_env: str = "subproc"  # native, subproc or dummy
    torch_threads: int = 1
    ppo: dict[str, Any] = field(default_factory=dict)  # SB3 PPO keyword arguments
    policy_kwargs: dict[str, Any] = field(default_factory=dict)
    normalize: dict[str, Any] = field(default_factory=dict)  # VecNormalize keyword arguments
    checkpoint_minutes: float = 2.0  # and a checkpoint at least this often (wall time)
    # Observation entries (EnvConfig.observation.entries(): e.g. arm, or one drawn field such as
    # arm.density_scale) that only the critic sees (a privileged critic):
    # tendon2r_gym.training.split_view.
    hide_from_actor: tuple[str, ...] = ()
    # Start from a trained model's weights and VecNormalize statistics (fine-tuning): a bundle
    # name (e.g. generalist) or a model zip; it must cover the env (learned.check_model_env).
    init_from: str | None = None
    # With init_from: the exploration noise the fine-tune starts from, SB3's log std of the
    # actions: one number for all, or one per action (the source's own shrank in its training;
    # PPO's clipped steps scale with it, so a fine-tune on the source's stalls).  None keeps
    # the source's.
    init_log_std: float | list[float] | None = None
    # The policy sees its last frame_stack observations, oldest first (rl_zoo3's frame_stack:
    # SB3's VecFrameStack after VecNormalize; zeros before an episode's first): a short history
    # from which to tell the arm's response, e.g. under per-episode randomization.
    frame_stack: int = 1
    # The stacked frames are frame_stride control steps apart (tendon2r_gym.policies.history): the
    # same
    # frame_stack inputs span (frame_stack - 1) * frame_stride + 1 steps.  1: VecFrameStack.
    frame_stride: int = 1

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        set_("env_kwargs", mapping("env_kwargs", self.env_kwargs))
        integer("total_timesteps", self.total_timesteps, 1, 10**10)
        integer("n_envs", self.n_envs, 1, 1024)
        integer("torch_threads", self.torch_threads, 1, 256)
        integer("frame_stack", self.frame_stack, 1, MAX_FRAME_STACK)
        integer("frame_stride", self.frame_stride, 1, MAX_FRAME_STRIDE)
        if self.frame_stride > 1 and self.frame_stack == 1:
            raise invalid("frame_stride", self.frame_stride, "1 when frame_stack is 1")
        residual = Residual(self.residual_scale, self.residual_filter_tau)  # validates both
        set_("residual_scale", residual.scale)
        set_("residual_filter_tau", residual.filter_tau)
        integer("eval_freq", self.eval_freq, 1, 10**10)
        integer("checkpoint_freq", self.checkpoint_freq, 1, 10**10)
        set_(
            "checkpoint_minutes",
            number("checkpoint_minutes", self.checkpoint_minutes, 0.0, lo_open=True),
        )
        if isinstance(self.eval_seeds, (str, bytes)) or not hasattr(self.eval_seeds, "__iter__"):
            raise invalid("eval_seeds", self.eval_seeds, "a list of integer seeds")
        set_("eval_seeds", [integer("eval_seeds", s, 0, 2**32 - 1) for s in self.eval_seeds])
        if not self.eval_seeds:
            raise invalid("eval_seeds", self.eval_seeds, "one or more integer seeds")
        if self.init_from is not None and not isinstance(self.init_from, str):
            raise invalid("init_from", self.init_from, "None, a bundle name or a model .zip")
        if self.init_log_std is not None:
            if self.init_from is None:
                raise invalid("init_log_std", self.init_log_std, "None without init_from")
            values, (lo, hi) = self.init_log_std, LOG_STD_RANGE
            if isinstance(values, (list, tuple)):
                if not values:
                    raise invalid(
                        "init_log_std", values, f"a number in [{lo:g}, {hi:g}], or one per action"
                    )
                set_("init_log_std", [number("init_log_std", v, lo, hi) for v in values])
            else:
                set_("init_log_std", number("init_log_std", values, lo, hi))
        if self.vec_env not in VEC_ENVS:
            raise invalid("vec_env", self.vec_env, f"one of {VEC_ENVS}")
        for name in ("ppo", "policy_kwargs", "normalize"):
            set_(name, mapping(name, getattr(self, name)))
        for key in SCHEDULES:
            if key in self.ppo:
                schedule(f"ppo.{key}", self.ppo[key])
        env_config = resolve(self.env_kwargs)  # once, before any worker starts
        hidden = tuple(self.hide_from_actor or ())
        check_keys("hide_from_actor", hidden, env_config.observation.entries())
        set_("hide_from_actor", hidden)
        set_("_env_config", env_config)  # not a field: no record holds it

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, values: dict[str, Any], where: str = "hyperparameters") -> Hyperparams:
        """Builds from a mapping with the fields as keys (an entry, or a run's config.yaml)."""
        values = copy.deepcopy(mapping(where, values))
        check_keys(where, values, keys())
        missing = [f.name for f in dataclasses.fields(cls) if _required(f) and f.name not in values]
        if missing:
            raise invalid(where, sorted(values), f"a mapping that also has {missing}")
        return cls(**values)

    @classmethod
    def from_entry(
        cls, name: str = "default", path: str | Path = PPO_CONFIG, env_config: str | None = None
    ) -> Hyperparams:
        """Returns entry ``name`` of a hyperparameter file.  ``env_config`` (a preset name or
        experiment-file path) replaces the entry's env preset, keeping its other env kwargs."""
        values = entry_values(name, path)
        if env_config is not None:
            env_kwargs = {**mapping("env_kwargs", values.get("env_kwargs")), "preset": env_config}
            values = {**values, "env_kwargs": env_kwargs}
        return cls.from_dict(values, f"{path}: {name}")

    def replace(self, **changes: Any) -> Hyperparams:
        """Returns a validated copy with the named fields changed."""
        return Hyperparams.from_dict({**self.to_dict(), **changes})

    def to_dict(self) -> dict[str, Any]:
        """Returns plain YAML-friendly values (what a run's config.yaml holds)."""
        out = copy.deepcopy(dataclasses.asdict(self))
        out["hide_from_actor"] = list(self.hide_from_actor)
        return out

    # -- derived quantities ----------------------------------------------------------------------
    @property
    def env_config(self) -> EnvConfig:
        """Returns the EnvConfig of env_kwargs, resolved once (at construction): what the run's
        envs are made of."""
        return self._env_config

    @property
    def residual(self) -> Residual:
        """Returns how the policy's action joins PD's command (residual_scale and
        residual_filter_tau: tendon2r_gym.policies.residual.Residual)."""
        return Residual(self.residual_scale, self.residual_filter_tau)

    @property
    def gamma(self) -> float:
        """Returns PPO's discount (also VecNormalize's, for reward normalization)."""
        return float(self.ppo.get("gamma", 0.99))

    @property
    def rollout_steps(self) -> int:
        """Returns the env steps per PPO update: n_envs x n_steps."""
        return self.n_envs * int(self.ppo.get("n_steps", 2048))

    def ppo_kwargs(self) -> dict[str, Any]:
        """Returns SB3 PPO's keyword arguments: ``ppo`` with each ``lin_<v>`` its SB3 schedule
        (``sb3_schedule``; validated at construction)."""
        out = dict(self.ppo)
        for key in SCHEDULES:
            value = out.get(key)
            if isinstance(value, str):
                out[key] = sb3_schedule(value)
        return out

    def policy(self, env_config: EnvConfig) -> tuple[Any, dict[str, Any]]:
        """Returns SB3's policy (MlpPolicy, or SplitViewPolicy when an entry is hidden from
        the actor) and its policy_kwargs, for an env of ``env_config``."""
        if not self.hide_from_actor:
            return "MlpPolicy", self.policy_kwargs
        from tendon2r_gym.training.split_view import SplitViewPolicy

        keep = env_config.observation.mask(self.hide_from_actor).tolist()
        # one mask per stacked frame
        return SplitViewPolicy, {**self.policy_kwargs, "actor_keep": keep * self.frame_stack}


def schedule(field: str, value: Any) -> float | str | None:
    """Returns a positive number as a float, ``lin_<v>`` (rl_zoo3's notation, v > 0) as it is,
    or None (no value clipping); raises naming ``field`` otherwise."""
    if value is None:
        return None
    allowed = f"a positive number or '{LINEAR}<positive number>' (linear decay to 0)"
    if isinstance(value, str):
        if not value.startswith(LINEAR):
            raise invalid(field, value, allowed)
        try:
            number(field, linear_schedule(value), 0.0, lo_open=True)
        except ValueError:
            raise invalid(field, value, allowed) from None
        return value
    return number(field, value, 0.0, lo_open=True)


def linear_schedule(value: str) -> float:
    """Returns v of a ``lin_<v>`` schedule; raises ValueError if v is not a number."""
    return float(value[len(LINEAR) :])


def sb3_schedule(value: str) -> Any:
    """Returns SB3's schedule of a validated ``lin_<v>``: SB3's LinearSchedule from v to 0 over
    the run."""
    from stable_baselines3.common.utils import LinearSchedule

    return LinearSchedule(linear_schedule(value), 0.0, 1.0)


def scaled_schedule(value: float | str, factor: float) -> float | str:
    """Returns a number or a ``lin_<v>`` schedule times ``factor`` (``lin_<v * factor>``)."""
    if isinstance(value, str) and value.startswith(LINEAR):
        return f"{LINEAR}{linear_schedule(value) * factor:g}"
    return float(value) * factor


def keys() -> list[str]:
    """Returns the keys a hyperparameter entry may hold."""
    return [f.name for f in dataclasses.fields(Hyperparams)]


def _required(f: dataclasses.Field) -> bool:
    return f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING

"""Stable-Baselines3's VecEnv API over the native vector env (tendon2r_gym.envs.vector_env)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from tendon2r_gym.envs.env_config import EnvConfig, resolve
from tendon2r_gym.policies.baselines import PDPolicy
from tendon2r_gym.policies.residual import NO_RESIDUAL, Residual, ResidualFilter, residual_command
from tendon2r_gym.task.gains import gains_of
from tendon2r_gym.validation import invalid


class SB3VecEnv(VecEnv):
    """Stable-Baselines3's VecEnv API over the native vector env (tendon2r_gym.envs.vector_env) in
    Gymnasium's SAME_STEP autoreset mode: ``terminal_observation`` and ``TimeLimit.truncated``
    go in each env's info, as SB3's own VecEnvs put them.  With an active ``residual``
    (tendon2r_gym.policies.residual.Residual) it also adds the agent's action to a batched PD
    command
    (one numpy call for all arms), through the residual's filter, at its scale."""

    def __init__(self, venv: Any, residual: Residual = NO_RESIDUAL) -> None:
        from gymnasium.vector import AutoresetMode

        if venv.autoreset_mode != AutoresetMode.SAME_STEP:
            raise invalid("autoreset_mode", venv.autoreset_mode, "SAME_STEP for SB3")
        self.venv = venv  # before VecEnv's init, which reads the env's render_mode
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self.residual = residual
        self.pd = PDPolicy.from_env(venv) if residual.active else None
        self.filter = ResidualFilter(residual.filter_tau, venv.config.ctrl_dt)
        self._starts = np.ones(venv.num_envs, dtype=bool)  # a slot's episode starts
        ranges = venv.config.mechanism_ranges
        self._random_arms = ranges is not None
        self._drawn_gains = ranges is not None and ranges.draws_gains
        self._raw: np.ndarray | None = None
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        seeds = list(self._seeds)
        self._raw, info = self.venv.reset(seed=seeds if any(s is not None for s in seeds) else None)
        self.reset_infos = _arm_infos(info, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        self._starts[:] = True
        return self._raw.copy()  # PD reads self._raw: the caller gets its own

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        actions = self._actions
        if self.pd is not None:
            if self._random_arms:  # PD follows each slot's arm
                arms = self.venv.arms
                gains = [gains_of(a.pd_gains) for a in arms] if self._drawn_gains else None
                self.pd.follow(
                    [a.mechanism for a in arms], [a.observation_delay for a in arms], gains
                )
            base, _ = self.pd.predict(self._raw)
            actions = residual_command(
                base, actions, self.residual.scale, self.filter, self._starts
            )
        obs, rewards, terminated, truncated, info = self.venv.step(actions)
        dones = terminated | truncated
        infos = _arm_infos(info, self.num_envs)
        if np.any(dones):  # as DummyVecEnv: the last step's info, the reset's info apart
            final = _arm_infos(info["final_info"], self.num_envs)
            for i in np.flatnonzero(dones):
                self.reset_infos[i], infos[i] = infos[i], final[i]
                infos[i]["terminal_observation"] = info["final_obs"][i]
        for i in range(self.num_envs):  # as DummyVecEnv: on every step
            infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
        self._raw, self._starts = obs, dones
        return obs.copy(), rewards.astype(np.float32), dones, infos

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


def make_native(
    n_envs: int,
    env: EnvConfig | Mapping[str, Any],
    residual: Residual = NO_RESIDUAL,
    seed: int | None = None,
) -> VecEnv:
    """Returns the native vector env for SB3 training of ``env`` (an EnvConfig, or env
    kwargs: resolved once): N arms in one process with staggered first episodes, batched PD
    for an active ``residual`` (its filter and scale), and SB3's VecMonitor."""
    from stable_baselines3.common.vec_env import VecMonitor

    from tendon2r_gym.envs.vector_env import Tendon2RVectorEnv

    native = Tendon2RVectorEnv(n_envs, resolve(env), autoreset_mode="SameStep", stagger=True)
    venv = SB3VecEnv(native, residual)
    venv.seed(seed)
    return VecMonitor(venv)


def _arm_infos(info: dict[str, Any], n: int) -> list[dict[str, Any]]:
    """Returns each of the n arms' entries of a Gymnasium vector info (the keys whose mask
    holds the arm), in the info's key order: one pass over the keys, not over the arms."""
    infos: list[dict[str, Any]] = [{} for _ in range(n)]
    for k, v in info.items():
        if k.startswith("_") or k in ("final_obs", "final_info"):
            continue
        rows = _arm_infos(v, n) if isinstance(v, dict) else v
        for i in np.flatnonzero(info[f"_{k}"]):
            infos[i][k] = rows[i]
    return infos

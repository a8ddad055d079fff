"""A native vector env: N arms of one model stepped in one process by ``mujoco.batch``.

``gym.make_vec("Tendon2R-v0", num_envs=N, vectorization_mode="vector_entry_point")`` returns
:class:`Tendon2RVectorEnv`.  One MjModel and N simulations are stepped by MuJoCo's batch API
(C threads, results bit-identical to one MjData per simulation); the observation, reward,
reference and divergence checks are batched numpy over the N arms.  The same seeds give the
same trajectories, observations and rewards as N single envs (``gym.make``), bit for bit.

Gymnasium 1.x conventions: ``autoreset_mode`` NEXT_STEP by default (SAME_STEP on request,
which SB3's adapter uses), per-env ``info`` arrays with their ``_key`` masks, truncation after
``episode_duration / ctrl_dt`` steps.  :class:`SB3VecEnv` exposes it to Stable-Baselines3.
"""

from __future__ import annotations

import math
import os
from typing import Any

import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from mujoco import batch as mj_batch

from tendon2r_gym import observation as obs_layout
from tendon2r_gym.config import merge_reference
from tendon2r_gym.env import (
    _DIVERGENCE_WARNINGS,
    DIVERGED_PAST_LIMIT,
    DIVERGED_SPEED,
    RAD_PER_DEG,
    _log_error,
)
from tendon2r_gym.env_config import EnvConfig
from tendon2r_gym.model import build_model, tendon_name
from tendon2r_gym.reference import Reference
from tendon2r_gym.validation import boolean, integer, invalid


class Tendon2RVectorEnv(VectorEnv):
    """N Tendon2R-v0 arms in one process (see the module docstring).  Takes the arguments of
    Tendon2R-v0 (preset, mechanism, reference, ...) plus ``num_envs``, ``autoreset_mode``,
    ``nthread`` (MuJoCo batch threads; None: one per ARMS_PER_THREAD arms, up to the CPUs this
    process may use; 0: one per CPU) and ``stagger`` (training: after each
    full reset, arm i's episode is already i / N of the way to its step limit, so the arms
    desynchronize; off by default, as it breaks the equality with single envs)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int,
        preset: str | os.PathLike = "default",
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        nthread: int | None = None,
        max_episode_steps: int | None = None,
        stagger: bool = False,
        **kwargs: Any,
    ) -> None:
        self.num_envs = integer("num_envs", num_envs, 1, 1_000_000)
        self.config = cfg = EnvConfig.make(preset, **kwargs)
        modes = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)
        if autoreset_mode not in modes + tuple(m.value for m in modes):
            allowed = " or ".join(f"AutoresetMode.{m.name} ({m.value!r})" for m in modes)
            raise invalid("autoreset_mode", autoreset_mode, allowed)
        mode = AutoresetMode(autoreset_mode)
        self.metadata = {**type(self).metadata, "autoreset_mode": mode}
        self.autoreset_mode = mode
        self.max_episode_steps = (
            cfg.max_episode_steps
            if max_episode_steps is None
            else integer("max_episode_steps", max_episode_steps, 1, 10**9)
        )
        self.mechanism, self.ctrl_dt = cfg.mechanism, cfg.ctrl_dt
        n_act = cfg.mechanism.n_tendons
        self.single_action_space = spaces.Box(-1.0, 1.0, (n_act,), np.float32)
        self.single_observation_space = spaces.Box(
            -np.inf, np.inf, (obs_layout.size(cfg.preview_steps),), np.float64
        )
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)

        self.model = build_model(cfg.mechanism)
        if nthread is None:
            nthread = default_nthread(self.num_envs)
        nthread = integer("nthread", nthread, 0, 4096)
        self.batch = mj_batch.Batch(self.model, self.num_envs, nthread=nthread)
        b = self.batch
        self._qpos, self._qvel, self._ctrl, self._time = (
            b.bind(k) for k in ("qpos", "qvel", "ctrl", "time")
        )
        first = self.model.sensor(f"force_{tendon_name(0)}").adr[0]
        self._sensors = b.bind("sensordata")
        self._force = slice(first, first + n_act)
        self._warn_ids = [int(w) for w in _DIVERGENCE_WARNINGS]
        q_lo, q_hi = cfg.mechanism.joint_range_rad
        self._q_lo, self._q_hi = q_lo, q_hi
        self._div_lo, self._div_hi = q_lo - DIVERGED_PAST_LIMIT, q_hi + DIVERGED_PAST_LIMIT
        self._offsets = np.arange(1, cfg.preview_steps + 1) * cfg.preview_dt
        self._w = tuple(cfg.reward_scales[k] for k in ("tracking", "ctrl", "divergence"))
        self._log_norm = 2.0 * math.log1p((180.0 / cfg.tracking_sigma_deg) ** 2)

        n = self.num_envs
        self._rngs = [seeding.np_random()[0] for _ in range(n)]
        self._refs: list[Reference] = [cfg.reference] * n
        self._amp, self._bias, self._omega, self._phase = (np.zeros((n, 2)) for _ in range(4))
        self._set_references(np.arange(n), [cfg.reference] * n)
        self._steps = np.zeros(n, dtype=np.int64)
        self._warn_count = np.zeros(n, dtype=np.int64)
        self._needs_reset = np.zeros(n, dtype=bool)
        # Training: the arms' first episodes end at staggered steps, so that every rollout
        # samples all phases of the reference instead of N copies of the same window.
        self._stagger = boolean("stagger", stagger)
        self._last_obs = np.zeros((n, self.single_observation_space.shape[0]))

    # -- references --------------------------------------------------------------------------
    def _set_references(self, ids: np.ndarray, refs: list[Reference]) -> None:
        for i, ref in zip(ids, refs, strict=True):
            self._refs[i] = ref
            self._amp[i], self._bias[i] = ref._amp, ref._bias
            self._omega[i], self._phase[i] = ref._omega, ref._phase

    # -- reset ---------------------------------------------------------------------------------
    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Resets every arm (or ``options["reset_mask"]``); seed s seeds arm i with s + i, as
        Gymnasium's SyncVectorEnv does.  ``options={"reference": {...}}`` fixes the reference,
        as on the single env."""
        n = self.num_envs
        mask = np.ones(n, dtype=bool)
        if options and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], dtype=bool)
        if isinstance(seed, (list, tuple)):
            seeds = list(seed)
        else:
            seeds = [None if seed is None else seed + i for i in range(n)]
        ids = np.flatnonzero(mask)
        for i in ids:
            if seeds[i] is not None:
                self._rngs[i], _ = seeding.np_random(seeds[i])
        fixed = None
        if options and "reference" in options:
            fixed = Reference.from_dict(
                merge_reference(self.config.reference.to_dict(), options["reference"])
            )
            if problems := fixed.workspace_violations(self.mechanism):
                raise ValueError(f"options['reference'] leaves the workspace: {problems}")
        self._reset_ids(ids, fixed)
        if self._stagger:
            self._steps[ids] = (ids * self.max_episode_steps) // n
        obs = self._observe()
        self._last_obs[ids] = obs[ids]
        info = self._reset_info(ids)
        return obs.copy(), info

    def _reset_ids(self, ids: np.ndarray, fixed: Reference | None = None) -> None:
        """Resets arms ``ids`` as Tendon2REnv.reset_model does, with each arm's own RNG."""
        if len(ids) == 0:
            return
        cfg, ranges = self.config, self.config.reference_ranges
        refs = []
        for i in ids:
            if fixed is not None:
                refs.append(fixed)
            elif ranges is not None:
                refs.append(ranges.sample(self._rngs[i], self.mechanism))
            else:
                refs.append(cfg.reference)
        self._set_references(ids, refs)
        self.batch.reset(ids, stage=mujoco.mjtStage.mjSTAGE_NONE.value)
        noise = cfg.reset_noise_scale
        for i, ref in zip(ids, refs, strict=True):
            rng = self._rngs[i]
            q = ref.q(0.0) + rng.uniform(-noise, noise, 2)
            qdot = ref.qdot(0.0) + rng.uniform(-noise, noise, 2)
            self._qpos[i] = np.clip(q, self._q_lo, self._q_hi)
            self._qvel[i] = qdot
        self.batch.forward(ids)
        self._steps[ids] = 0
        self._warn_count[ids] = self._warnings()[ids]
        self._needs_reset[ids] = False

    def _reset_info(self, ids: np.ndarray) -> dict[str, Any]:
        mask = np.zeros(self.num_envs, dtype=bool)
        mask[ids] = True
        return {
            "force_need_N": np.full(self.num_envs, self.config.force_need),
            "_force_need_N": mask,
        }

    # -- step ----------------------------------------------------------------------------------
    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        n, n_act = self.num_envs, self.single_action_space.shape[0]
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != (n, n_act):
            raise ValueError(f"actions have shape {a.shape}; allowed: ({n}, {n_act}) in [-1, 1]")
        if not np.isfinite(a).all():
            raise ValueError(f"actions = {a.tolist()} are not all finite; allowed: [-1, 1]")
        a = a.clip(-1.0, 1.0)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        # NEXT_STEP: arms that ended last step are reset now and report the reset observation.
        resetting = self._needs_reset.copy()
        if resetting.any():
            self._reset_ids(np.flatnonzero(resetting))
            ids = active = np.flatnonzero(~resetting)
        else:  # the common step: every arm, without index arrays
            ids, active = None, slice(None)
        self._ctrl[active] = a[active]
        failed = np.zeros(n, dtype=bool)
        try:
            self.batch.step(ids, nstep=self.config.n_substeps)
        except mj_batch.SimulationError as e:  # MuJoCo raised: those arms diverged
            failed[e.ids] = True
        diverged = self._check_divergence(active, failed)
        obs = self._observe()
        if diverged.any():
            obs[diverged] = self._last_obs[diverged]  # the last good state, as the single env
        rewards, terms = self._rewards(obs, a, diverged)
        rewards[resetting] = 0.0
        self._steps[active] += 1
        terminated[active] = diverged[active]
        # As Gymnasium's TimeLimit: truncated at the step limit, terminated or not.
        truncated[active] = self._steps[active] >= self.max_episode_steps
        info = self._step_info(obs, terms, diverged, ~resetting)
        done = terminated | truncated
        self._last_obs[:] = obs
        if self.autoreset_mode == AutoresetMode.SAME_STEP and done.any():
            ids = np.flatnonzero(done)
            info["final_obs"] = np.full(n, None, dtype=object)
            for i in ids:
                info["final_obs"][i] = obs[i].copy()
            info["_final_obs"] = done.copy()
            self._reset_ids(ids)
            fresh = self._observe()
            obs[ids] = fresh[ids]
            self._last_obs[ids] = fresh[ids]
        else:
            self._needs_reset = done
        return obs.copy(), rewards, terminated, truncated, info

    def _warnings(self) -> np.ndarray:
        return self.batch.warning[:, self._warn_ids, 1].sum(axis=1)  # (lastinfo, number)

    def _check_divergence(self, active: np.ndarray | slice, failed: np.ndarray) -> np.ndarray:
        """Per arm: a new MuJoCo instability warning, a failed call, a joint far past its limit
        or too fast, or a non-finite state; a diverged arm is left in a finite state."""
        warn = self._warnings()
        q, w = self._qpos, self._qvel
        with np.errstate(invalid="ignore"):
            bad = (
                (warn > self._warn_count)
                | failed
                | ~np.all((q > self._div_lo) & (q < self._div_hi), axis=1)
                | ~np.all(np.abs(w) < DIVERGED_SPEED, axis=1)
            )
        self._warn_count[:] = warn
        mask = np.zeros(self.num_envs, dtype=bool)
        mask[active] = bad[active]
        if mask.any():
            q[mask] = np.nan_to_num(q[mask], nan=0.0, posinf=0.0, neginf=0.0)
            w[mask] = 0.0
        return mask

    def _observe(self) -> np.ndarray:
        """The observations of every arm, written by the named slices of
        tendon2r_gym.observation, with the same floating-point operations as
        Tendon2REnv._get_obs (numpy's float64 sin and cos round as math's do; tested)."""
        m, L = self.mechanism, obs_layout
        q, w = self._qpos, self._qvel
        out = np.empty((self.num_envs, self.single_observation_space.shape[0]))
        out[:, L.Q], out[:, L.DQ] = q, w
        arg = self._omega * self._time[:, None] + self._phase  # (N, 2)
        q_des = self._amp * np.sin(arg) + self._bias
        out[:, L.Q_DES] = q_des
        out[:, L.DQ_DES] = self._amp * self._omega * np.cos(arg)
        e = out[:, L.ERROR] = q_des - q
        out[:, L.ERROR_LOG] = _log_errors(e)
        angle = np.empty((self.num_envs, 2))  # link c, link b
        angle[:, 0] = q[:, 0]
        angle[:, 1] = q[:, 0] + q[:, 1]
        cos, sin = np.cos(angle), np.sin(angle)
        (c1, c12), (s1, s12) = cos.T, sin.T
        w1, w12 = w[:, 0], w[:, 0] + w[:, 1]
        out[:, L.EFFECTOR_POS] = np.stack(
            [m.a + m.c * c1 + m.b * c12, m.c * s1 + m.b * s12], axis=1
        )
        out[:, L.EFFECTOR_VEL] = np.stack(
            [-m.c * s1 * w1 - m.b * s12 * w12, m.c * c1 * w1 + m.b * c12 * w12], axis=1
        )
        # q_des(t + k dt) for every k at once: (N, P, 2), stored k by k, A then B.
        ahead = arg[:, None, :] + self._omega[:, None, :] * self._offsets[None, :, None]
        preview = self._amp[:, None, :] * np.sin(ahead) + self._bias[:, None, :]
        out[:, L.preview_slice(len(self._offsets))] = preview.reshape(self.num_envs, -1)
        return out

    def _rewards(
        self, obs: np.ndarray, a: np.ndarray, diverged: np.ndarray
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        w_track, w_ctrl, w_div = self._w
        e = obs[:, obs_layout.ERROR] / RAD_PER_DEG
        if self.config.tracking_form == "log":
            sig = self.config.tracking_sigma_deg
            u = e / sig  # math.log1p, as the single env: numpy's may differ in the last bit
            logs = np.fromiter(map(math.log1p, (u * u).ravel().tolist()), float, u.size)
            logs = logs.reshape(e.shape)
            tracking = 1.0 - (logs[:, 0] + logs[:, 1]) / self._log_norm
        else:
            tracking = -(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1])
        terms = {
            "tracking": w_track * tracking,
            "ctrl": -w_ctrl * np.sum(a * a, axis=1),
            "divergence": np.where(diverged, -w_div, 0.0),
        }
        return sum(terms.values()), terms

    def _step_info(
        self, obs: np.ndarray, terms: dict[str, np.ndarray], diverged: np.ndarray, mask: np.ndarray
    ) -> dict[str, Any]:
        values = {
            **{f"reward_{k}": v for k, v in terms.items()},
            "tracking_error_deg": obs[:, obs_layout.ERROR] / RAD_PER_DEG,
            "tendon_tension": -self._sensors[:, self._force],
            "time": self._time.copy(),
            "diverged": diverged,
        }
        info: dict[str, Any] = {}
        for key, value in values.items():
            info[key], info[f"_{key}"] = value, mask.copy()
        return info

    def close_extras(self, **kwargs: Any) -> None:
        self.batch = None


#: Arms per MuJoCo batch thread by default.  On 2 cores (python scripts/bench_speed.py, columns
#: native_1thread and native_2threads of results/speed.md), a second thread pays from 16 arms
#: on; at 8 arms and fewer, one and two threads differ by less than the noise between runs.
ARMS_PER_THREAD = 8


def default_nthread(num_envs: int) -> int:
    """Returns the default number of MuJoCo batch threads: one per ARMS_PER_THREAD arms, at
    least one, at most the CPUs this process may run on."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(cpus or 1, num_envs // ARMS_PER_THREAD))


def _log_errors(e: np.ndarray) -> np.ndarray:
    """The single env's ``_log_error`` on every entry of e (math.log1p, bit for bit: numpy's
    log1p may differ in the last bit)."""
    return np.fromiter(map(_log_error, e.ravel().tolist()), float, e.size).reshape(e.shape)

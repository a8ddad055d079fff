"""A native vector env: N arms of one model stepped in one process by ``mujoco.batch``.

``gym.make_vec("Tendon2R-v1", num_envs=N, vectorization_mode="vector_entry_point")`` returns
`Tendon2RVectorEnv`.  One MjModel and N simulations are stepped by MuJoCo's batch API
(C threads, results bit-identical to one MjData per simulation); the observation, reward,
reference and divergence checks are the formulas of tendon2r_gym.envs.formulas on numpy arrays
over the N arms.  The same seeds give the same trajectories, observations, rewards and infos as
N single envs (``gym.make``), bit for bit.

Gymnasium 1.x conventions: ``autoreset_mode`` NEXT_STEP by default (SAME_STEP on request,
which SB3's adapter uses), per-env ``info`` arrays with their ``_key`` masks, truncation after
``episode_duration / ctrl_dt`` steps.  tendon2r_gym.training.vector_env_sb3 exposes it to
Stable-Baselines3.
"""

from __future__ import annotations

import os
from typing import Any

import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from mujoco import batch as mj_batch

from tendon2r_gym.envs.env_config import EnvConfig, resolve
from tendon2r_gym.envs.formulas import (
    DIVERGENCE_WARNING_IDS,
    Formulas,
    arm_params,
    reference_params,
)
from tendon2r_gym.envs.timing import Timing
from tendon2r_gym.envs.vector_info import autoreset, with_final, without_empty
from tendon2r_gym.ops import BATCH
from tendon2r_gym.simulation.actuation import TorqueToTension, cond_of_rows, sparse_rows
from tendon2r_gym.simulation.model import build_model, tendon_name
from tendon2r_gym.simulation.realism import CommandDelay, Drive, Sensors
from tendon2r_gym.task import observation as obs_layout
from tendon2r_gym.task.reference import Reference
from tendon2r_gym.validation import boolean, integer, invalid, real_array


class Tendon2RVectorEnv(VectorEnv):
    """N Tendon2R arms in one process (see the module docstring).  Takes the arguments of
    the Tendon2R env (preset, mechanism, reference, ..., or a resolved EnvConfig as ``preset``
    or ``config``) plus ``num_envs``, ``autoreset_mode``, ``nthread`` (MuJoCo batch threads;
    None: one per ARMS_PER_THREAD arms, up to the CPUs this process may use; 0: one per CPU)
    and ``stagger`` (training: after each full reset, arm i's episode is already i / N of the
    way to its step limit, so the arms desynchronize; off by default, as it breaks the
    equality with single envs)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int,
        preset: EnvConfig | str | os.PathLike = "default",
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        nthread: int | None = None,
        max_episode_steps: int | None = None,
        stagger: bool = False,
        **kwargs: Any,
    ) -> None:
        self.num_envs = integer("num_envs", num_envs, 1, 1_000_000)
        self.config = cfg = resolve(preset, **kwargs)
        self.timing = timing = Timing.of(cfg)
        mode = autoreset(autoreset_mode)
        self.metadata = {**type(self).metadata, "autoreset_mode": mode}
        self.autoreset_mode = mode
        self.max_episode_steps = (
            timing.max_episode_steps
            if max_episode_steps is None
            else integer("max_episode_steps", max_episode_steps, 1, 10**9)
        )
        self.mechanism, self.ctrl_dt = cfg.mechanism, cfg.ctrl_dt
        n_act = cfg.n_actions
        self.single_action_space = spaces.Box(-1.0, 1.0, (n_act,), np.float32)
        n_obs = cfg.observation.size
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (n_obs,), np.float64)
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
        self._force = slice(first, first + cfg.mechanism.n_tendons)
        #: In ``action_mode="joint_torque"``, the map from normalized joint torques to tendon
        #: commands (the single env's ``torque_map``, batched over the arms); None in tension mode.
        self.torque_map: TorqueToTension | None = None
        if cfg.action_mode == "joint_torque":
            self.torque_map = TorqueToTension(cfg.mechanism)
        self._ten_J = b.bind("ten_J")
        self._J_rows = sparse_rows(self.model)
        # Realism (tendon2r_gym.simulation.realism): spools and lags; an arm is put at
        # rest on a scratch MjData, as the single env does it, and copied into the batch.
        self.drive = Drive(self.model, cfg.mechanism)
        if self.drive.has_state:
            self._scratch = mujoco.MjData(self.model)
            self._act = b.bind("act")
        self._delay: CommandDelay | None = None
        if timing.delay_capacity:
            n_motors = cfg.mechanism.n_tendons
            self._delay = CommandDelay(timing.delay_capacity, self.num_envs, n_motors)
        self._sensing: Sensors | None = None
        if timing.sensed:  # the observation is a measurement; reward and info are true
            n_late = timing.observation_delay_capacity
            self._sensing = Sensors(n_late, self.num_envs, timing.noisy)
        for i in range(self.num_envs):
            self._bind_delays(i, cfg, self.drive, timing)
        if cfg.mechanism.elastic:
            self._qfrc_passive = b.bind("qfrc_passive")  # the cables' force on their spools
        self.formulas = Formulas(cfg)

        n = self.num_envs
        # Each arm's config, model, drive, observed numbers (arm_params, one row per number)
        # and rest command: all the nominal arm's, until mechanism_ranges draws new arms.
        self._arm_cfgs: list[EnvConfig] = [cfg] * n
        self._models: list[mujoco.MjModel] = [self.model] * n
        self._drives: list[Drive] = [self.drive] * n
        self._arm = np.tile(np.array(arm_params(cfg, cfg))[:, None], (1, n))
        self._rest = np.tile(np.array(self.formulas.rest_command(cfg)), (n, 1))
        self._rngs = [seeding.np_random()[0] for _ in range(n)]
        self._refs: list[Reference] = [cfg.reference] * n
        self._ref = np.zeros((8, n))  # reference_params of each arm, one row per number
        self._set_references(np.arange(n), [cfg.reference] * n)
        self._bind_rate_need()
        self._steps = np.zeros(n, dtype=np.int64)
        self._warn_count = np.zeros(n, dtype=np.int64)
        self._needs_reset = np.zeros(n, dtype=bool)
        # Training: the arms' first episodes end at staggered steps, so that every rollout
        # samples all phases of the reference instead of N copies of the same window.
        self._stagger = boolean("stagger", stagger)
        self._last_obs = np.zeros((n, self.single_observation_space.shape[0]))
        self._last_truth = self._last_obs.copy()  # of the true state, with sensors
        self._last_action = np.zeros((n, n_act))  # the applied commands, as observed

    @property
    def arms(self) -> list[EnvConfig]:
        """Returns each slot's arm config: the env's, or the draw of mechanism_ranges."""
        return list(self._arm_cfgs)

    # -- references --------------------------------------------------------------------------
    def _set_references(self, ids: np.ndarray, refs: list[Reference]) -> None:
        for i, ref in zip(ids, refs, strict=True):
            self._refs[i] = ref
            self._ref[:, i] = reference_params(ref)

    # -- reset ---------------------------------------------------------------------------------
    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Resets every arm (or ``options["reset_mask"]``); seed s seeds arm i with s + i, as
        Gymnasium's SyncVectorEnv does.  ``options={"reference": {...}}`` fixes the reference,
        as on the single env."""
        n = self.num_envs
        fixed = self.formulas.reference_option(options)
        mask = np.ones(n, dtype=bool)
        if options and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], dtype=bool)
            if mask.shape != (n,):
                raise invalid("options['reset_mask']", options["reset_mask"], f"{n} booleans")
        if isinstance(seed, (list, tuple, np.ndarray)):
            if len(seed) != n:
                raise invalid("seed", seed, f"None, an int, or a list of {n} ints or None")
            seeds = [
                None if s is None else integer(f"seed[{i}]", s, 0, 2**63)
                for i, s in enumerate(seed)
            ]
        else:
            seed = None if seed is None else integer("seed", seed, 0, 2**63 - n)
            seeds = [None if seed is None else seed + i for i in range(n)]
        ids = np.flatnonzero(mask)
        for i in ids:
            if seeds[i] is not None:
                self._rngs[i], _ = seeding.np_random(seeds[i])
        self._reset_ids(ids, fixed)
        if self._stagger:
            self._steps[ids] = (ids * self.max_episode_steps) // n
        obs = self._observe()
        self._last_obs[ids] = obs[ids]
        if self._sensing is not None:
            self._last_truth[ids] = self._observe(measured=False)[ids]
        return obs.copy(), self._reset_info(ids)

    def _reset_ids(self, ids: np.ndarray, fixed: Reference | None = None) -> None:
        """Resets arms ``ids`` as Tendon2REnv.reset_model does, with each arm's own RNG."""
        if len(ids) == 0:
            return
        formulas = self.formulas
        arms, refs = zip(*(formulas.episode(self._rngs[i], fixed) for i in ids), strict=True)
        if self.config.mechanism_ranges is not None:
            self._set_arms(ids, list(arms))
        self._set_references(ids, list(refs))
        self.batch.reset(ids, stage=mujoco.mjtStage.mjSTAGE_NONE.value)
        for i, ref in zip(ids, refs, strict=True):
            q, dq = formulas.initial_state(self._rngs[i], ref)
            if self.drive.has_state:
                self._settle(i, q, dq)
            else:
                self._qpos[i], self._qvel[i] = q, dq
            if self._sensing is not None:
                self._sensing.reset(i, self._state(i).tolist(), self._rngs[i])
        self.batch.forward(ids)
        self._steps[ids] = 0
        self._last_action[ids] = self._rest[ids]
        if self._delay is not None:
            self._delay.reset(ids)
        self._warn_count[ids] = self._warnings()[ids]
        self._needs_reset[ids] = False

    def _set_arms(self, ids: np.ndarray, arms: list[EnvConfig]) -> None:
        """Makes each of ``arms`` (drawn arm configs) the arm of its slot in ``ids``: its own
        model in the batch (mujoco.batch's set_models: one layout, other parameters), drive,
        observed numbers, rest command, and the joint-torque map's and delay's copies."""
        cfg = self.config
        for i, arm in zip(ids, arms, strict=True):
            self._arm_cfgs[i] = arm
            self._models[i] = model = build_model(arm.mechanism)
            self._drives[i] = Drive(model, arm.mechanism)
            self._arm[:, i] = arm_params(arm, cfg)
            self._rest[i] = self.formulas.rest_command(arm)
            self._bind_delays(i, arm, self._drives[i])
        self.batch.set_models(self._models)
        if self.torque_map is not None:
            self.torque_map.follow([a.mechanism for a in self._arm_cfgs])
        self._bind_rate_need()

    def _bind_rate_need(self) -> None:
        """Sets each slot's 1 / s of the action_rate_need term (Formulas.rate_need_inverse)."""
        need = np.array([a.needs.torque_rate_need for a in self._arm_cfgs])
        max_torque = None
        if self.torque_map is not None:
            max_torque = np.broadcast_to(self.torque_map.max_torque, need.shape)
        self._rate_inv = self.formulas.rate_need_inverse(need, max_torque)

    def _bind_delays(
        self, i: int, arm: EnvConfig, drive: Drive, timing: Timing | None = None
    ) -> None:
        """Gives slot i the motor delay, rest command and sensors of the arm config ``arm``
        (``timing``: its Timing, if known)."""
        if self._delay is None and self._sensing is None:
            return
        timing = timing or Timing.of(arm)
        if self._delay is not None:
            self._delay.set_arm(i, timing.delay_steps, drive.ctrl)
        if self._sensing is not None:
            self._sensing.set_arm(i, timing.observation_delay_steps, arm.observation_noise)

    def _settle(self, i: int, q: np.ndarray, dq: np.ndarray) -> None:
        """Puts arm i at rest with its motors and cables (realism.Drive.settle, as the single
        env's reset)."""
        model = self._models[i]
        d = self._scratch if model is self.model else mujoco.MjData(model)
        mujoco.mj_resetData(model, d)
        self._drives[i].settle(d, q, dq)
        self._qpos[i], self._qvel[i], self._ctrl[i], self._act[i] = d.qpos, d.qvel, d.ctrl, d.act

    def _reset_info(self, ids: np.ndarray, info: dict[str, Any] | None = None) -> dict[str, Any]:
        """Adds the single env's reset info of arms ``ids`` to ``info``, as Gymnasium's vector
        envs batch it (``_key`` masks, a mapping per nested dict)."""
        info = {} if info is None else info
        for i in ids:
            row = self.formulas.reset_info(self._refs[i], float(self._time[i]), self._arm_cfgs[i])
            info = self._add_info(info, row, int(i))
        return info

    # -- step ----------------------------------------------------------------------------------
    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        n, n_act = self.num_envs, self.single_action_space.shape[0]
        allowed = f"({n}, {n_act}) finite real numbers in [-1, 1]; values outside are clipped"
        a = real_array("actions", actions, (n, n_act), allowed).clip(-1.0, 1.0)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        # NEXT_STEP: arms that ended last step are reset now and report the reset observation.
        resetting = self._needs_reset.copy()
        reset_ids = np.flatnonzero(resetting)
        if len(reset_ids):
            self._reset_ids(reset_ids)
            ids = active = np.flatnonzero(~resetting)
        else:  # the common step: every arm, without index arrays
            ids, active = None, slice(None)
        last = self._last_action.copy()
        if self.formulas.alpha != 1.0:  # action_filter_tau
            a = np.stack(self.formulas.command(list(a.T), list(last.T)), axis=1)
        self._last_action[active] = a[active]
        if self.torque_map is None:
            u = a
        else:  # joint_torque: PD's tension distribution at the current q
            # every arm, so that the kinematics batch keeps one size
            u = self.torque_map.joint_torque_command(self._qpos[:, :2], a)
        if self._delay is not None:  # the motors get the command of delay_steps ago
            u = self._delay(u, active)
        self._ctrl[active] = u[active]
        failed = np.zeros(n, dtype=bool)
        try:
            self.batch.step(ids, nstep=self.timing.n_substeps)
        except mj_batch.SimulationError as e:  # MuJoCo raised: those arms diverged
            failed[e.ids] = True
        diverged = self._check_divergence(active, failed)
        if self._sensing is not None:
            stepped = np.flatnonzero(~resetting)
            self._sensing.store(self._state(), self._rngs, stepped)
        obs = self._observe()
        if diverged.any():
            obs[diverged] = self._last_obs[diverged]  # the last good state, as the single env
        truth = obs
        if self._sensing is not None:  # reward and info on the true state
            truth = self._true_obs(obs)
            truth[diverged] = self._last_truth[diverged]
            self._last_truth[:] = truth
        rewards, terms = self._rewards(truth, a, last, diverged)
        rewards[resetting] = 0.0
        self._steps[active] += 1
        terminated[active] = diverged[active]
        # As Gymnasium's TimeLimit: truncated at the step limit, terminated or not.
        truncated[active] = self._steps[active] >= self.max_episode_steps
        # As SyncVectorEnv: step info for the arms that stepped, reset info for the others.
        info = self._step_info(truth, terms, diverged, ~resetting) if len(reset_ids) < n else {}
        if len(reset_ids):  # as SyncVectorEnv: a resetting arm reports its reset info
            info = self._reset_info(reset_ids, info)
        done = terminated | truncated
        self._last_obs[:] = obs
        if self.autoreset_mode == AutoresetMode.SAME_STEP and done.any():
            # As SyncVectorEnv: a finished arm reports its last step in final_obs and
            # final_info, then its reset observation and reset info.
            obs = obs.copy()  # info holds views of the final observations
            info, ids = with_final(obs, info, done), np.flatnonzero(done)
            self._reset_ids(ids)
            fresh = self._observe()
            obs[ids] = fresh[ids]
            self._last_obs[ids] = fresh[ids]
            if self._sensing is not None:
                self._last_truth[ids] = self._observe(measured=False)[ids]
            info = self._reset_info(ids, without_empty(info))
        else:
            self._needs_reset = done
        return obs.copy(), rewards, terminated, truncated, info

    def _warnings(self) -> np.ndarray:
        return self.batch.warning[:, DIVERGENCE_WARNING_IDS, 1].sum(axis=1)  # (lastinfo, number)

    def _check_divergence(self, active: np.ndarray | slice, failed: np.ndarray) -> np.ndarray:
        """Per arm: a new MuJoCo instability warning, a failed call, or a state outside the
        valid domain (Formulas.out_of_domain); a diverged arm is left in a finite state."""
        warn = self._warnings()
        q, w = self._qpos, self._qvel
        with np.errstate(invalid="ignore"):
            out = self.formulas.out_of_domain(BATCH, q[:, 0], q[:, 1], w[:, 0], w[:, 1])
        bad = (warn > self._warn_count) | failed | out
        self._warn_count[:] = warn
        mask = np.zeros(self.num_envs, dtype=bool)
        mask[active] = bad[active]
        if mask.any():
            q[mask] = np.nan_to_num(q[mask], nan=0.0, posinf=0.0, neginf=0.0)
            w[mask] = 0.0
        return mask

    def _state(self, i: int | slice = slice(None)) -> np.ndarray:
        """Returns the true (q_A, q_B, dq_A, dq_B) of arm i (or of every arm, (N, 4))."""
        return np.concatenate([self._qpos[i, :2], self._qvel[i, :2]], axis=-1)

    def _observe(self, measured: bool = True) -> np.ndarray:
        """The observations of every arm (tendon2r_gym.envs.formulas.Formulas.observation on
        arrays): of what the sensors measure, or with ``measured=False`` of the true state."""
        if measured and self._sensing is not None:
            q1, q2, w1, w2 = self._sensing.read().T.copy()
        else:
            q, w = self._qpos, self._qvel
            q1, q2, w1, w2 = q[:, 0], q[:, 1], w[:, 0], w[:, 1]
        parts = self.formulas.observation(
            BATCH,
            q1,
            q2,
            w1,
            w2,
            self._time,
            tuple(self._ref),
            tuple(self._arm),
            list(self._last_action.T),
        )
        return np.stack(parts, axis=1)

    def _true_obs(self, measured: np.ndarray) -> np.ndarray:
        """Returns the observations of the true state: ``measured`` (the sensors' observations
        of this step) with the entries the joint state sets rewritten (Formulas.state_entries, and
        Formulas.error_rate_entries if observed)."""
        truth = measured.copy()
        q, w, q_des = self._qpos, self._qvel, measured[:, obs_layout.Q_DES]
        joints, rest = self.formulas.state_entries(
            BATCH, q[:, 0], q[:, 1], w[:, 0], w[:, 1], q_des[:, 0], q_des[:, 1], tuple(self._arm)
        )
        head, tail = obs_layout.STATE
        truth[:, head], truth[:, tail] = np.stack(joints, axis=1), np.stack(rest, axis=1)
        if self.formulas.observes_rate:
            cfg, dq_des = self.config, measured[:, obs_layout.DQ_DES]
            where = obs_layout.error_rate_slice(cfg.preview_steps, cfg.n_actions)
            rate = self.formulas.error_rate_entries(
                BATCH, w[:, 0], w[:, 1], dq_des[:, 0], dq_des[:, 1], tuple(self._arm)
            )
            truth[:, where] = np.stack(rate, axis=1)
        return truth

    def _rewards(
        self, obs: np.ndarray, a: np.ndarray, last: np.ndarray, diverged: np.ndarray
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        e = obs[:, obs_layout.ERROR]
        de1 = de2 = 0.0
        if self.formulas.weighs_rate:  # the error's rate, read only where it is weighed
            de = obs[:, obs_layout.DQ_DES] - obs[:, obs_layout.DQ]
            de1, de2 = de[:, 0], de[:, 1]
        terms = self.formulas.reward_terms(
            BATCH, e[:, 0], e[:, 1], list(a.T), list(last.T), self._rate_inv, diverged, de1, de2
        )
        return self.formulas.scale(terms)

    def _moment_arm_cond(self) -> np.ndarray:
        """cond(J) of every arm, from the batch's sparse ten_J (as the single env's info)."""
        J = self._ten_J
        rows = [tuple(0.0 if k is None else J[:, k] for k in row) for row in self._J_rows]
        with np.errstate(divide="ignore", invalid="ignore"):
            return cond_of_rows(BATCH, rows)

    def _step_info(
        self, obs: np.ndarray, terms: dict[str, np.ndarray], diverged: np.ndarray, mask: np.ndarray
    ) -> dict[str, Any]:
        if self.mechanism.elastic:
            tension = self.drive.tension_view(self._qfrc_passive).copy()
        else:
            tension = -self._sensors[:, self._force]
        values = self.formulas.step_info(
            obs,
            terms,
            tension,
            self._moment_arm_cond(),
            self._time.copy(),
            diverged,
        )
        info: dict[str, Any] = {}
        for key, value in values.items():
            info[key], info[f"_{key}"] = value, mask.copy()
        return info

    def close_extras(self, **kwargs: Any) -> None:
        self.batch = None


#: The environment variable that gives a job its CPU share: set by the executors that run
#: several jobs at once (tendon2r_gym.training.executors: local workers, Ray tasks), it caps
#: the default batch threads, so that N jobs on N cores do not fight over them.
CPUS_VAR = "TENDON2R_CPUS"

#: Arms per MuJoCo batch thread by default.  On 2 cores (python -m research.studies.speed, columns
#: native_1thread and native_2threads of research/results/speed.md), a second thread pays from
#: 16 arms on; at 8 arms and fewer, one and two threads differ by less than the noise between runs.
ARMS_PER_THREAD = 8


def default_nthread(num_envs: int) -> int:
    """Returns the default number of MuJoCo batch threads: one per ARMS_PER_THREAD arms, at
    least one, at most the CPUs this process may run on and its job's share (CPUS_VAR, if
    set).  The threads change no result: the batch is bit-identical on any number."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    share = os.environ.get(CPUS_VAR, "")
    cap = min(cpus or 1, int(share)) if share.isdigit() and int(share) > 0 else cpus or 1
    return max(1, min(cap, num_envs // ARMS_PER_THREAD))

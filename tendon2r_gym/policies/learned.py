"""Learned policies: residual RL on top of the PD baseline, and loading trained PPO runs.

With ``residual_scale > 0`` the agent's action a in [-1, 1] is added to the PD command:
command = clip(PD(obs) + residual_scale * a, -1, 1).  The agent starts at PD's performance
(SB3 initializes the policy mean near zero) and learns what PD lacks, such as acceleration
feed-forward.  With ``residual_scale = 0`` the agent drives the motors directly ("from
scratch").  With ``residual_filter_tau > 0`` the residual passes a first-order low-pass
(:class:`ResidualFilter`) before it is added, and PD's own command does not: a filter on the
whole command would put its lag inside PD's loop.

``residual_relative_to`` sets what ``residual_scale`` is a fraction of, per joint:

- ``range`` (default): the joint's whole command range, the same on every arm;
- ``need`` (joint-torque mode only): the joint's torque need, the peak torque that inverse
  dynamics of the arm's reference needs (EnvConfig.needs.torque_need), over the joint's torque
  range (:attr:`TorqueToTension.max_torque`): residual_scale * need_j / max_torque_j.  On an
  arm whose joint needs a small part of its range, a residual relative to the range can
  move that joint far more than its task does; relative to the need, the residual's reach
  follows the task on every arm.

A trained model only meets the env it was trained for: :meth:`PPOPolicy.load` compares the env
config recorded in the run (``run.json``) with the env's and refuses another mechanism,
reference set or observation layout, and its model zip and VecNormalize pkl when unreadable or
made for another observation or action size (tendon2r_gym.policies.files).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from tendon2r_gym.envs.env import make as make_env
from tendon2r_gym.envs.env_config import EnvConfig, low_pass_alpha
from tendon2r_gym.llvm import load_triton
from tendon2r_gym.policies import inference
from tendon2r_gym.policies.baselines import PDPolicy
from tendon2r_gym.policies.files import (
    check_model_spaces,
    check_stats_shape,
    load_model,
    load_vecnormalize,
    model_data,
    vecnormalize,
)
from tendon2r_gym.policies.runs import RUN_META, model_files, stem_of, training_record
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.task import observation
from tendon2r_gym.task.arms import CONTROLLER, MechanismRanges, gain_field, reference_ranges
from tendon2r_gym.task.gains import Gains, gains_of
from tendon2r_gym.task.reference import Reference, ReferenceRanges
from tendon2r_gym.validation import invalid, number, real_array

#: Env config settings a trained model depends on, compared as recorded (a setting recorded
#: before it existed takes its EnvConfig default): what its actions mean, its timing and the
#: optional entries it observes (an arm's env takes them from the model, as a user would).
MODEL_SETTINGS = (
    "action_mode",
    "action_filter_tau",
    "ctrl_dt",
    "preview_steps",
    "preview_dt",
    "observe",
    "error_units",
)
#: Env config fields a trained model depends on: what it observes, what its actions mean and
#: what it must track.
MODEL_ENV_FIELDS = (
    "observation",
    "mechanism",
    "reference",
    "reference_ranges",
    "mechanism_ranges",
    *MODEL_SETTINGS,
)


#: What a residual_scale is a fraction of (module docstring).
RESIDUAL_RELATIVE_TO = ("range", "need")


def residual_scales(scale: float, relative_to: str, torque_need: Any, pd: PDPolicy) -> Any:
    """Returns the residual's scale: ``scale``, or relative to the need (module docstring)
    ``scale * torque_need / max_torque`` per joint: (2,) for one arm, (N, 2) for N
    (``torque_need``: each episode's EnvConfig.needs.torque_need, as reset infos give it, (2,) or
    (N, 2), read only relative to the need; max_torque: that of the arms ``pd`` follows, one
    or N)."""
    if relative_to == "range":
        return scale
    return scale * np.asarray(torque_need, dtype=float) / pd.actuation.max_torque


#: The largest residual_scale (a fraction of the command range, or of the need).
MAX_RESIDUAL_SCALE = 2.0
#: The largest residual_filter_tau (s).
MAX_RESIDUAL_FILTER_TAU = 1.0


@dataclasses.dataclass(frozen=True)
class Residual:
    """How a policy's action joins PD's command (module docstring): ``scale`` (0: no PD, the
    action is the command; > 0: a residual on PD), the residual's low-pass ``filter_tau`` (s)
    and what the scale is ``relative_to``.  An entry, a run record and a deployed policy
    carry these three as ``residual_scale``, ``residual_filter_tau`` and
    ``residual_relative_to`` (:meth:`to_record`, :meth:`from_record`); errors name those."""

    scale: float = 0.0
    filter_tau: float = 0.0
    relative_to: str = "range"

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        set_("scale", number("residual_scale", self.scale, 0.0, MAX_RESIDUAL_SCALE))
        tau = number("residual_filter_tau", self.filter_tau, 0.0, MAX_RESIDUAL_FILTER_TAU)
        if tau > 0 and self.scale == 0:
            raise invalid("residual_filter_tau", tau, "0 without a residual (residual_scale 0)")
        set_("filter_tau", tau)
        if self.relative_to not in RESIDUAL_RELATIVE_TO:
            raise invalid(
                "residual_relative_to", self.relative_to, f"one of {list(RESIDUAL_RELATIVE_TO)}"
            )
        if self.relative_to != "range" and self.scale == 0:
            raise invalid("residual_relative_to", self.relative_to, "'range' without a residual")

    @property
    def active(self) -> bool:
        """Whether the action is a residual on PD (scale > 0)."""
        return self.scale > 0

    def check_action_mode(self, action_mode: str) -> None:
        """Raises if the residual cannot act in an env of ``action_mode``: ``need`` is a
        joint's torque need, so only joint-torque actions are relative to it."""
        if self.relative_to == "need" and action_mode != "joint_torque":
            raise invalid(
                "residual_relative_to",
                self.relative_to,
                f"'range' in action_mode {action_mode!r} ('need' "
                "only with action_mode 'joint_torque', whose actions are joint torques)",
            )

    def to_record(self) -> dict[str, Any]:
        """Returns the fields under the names an entry and a run record give them."""
        return {
            "residual_scale": self.scale,
            "residual_filter_tau": self.filter_tau,
            "residual_relative_to": self.relative_to,
        }

    @classmethod
    def from_record(cls, record: dict[str, Any] | None) -> Residual:
        """Returns the residual an entry or a model's run record (run.json) gives; a field
        recorded before it existed, or no record, takes its default (no filter, ``range``)."""
        record = record or {}
        return cls(
            float(record.get("residual_scale", 0.0)),
            float(record.get("residual_filter_tau", 0.0)),
            str(record.get("residual_relative_to", "range")),
        )

    def scales(self, torque_need: Any, pd: PDPolicy) -> Any:
        """Returns the residual's scale on the arms ``pd`` follows: :func:`residual_scales`."""
        return residual_scales(self.scale, self.relative_to, torque_need, pd)


#: No residual: the policy's action is the command (plain PPO).
NO_RESIDUAL = Residual()


class ResidualPDWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """The agent's action is a residual on the PD command (see module docstring)."""

    def __init__(
        self,
        env: gym.Env,
        residual_scale: float,
        residual_filter_tau: float = 0.0,
        residual_relative_to: str = "range",
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self,
            residual_scale=residual_scale,
            residual_filter_tau=residual_filter_tau,
            residual_relative_to=residual_relative_to,
        )
        super().__init__(env)
        number("residual_scale", residual_scale, 0.0, MAX_RESIDUAL_SCALE, lo_open=True)
        self.residual = Residual(residual_scale, residual_filter_tau, residual_relative_to)
        config = env.unwrapped.config
        self.residual.check_action_mode(config.action_mode)
        self.pd = PDPolicy.from_env(env)
        self.filter = ResidualFilter(residual_filter_tau, config.ctrl_dt)
        self._obs: np.ndarray | None = None
        self._scale = self.residual.scales(config.needs.torque_need, self.pd)

    def reset(self, **kwargs: Any):
        self._obs, info = self.env.reset(**kwargs)
        self.pd.reset(info)  # follows the episode's arm, if the env draws arms
        self._scale = self.residual.scales(info["torque_need_Nm"], self.pd)
        self.filter.clear()
        return self._obs, info

    def step(self, action: np.ndarray):
        base, _ = self.pd.predict(self._obs)
        command = residual_command(base, action, self._scale, self.filter)
        self._obs, reward, terminated, truncated, info = self.env.step(command)
        return self._obs, reward, terminated, truncated, info


class ResidualFilter:
    """A first-order low-pass on the residual of one env or a batch of them: y <- y + alpha
    (r - y), alpha = 1 - exp(-ctrl_dt / tau), y = 0 where an episode starts (the policy starts
    at PD's command); ``tau = 0``: none (y = r).  Its state is not observed: the env observes
    the command it applied, PD's plus y."""

    def __init__(self, tau: float, ctrl_dt: float) -> None:
        tau = number("residual_filter_tau", tau, 0.0, MAX_RESIDUAL_FILTER_TAU)
        self.alpha = low_pass_alpha(tau, ctrl_dt)
        self._y: np.ndarray | None = None

    def clear(self) -> None:
        """Starts every episode anew (the next residual is the first of its episode)."""
        self._y = None

    def __call__(self, residual: np.ndarray, start: Any = None) -> np.ndarray:
        """Returns the filtered ``residual`` (shape (*batch, n)); where ``start`` (a bool per
        batch row, as SB3's ``episode_start``) the filter restarts from 0 first."""
        if self.alpha == 1.0:
            return residual
        if self._y is None or self._y.shape != np.shape(residual):
            self._y = np.zeros(np.shape(residual))
        elif start is not None:
            self._y[np.broadcast_to(np.asarray(start, dtype=bool), self._y.shape[:-1])] = 0.0
        self._y = self._y + self.alpha * (residual - self._y)
        return self._y.copy()


def residual_command(
    base: np.ndarray,
    action: np.ndarray,
    scale: Any,
    filter_: ResidualFilter | None = None,
    start: Any = None,
) -> np.ndarray:
    """Returns clip(base + r, -1, 1) with r = scale * clip(action, -1, 1) (``scale``: a number,
    or one per joint, :func:`residual_scales`; through ``filter_`` if given; ``start`` as
    :meth:`ResidualFilter.__call__` takes it): the PD command ``base`` plus the agent's
    residual.  Training (ResidualPDWrapper, the native vector env) and
    deployment (PPOPolicy) share it, and it refuses an action of the wrong shape or a
    non-finite one."""
    shape = np.shape(base)
    a = real_array("action", action, shape, f"finite real numbers of shape {shape} in [-1, 1]")
    residual = scale * np.clip(a, -1.0, 1.0)
    if filter_ is not None:
        residual = filter_(residual, start)
    return np.clip(base + residual, -1.0, 1.0)


def make_training_env(
    env_kwargs: dict[str, Any], residual: Residual = NO_RESIDUAL, zero_obs: tuple[str, ...] = ()
) -> gym.Env:
    """Returns Tendon2R-v0 with the given kwargs, wrapped for residual learning if
    ``residual`` is active.  ``zero_obs`` names observation entries
    (tendon2r_gym.task.observation) to blank out, for ablations: a constant zero carries no
    information."""
    env = make_env(**env_kwargs)
    if zero_obs:
        keep = observation.mask(zero_obs, env.observation_space.shape[0])
        env = gym.wrappers.TransformObservation(env, lambda o: o * keep, env.observation_space)
    if not residual.active:
        return env
    return ResidualPDWrapper(env, **residual.to_record())


def recorded_settings(recorded: dict[str, Any]) -> dict[str, Any]:
    """Returns the MODEL_SETTINGS of a recorded env config (a setting recorded before it
    existed: its EnvConfig default; the flags ``observe`` replaced, read into it)."""
    recorded = observation.from_flags(recorded)
    default = {f.name: f.default for f in dataclasses.fields(EnvConfig)}
    out = {k: recorded.get(k, default[k]) for k in MODEL_SETTINGS}
    return {**out, "observe": without_arm(out["observe"])}


def config_settings(config: EnvConfig) -> dict[str, Any]:
    """Returns the MODEL_SETTINGS of an env config, as :func:`recorded_settings` gives them."""
    out = {k: getattr(config, k) for k in MODEL_SETTINGS}
    return {**out, "observe": without_arm(config.observe)}


def without_arm(observe: Any) -> list[str]:
    """Returns the entries of ``observe`` that a model's settings carry: all but ``arm`` (a
    model that observed its arm sees one fixed arm through :func:`arm_features`)."""
    return [name for name in observe if name != "arm"]


def model_settings(model_path: str | Path) -> dict[str, Any]:
    """Returns the MODEL_SETTINGS a saved model was trained with, as env kwargs: with them, any
    arm's env is one the model runs in (what its actions mean and its timing); a model saved
    without its run record: the EnvConfig defaults."""
    return recorded_settings((training_record(model_path) or {}).get("env_config", {}))


def settings_on(model_path: str | Path, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """Returns the model's :func:`model_settings` that differ from those of the env of
    ``env_kwargs`` (an arm): with them added, the arm's env is one the model runs in, and a
    report names them beside its row."""
    config = EnvConfig.make(**env_kwargs)
    ours = config_settings(config)
    out = {k: v for k, v in model_settings(model_path).items() if _plain(ours[k]) != _plain(v)}
    if "observe" in out and "arm" in config.observe:  # the env's own arm slice stays
        out["observe"] = [*out["observe"], "arm"]
    return out


def in_model_settings(model_path: str | Path, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """Returns ``env_kwargs`` with the model's :func:`settings_on` added: the env of that arm
    that the model runs in."""
    return {**env_kwargs, **settings_on(model_path, env_kwargs)}


def check_model_env(recorded: dict[str, Any], env: gym.Env, where: str) -> None:
    """Raises if ``env`` differs from the env config a model was trained with in any field of
    MODEL_ENV_FIELDS.  The recorded config is read back through the same constructors, so a
    field added later takes its default (for a model trained on reference_ranges, the nominal
    reference does not matter).  The mechanisms are compared without their realism fields
    (Mechanism.ideal): a policy trained on the ideal arm runs on the same arm with real
    cables, motors and sensors, as it would on hardware.  A model trained on random arms (a
    generalist) runs on one arm inside its ranges: its undrawn fields must match, its drawn
    fields and its reference lie inside the training ranges, else the ValueError names the
    first field out, its value and the range.  A model that observed its arm sees it on an
    env that does not (PPOPolicy appends :func:`arm_features`), or on one that observes it
    over the same ranges."""
    config = env.unwrapped.config
    theirs = {"observation": recorded.get("observation"), **recorded_settings(recorded)}
    ours = {"observation": config.observation_layout(), **config_settings(config)}
    if observes_arm(recorded):
        theirs["arm_feature_ranges"] = feature_ranges(recorded)
        ours["arm_feature_ranges"] = config.feature_ranges
        if arm_features(recorded, env) is not None:  # appended by PPOPolicy
            ours["observation"] = [*ours["observation"], theirs["observation"][-1]]
            ours["arm_feature_ranges"] = theirs["arm_feature_ranges"]
    mech = Mechanism.from_dict(recorded["mechanism"])
    arms = recorded.get("mechanism_ranges")
    arm_ranges = MechanismRanges.from_value(arms) if arms else None
    ranges = recorded.get("reference_ranges")
    if arm_ranges is not None and config.mechanism_ranges is None:  # a generalist on one arm
        drawn = {*arm_ranges.names, "max_tendon_force"}  # auto: sized per arm
        undrawn = lambda m: {k: v for k, v in m.ideal().to_dict().items() if k not in drawn}  # noqa: E731
        theirs["mechanism"], ours["mechanism"] = undrawn(mech), undrawn(config.mechanism)
        _compare(theirs, ours, where)
        problems = arm_ranges.violations(config)
        if ranges:
            problems += reference_ranges(ranges).violations(config.reference)
        if problems:
            raise ValueError(
                f"{where} was trained on random arms and does not cover this one: "
                f"{'; '.join(problems)}; allowed: an arm and reference inside its training "
                "ranges"
            )
        return
    # Drawn arms: the nominal mechanism as given (max_tendon_force possibly "auto").
    theirs["mechanism"] = mech if arms else mech.ideal()
    ours["mechanism"] = config.base_mechanism if arms else config.mechanism.ideal()
    theirs["reference"] = None if ranges else Reference.from_dict(recorded["reference"])
    ours["reference"] = None if ranges else config.reference
    theirs["reference_ranges"] = ReferenceRanges.from_dict(ranges) if ranges else None
    ours["reference_ranges"] = config.reference_ranges
    theirs["mechanism_ranges"], ours["mechanism_ranges"] = arm_ranges, config.mechanism_ranges
    _compare(theirs, ours, where)


def arm_features(recorded: dict[str, Any], env: gym.Env) -> np.ndarray | None:
    """Returns the ``arm`` slice a model that observed ``arm`` expects, for an env of
    one fixed arm that does not observe it: the arm's fields normalized over the model's
    :func:`feature_ranges`, as its training env computed them.  None if the model did not
    observe its arm, or the env observes it or draws arms itself."""
    config = env.unwrapped.config
    observed = "arm" in config.observe
    if not observes_arm(recorded) or observed or config.mechanism_ranges is not None:
        return None
    return np.array(feature_ranges(recorded).features(config), dtype=np.float64)


def observes_arm(recorded: dict[str, Any]) -> bool:
    """Returns whether a model's recorded observation layout ends with the ``arm`` slice."""
    layout = recorded.get("observation") or []
    return bool(layout) and layout[-1][0] == "arm"


def feature_ranges(recorded: dict[str, Any]) -> MechanismRanges | None:
    """Returns the ranges a model's ``arm`` slice was normalized over (EnvConfig.feature_ranges
    of its recorded env config), or None if it did not observe its arm."""
    if not observes_arm(recorded):
        return None
    value = recorded.get("arm_feature_ranges") or recorded["mechanism_ranges"]
    return MechanismRanges.from_value(value)


def fine_tune_env_kwargs(model_path: str | Path, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """Returns the env kwargs on which a run fine-tunes the model (``init_from``) on the env
    of ``env_kwargs``: with the model's :func:`model_settings` (what its actions mean, its
    timing), and, if it observed its arm, the arm slice over the model's ranges
    (observe ``arm``, ``arm_feature_ranges``), so that the run's every env, its record and
    its deployment see the arm as the model did."""
    out = in_model_settings(model_path, env_kwargs)
    recorded = (training_record(model_path) or {}).get("env_config", {})
    if observes_arm(recorded):
        observe = [*EnvConfig.make(**out).observe, "arm"]
        out.update(observe=observe, arm_feature_ranges=feature_ranges(recorded).to_dict())
    return out


def drawn_gains(recorded: dict[str, Any]) -> list[str]:
    """Returns the PD gains (CONTROLLER fields) that a model's training env drew per episode
    (``recorded``: its run.json env_config)."""
    arms = recorded.get("mechanism_ranges")
    return [n for n in MechanismRanges.from_value(arms).names if n in CONTROLLER] if arms else []


def trained_on_drawn_gains(model_path: str | Path) -> bool:
    """Returns whether the model (``<name>.zip`` in a run folder or bundle) was trained on
    drawn PD gains: then it runs on an arm's own, e.g. tendon2r-tune-pd's."""
    return bool(drawn_gains(training_record(model_path)["env_config"]))


def deployed_gains(recorded: dict[str, Any], env: gym.Env) -> Gains:
    """Returns the gains of the PD inside a residual model deployed on ``env``: those of its
    training env (``pd_gains``), except the gains its training drew per episode
    (:func:`drawn_gains`), which are ``env``'s: the gains a user tuned for their arm, inside
    the training ranges (check_model_env)."""
    gains = gains_of(recorded.get("pd_gains"))
    drawn = drawn_gains(recorded)
    theirs = gains_of(env.unwrapped.config.pd_gains)
    return dataclasses.replace(
        gains, **{gain_field(n): getattr(theirs, gain_field(n)) for n in drawn}
    )


def _compare(theirs: dict[str, Any], ours: dict[str, Any], where: str) -> None:
    for name in theirs:
        if _plain(theirs[name]) != _plain(ours[name]):
            raise ValueError(
                f"{where} was trained for another env: {name} = {_shown(theirs[name])} there, "
                f"{_shown(ours[name])} in this env; allowed: the env it was trained on "
                "(make the env from the run's run.json env_config)"
            )


def _shown(value: Any) -> Any:
    return value.to_dict() if hasattr(value, "to_dict") else value


def _plain(value: Any) -> Any:
    """Returns value as plain JSON data (objects by their to_dict, tuples as lists)."""
    return json.loads(json.dumps(_shown(value)))


def trained_model(
    model_path: str | Path, env: gym.Env, field: str = "model"
) -> tuple[Path, Path, dict[str, Any]]:
    """Returns (``<name>.zip``, ``<name>_vecnormalize.pkl``, the run's run.json) of a model
    that tendon2r-train wrote, after checking that it was trained for ``env``
    (:func:`check_model_env`; a ValueError naming ``field`` otherwise) and that both files are
    readable and made for it (:func:`check_model_files`; a ValueError naming the file)."""
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
    check_model_files(zip_path, stats, meta, env)
    return zip_path, stats, meta


def check_model_files(zip_path: Path, stats: Path, meta: dict[str, Any], env: gym.Env) -> None:
    """Raises a ValueError naming the file if the model zip or its VecNormalize pkl is
    unreadable, or made for another observation or action size than ``env`` (whose config
    matches the run's ``meta``, :func:`check_model_env`) gives it: the model sees the env's
    observation (with its :func:`arm_features` appended), ``frame_stack`` times."""
    arm = arm_features(meta["env_config"], env)
    seen = env.observation_space.shape[0] + (0 if arm is None else arm.size)
    stack = int(meta.get("frame_stack", 1))
    where = f"the env it is loaded on (that of its {RUN_META})"
    data = model_data(zip_path)
    check_model_spaces(zip_path, data, (stack * seen,), env.action_space.shape, where)
    check_stats_shape(stats, vecnormalize(stats), (seen,), where)


class PPOPolicy:
    """A trained PPO (+ its VecNormalize statistics) behind the SB3 ``predict`` interface,
    acting on raw observations of the unwrapped env: normalizes them with VecNormalize's own
    ``normalize_obs``, and adds PD if it was residual: the PD of its training env's gains
    (``pd_gains``), whatever the env's are, except gains drawn in training, which are the
    env's (:func:`deployed_gains`), and the residual through the filter it trained with
    (``residual_filter_tau``), at the scale it trained with (``residual_relative_to``: per
    joint relative to each episode's torque need, from the reset info)."""

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
        #: The ``arm`` slice appended to each observation (:func:`arm_features`), or None.
        self.arm = arm
        #: The model sees its last frame_stack normalized observations, frame_stride control
        #: steps apart, oldest first, as in training (tendon2r_gym.policies.history).
        self.frame_stack, self.frame_stride = frame_stack, frame_stride
        self._history = None
        if frame_stack > 1:
            from tendon2r_gym.policies.history import FrameHistory

            self._history = FrameHistory(frame_stack, frame_stride)
        self.pd, self.filter, self._scale = None, None, residual.scale
        if residual.active and env is not None:  # the PD it was trained on: its gains
            config = env.unwrapped.config
            residual.check_action_mode(config.action_mode)
            self.pd = PDPolicy.from_env(env, gains=gains_of(pd_gains))
            self.filter = ResidualFilter(residual.filter_tau, config.ctrl_dt)
            self._scale = residual.scales(config.needs.torque_need, self.pd)

    @classmethod
    def load(cls, model_path: str | Path, env: gym.Env) -> PPOPolicy:
        """Loads ``<name>.zip`` with ``<name>_vecnormalize.pkl`` and the run's run.json; raises
        if the env is not the one the model was trained on, or a file is corrupt or made for
        another observation size (:func:`trained_model`)."""
        load_triton()  # torch's triton after a GL context's LLVM segfaults: tendon2r_gym.llvm
        from stable_baselines3.common.vec_env import DummyVecEnv

        zip_path, stats, meta = trained_model(model_path, env)
        model = load_model(zip_path, device="cpu")
        arm = arm_features(meta["env_config"], env)
        seen = env if arm is None else _with_arm(env, arm)
        vecnorm = load_vecnormalize(stats, DummyVecEnv([lambda: seen]))
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
            self._scale = self.residual.scales(info["torque_need_Nm"], self.pd)
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
        command = residual_command(base, action, self._scale, self.filter, episode_start)
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

"""What a trained model needs of its env: the settings its actions, timing and observation
depend on (MODEL_SETTINGS), the check that an env is one it runs in (a generalist: any arm
inside its training ranges), the arm slice a model that observed its arm expects on one fixed
arm, and the PD gains a deployed residual uses (the env kwargs a fine-tune inherits:
tendon2r_gym.training.init_from.fine_tune_env_kwargs)."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from tendon2r_gym.artifacts.runs import training_record
from tendon2r_gym.envs.env_config import EnvConfig, resolve
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.task import observation
from tendon2r_gym.task.arms import CONTROLLER, MechanismRanges, gain_field, reference_ranges
from tendon2r_gym.task.gains import Gains, gains_of
from tendon2r_gym.task.reference import Reference, ReferenceRanges

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


#: Mechanism fields that say how the arm is simulated, not what it is: a generalist runs on an
#: arm integrated with another integrator or step (one its cables need, or the user's).
SIMULATION = ("integrator", "sim_dt")

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


def recorded_settings(recorded: dict[str, Any]) -> dict[str, Any]:
    """Returns the MODEL_SETTINGS of a recorded env config (a setting recorded before it
    existed: its EnvConfig default; the flags ``observe`` replaced, read into it)."""
    recorded = observation.from_flags(recorded)
    default = {f.name: f.default for f in dataclasses.fields(EnvConfig)}
    out = {k: recorded.get(k, default[k]) for k in MODEL_SETTINGS}
    return {**out, "observe": without_arm(out["observe"])}


def config_settings(config: EnvConfig) -> dict[str, Any]:
    """Returns the MODEL_SETTINGS of an env config, as `recorded_settings` gives them."""
    out = {k: getattr(config, k) for k in MODEL_SETTINGS}
    return {**out, "observe": without_arm(config.observe)}


def without_arm(observe: Any) -> list[str]:
    """Returns the entries of ``observe`` that a model's settings carry: all but ``arm`` (a
    model that observed its arm sees one fixed arm through `arm_features`)."""
    return [name for name in observe if name != "arm"]


def model_settings(model_path: str | Path) -> dict[str, Any]:
    """Returns the MODEL_SETTINGS a saved model was trained with, as env kwargs: with them, any
    arm's env is one the model runs in (what its actions mean and its timing); a model saved
    without its run record: the EnvConfig defaults."""
    return recorded_settings((training_record(model_path) or {}).get("env_config", {}))


def settings_on(model_path: str | Path, env: EnvConfig | Mapping[str, Any]) -> dict[str, Any]:
    """Returns the model's `model_settings` that differ from those of the env ``env`` (an
    arm: an EnvConfig, or env kwargs, resolved once): with them added, the arm's env is one
    the model runs in, and a report names them beside its row."""
    config = resolve(env)
    ours = config_settings(config)
    out = {k: v for k, v in model_settings(model_path).items() if _plain(ours[k]) != _plain(v)}
    if "observe" in out and "arm" in config.observe:  # the env's own arm slice stays
        out["observe"] = [*out["observe"], "arm"]
    return out


def in_model_settings(model_path: str | Path, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """Returns ``env_kwargs`` with the model's `settings_on` added: the env of that arm
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
    first field out, its value and the range; its integrator and step (SIMULATION) may
    differ.  A model that observed its arm sees it on an env that does not (PPOPolicy appends
    `arm_features`), or on one that observes it over the same ranges."""
    config = env.unwrapped.config
    theirs = {"observation": recorded.get("observation"), **recorded_settings(recorded)}
    ours = {"observation": config.observation.layout(), **config_settings(config)}
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
        # auto: sized per arm; and how the arm is integrated is not the arm
        drawn = {*arm_ranges.names, "max_tendon_force", *SIMULATION}
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
    `feature_ranges`, as its training env computed them.  None if the model did not
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
    (`drawn_gains`), which are ``env``'s: the gains a user tuned for their arm, inside
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

"""Property-based tests (hypothesis): any input either works or gets a ValueError naming a field.

Draws ``gym.make`` keyword sets, experiment files and actions, with NaN, inf, huge, negative,
empty and wrongly typed values beside plausible ones.  Every draw must either build an env whose
observations stay finite, or raise a ValueError whose message names the field (``<field> = ...
is invalid; allowed: ...``, or an unknown key with the allowed ones); never another exception.

CI runs a short profile; ``make properties`` runs the long one (HYPOTHESIS_PROFILE=long).
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings

import gymnasium as gym
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

import tendon2r_gym  # noqa: F401  (registers Tendon2R-v0)
from tendon2r_gym.envs.env_config import arguments
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.task.rewards import REWARD_SCALES

settings.register_profile(
    "ci", max_examples=25, deadline=None, suppress_health_check=list(HealthCheck)
)
settings.register_profile(
    "long", max_examples=1000, deadline=None, suppress_health_check=list(HealthCheck)
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

MECHANISM_FIELDS = [f.name for f in dataclasses.fields(Mechanism)]
REFERENCE_FIELDS = ["amp_deg", "freq_hz", "bias_deg", "phase_deg", "omega_rad_s"]
KEYWORDS = sorted(arguments())

#: Numbers of every kind a user may type: NaN, inf, huge, tiny, negative, zero.
odd_floats = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, 1e300, -1e300, math.nan, math.inf, -math.inf]),
)
plausible = st.floats(0.0, 0.2)
scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**12), 10**12),
    odd_floats,
    plausible,
    st.text(max_size=6),
)
pairs = st.one_of(
    st.lists(st.one_of(plausible, odd_floats, st.text(max_size=3)), max_size=3),
    st.lists(plausible, min_size=2, max_size=2).map(np.array),
    st.tuples(st.floats(-60, 60), st.floats(-60, 60)),
)
values = st.one_of(scalars, pairs, st.dictionaries(st.text(max_size=4), scalars, max_size=2))


def _section(fields: list[str]) -> st.SearchStrategy:
    return st.dictionaries(st.sampled_from([*fields, "bogus"]), st.one_of(values, plausible),
                           max_size=3)  # fmt: skip


keyword_sets = st.fixed_dictionaries(
    {},
    optional={
        **{k: values for k in KEYWORDS},
        "mechanism": st.one_of(values, _section(MECHANISM_FIELDS)),
        "reference": st.one_of(values, _section(REFERENCE_FIELDS)),
        "reward_scales": st.one_of(values, _section(list(REWARD_SCALES))),
        "not_a_keyword": values,
    },
)


def names_a_field(message: str) -> bool:
    """The project's wording: a field and its value, or an unknown key with the allowed ones."""
    return (" is invalid; allowed: " in message) or ("unknown key" in message)


def make_or_refuse(**kwargs) -> gym.Env | None:
    """Returns the env, or None after checking that the refusal names a field."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return gym.make("Tendon2R-v0", **kwargs)
    except ValueError as e:
        assert names_a_field(str(e)), f"a ValueError that names no field: {e}"
        event("refused")
        return None


def run_a_few_steps(env: gym.Env, actions: list) -> None:
    obs, _ = env.reset(seed=0)
    assert np.isfinite(obs).all()
    for action in actions:
        obs, reward, terminated, truncated, _ = env.step(action)
        assert np.isfinite(obs).all() and np.isfinite(reward)
        if terminated or truncated:
            break


@given(kwargs=keyword_sets)
def test_any_keyword_set_works_or_names_a_field(kwargs):
    env = make_or_refuse(**kwargs)
    if env is not None:
        event("built")
        run_a_few_steps(env, [env.action_space.sample() for _ in range(5)])
        env.close()


#: One or two fields of the default arm set to a number of any size or sign: deep paths (the
#: stability criterion, inverse dynamics, the force limit) rather than type checks.
near_valid = st.one_of(
    st.dictionaries(st.sampled_from(MECHANISM_FIELDS), st.floats(-1.0, 1.0) | odd_floats,
                    min_size=1, max_size=2).map(lambda m: {"mechanism": m}),
    st.dictionaries(st.sampled_from(REFERENCE_FIELDS[:3]),
                    st.tuples(st.floats(-200, 200), st.floats(-200, 200)) | pairs,
                    min_size=1, max_size=2).map(lambda r: {"reference": r}),
    st.dictionaries(st.sampled_from(KEYWORDS), st.floats(-10.0, 10.0) | odd_floats, max_size=2),
)  # fmt: skip


@given(kwargs=near_valid)
@example(kwargs={"mechanism": {"sim_dt": 4.243547665183028e-245}})  # once 1e245 substeps
@example(kwargs={"mechanism": {"sim_dt": 1e-6}, "ctrl_dt": 0.002})
def test_any_number_in_a_valid_config_works_or_names_a_field(kwargs):
    test_any_keyword_set_works_or_names_a_field.hypothesis.inner_test(kwargs)


actions = st.one_of(
    st.lists(odd_floats, max_size=4),
    st.lists(st.floats(-1, 1), min_size=2, max_size=2).map(np.array),
    st.lists(st.floats(-1e6, 1e6), min_size=2, max_size=2),
    st.lists(st.text(max_size=2), max_size=2),
    scalars,
)


@pytest.fixture(scope="module")
def env():
    env = gym.make("Tendon2R-v0")
    yield env
    env.close()


@given(action=actions)
def test_any_action_steps_or_names_the_action(env, action):
    env.reset(seed=0)
    try:
        obs, reward, *_ = env.step(action)
    except ValueError as e:
        assert "action" in str(e) and names_a_field(str(e)), str(e)
        return
    assert np.isfinite(obs).all() and np.isfinite(reward)


yaml_documents = st.one_of(
    keyword_sets.map(lambda d: yaml.safe_dump(_plain(d))),
    st.text(max_size=40),
    st.sampled_from(["", "- 1\n- 2\n", "mechanism: [1, 2", "reference: {amp_deg: 5}", "null"]),
)


def _plain(value):
    """What a YAML file can hold: numpy arrays as lists, tuples as lists."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


@given(text=yaml_documents)
def test_any_experiment_file_works_or_names_the_file_or_a_field(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("exp") / "arm.yaml"
    path.write_text(text)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            env = gym.make("Tendon2R-v0", preset=str(path))
    except ValueError as e:
        assert "arm.yaml" in str(e) or names_a_field(str(e)), str(e)
        return
    run_a_few_steps(env, [env.action_space.sample() for _ in range(3)])
    env.close()

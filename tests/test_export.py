"""tendon2r-export writes the model the env steps, for every preset and every realism field;
tendon2r-view refuses a bad pose or image size, naming the flag."""

import xml.etree.ElementTree as ET

import gymnasium as gym
import mujoco
import numpy as np
import pytest
import yaml

import tendon2r_gym  # noqa: F401  (registers Tendon2R-v0)
from tendon2r_gym.app.tools import export_main, view_main
from tendon2r_gym.presets import list_presets, load_yaml, merge_env_kwargs, preset_path
from tendon2r_gym.simulation.realism import PERTURBATIONS, Drive

STEPS = 1000
#: Realism fields that the env applies in Python, not in the model (the XML's comment says so).
PYTHON_SIDE = {
    "motor_delay": "motor_delay",
    "observation_noise_angle": "observation_noise",
    "observation_noise_speed": "observation_noise",
    "observation_delay": "observation_delay",
}


def _realism_config(tmp_path, field: str) -> str:
    """Writes the default preset with ``field`` at the top of its PERTURBATIONS range (a valid
    value that is not the default) and returns the file; a name with ``--`` in it, which the
    XML's comment must not carry."""
    value = PERTURBATIONS[field][1]
    if field.startswith("observation_noise_"):
        override = {"observation_noise": [value, 0.0] if "angle" in field else [0.0, value]}
    elif field == "observation_delay":
        override = {field: value}
    elif field == "motor_mass":  # only an elastic cable has a spool
        override = {"mechanism": {field: value, "tendon_elasticity": 5000.0}}
    else:
        override = {"mechanism": {field: value}}
    data = merge_env_kwargs(load_yaml(preset_path("default")), override)
    path = tmp_path / f"default--{field}.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def _fields(model: mujoco.MjModel) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Returns every array of ``model`` by name, and every other field (its sizes, options,
    visual settings and statistics) as text."""
    named = {k: getattr(model, k) for k in dir(model) if not k.startswith("_")}
    arrays = {k: v for k, v in named.items() if isinstance(v, np.ndarray)}
    structs = (int, float, mujoco.MjOption, mujoco.MjVisual, mujoco.MjStatistic)
    return arrays, {k: repr(v) for k, v in named.items() if isinstance(v, structs)}


def _trajectory(model, mech, q, dq, ctrl, frame_skip) -> np.ndarray:
    """Returns the joint angles after each control step of ``ctrl`` from the env's reset state
    (q, dq) on ``model``, stepped with MuJoCo alone: no delay, no sensors."""
    data = mujoco.MjData(model)
    Drive(model, mech).settle(data, q, dq)
    out = np.empty((len(ctrl), 2))
    for i, u in enumerate(ctrl):
        data.ctrl[:] = u
        mujoco.mj_step(model, data, nstep=frame_skip)
        out[i] = data.qpos[:2]
    warned = data.warning.number
    assert not warned.any(), f"MuJoCo warned {warned}: a reset state would compare as equal"
    return out


def _exported_and_env(tmp_path, config: str):
    """Exports ``config`` with tendon2r-export and returns (the XML's text, the model
    MjModel.from_xml_path loads from it, the env, the env's MjModel of the config's arm)."""
    out = export_main(["--env-config", config, "--out", str(tmp_path / "export" / "arm.xml")])
    text = out.read_text()
    env = gym.make("Tendon2R-v0", preset=config)
    # Before the first reset: an env with mechanism_ranges then draws another arm.
    return text, mujoco.MjModel.from_xml_path(str(out)), env, env.unwrapped.model


def _check_same_model(tmp_path, config: str) -> tuple[str, mujoco.MjModel]:
    """Checks that the exported model of ``config`` is the env's, field for field and
    trajectory for trajectory; returns the XML and the model."""
    text, exported, env, model = _exported_and_env(tmp_path, config)
    ET.fromstring(text)  # well-formed XML for any parser, not MuJoCo's alone
    inner = env.unwrapped
    for name in ("body_mass", "body_inertia", "tendon_lengthspring", "actuator_gainprm"):
        np.testing.assert_array_equal(getattr(exported, name), getattr(model, name), name)
    (arrays, others), (env_arrays, env_others) = _fields(exported), _fields(model)
    assert arrays.keys() == env_arrays.keys() and others == env_others
    for name, value in env_arrays.items():
        np.testing.assert_array_equal(arrays[name], value, err_msg=name)

    env.reset(seed=0)
    q, dq = inner.data.qpos[:2].copy(), inner.data.qvel[:2].copy()
    ctrl = np.random.default_rng(0).uniform(-1.0, 1.0, (STEPS, model.nu))
    mech, skip = inner.config.mechanism, inner.frame_skip
    ours = _trajectory(exported, mech, q, dq, ctrl, skip)
    theirs = _trajectory(model, mech, q, dq, ctrl, skip)
    assert np.ptp(theirs, axis=0).min() > 0.1, "both joints move"
    np.testing.assert_array_equal(ours, theirs)  # exactly, well within 1e-4 rad
    env.close()
    return text, exported


@pytest.mark.parametrize("preset", list_presets())
def test_export_of_every_preset_is_the_env_model(tmp_path, preset):
    text, _ = _check_same_model(tmp_path, preset)
    from tendon2r_gym.app.tools import export_note
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.simulation.model import to_xml

    cfg = EnvConfig.make(preset)  # the file is the preset's model under the preset's note
    assert text == to_xml(cfg.mechanism, export_note(cfg, preset))


@pytest.mark.parametrize("field", sorted(PERTURBATIONS))
def test_export_of_every_realism_field_is_the_env_model(tmp_path, field):
    """Each realism field on its own: the XML is the env's model, and it carries the field (the
    model differs from the default's) unless the env applies it in Python (then the XML's
    comment names it)."""
    text, exported = _check_same_model(tmp_path, _realism_config(tmp_path, field))
    default = export_main(["--env-config", "default", "--out", str(tmp_path / "default.xml")])
    base = _fields(mujoco.MjModel.from_xml_path(str(default)))[0]
    arrays = _fields(exported)[0]
    changed = [k for k, v in base.items() if not np.array_equal(arrays[k], v)]
    if field in PYTHON_SIDE:
        assert not changed
        assert PYTHON_SIDE[field] in text.split("-->")[0]
    else:
        assert changed, f"{field} is not in the exported model"


@pytest.mark.parametrize(
    "argv",
    [
        ["--q-deg", "10", "20", "30"],
        ["--q-deg", "10"],
        ["--q-deg", "10", "nan"],
        ["--q-deg", "inf", "0"],
        ["--q-deg", "0", "95"],
        ["--width", "0"],
        ["--height", "20000"],
    ],
)
def test_view_refuses_bad_pose_and_size(tmp_path, argv):
    flag = argv[0]
    with pytest.raises(ValueError, match=f"^{flag} = .* is invalid; allowed: "):
        view_main([*argv, "--save", str(tmp_path / "view.png")])
    assert not (tmp_path / "view.png").exists()


def test_view_renders_an_elastic_arm(tmp_path):
    """The real_arm's spools follow its two joints in qpos: a pose sets the joints only."""
    import imageio.v2 as imageio

    out = view_main(
        ["--env-config", "real_arm", "--q-deg", "10", "-20", "--width", "64", "--height", "48",
         "--save", str(tmp_path / "view.png")]
    )  # fmt: skip
    assert imageio.imread(out).shape[:2] == (48, 64)

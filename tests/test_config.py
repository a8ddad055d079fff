"""Experiment files, presets and the force limit that fits (your own arm)."""

import warnings

import gymnasium as gym
import numpy as np
import pytest

from tendon2r_gym import EnvConfig
from tendon2r_gym.envs.env_config import FORCE_HEADROOM
from tendon2r_gym.evaluation.evaluator import evaluate
from tendon2r_gym.presets import PRESET_DIR, list_presets, load_yaml

#: The course mechanism of the issue: it needs about 0.8 N, more than the old fixed 0.5 N.
COURSE_ARM = """\
mechanism: {R1: 0.025, R2: 0.049, a: 0.068, b: 0.056, c: 0.091}
reference:
  amp_deg: [51.86, 29.54]
  freq_hz: [3.47, 1.02]
  bias_deg: [19.6, 9.9]
fit_to_workspace: true
"""


def test_presets_ship_inside_the_package():
    assert {"default", "report_002", "parallel"} <= set(list_presets())
    assert PRESET_DIR.parent.name == "data" and PRESET_DIR.parent.parent.name == "tendon2r_gym"


def test_experiment_file_holds_any_env_kwarg(tmp_path):
    path = tmp_path / "arm.yaml"
    path.write_text(
        COURSE_ARM + "ctrl_dt: 2e-3\nepisode_duration: 1.0\npreview_steps: 2\n"
        "reward_scales: {ctrl: 0.0}\n"
    )
    env = gym.make("Tendon2R-v0", preset=str(path))
    cfg = env.unwrapped.config
    assert cfg.ctrl_dt == 0.002 and cfg.episode_duration == 1.0 and cfg.preview_steps == 2
    assert cfg.reward_scales["ctrl"] == 0.0 and cfg.reward_scales["tracking"] == 1.0
    assert env.spec.max_episode_steps == 500
    # gym.make's own kwargs override the file; a mechanism dict only the fields it names.
    env = gym.make("Tendon2R-v0", preset=str(path), ctrl_dt=0.001, mechanism={"a": 0.07})
    cfg = env.unwrapped.config
    assert cfg.ctrl_dt == 0.001 and cfg.mechanism.a == 0.07 and cfg.mechanism.R1 == 0.025


def test_yaml_reads_exponents_as_numbers(tmp_path):
    path = tmp_path / "x.yaml"
    path.write_text("a: 1e-3\nb: 1.0e-3\nc: -2E+2\nd: 1_000\ne: '1e-3'\n")
    data = load_yaml(path)
    assert data["a"] == data["b"] == 0.001 and data["c"] == -200.0
    assert data["e"] == "1e-3"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("ctrl_dtt: 0.002\n", r"unknown key 'ctrl_dtt'; did you mean 'ctrl_dt'"),
        ("mechanism: {R3: 0.01}\n", r"unknown key 'R3'"),
        ("mechanism: 5\n", r"mechanism = 5 is invalid"),
        ("- a\n- b\n", "top level"),
        ("reference: {amp_deg: [1, 1]}\n", "reference"),
    ],
)
def test_bad_experiment_files_are_rejected_at_make(tmp_path, text, match):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        gym.make("Tendon2R-v0", preset=str(path))


def test_empty_experiment_file_names_what_is_missing(tmp_path):
    path = tmp_path / "empty.yaml"
    path.write_text("")
    with pytest.raises(ValueError, match="needs a reference section"):
        gym.make("Tendon2R-v0", preset=str(path))


def test_auto_force_limit_fits_the_reference(tmp_path):
    path = tmp_path / "arm.yaml"
    path.write_text(COURSE_ARM)
    env = gym.make("Tendon2R-v0", preset=str(path))
    u = env.unwrapped
    need = u.force_need()
    assert 0.5 < need < 5.0
    assert u.mechanism.max_tendon_force == pytest.approx(FORCE_HEADROOM * need, rel=1e-2)
    _, info = env.reset(seed=0)
    assert info["force_need_N"] == need
    torque_need = u.arm.needs.torque_need
    assert tuple(info["torque_need_Nm"]) == torque_need and min(torque_need) > 0
    assert env.unwrapped.model.actuator_gainprm[0, 0] == u.mechanism.max_tendon_force


def test_a_fixed_limit_below_the_need_warns_with_both_figures(tmp_path):
    path = tmp_path / "arm.yaml"
    path.write_text(COURSE_ARM.replace("c: 0.091}", "c: 0.091, max_tendon_force: 0.5}"))
    with pytest.warns(UserWarning, match=r"max_tendon_force = 0.5 N is below the 0\.\d+ N"):
        gym.make("Tendon2R-v0", preset=str(path))


def test_force_need_matches_the_peak_force_of_computed_torque():
    """The need is what inverse dynamics of the reference asks for: computed torque on the
    default preset (from the reference, no error to correct) never asks much more."""
    cfg = EnvConfig.make("default")
    metrics, _ = evaluate("ct", {"preset": "default"}, [0])
    assert max(metrics["max_tension_N"]) == pytest.approx(cfg.needs.force_need, rel=0.1)


def test_reference_ranges_use_their_worst_corner():
    ranges = {
        "amp_deg": [[5, 25], [5, 20]],
        "freq_hz": [[0.5, 3], [0.5, 3]],
        "bias_deg": [[-10, 10], [-15, 5]],
    }
    fixed = EnvConfig.make("default", reference={"amp_deg": [5, 5], "freq_hz": [0.5, 0.5]})
    ranged = EnvConfig.make("default", reference_ranges=ranges)
    assert ranged.needs.force_need > fixed.needs.force_need


def _course_draw(rng):
    mech = {k: float(rng.uniform(0.01, 0.05)) for k in ("R1", "R2")}
    mech.update({k: float(rng.uniform(0.03, 0.10)) for k in ("a", "b", "c")})
    ref = {
        "amp_deg": rng.uniform(0, 55, 2).tolist(),
        "freq_hz": rng.uniform(0.1, 4, 2).tolist(),
        "bias_deg": rng.uniform(-35, 35, 2).tolist(),
    }
    return mech, ref


def test_pd_tracks_random_course_arms_with_the_default_limit(tmp_path):
    """PD <= 1 deg RMS per joint on 10 seeded random arms and references inside the course's
    ranges, with the default (auto) force limit.  Draws the validation rejects are skipped, and
    their error says why."""
    rng = np.random.default_rng(2026)
    done, skipped = 0, 0
    while done < 10:
        assert skipped < 100, f"{skipped} draws refused: the draw or the validation is wrong"
        mech, ref = _course_draw(rng)
        path = tmp_path / f"arm_{done}_{skipped}.yaml"
        path.write_text(f"mechanism: {mech}\nreference: {ref}\nfit_to_workspace: true\n")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                metrics, _ = evaluate("pd", {"preset": str(path)}, [0])
        except ValueError as e:
            assert "allowed" in str(e) or "does not fit" in str(e), e
            skipped += 1
            continue
        assert max(metrics["rms_deg"]) <= 1.0, (mech, ref, metrics["rms_deg"])
        assert max(metrics["saturated_fraction"]) == 0.0
        done += 1


def test_the_flags_observe_replaced_are_read_from_older_files(tmp_path):
    """An experiment file or run record of tendon2r_gym 0.2 names the optional observation
    entries with four flags: they are read into ``observe`` (true adds, false removes, over the
    file's own list), a non-bool flag is refused by name, and the contract's form of a config
    writes them back."""
    from tendon2r_gym.presets import preset_path
    from tendon2r_gym.task import observation

    old = tmp_path / "old_arm.yaml"
    flags = "observe_error_rate: true\nobserve_force_limit: false\n"
    old.write_text(preset_path("default").read_text() + flags)
    assert EnvConfig.make(str(old)).observe == ("error_rate",)
    assert EnvConfig.make(str(old), observe_error_rate=False).observe == ()
    assert EnvConfig.make(str(old), observe=["feedforward"]).observe == ("feedforward",)
    assert EnvConfig.make(observe_feedforward=True, observe=["error_rate"]).observe == (
        "error_rate",
        "feedforward",
    )
    with pytest.raises(ValueError, match="observe_arm = 'yes' is invalid; allowed: true or false"):
        EnvConfig.make(observe_arm="yes")
    record = EnvConfig.make(observe=["force_limit", "error_rate"]).to_dict()
    assert record["observe"] == ["error_rate", "force_limit"]  # OBSERVABLE's order
    flags = observation.as_flags(record)
    assert "observe" not in flags and flags["observe_force_limit"] and not flags["observe_arm"]
    assert EnvConfig.from_kwargs(flags) == EnvConfig.from_kwargs(record)


def test_invalid_field_reads_the_field_an_error_names():
    from tendon2r_gym.simulation.mechanism import Mechanism
    from tendon2r_gym.validation import invalid, invalid_field

    with pytest.raises(ValueError) as e:
        Mechanism(R1=-1.0)
    assert invalid_field(e.value) == "R1"
    assert invalid_field(invalid("fit", "x", "names")) == "fit"

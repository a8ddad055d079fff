"""The candidates study (research.studies.candidates): a shipped model given as a candidate
reproduces the envelope study's row for it, beside the classical references; bad flags are
refused before anything runs."""

import json

import pytest

from research.studies import candidates


def _one_arm(tmp_path):
    """The envelope study's results with its first one-geometry arm only."""
    study = json.loads(candidates.STUDY.read_text())
    name = next(a for a in study["arms"] if candidates.kind_of(a) == "one_geometry")
    path = tmp_path / "study.json"
    path.write_text(json.dumps({**study, "arms": {name: study["arms"][name]}}))
    return path, name, study["arms"][name]


@pytest.mark.slow
def test_the_shipped_model_as_a_candidate_reproduces_the_study_row(tmp_path):
    from tendon2r_gym.artifacts.bundle import bundled_model
    from tendon2r_gym.evaluation.metrics import worst_ratio

    study, name, arm = _one_arm(tmp_path)
    argv = ["--models", f"copy={bundled_model('real_arm')}", "--study", str(study),
            "--out", str(tmp_path / "out")]  # fmt: skip
    result = candidates.main(argv)
    row = result["rows"]["copy"][name]
    assert row["rms_deg"] == arm["rows"]["real_arm"]["rms_deg"]
    assert result["summary"]["copy"] == result["summary"]["real_arm"]
    floor = result["rows"]["ct_floor"][name]
    assert set(result["rows"]) == {"ct", "ct_floor", "copy"} and "rms_deg" in floor
    ratio = result["summary"]["copy"]["one_geometry"]["median_ratio_to"]
    assert ratio["ct"] == worst_ratio(row["rms_deg"], result["rows"]["ct"][name]["rms_deg"])


def test_the_floor_switches_off_the_delays_the_lag_and_the_friction():
    arm = {"preset": "real_arm", "mechanism": {"motor_delay": 0.002, "motor_tau": 0.003,
           "tendon_friction": 0.01, "tendon_damping": 2.0}, "observation_delay": 0.002}  # fmt: skip
    out = candidates.floor(arm)
    assert out["mechanism"] == {"motor_delay": 0.0, "motor_tau": 0.0, "tendon_friction": 0.0,
                                "tendon_damping": 2.0}  # fmt: skip
    assert out["observation_delay"] == 0.0 and arm["mechanism"]["motor_delay"] == 0.002


@pytest.mark.parametrize(("argv", "match"), [
    ([], r"^--models = \[\] is invalid"),
    (["--models", "x"], r"^--models = 'x' is invalid"),
    (["--models", "x=missing/run"], r"^--models = 'x=missing/run' is invalid"),
    (["--models", "x=.", "--kinds", "giant"], r"^--kinds = 'giant' is invalid"),
])  # fmt: skip
def test_bad_flags_are_refused_before_anything_runs(tmp_path, argv, match):
    with pytest.raises(ValueError, match=match):
        candidates.main([*argv, "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()

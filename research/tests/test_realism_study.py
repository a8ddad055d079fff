"""The realism study (research.studies.realism): its arms, its pages and how it runs each
residual."""

import json

import numpy as np
import pytest

from research.studies import realism
from research.studies.realism import on_its_pd, perturbed_arms, realism_lines
from tendon2r_gym.app.report import PRINTED
from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.envs.timing import Timing
from tendon2r_gym.evaluation.evaluator import evaluate
from tendon2r_gym.simulation.mechanism import REALISM_LIMITS
from tendon2r_gym.simulation.realism import PERTURBATIONS
from tendon2r_gym.task.arms import MechanismRanges
from tests.reading import bullets, figures, rows_of
from tests.reading import row as named_row


def test_realism_lines_report_each_residual_against_pd():

    force = lambda f: {"rms_tension_N": [f] * 3, "rms_tension_rate_N_per_s": [10 * f] * 3}  # noqa: E731
    row = lambda pd, ppo, rnd: {  # noqa: E731
        "pd": {"rms_deg": pd, **force(1.0)}, "ct": {"rms_deg": [0.01, 0.01]},
        "pd_tuned": {"rms_deg": [0.5, 0.5], "bandwidth_hz": 12.3},
        "ppo": {"rms_deg": ppo, **force(2.0)}, "randomized": {"rms_deg": rnd, **force(0.5)},
    }  # fmt: skip
    rows = [
        {"arm": "a", **row([1.0, 1.0], [2.0, 0.5], [0.5, 0.25])},
        {"arm": "b", **row([1.0, 2.0], [0.5, 0.5], [0.5, 2.5])},
    ]
    text = "\n".join(realism_lines(rows))
    assert rows_of(text)[0] == ["a", "1.0000 / 1.0000", "0.5000 / 0.5000 (12.3 Hz)",
                                "0.0100 / 0.0100", "2.0000 / 0.5000 (2.00x)",
                                "0.5000 / 0.2500 (0.50x)"]  # fmt: skip
    # Per residual (ideal-trained, then randomized): the arms where it is <= PD on both
    # joints, of 2, and the median worst-joint ratio; the same against PD tuned per arm;
    # then its median RMS tension and tension rate as multiples of PD's.
    assert [figures(line) for line in bullets(text)] == [
        [1, 2, 1.25], [1, 2, 2.5], [2, 2],
        [1, 2, 0.88], [1, 2, 3.0], [0.5, 0.5],
    ]  # fmt: skip


def test_the_study_runs_a_residual_on_drawn_gains_on_the_arms_tuned_pd(tmp_path):
    """In the realism study (and its ablation) a residual trained on drawn PD gains runs on
    the arm with the gains tendon2r-tune-pd found there; any other policy on the arm as is."""

    ranges = {"drawn": ["real_arm", {"pd_bandwidth_hz": [10.0, 40.0]}], "fixed": "real_arm"}
    models = {}
    for name, value in ranges.items():
        (tmp_path / name).mkdir()
        config = EnvConfig.make("real_arm", mechanism_ranges=value).to_dict()
        record = {"seed": 0, "env_kwargs": {}, "env_config": config}
        (tmp_path / name / "run.json").write_text(json.dumps(record))
        models[name] = tmp_path / name / "best_model.zip"
    arm, tuned = {"preset": "real_arm"}, {"preset": "real_arm", "pd_gains": {"bandwidth_hz": 20}}
    assert on_its_pd(arm, tuned, models["drawn"]) is tuned
    assert on_its_pd(arm, tuned, models["fixed"]) is arm
    assert on_its_pd(arm, tuned, None) is arm


def test_real_arm_preset_and_perturbed_arms():
    """real_arm turns every effect on over the pull_only arm; the perturbed arms are valid,
    seeded and inside PERTURBATIONS; PD keeps real_arm stable."""

    real, ideal = EnvConfig.make("real_arm"), EnvConfig.make("pull_only")
    assert all(getattr(real.mechanism, k) > 0 for k in REALISM_LIMITS) and Timing.of(real).sensed
    assert real.mechanism.ideal() == ideal.mechanism  # same arm, same auto force limit
    arms = perturbed_arms("real_arm", 4, 7)
    assert arms == perturbed_arms("real_arm", 4, 7) != perturbed_arms("real_arm", 4, 8)
    ranges = MechanismRanges.from_value(PERTURBATIONS)
    for kwargs in arms:
        assert not ranges.violations(EnvConfig.make(**kwargs))
    metrics, _ = evaluate("pd", {"preset": "real_arm"}, [0])
    assert max(metrics["rms_deg"]) < 1.0  # stable (the ideal arm: 0.09 deg)


def test_the_study_runs_every_policy_on_its_arms(tmp_path, monkeypatch, short_episodes):
    """On one perturbed arm (each arm tunes PD, the bulk of the study's time; one jittered
    rerun per figure), every policy runs and gets its row and reproducibility."""
    from tendon2r_gym.evaluation import evaluator

    arms = realism.realism_arms()[1:2]
    monkeypatch.setattr(realism, "realism_arms", lambda: arms)
    monkeypatch.setattr(evaluator, "REPRO_RUNS", 1)
    result = realism.main(["--episodes", "1", "--out", str(tmp_path)])
    md = (tmp_path / "realism.md").read_text()
    assert json.loads((tmp_path / "realism.json").read_text()) == result
    assert [r["arm"] for r in result["rows"]] == [name for name, _ in arms]
    for row in result["rows"]:
        policies = ("pd", "pd_tuned", "ct", "ppo", "randomized")
        assert all(len(row[k]["rms_deg"]) == 2 for k in policies), row
        assert all(len(row[k]["reproducible_to"]) == 2 for k in policies), row
        cells = named_row(md, row["arm"])
        assert figures(cells[1])[:2] == pytest.approx(row["pd"]["rms_deg"], abs=5e-5)


def test_a_figure_that_reruns_change_shows_its_tolerance():
    cell = lambda rms, tol: {"rms_deg": rms, "reproducible_to": tol, **force}  # noqa: E731
    force = {"rms_tension_N": [1.0] * 3, "rms_tension_rate_N_per_s": [1.0] * 3}
    arm = {
        "arm": "a", "pd": cell([1.0, 1.0], [0.0, 0.0]), "ct": cell([0.5, 0.5], [1e-9, 0.0]),
        "pd_tuned": {**cell([0.5, 0.5], [0.0, 0.0]), "bandwidth_hz": 12.3},
        "ppo": cell([2.5, 7.2], [1.3, PRINTED]), "randomized": cell([0.2, 0.1], [PRINTED / 2, 0]),
    }  # fmt: skip
    text = "\n".join(realism_lines([arm]))
    assert rows_of(text) == [["a", "1.0000 / 1.0000", "0.5000 / 0.5000 (12.3 Hz)",
                              "0.5000 / 0.5000", "2.5000 / 7.2000 *to 1.3 / 5e-05* (7.20x)",
                              "0.2000 / 0.1000 (0.20x)"]]  # fmt: skip
    assert np.isfinite(PRINTED)

"""The scale-up measurement (research.studies.scale_up): its report from a results file, its
checks, and (marked ``cluster``: pytest -m cluster research/tests/test_scale_up.py) a tiny
run of every mode, on a two-node Ray cluster on 127.0.0.1."""

import importlib.util
import json

import pytest
import yaml

from research.studies import scale_up
from tests.reading import rows_of

HAS_RAY = importlib.util.find_spec("ray") is not None


def _tiny(tmp_path):
    """A tiny hyperparameter entry (tests/test_training.py's): 256 steps of 0.1 s episodes."""
    from tendon2r_gym.training import Hyperparams

    base = Hyperparams.from_entry("default")
    hp = base.replace(
        env_kwargs={"preset": "default", "episode_duration": 0.1},
        ppo={**base.ppo, "n_steps": 64, "batch_size": 64, "n_epochs": 1},
        n_envs=2, eval_freq=128, checkpoint_freq=128, eval_seeds=[0],
    )  # fmt: skip
    path = tmp_path / "ppo.yaml"
    path.write_text(yaml.safe_dump({"tiny": hp.to_dict()}))
    return path


def _row(wall, same=True):
    return {"wall_s": wall, "load_before": 1.0, "identical_to": "workers_1",
            "identical": {"0": {"evaluations": True, "best_model": same}}}  # fmt: skip


def test_the_report_gives_each_mode_its_ratio_and_target_and_names_a_differing_seed(tmp_path):
    modes = {"workers_1": {**_row(100.0), "ratio_to_workers_1": 1.0},
             "workers_2": {**_row(55.0), "ratio_to_workers_1": 0.55, "target": 0.6, "met": True},
             "cluster": {**_row(70.0, same=False), "ratio_to_workers_1": 0.7, "target": 0.6,
                         "met": False}}  # fmt: skip
    result = {"command": "python -m research.studies.scale_up", "hyperparams": "default",
              "config": None, "steps": 300000, "seeds": [0], "cpus": 2, "target": 0.6,
              "modes": modes}  # fmt: skip
    (tmp_path / "scale_up.json").write_text(json.dumps(result))
    assert scale_up.main(["--out", str(tmp_path), "--only-report"]) == result
    md = (tmp_path / "scale_up.md").read_text()
    assert rows_of(md) == [
        ["workers_1", "100.0", "1.000", "-", "-", "1 of 1 (vs workers_1)", "1.00"],
        ["workers_2", "55.0", "0.550", "<= 0.6", "yes", "1 of 1 (vs workers_1)", "1.00"],
        ["cluster", "70.0", "0.700", "<= 0.6", "no", "0 of 1 (vs workers_1)", "1.00"],
    ]
    # snapshot: which seed of which mode differs, and in which file, is told in this one line
    assert "cluster: seed 0 (best_model)" in md


@pytest.mark.parametrize(("argv", "match"), [
    (["--steps", "0"], r"^--steps = 0 is invalid"),
    (["--seeds", "0", "0"], r"^--seeds = \[0, 0\] is invalid.*distinct"),
    (["--modes", "workers_3"], r"^--modes = 'workers_3' is invalid.*one of"),
])  # fmt: skip
def test_bad_flags_are_refused_before_anything_trains(tmp_path, argv, match):
    with pytest.raises(ValueError, match=match):
        scale_up.main([*argv, "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()


@pytest.mark.cluster
@pytest.mark.skipif(not HAS_RAY, reason='needs pip install "tendon2r_gym[cluster]"')
def test_a_tiny_run_of_every_mode_gives_the_same_bits(tmp_path, request):
    """Two seeds of a tiny entry in one process, on two local workers and on the two-node
    loopback cluster: every seed bit-identical, a wall time and a ratio per mode.  Run only
    when asked for (-m cluster): make research-test selects no marker."""
    if "cluster" not in (request.config.getoption("-m") or ""):
        pytest.skip("a Ray cluster's start: run with pytest -m cluster")
    config = _tiny(tmp_path)
    argv = ["--config", str(config), "--hyperparams", "tiny", "--steps", "256", "--seeds", "0",
            "1", "--out", str(tmp_path / "out"), "--run-dir", str(tmp_path / "runs")]  # fmt: skip
    result = scale_up.main(argv)
    assert list(result["modes"]) == list(scale_up.MODES)
    for mode, row in result["modes"].items():
        assert row["wall_s"] > 0 and row["all_identical"], (mode, row)
        assert set(row["identical"]) == {"0", "1"}
    assert result["modes"]["workers_1"]["ratio_to_workers_1"] == 1.0
    assert {p.name for p in (tmp_path / "runs").iterdir()} == set(scale_up.MODES)
    assert (tmp_path / "out" / "scale_up.md").read_text().count("| 2 of 2 (vs workers_1) |") == 3

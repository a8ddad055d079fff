"""The ten-seed study (research.studies.ten_seeds): two tiny seeds of each recipe trained,
compared with PD and CT, resumed without training again, and its flags checked."""

import json

import pytest
import yaml

from research.studies import ten_seeds


def _tiny(tmp_path):
    """Both entries of the study as a tiny one: 128 steps of 0.1 s episodes."""
    from tendon2r_gym.training import Hyperparams

    out = {}
    for entry in ten_seeds.ENTRIES.values():
        base = Hyperparams.from_entry(entry)
        env_kwargs = {**base.env_kwargs, "episode_duration": 0.1}
        hp = base.replace(
            env_kwargs=env_kwargs,
            ppo={**base.ppo, "n_steps": 32, "batch_size": 64, "n_epochs": 1},
            n_envs=2, eval_freq=64, checkpoint_freq=64, eval_seeds=[0],
        )  # fmt: skip
        out[entry] = hp.to_dict()
    path = tmp_path / "ppo.yaml"
    path.write_text(yaml.safe_dump(out))
    return path


@pytest.mark.slow
def test_two_tiny_seeds_give_rows_with_intervals_and_a_rerun_trains_nothing(tmp_path):
    argv = ["--config", str(_tiny(tmp_path)), "--steps", "128", "--seeds", "0", "1",
            "--run-dir", str(tmp_path / "runs"), "--out", str(tmp_path / "out")]  # fmt: skip
    result = ten_seeds.main(argv)
    rows = {r["policy"]: r for r in result["rows"]}
    assert {"pd", "ct", "ppo scratch", "ppo residual"} <= set(rows)
    for label in ten_seeds.ENTRIES:
        spread = rows[f"{label} (2 seeds)"]
        assert spread["training_seeds"] == [0, 1]
        assert spread["statistics"]["runs"] == 2
        assert len(spread["statistics"]["rms_deg_iqm_ci"]) == 2
    evaluations = tmp_path / "runs" / "default" / "seed_1" / "evaluations.json"
    before = evaluations.read_bytes()
    again = ten_seeds.main(argv)  # resumed: every seed is done, so only evaluated
    assert evaluations.read_bytes() == before
    assert [r["rms_deg"] for r in again["rows"]] == [r["rms_deg"] for r in result["rows"]]
    assert json.loads((tmp_path / "out" / "ten_seeds.json").read_text())["seeds"] == [0, 1]


@pytest.mark.parametrize(("argv", "match"), [
    (["--steps", "0"], r"^--steps = 0 is invalid"),
    (["--seeds", "0", "0"], r"^--seeds = \[0, 0\] is invalid.*distinct"),
    (["--workers", "0"], r"^--workers = 0 is invalid"),
])  # fmt: skip
def test_bad_flags_are_refused_before_anything_trains(tmp_path, argv, match):
    with pytest.raises(ValueError, match=match):
        ten_seeds.main([*argv, "--out", str(tmp_path / "out"), "--run-dir", str(tmp_path / "r")])
    assert not (tmp_path / "out").exists() and not (tmp_path / "r").exists()

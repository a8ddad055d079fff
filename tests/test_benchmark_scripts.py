"""The speed and time-step scripts run end to end, and the defaults follow their results.

These are smoke tests with tiny budgets: they check outputs, never timings."""

import json
from pathlib import Path

import bench_speed  # scripts/ is on sys.path via tests/conftest.py

from tendon2r_gym.mechanism import Mechanism

RESULTS = Path(__file__).resolve().parent.parent / "results"


def test_bench_speed_writes_every_figure(tmp_path):
    result = bench_speed.main(
        [
            "--steps",
            "200",
            "--ppo-timesteps",
            "512",
            "--vector-seconds",
            "0.1",
            "--out",
            str(tmp_path),
        ]
    )
    saved = json.loads((tmp_path / "speed.json").read_text())
    assert saved["overhead_ratio"] == result["overhead_ratio"] > 0
    for env_id in ("Tendon2R-v0", "Reacher-v5"):
        assert saved[env_id]["raw_physics_us"] > 0 and saved[env_id]["env_step_us"] > 0
    assert set(saved["vector"]) == {f"{m}_{n}" for m in ("sync", "async") for n in (1, 2, 4, 8)}
    assert saved["ppo"]["timesteps"] >= 512 and saved["ppo"]["peak_pss_mb_all_processes"] > 0
    md = (tmp_path / "speed.md").read_text()
    assert "--out" in md and "Overhead ratio" in md and "target >= 2000" in md


def test_default_time_step_is_the_study_recommendation():
    """Mechanism's default integrator and sim_dt are what results/timestep_study.json chose
    (re-run scripts/timestep_study.py after changing the model, then update the default)."""
    chosen = json.loads((RESULTS / "timestep_study.json").read_text())["recommended"]
    mech = Mechanism()
    assert (mech.integrator.lower(), mech.sim_dt) == (
        chosen["integrator"].lower(),
        chosen["sim_dt"],
    )

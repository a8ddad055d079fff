"""rl_zoo3, as a user runs it: README's command with our hyperparameter file, a few hundred
steps, from scratch and residual."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

CONF = Path(__file__).resolve().parent.parent / "configs" / "rl_zoo3" / "ppo.yml"


@pytest.mark.parametrize("env_id", ["Tendon2R-v2", "Tendon2RResidual-v1", "Tendon2RResidual-v2"])
def test_rl_zoo3_trains_with_our_hyperparameter_file(tmp_path, env_id):
    cmd = [sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", env_id,
           "--gym-packages", "tendon2r_gym", "--conf-file", str(CONF), "-n", "256",
           "--log-folder", str(tmp_path), "--eval-freq", "-1", "--hyperparams", "n_envs:2",
           "n_steps:64", "batch_size:64"]  # fmt: skip
    proc = subprocess.run(
        cmd, capture_output=True, text=True, env={**os.environ, "MUJOCO_GL": "egl"}, timeout=600
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (tmp_path / "ppo" / f"{env_id}_1" / f"{env_id}.zip").is_file()
    wrapped = (
        "ResidualPDWrapper"
        in (tmp_path / "ppo" / f"{env_id}_1" / env_id / "config.yml").read_text()
    )
    assert wrapped == (env_id == "Tendon2RResidual-v1")  # v2's id has PD inside already


def test_the_zoo_file_is_generated_from_ours():
    """configs/rl_zoo3/ppo.yml is zoo_file() of tendon2r_gym/data/ppo.yaml: the same env kwargs, PPO
    settings, normalization and budget (python scripts/export_zoo.py rewrites it)."""
    from tendon2r_gym.training import Hyperparams
    from tendon2r_gym.training.zoo import ENTRIES, zoo_file

    assert CONF.read_text() == zoo_file()
    zoo = yaml.safe_load(CONF.read_text())
    for env_id, name in ENTRIES.items():
        hp = Hyperparams.from_entry(name)
        assert zoo[env_id]["env_kwargs"] == hp.env_kwargs
        assert zoo[env_id]["n_timesteps"] == hp.total_timesteps
        assert ("env_wrapper" in zoo[env_id]) == (hp.residual_scale > 0 and env_id.endswith("v1"))


def test_the_residual_trains_on_the_registered_reward():
    """One reward: the residual zoo entry is the registered env (its preset only) under our
    wrapper, and no entry overrides a reward setting."""
    import yaml

    from tendon2r_gym.training.zoo import zoo_file

    table = yaml.safe_load(zoo_file())
    assert table["Tendon2RResidual-v1"]["env_kwargs"] == {"preset": "default"}
    assert "env_wrapper" in table["Tendon2RResidual-v1"]
    for entry in table.values():
        assert not {"reward_scales", "tracking_form", "tracking_sigma_deg"} & set(
            entry["env_kwargs"]
        )

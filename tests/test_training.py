"""Smoke tests of PPO training (tiny budgets) and of the benchmark on bundled models."""

import json
import pickle

import numpy as np
import pytest
import train_ppo  # scripts/ is on sys.path via tests/conftest.py
import yaml


@pytest.fixture
def tiny_config(tmp_path):
    table = yaml.safe_load(open(train_ppo.Args.config))
    cfg = table["default"]
    cfg["env_kwargs"] = {"preset": "default", "episode_duration": 0.1}
    cfg["ppo"].update(n_steps=64, batch_size=64, n_epochs=1)
    cfg.update(eval_freq=128, checkpoint_freq=128, eval_seeds=[0])
    path = tmp_path / "ppo.yaml"
    path.write_text(yaml.safe_dump({"default": cfg}))
    return path


def test_smoke_train_then_resume(tmp_path, tiny_config):
    from stable_baselines3 import PPO

    run = tmp_path / "run"
    first = train_ppo.train(
        train_ppo.parse_args(
            [
                "--config",
                str(tiny_config),
                "--total-timesteps",
                "256",
                "--n-envs",
                "2",
                "--run-dir",
                str(run),
            ]
        )
    )
    assert first["timesteps"] >= 256
    for name in (
        "best_model.zip",
        "best_model_vecnormalize.pkl",
        "last_model.zip",
        "config.yaml",
        "command.txt",
        "policy.json",
    ):
        assert (run / name).is_file(), name
    assert list((run / "checkpoints").glob("*vecnormalize*.pkl"))
    PPO.load(run / "best_model.zip", device="cpu")
    with open(run / "best_model_vecnormalize.pkl", "rb") as f:
        assert pickle.load(f).obs_rms.mean.shape == (20,)
    best_before = np.mean(json.loads((run / "best_metrics.json").read_text())["rms_deg"])
    resumed = train_ppo.train(
        train_ppo.parse_args(
            [
                "--config",
                str(tiny_config),
                "--total-timesteps",
                "512",
                "--n-envs",
                "2",
                "--run-dir",
                str(run),
                "--resume",
            ]
        )
    )
    assert resumed["timesteps"] > first["timesteps"]
    best_after = np.mean(json.loads((run / "best_metrics.json").read_text())["rms_deg"])
    assert best_after <= best_before, "a resumed run must not replace a better best model"
    assert yaml.safe_load((run / "config.yaml").read_text())["total_timesteps"] == 512
    # A crash that never wrote last_model: --resume falls back to the newest checkpoint.
    for f in run.glob("last_model*"):
        f.unlink()
    state, stats = train_ppo.latest_state(run)
    assert state.parent.name == "checkpoints" and stats.is_file()
    assert PPO.load(state, device="cpu").num_timesteps == resumed["timesteps"]
    again = train_ppo.train(
        train_ppo.parse_args(
            ["--config", str(tiny_config), "--total-timesteps", "768", "--n-envs", "2"]
            + ["--run-dir", str(run), "--resume"]
        )
    )
    assert again["timesteps"] >= 768
    _check_bundle(run, tmp_path / "models")


def _check_bundle(run, root):
    """A finished run bundles into root/<preset>/seed_<n>/ and loads through the lookup."""
    import gymnasium as gym

    from tendon2r_gym.bundle import bundle_meta, bundle_runs, bundled_model
    from tendon2r_gym.learned import PPOPolicy

    with pytest.raises(FileNotFoundError, match="no bundled PPO model"):
        bundled_model("default", root=root)
    bundle_runs([run], "default", "python scripts/train_ppo.py --bundle", root=root)
    meta = bundle_meta("default", root=root)
    assert meta["seeds"] == [0] and meta["primary_seed"] == 0
    path = bundled_model("default", root=root)
    assert path == root / "default" / "seed_0" / "best_model.zip"
    assert not (path.parent / "checkpoints").exists(), "only the small files are bundled"
    env = gym.make("Tendon2R-v0")
    obs, _ = env.reset(seed=0)
    action, _ = PPOPolicy.load(path, env).predict(obs)
    assert action.shape == (2,) and env.action_space.contains(action)
    with pytest.raises(ValueError, match="seed = 7"):
        bundled_model("default", seed=7, root=root)
    with pytest.raises(FileNotFoundError, match="lacks"):
        bundle_runs([root / "nothing"], "x", "cmd", root=root)


def test_bad_override_is_rejected(tiny_config):
    with pytest.raises(ValueError, match="n_envs"):
        train_ppo.resolve_config(
            train_ppo.parse_args(["--config", str(tiny_config), "--n-envs", "0"])
        )


def test_benchmark_runs_on_bundled_models(tmp_path):
    import benchmark

    result = benchmark.main(["--episodes", "1", "--out", str(tmp_path)])
    md = (tmp_path / "benchmark.md").read_text()
    assert "| default | pd |" in md and "quoted" in md
    rows = json.loads((tmp_path / "benchmark.json").read_text())["presets"]
    assert {"pd", "ct", "ppo"} <= {r["policy"] for r in rows}
    ppo = [r for r in result["presets"] if r["policy"] == "ppo" and r["preset"] == "default"]
    assert ppo and "rms_deg" in ppo[0], "the bundled default PPO model must load and run"
    assert "Target (PPO RMS <= PD RMS on both joints)" in md

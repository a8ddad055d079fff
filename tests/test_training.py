"""PPO training (tiny budgets): the run folder, resume, interruption, bundles, model/env checks."""

import json
import os
import signal
import subprocess
import sys
import time

import gymnasium as gym
import numpy as np
import pytest
import yaml
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import DummyVecEnv

from tendon2r_gym.app.args import parse
from tendon2r_gym.app.cli import TrainArgs, experiment, train_main
from tendon2r_gym.artifacts.bundle import bundle_meta, bundle_runs, bundled_model
from tendon2r_gym.artifacts.files import load_policy, load_vecnormalize
from tendon2r_gym.artifacts.runs import REMOVED, RunFolder
from tendon2r_gym.evaluation.evaluator import evaluate
from tendon2r_gym.evaluation.metrics import beats, selection_rank, within_limits
from tendon2r_gym.policies.learned import PPOPolicy
from tendon2r_gym.policies.residual import residual_command
from tendon2r_gym.presets import PPO_CONFIG
from tendon2r_gym.training import Hyperparams


def _tiny(tmp_path, residual=0.5, steps=256, ppo=(), env=(), **extra):
    base = Hyperparams.from_entry("default")
    hp = base.replace(
        env_kwargs={"preset": "default", "episode_duration": 0.1, **dict(env)},
        ppo={**base.ppo, "n_steps": 64, "batch_size": 64, "n_epochs": 1, **dict(ppo)},
        residual_scale=residual,
        total_timesteps=steps,
        n_envs=2,
        eval_freq=128,
        checkpoint_freq=128,
        eval_seeds=[0],
        **extra,
    )
    path = tmp_path / "ppo.yaml"
    path.write_text(yaml.safe_dump({"tiny": hp.to_dict()}))
    return path


def _train(config, run, *more):
    return train_main(
        ["--config", str(config), "--hyperparams", "tiny", "--run-dir", str(run), *more]
    )


def assert_best_is_the_best_ranked_evaluation(folder: RunFolder) -> None:
    """best_model is the evaluation with the lowest RMS among those <= PD within the smoothness
    limits, else the lowest overall (resumed segments included); pd_eval.json holds PD's
    tracking metrics on the eval seeds, and on the same seeds started on the reference, where
    the smoothness is measured."""
    pd = folder.read_json("pd_eval.json")
    meta = folder.read_json("run.json")
    kwargs, seeds = meta["env_kwargs"], folder.read_config()["eval_seeds"]
    on_reference = {k: v for k, v in kwargs.items() if k != "reset_noise_scale"}

    def pd_on(env_kwargs: dict) -> dict:
        metrics = evaluate("pd", env_kwargs, seeds)[0]
        return {k: v for k, v in metrics.items() if k != "policy"}

    assert pd == {**pd_on(kwargs), "on_reference": pd_on(on_reference)}
    rows = folder.read_json("evaluations.json")
    for row in rows:
        assert row["beats_pd"] == beats(row["rms_deg"], pd["rms_deg"])
        assert row["within_limits"] == within_limits(
            row["tension_x_pd"], row["tension_rate_x_pd"], meta["residual_scale"] > 0
        )
    best = rows[min(range(len(rows)), key=lambda i: selection_rank(rows[i]))]  # first of equals
    assert folder.read_json("best_metrics.json")["rms_deg"] == best["rms_deg"]


def test_the_best_model_is_the_most_precise_one_that_beats_pd_within_the_limits():
    def row(rms: float, tension_x_pd: float, rate_x_pd: float, residual: bool) -> dict:
        return {
            "rms_deg": [rms, rms],
            "beats_pd": rms <= 0.1,  # PD at 0.1 deg
            "within_limits": within_limits(tension_x_pd, rate_x_pd, residual),
        }

    for residual in (False, True):
        precise_chatter, smooth = row(0.01, 1.0, 12.0, residual), row(0.02, 1.0, 9.0, residual)
        ranks = selection_rank(smooth) < selection_rank(precise_chatter)
        # Plain PPO (rate limit 10x PD's): the smooth one wins; a residual (3x): neither keeps
        # the limits, so the more precise one does.
        assert ranks == (not residual)
        # A smooth policy that loses to PD never outranks one that beats it.
        assert selection_rank(precise_chatter) < selection_rank(row(0.2, 1.0, 0.0, residual))
        # Too much tension counts as out of the limits too.
        assert selection_rank(row(0.03, 1.4, 1.0, residual)) < selection_rank(
            row(0.02, 1.6, 1.0, residual)
        )


def test_smoke_train_then_resume(tmp_path):
    config, run = _tiny(tmp_path), tmp_path / "run"
    first = _train(config, run)["runs"][0]
    folder = RunFolder(run / "seed_0")
    assert first["timesteps"] >= 256
    for name in ("best_model.zip", "best_model_vecnormalize.pkl", "last_model.zip", "run.json",
                 "config.yaml", "command.txt", "evaluations.json", "summary.json"):  # fmt: skip
        assert folder.file(name).is_file(), name
    meta = folder.read_json("run.json")
    assert meta["env_config"]["mechanism"]["R1"] == 0.014 and meta["residual_scale"] == 0.5
    assert_best_is_the_best_ranked_evaluation(folder)
    # The same command again, without --resume, would start over on top of the run: refused,
    # the run untouched.
    saved = {p: p.read_bytes() for p in (run / "seed_0").iterdir() if p.is_file()}
    with pytest.raises(ValueError, match=r"run_dir = .*--resume continues them"):
        _train(config, run)
    assert {p: p.read_bytes() for p in (run / "seed_0").iterdir() if p.is_file()} == saved
    # A run from before pd_eval.json kept PD's full metrics (its RMS alone) resumes: PD's
    # metrics are measured again for the smoothness-aware ranking.
    folder.write_json("pd_eval.json", folder.read_json("pd_eval.json")["rms_deg"])
    resumed = _train(config, run, "--total-timesteps", "512", "--resume")["runs"][0]
    assert resumed["timesteps"] >= 512
    assert resumed["pd_eval_rms_deg"] == folder.read_json("pd_eval.json")["rms_deg"]
    assert folder.read_json("summary.json")["wall_time_s"] >= first["wall_time_s"]
    assert len(resumed["segments"]) == 2, "summary.json adds up every segment"
    lines = folder.file("command.txt").read_text().splitlines()
    assert [line.split().count("--resume") for line in lines] == [0, 1], lines
    assert_best_is_the_best_ranked_evaluation(folder)
    # A crash that never wrote last_model, and a corrupt newest checkpoint: resume falls back.
    for f in run.glob("seed_0/last_model*"):
        f.unlink()
    newest = folder.checkpoint_candidates()[0][0]
    newest.write_bytes(b"truncated")
    with pytest.warns(UserWarning, match="skipping unreadable"):
        again = _train(config, run, "--total-timesteps", "768", "--resume")["runs"][0]
    assert again["timesteps"] >= 768
    _check_bundle(run / "seed_0", tmp_path / "models")


def _check_bundle(run, root):
    with pytest.raises(ValueError, match="bundle"):
        bundled_model("tiny", root=root)
    bundle_runs([run], "tiny", "tendon2r-train --bundle tiny", root=root)
    meta = bundle_meta("tiny", root=root)
    assert meta["seeds"] == [0] and meta["primary_seed"] == 0
    assert meta["train_command"].split().count("--resume") == 0
    path = bundled_model("tiny", root=root)
    assert not (path.parent / "checkpoints").exists(), "only the small files are bundled"
    env = gym.make("Tendon2R-v0")
    obs, _ = env.reset(seed=0)
    action, _ = PPOPolicy.load(path, env).predict(obs)
    assert action.shape == (2,) and env.action_space.contains(action)
    # A model meets only its own env.
    for other in ({"preset": "report_002"}, {"preview_steps": 2}, {"ctrl_dt": 0.002}):
        with pytest.raises(ValueError, match="trained for another env"):
            PPOPolicy.load(path, gym.make("Tendon2R-v0", **other))
    with pytest.raises(ValueError, match="seed"):
        bundled_model("tiny", seed=7, root=root)
    with pytest.raises(FileNotFoundError, match="lacks"):
        bundle_runs([root / "nothing"], "x", "cmd", root=root)


def test_from_scratch_smoke_train(tmp_path):
    # Started off the reference, as the plain entries train and evaluate.
    config = _tiny(tmp_path, residual=0.0, env={"reset_noise_scale": 0.02})
    out = _train(config, tmp_path / "run")
    assert out["finished"] == [0]
    folder = RunFolder(tmp_path / "run" / "seed_0")
    assert folder.read_json("run.json")["residual_scale"] == 0
    assert_best_is_the_best_ranked_evaluation(folder)  # plain PPO's limits


def test_train_on_an_experiment_file(tmp_path):
    arm = tmp_path / "arm.yaml"
    arm.write_text(
        "mechanism: {R1: 0.02, R2: 0.03, a: 0.06, b: 0.06, c: 0.09}\n"
        "reference: {amp_deg: [10, 10], freq_hz: [1, 1], bias_deg: [0, 0]}\n"
        "episode_duration: 0.1\n"
    )
    hp = experiment(TrainArgs(hyperparams="default", env_config=str(arm))).hyperparams
    assert hp.env_kwargs["preset"] == str(arm)
    config = _tiny(tmp_path)
    run = tmp_path / "run"
    train_main(["--config", str(config), "--hyperparams", "tiny", "--env-config", str(arm),
                "--run-dir", str(run)])  # fmt: skip
    recorded = RunFolder(run / "seed_0").read_json("run.json")["env_config"]
    assert recorded["mechanism"]["R1"] == 0.02
    assert recorded["mechanism"]["max_tendon_force"] > 0, "auto is resolved before recording"


def test_a_linear_schedule_as_rl_zoo3_writes_it_decays_over_the_run(tmp_path):
    config = _tiny(tmp_path, ppo={"learning_rate": "lin_3e-4", "clip_range": "lin_0.2"})
    run = tmp_path / "run"
    _train(config, run)
    model = PPO.load(RunFolder(run / "seed_0").file("last_model.zip"), device="cpu")
    assert model.lr_schedule(1.0) == pytest.approx(3e-4)
    assert model.lr_schedule(0.25) == pytest.approx(0.75e-4)
    assert model.clip_range(0.5) == pytest.approx(0.1)
    assert model.policy.optimizer.param_groups[0]["lr"] < 1e-4, "the last update ran decayed"


@pytest.mark.parametrize(
    ("override", "match"),
    [
        (["--n-envs", "0"], "n_envs"),
        (["--hyperparams", "nope"], "hyperparams"),
        (["--env-config", "nope"], "unknown preset"),
    ],
)
def test_bad_train_arguments_are_rejected(override, match):
    with pytest.raises(ValueError, match=match):
        experiment(parse(TrainArgs, ["--config", str(PPO_CONFIG), *override]))


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [("total_timesteps", 0, "total_timesteps = 0"), ("eval_seeds", [], "eval_seeds"),
     ("vec_env", "gpu", "vec_env = 'gpu'"),
     ("residual_scale", -1, "residual_scale = -1"), ("env_kwargs", {"ctrl_dt": -1}, "ctrl_dt"),
     ("ppo", {"learning_rate": "lin_x"}, "ppo.learning_rate = 'lin_x'"),
     ("ppo", {"clip_range": "cos_0.2"}, "ppo.clip_range = 'cos_0.2'"),
     ("ppo", {"learning_rate": "lin_3e-4_after_0.6"},  # no decay tail: rl_zoo3's lin_<v> only
      r"ppo.learning_rate = 'lin_3e-4_after_0.6' is invalid; allowed: .* or 'lin_<positive"),
     ("ppo", {"learning_rate": -3e-4}, "ppo.learning_rate = -0.0003")],
)  # fmt: skip
def test_hyperparams_are_validated_once_naming_the_field(field, value, match):
    with pytest.raises(ValueError, match=match):
        Hyperparams.from_entry("default").replace(**{field: value})
    with pytest.raises(ValueError, match="unknown key 'totl_timesteps'"):
        Hyperparams.from_dict({**Hyperparams.from_entry("default").to_dict(), "totl_timesteps": 1})


@pytest.mark.parametrize("key", sorted(REMOVED))
def test_a_removed_option_in_a_new_entry_is_an_unknown_key(tmp_path, key):
    """A removed option (held off or on) is no key of a hyperparameter entry; only a run
    record written before it went may hold it off (tendon2r_gym.artifacts.runs.REMOVED)."""
    path = tmp_path / "mine.yaml"
    path.write_text(yaml.safe_dump({"mine": {"base": "default", key: REMOVED[key]}}))
    with pytest.raises(ValueError, match=rf"mine: unknown key '{key}'"):
        Hyperparams.from_entry("mine", path)
    with pytest.raises(ValueError, match=rf"unknown key '{key}'"):
        Hyperparams.from_entry("default").replace(**{key: REMOVED[key]})


def _start_training(tmp_path, seeds, steps, *more):
    config = _tiny(tmp_path, steps=steps, checkpoint_minutes=0.005)
    cmd = [sys.executable, "-c", "from tendon2r_gym.app.cli import train; train()", "--config",
           str(config), "--hyperparams", "tiny", "--run-dir", str(tmp_path / "run"), "--seeds",
           *map(str, seeds), *more]  # fmt: skip
    env = {**os.environ, "MUJOCO_GL": "egl"}
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def _wait_for(path, proc, timeout=120):
    start = time.monotonic()
    while not list(path.parent.glob(path.name)):
        assert proc.poll() is None, proc.stdout.read().decode()[-2000:]
        assert time.monotonic() - start < timeout
        time.sleep(0.1)


def test_ctrl_c_stops_every_seed_and_saves_and_resume_keeps_the_overrides(tmp_path):
    """SIGINT during seed 0 of two: exit 130, last_model and summary saved, seed 1 never
    starts, seeds_summary.json written.  A resume without the flags continues the run that was
    started: its seeds, and the budget and n_envs overridden on the first command."""
    proc = _start_training(tmp_path, [0, 1], 256, "--total-timesteps", "10000000", "--n-envs", "3")
    _wait_for(tmp_path / "run" / "seed_0" / "evaluations.json", proc)
    proc.send_signal(signal.SIGINT)
    out = proc.communicate(timeout=120)[0].decode()
    assert proc.returncode == 130, out[-2000:]
    run = RunFolder(tmp_path / "run" / "seed_0")
    assert run.file("last_model.zip").is_file()
    assert run.read_json("summary.json")["interrupted"] is True
    assert not (tmp_path / "run" / "seed_1").exists()
    agg = json.loads((tmp_path / "run" / "seeds_summary.json").read_text())
    assert agg["finished"] == []
    resumed = experiment(parse(TrainArgs, ["--run-dir", str(tmp_path / "run"), "--resume"]))
    assert resumed.hyperparams.total_timesteps == 10**7, "not the entry's 256"
    assert resumed.hyperparams.n_envs == 3 and resumed.seeds == [0]
    extended = experiment(
        parse(TrainArgs, ["--run-dir", str(tmp_path / "run"), "--resume", "--seeds", "0", "1",
                          "--total-timesteps", "512"])
    )  # fmt: skip
    assert extended.hyperparams.total_timesteps == 512 and extended.seeds == [0, 1]
    assert extended.hyperparams.n_envs == 3
    done = extended.train(resume=True)
    assert done["finished"] == [0, 1] and all(r["timesteps"] >= 512 for r in done["runs"])


def test_resume_takes_the_most_trained_state_whatever_the_file_times(tmp_path):
    """checkpoint_candidates orders the saved states by the steps each recorded (last_model
    first among equals), so a run folder copied without its file times (cp -r) resumes from
    its most trained state; an unreadable last_model comes last."""
    import zipfile

    run = RunFolder(tmp_path / "seed_0")
    run.checkpoints.mkdir(parents=True)

    def save(stem, steps, stats):
        with zipfile.ZipFile(stem.with_suffix(".zip"), "w") as z:
            z.writestr("data", json.dumps({"num_timesteps": steps}))
        stats.write_bytes(b"stats")

    for steps in (300, 100, 200):  # written in this order: the newest file holds 200 steps
        save(run.checkpoints / f"rl_model_{steps}_steps", steps,
             run.checkpoints / f"rl_model_vecnormalize_{steps}_steps.pkl")  # fmt: skip
    save(run.path / "last_model", 300, run.path / "last_model_vecnormalize.pkl")
    os.utime(run.path / "last_model.zip", (0, 0))  # the oldest file of all
    names = [z.name for z, _ in run.checkpoint_candidates()]
    assert names == ["last_model.zip", *(f"rl_model_{n}_steps.zip" for n in (300, 200, 100))]
    (run.path / "last_model.zip").write_bytes(b"truncated")
    assert [z.name for z, _ in run.checkpoint_candidates()][-1] == "last_model.zip"


def test_sigkill_loses_little_thanks_to_timed_checkpoints(tmp_path):
    """Checkpoints are also taken by time, and written whole: after a SIGKILL at any moment,
    --resume has a complete state to continue (the newest zip and its statistics load)."""
    proc = _start_training(tmp_path, [0], steps=10**7)
    _wait_for(tmp_path / "run" / "seed_0" / "checkpoints" / "rl_model_*_steps.zip", proc)
    proc.kill()
    proc.wait()
    candidates = RunFolder(tmp_path / "run" / "seed_0").checkpoint_candidates()
    assert candidates
    zip_path, stats = candidates[0]
    load_policy(zip_path)
    load_vecnormalize(stats, DummyVecEnv([lambda: gym.make("Tendon2R-v0")]))


def test_a_run_on_reference_ranges_records_them_and_loads(tmp_path):
    ranges = {"amp_deg": [[5, 10], [5, 10]], "freq_hz": [[0.5, 1], [0.5, 1]],
              "bias_deg": [[-5, 5], [-5, 5]]}  # fmt: skip
    config = _tiny(tmp_path)
    cfg = yaml.safe_load(config.read_text())
    cfg["tiny"]["env_kwargs"]["reference_ranges"] = ranges
    config.write_text(yaml.safe_dump(cfg))
    _train(config, tmp_path / "run")
    run = RunFolder(tmp_path / "run" / "seed_0")
    assert run.read_json("run.json")["env_config"]["reference_ranges"]["amp_deg"] == [
        [5, 10],
        [5, 10],
    ]
    env = gym.make("Tendon2R-v0", **run.read_json("run.json")["env_kwargs"])
    PPOPolicy.load(run.best.with_suffix(".zip"), env)


def test_fine_tuning_starts_from_a_generalists_weights_on_an_arm_inside_its_ranges(tmp_path):
    """--init-from: a run on random arms, fine-tuned on one arm inside its ranges, starts from
    its weights and observation statistics; an arm outside them is refused by name."""
    import torch
    from stable_baselines3 import PPO

    gen = _tiny(tmp_path)
    hp = Hyperparams.from_dict(yaml.safe_load(gen.read_text())["tiny"])
    hp = hp.replace(env_kwargs={"preset": "generalist", "episode_duration": 0.1})
    gen.write_text(yaml.safe_dump({"tiny": hp.to_dict()}))
    _train(gen, tmp_path / "gen")
    source = tmp_path / "gen" / "seed_0" / "last_model.zip"
    arm = tmp_path / "arm.yaml"
    arm.write_text(
        "mechanism: {R1: 0.02, R2: 0.03, a: 0.06, b: 0.06, c: 0.09}\n"
        "reference: {amp_deg: [10, 10], freq_hz: [1, 1], bias_deg: [0, 0]}\n"
        "episode_duration: 0.1\n"
    )
    config = _tiny(tmp_path, steps=64)
    run = tmp_path / "tuned"
    _train(config, run, "--env-config", str(arm), "--init-from", str(source))
    tuned = PPO.load(run / "seed_0" / "last_model.zip", device="cpu").policy.state_dict()
    first = PPO.load(source, device="cpu").policy.state_dict()
    # one small update away from the generalist, not a fresh network, nor no update at all
    assert all(torch.allclose(tuned[k], first[k], atol=0.05) for k in first)
    assert any(not torch.equal(tuned[k], first[k]) for k in first)
    # its own steps: the source's count does not eat the fine-tune's budget
    steps = json.loads((run / "seed_0" / "summary.json").read_text())["timesteps"]
    source_steps = json.loads((tmp_path / "gen" / "seed_0" / "summary.json").read_text())
    assert 0 < steps < source_steps["timesteps"], steps
    far = tmp_path / "far.yaml"
    far.write_text(arm.read_text().replace("c: 0.09", "c: 0.2"))
    with pytest.raises(ValueError, match=r"c = 0.2 outside \[0.025, 0.12\]"):
        _train(config, tmp_path / "far", "--env-config", str(far), "--init-from", str(source))
    assert not (tmp_path / "far").exists(), "a refused start writes nothing"


def test_the_registered_fine_tune_trains_on_its_generalists_reward():
    """generalist_finetune trains on the reward its source entry trained on (tracking form,
    sigma, every weight), as the env resolves them; only the arm differs."""
    from tendon2r_gym.envs.env_config import EnvConfig

    tune = Hyperparams.from_entry("generalist_finetune")
    source = Hyperparams.from_entry(tune.init_from)

    def reward(hp: Hyperparams) -> tuple:
        c = EnvConfig.make(**hp.env_kwargs)
        return c.tracking_form, c.tracking_sigma_deg, c.reward_scales

    assert reward(tune) == reward(source)
    assert reward(source) != reward(Hyperparams.from_entry("default"))  # the test can fail


def test_a_filtered_residual_trains_deploys_and_fine_tunes_with_its_filter(tmp_path):
    """residual_filter_tau: run.json records it; PPOPolicy.load adds PD to the model's residual
    through the same filter, restarted with each episode; the eval callback's score is the
    loaded policy's; a fine-tune takes its source's filter; it needs a residual."""
    from tendon2r_gym.evaluation.evaluator import evaluate

    tau = 0.005
    _train(_tiny(tmp_path, residual_filter_tau=tau), tmp_path / "run")
    run = RunFolder(tmp_path / "run" / "seed_0")
    assert run.read_json("run.json")["residual_filter_tau"] == tau
    kwargs = {"preset": "default", "episode_duration": 0.1}
    model_path = run.best.with_suffix(".zip")
    env = gym.make("Tendon2R-v0", **kwargs)
    policy = PPOPolicy.load(model_path, env)
    alpha = -np.expm1(-env.unwrapped.config.ctrl_dt / tau)
    for seed in (1, 2):
        obs, info = env.reset(seed=seed)
        policy.reset(info)
        y = np.zeros(2)
        for _ in range(10):
            raw, _ = policy.model.predict(
                policy.vecnormalize.normalize_obs(obs), deterministic=True
            )
            y = y + alpha * (0.5 * np.clip(raw, -1, 1) - y)
            action, _ = policy.predict(obs)
            expected = np.clip(policy.pd.predict(obs)[0] + y, -1, 1).astype(np.float32)
            np.testing.assert_allclose(action, expected, atol=1e-6)
            obs = env.step(action)[0]
    metrics, _ = evaluate("ppo", kwargs, [0], model_path)
    assert metrics["rms_deg"] == run.read_json("best_metrics.json")["rms_deg"]
    config = _tiny(tmp_path, steps=64, init_from=str(model_path))  # the entry's filter: none
    _train(config, tmp_path / "tuned")
    assert (
        RunFolder(tmp_path / "tuned" / "seed_0").read_json("run.json")["residual_filter_tau"] == tau
    )
    with pytest.raises(ValueError, match=r"residual_filter_tau = 0.005 .*residual_scale 0"):
        Hyperparams.from_dict(yaml.safe_load(config.read_text())["tiny"]).replace(
            residual_scale=0.0, init_from=None, residual_filter_tau=tau
        )


def test_a_fine_tune_starts_from_the_exploration_noise_it_asks_for(tmp_path):
    """init_log_std: the fine-tune starts from the source's weights with its exploration noise
    (the policy's log std) reset to that value; it needs init_from."""
    import torch
    from stable_baselines3 import PPO

    config = _tiny(tmp_path)
    _train(config, tmp_path / "source")
    source = tmp_path / "source" / "seed_0" / "last_model.zip"
    cfg = yaml.safe_load(config.read_text())
    cfg["tiny"].update(init_from=str(source), init_log_std=-2.5, total_timesteps=64)
    config.write_text(yaml.safe_dump(cfg))
    _train(config, tmp_path / "tuned")
    first = PPO.load(source, device="cpu").policy
    tuned = PPO.load(tmp_path / "tuned" / "seed_0" / "last_model.zip", device="cpu").policy
    assert torch.allclose(tuned.log_std, torch.full_like(first.log_std, -2.5), atol=0.01)
    assert not torch.allclose(first.log_std, tuned.log_std, atol=0.1)
    w = "mlp_extractor.policy_net.0.weight"
    assert torch.allclose(tuned.state_dict()[w], first.state_dict()[w], atol=0.05)
    # one value per action
    n = first.log_std.numel()
    per_action = [-2.0 - 0.5 * i for i in range(n)]
    cfg["tiny"]["init_log_std"] = per_action
    config.write_text(yaml.safe_dump(cfg))
    _train(config, tmp_path / "per_action")
    tuned = PPO.load(tmp_path / "per_action" / "seed_0" / "last_model.zip", device="cpu").policy
    assert torch.allclose(tuned.log_std, torch.tensor(per_action), atol=0.01)
    cfg["tiny"]["init_log_std"] = per_action + [-2.0]
    config.write_text(yaml.safe_dump(cfg))
    with pytest.raises(ValueError, match=rf"init_log_std = .* or {n} \(the model's actions\)"):
        _train(config, tmp_path / "too_many")
    assert not (tmp_path / "too_many").exists(), "a refused start writes nothing"
    hp = Hyperparams.from_dict(cfg["tiny"])
    with pytest.raises(ValueError, match=r"init_log_std = \[.*\] is invalid.*without init_from"):
        hp.replace(init_from=None)
    for bad in (5, [-2.0, "x"], []):
        with pytest.raises(ValueError, match=r"init_log_std = "):
            hp.replace(init_log_std=bad)


def test_a_residual_trained_on_tuned_gains_is_scored_and_loaded_with_them(tmp_path):
    """pd_gains of the training env are the residual's PD everywhere: the eval callback's
    score equals a fresh evaluation of the loaded best model on an env without pd_gains
    (PPOPolicy.load takes the recorded gains), and the PD under it uses them."""
    from tendon2r_gym.evaluation.evaluator import evaluate
    from tendon2r_gym.task.gains import Gains

    config = _tiny(tmp_path)
    cfg = yaml.safe_load(config.read_text())
    cfg["tiny"]["env_kwargs"]["pd_gains"] = {"bandwidth_hz": 11.0}
    config.write_text(yaml.safe_dump(cfg))
    _train(config, tmp_path / "run")
    run = RunFolder(tmp_path / "run" / "seed_0")
    plain = {"preset": "default", "episode_duration": 0.1}
    model = run.best.with_suffix(".zip")
    policy = PPOPolicy.load(model, gym.make("Tendon2R-v0", **plain))
    assert policy.pd.gains == Gains.from_dict({"bandwidth_hz": 11.0})
    metrics, _ = evaluate("ppo", plain, [0], model)
    assert metrics["rms_deg"] == run.read_json("best_metrics.json")["rms_deg"]


def test_arm_features_for_the_critic_only(tmp_path):
    """hide_from_actor (privileged critic): the hidden slice does not reach the actor (its
    output ignores it), the critic still reads it, and the saved model loads and acts."""
    import torch
    from stable_baselines3 import PPO

    from tendon2r_gym.task.observation import arm_slice

    config = _tiny(tmp_path)
    cfg = yaml.safe_load(config.read_text())
    cfg["tiny"]["env_kwargs"] = {"preset": "generalist", "observe": ["arm"],
                                 "episode_duration": 0.1}  # fmt: skip
    cfg["tiny"]["hide_from_actor"] = ["arm"]
    config.write_text(yaml.safe_dump(cfg))
    _train(config, tmp_path / "run")
    run = RunFolder(tmp_path / "run" / "seed_0")
    model = PPO.load(run.best.with_suffix(".zip"), device="cpu")
    policy = model.policy
    assert type(policy).__name__ == "SplitViewPolicy"
    obs = torch.as_tensor(np.random.default_rng(0).normal(size=(4, *model.observation_space.shape)),
                          dtype=torch.float32)  # fmt: skip
    other = obs.clone()
    other[:, arm_slice(3, 2, 5)] += 1.0  # another arm
    actor = lambda o: policy.get_distribution(o).distribution.mean  # noqa: E731
    critic = policy.predict_values
    with torch.no_grad():
        assert torch.equal(actor(obs), actor(other))
        assert not torch.equal(critic(obs), critic(other))
    env = gym.make("Tendon2R-v0", **run.read_json("run.json")["env_kwargs"])
    PPOPolicy.load(run.best.with_suffix(".zip"), env).predict(env.reset(seed=0)[0])
    with pytest.raises(ValueError, match="hide_from_actor: unknown key 'armm'"):
        Hyperparams.from_dict({**cfg["tiny"], "hide_from_actor": ["armm"]})


def test_one_drawn_field_hidden_from_the_actor():
    """hide_from_actor: [arm.<field>] blanks that one entry of the arm slice for the actor
    (e.g. the model's errors, which a user cannot know), which still reads the other drawn
    fields; the critic reads them all.  An unknown field is refused by name."""
    import torch

    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.task.observation import arm_slice

    env_kwargs = {"preset": "generalist", "observe": ["arm"], "episode_duration": 0.1}
    hp = Hyperparams.from_entry("default").replace(
        env_kwargs=env_kwargs, hide_from_actor=["arm.R2"], n_envs=1
    )
    config = EnvConfig.make(**env_kwargs)
    assert config.observation.arm_fields == ("R1", "R2", "a", "b", "c")
    arm = arm_slice(3, 2, 5)
    mask = config.observation.mask(hp.hide_from_actor)
    assert mask[arm].tolist() == [1, 0, 1, 1, 1] and mask[: arm.start].all()
    policy_class, kwargs = hp.policy(config)
    model = PPO(policy_class, gym.make("Tendon2R-v0", **env_kwargs), policy_kwargs=kwargs)
    obs = torch.as_tensor(np.random.default_rng(0).normal(size=(4, config.observation.size)),
                          dtype=torch.float32)  # fmt: skip
    actor = lambda o: model.policy.get_distribution(o).distribution.mean  # noqa: E731
    for index, read_by_actor in zip(range(arm.start, arm.stop), mask[arm], strict=True):
        other = obs.clone()
        other[:, index] += 1.0
        with torch.no_grad():
            assert torch.equal(actor(obs), actor(other)) != bool(read_by_actor)
            assert not torch.equal(model.policy.predict_values(obs),
                                   model.policy.predict_values(other))  # fmt: skip
    with pytest.raises(ValueError, match="hide_from_actor: unknown key 'arm.motor_tau'"):
        hp.replace(hide_from_actor=["arm.motor_tau"])


@pytest.mark.parametrize("force_limit", [False, True])
def test_a_model_that_observed_its_arm_runs_on_one_fixed_arm(tmp_path, force_limit):
    """Observing the arm on random arms, deployed on an env of one arm inside the ranges (no arm
    slice of its own): PPOPolicy appends the arm's fields normalized over the training ranges,
    the very features the training env would compute for that arm, and acts on them.  A model
    that observed the force limit runs on the arm's env with the model's settings
    (in_model_settings, as the benchmark makes it), which observes that arm's own limit."""
    from tendon2r_gym.artifacts.model_env import in_model_settings
    from tendon2r_gym.evaluation.evaluator import evaluate
    from tendon2r_gym.task.arms import MechanismRanges

    config = _tiny(tmp_path)
    cfg = yaml.safe_load(config.read_text())
    observe = ["arm", "force_limit"] if force_limit else ["arm"]
    cfg["tiny"]["env_kwargs"] = {"preset": "generalist", "observe": observe,
                                 "episode_duration": 0.1}  # fmt: skip
    config.write_text(yaml.safe_dump(cfg))
    _train(config, tmp_path / "run")
    best = RunFolder(tmp_path / "run" / "seed_0").best.with_suffix(".zip")
    arm = {"mechanism": {"R1": 0.02, "R2": 0.03, "a": 0.06, "b": 0.06, "c": 0.09},
           "reference": {"amp_deg": [10, 10], "freq_hz": [1, 1], "bias_deg": [0, 0]},
           "episode_duration": 0.1}  # fmt: skip
    if force_limit:
        with pytest.raises(ValueError, match="force_limit_log"):
            PPOPolicy.load(best, gym.make("Tendon2R-v0", **arm))
        arm = in_model_settings(best, arm)
        assert arm["observe"] == ["force_limit"]  # the model's, without its arm slice
    env = gym.make("Tendon2R-v0", **arm)
    policy = PPOPolicy.load(best, env)
    expected = MechanismRanges.from_value("envelope").features(env.unwrapped.config)
    np.testing.assert_array_equal(policy.arm, expected)
    obs, _ = env.reset(seed=0)
    limit = np.log(env.unwrapped.config.mechanism.max_tendon_force)
    assert (obs[-1] == pytest.approx(limit, rel=1e-12)) == force_limit
    seen = policy.vecnormalize.normalize_obs(np.concatenate([obs, expected]))
    raw, _ = policy.model.predict(seen, deterministic=True)
    base, _ = policy.pd.predict(obs)
    np.testing.assert_allclose(  # float32 rounding: the policy runs float64 (inference)
        policy.predict(obs)[0], residual_command(base, raw, 0.5).astype(np.float32), atol=1e-6
    )
    metrics, _ = evaluate("ppo", arm, [0], best)
    assert np.all(np.isfinite(metrics["rms_deg"]))
    far = {**arm, "mechanism": {**arm["mechanism"], "c": 0.2}}
    with pytest.raises(ValueError, match=r"c = 0.2 outside \[0.025, 0.12\]"):
        PPOPolicy.load(best, gym.make("Tendon2R-v0", **far))


@pytest.mark.parametrize("stride", [1, 2])
def test_frame_stack_trains_resumes_and_deploys_as_sb3_stacks(tmp_path, stride):
    """frame_stack (rl_zoo3's key): the model sees its last k normalized observations, oldest
    first, frame_stride steps apart; PPOPolicy.load stacks them itself, so its actions equal
    the model's on the training wrapper (SB3's VecFrameStack at stride 1) over the saved
    VecNormalize, a reset starts the stack anew, and the eval callback's score is the loaded
    policy's.  A run resumes with its stack."""
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from tendon2r_gym.evaluation.evaluator import evaluate
    from tendon2r_gym.training.frame_stack import stacked

    config = _tiny(tmp_path, frame_stack=3, frame_stride=stride)
    run_dir = tmp_path / "run"
    _train(config, run_dir)
    assert (
        _train(config, run_dir, "--total-timesteps", "512", "--resume")["runs"][0]["timesteps"]
        >= 512
    )
    run = RunFolder(run_dir / "seed_0")
    assert run.read_json("run.json")["frame_stack"] == 3
    assert run.read_json("run.json")["frame_stride"] == stride
    kwargs = {"preset": "default", "episode_duration": 0.1}
    model_path = run.best.with_suffix(".zip")
    policy = PPOPolicy.load(model_path, gym.make("Tendon2R-v0", **kwargs))
    model = PPO.load(model_path, device="cpu")
    assert (
        model.observation_space.shape[0] == 3 * gym.make("Tendon2R-v0").observation_space.shape[0]
    )
    venv = VecNormalize.load(str(run.file("best_model_vecnormalize.pkl")),
                             DummyVecEnv([lambda: gym.make("Tendon2R-v0", **kwargs)]))  # fmt: skip
    venv.training = venv.norm_reward = False
    sb3 = stacked(venv, 3, stride)
    env = gym.make("Tendon2R-v0", **kwargs)
    for seed in (1, 2):  # the second episode must not see the first's frames
        sb3.seed(seed)
        frames = sb3.reset()
        obs, info = env.reset(seed=seed)
        policy.reset(info)
        for _ in range(20):
            expected, _ = model.predict(frames, deterministic=True)
            action, _ = policy.predict(obs)
            base = policy.pd.predict(obs)[0]
            np.testing.assert_allclose(action, residual_command(base, expected[0], 0.5), atol=1e-6)
            obs = env.step(action)[0]
            frames = sb3.step(action[None])[0]
    metrics, _ = evaluate("ppo", kwargs, [0], model_path)
    assert metrics["rms_deg"] == run.read_json("best_metrics.json")["rms_deg"]
    with pytest.raises(ValueError, match="frame_stack = 0"):
        Hyperparams.from_entry("default").replace(frame_stack=0)


def test_fine_tuning_a_generalist_that_observed_its_arm(tmp_path):
    """--init-from a model trained on random arms with the arm's features, in joint-torque
    mode: the fine-tune on one arm trains in the source's action mode and sees that arm's
    features over the source's ranges; deployed on the arm's plain env it appends them
    (the same actions as on an env that observes them) and reproduces its training
    evaluation; it is refused on another arm."""
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.evaluation.evaluator import evaluate
    from tendon2r_gym.task.arms import MechanismRanges

    config = _tiny(tmp_path)
    cfg = yaml.safe_load(config.read_text())
    tiny = cfg["tiny"]
    cfg["source"] = {**tiny, "env_kwargs": {"preset": "generalist", "observe": ["arm"],
                                            "action_mode": "joint_torque",
                                            "episode_duration": 0.1}}  # fmt: skip
    config.write_text(yaml.safe_dump(cfg))
    train_main(["--config", str(config), "--hyperparams", "source", "--run-dir",
                str(tmp_path / "source")])  # fmt: skip
    source = tmp_path / "source" / "seed_0" / "best_model.zip"
    _train(config, tmp_path / "tuned", "--init-from", str(source))
    run = RunFolder(tmp_path / "tuned" / "seed_0")
    kwargs = run.read_json("run.json")["env_kwargs"]
    envelope = MechanismRanges.from_value("envelope")
    assert kwargs["action_mode"] == "joint_torque" and kwargs["observe"] == ["arm"]
    assert MechanismRanges.from_value(kwargs["arm_feature_ranges"]) == envelope
    plain = {"preset": "default", "episode_duration": 0.1, "action_mode": "joint_torque"}
    model = run.best.with_suffix(".zip")
    policy = PPOPolicy.load(model, gym.make("Tendon2R-v0", **plain))
    assert policy.arm.tolist() == envelope.features(EnvConfig.make(**plain))
    seen = gym.make("Tendon2R-v0", **kwargs)
    full, _ = seen.reset(seed=3)
    assert np.array_equal(
        policy.predict(full[: -policy.arm.size])[0], PPOPolicy.load(model, seen).predict(full)[0]
    )
    metrics, _ = evaluate("ppo", plain, [0], model)
    assert metrics["rms_deg"] == run.read_json("best_metrics.json")["rms_deg"]
    other = gym.make("Tendon2R-v0", **plain, mechanism={"R1": 0.02})
    with pytest.raises(ValueError, match="trained for another env: mechanism"):
        PPOPolicy.load(model, other)

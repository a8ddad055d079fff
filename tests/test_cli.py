"""The console commands: evaluate's outputs and errors, the benchmark on bundled models and on
your own arm."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import tendon2r_gym
from tendon2r_gym.app.args import parse
from tendon2r_gym.app.benchmark import FINETUNED, LEARNED, ZERO_SHOT, compare
from tendon2r_gym.app.cli import EvaluateArgs, benchmark_main, evaluate_main
from tendon2r_gym.app.markdown import rows_of
from tendon2r_gym.evaluation import evaluator as evaluation
from tendon2r_gym.evaluation.evaluator import BASELINE, PolicyEntry, names
from tendon2r_gym.policies.baselines import PDPolicy

ARM = """\
mechanism: {R1: 0.025, R2: 0.065, a: 0.068, b: 0.056, c: 0.091}
reference: {amp_deg: [51.86, 29.54], freq_hz: [3.47, 1.02], bias_deg: [19.6, 9.9]}
episode_duration: 0.2
"""


def test_evaluate_writes_json_plots_and_video(tmp_path):
    config = tmp_path / "my_arm.yaml"
    config.write_text(
        "mechanism: {R1: 0.012, R2: 0.02, a: 0.05, b: 0.07, c: 0.09}\n"
        "reference: {amp_deg: [10, 10], omega_rad_s: [6.0, 9.0], bias_deg: [0, -5]}\n"
    )
    out = tmp_path / "m.json"
    evaluate_main(
        ["--policy", "pd", "--env-config", str(config), "--episodes", "2", "--episode-duration",
         "0.1", "--json", str(out), "--plots", str(tmp_path / "p"), "--video",
         str(tmp_path / "v.gif")]
    )  # fmt: skip
    metrics = json.loads(out.read_text())
    for key in ("rms_deg", "max_deg", "rms_tension_N", "saturated_fraction"):
        assert len(metrics[key]) == 2
    assert metrics["episodes"] == 2 and metrics["seeds"] == [0, 1]
    assert metrics["steps"] == 2 * 100, "episode_duration / ctrl_dt steps per episode"
    for name in ("tracking.png", "forces.png", "effector_path.png"):
        assert (tmp_path / "p" / name).stat().st_size > 1000
    assert (tmp_path / "v.gif").stat().st_size > 1000


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--policy", "ppo", "--model", "/nonexistent/model.zip"], r"'/nonexistent/model.zip'"),
        (["--policy", "ppo", "--model", "{tmp}"], "an existing SB3 model file"),
        (["--policy", "pd", "--model", "/x/model.zip"], "uses no model"),
        (["--policy", "ct", "--bundle", "default"], "uses no model"),
        (["--policy", "pd", "--episodes", "0"], r"--episodes = 0 is invalid"),
        (["--policy", "ppo", "--bundle", "nope"], r"bundle = 'nope' is invalid"),
    ],
)
def test_evaluate_argument_errors_are_clear(tmp_path, argv, match):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    with pytest.raises(ValueError, match=match) as err:
        evaluate_main(argv)
    assert ".zip.zip" not in str(err.value)


def test_a_bad_argument_is_a_one_line_error_with_exit_code_2():
    proc = subprocess.run(
        [sys.executable, "-c", "from tendon2r_gym.app.cli import evaluate; evaluate()", "--policy",
         "pd", "--episodes", "0"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert proc.returncode == 2
    assert proc.stderr.strip().startswith("error: --episodes = 0 is invalid")


def test_benchmark_on_bundled_models(tmp_path, monkeypatch, short_episodes):
    """Every bundled model loads and runs, and the page is the report of the JSON record (one
    jittered rerun per figure instead of REPRO_RUNS: the tolerance's machinery, in less time)."""
    from tendon2r_gym.app import report
    from tendon2r_gym.evaluation import evaluator

    monkeypatch.setattr(evaluator, "REPRO_RUNS", 1)
    result = benchmark_main(["--episodes", "1", "--out", str(tmp_path)])
    md = (tmp_path / "benchmark.md").read_text()
    cells = rows_of(md)
    assert ["default", "pd"] in [row[:2] for row in cells]
    assert any(row[1].startswith("*quoted:") for row in cells), "the reports' own figures"
    labels = {(r["env"], r["policy"]) for r in result["rows"]}
    for env in ("default", "report_002"):
        for policy in (*names(BASELINE), *LEARNED):
            assert (env, policy) in labels
    assert all("rms_deg" in r for r in result["rows"]), "every bundled model loads and runs"
    models = [r["model"] for r in result["rows"] if "model" in r]
    assert models and all(m.startswith("tendon2r_gym/data/models/") for m in models), models
    assert json.loads((tmp_path / "benchmark.json").read_text())["rows"]
    record = json.loads((tmp_path / "benchmark.json").read_text())
    assert md == "\n".join(report.bundled_page(record)) + "\n"
    assert all(len(r["reproducible_to"]) == 2 for r in result["rows"])


def test_benchmark_on_your_own_arm(tmp_path, monkeypatch):
    _untuned(monkeypatch)
    arm = tmp_path / "my_arm.yaml"
    arm.write_text(ARM)
    out = tmp_path / "out"
    result = benchmark_main(
        ["--env-config", str(arm), "--train-steps", "256", "--seeds", "0", "--episodes", "1",
         "--out", str(out), "--run-dir", str(tmp_path / "runs")]
    )  # fmt: skip
    policies = [r["policy"] for r in result["rows"]]
    assert policies[: len(names(BASELINE)) + len(LEARNED)] == [*names(BASELINE), *LEARNED]
    # then each shipped generalist, zero-shot: this arm's R2 is outside the envelope
    zero_shot = [r for r in result["rows"] if r["policy"].endswith("zero-shot")]
    assert [r["policy"] for r in zero_shot] == [f"{g} zero-shot" for g in ZERO_SHOT]
    package = str(Path(tendon2r_gym.__file__).resolve().parent)
    assert not [r for r in result["rows"] if package in r.get("missing", "")], "a machine's path"
    for row in zero_shot:  # the pull-only ones have another observation (three commands)
        assert "R2 = 0.065 outside [0.008, 0.06]" in row["missing"] or (
            any(k in row["policy"] for k in ("pull_only", "real_arm", "generalist_real"))
            and "was trained for another env" in row["missing"]
        ), row
    tuned = next(r for r in result["rows"] if r["policy"] == "PD tuned")  # tendon2r-tune-pd's
    assert tuned["pd_gains"]["bandwidth_hz"] > 0 and "rms_deg" in tuned
    finetuned = [r for r in result["rows"] if r["policy"] in FINETUNED]
    assert [r["policy"] for r in finetuned] == list(FINETUNED)  # nothing to start from
    assert all("R2 = 0.065 outside [0.008, 0.06]" in r["missing"] for r in finetuned)
    assert result["force_need_N"] > 0.5, "the course arm needs more than the old 0.5 N"
    assert ["my_arm", "pd"] in [row[:2] for row in rows_of((out / "benchmark.md").read_text())]
    assert (out / "plots" / "my_arm" / "pd" / "tracking.png").is_file()
    assert (tmp_path / "runs" / "ppo_scratch" / "seed_0" / "run.json").is_file()


def _untuned(monkeypatch):
    """PD's tuning (tendon2r-tune-pd's own tests: tests/test_tuning.py) as a stub, the
    package's gains; and one jittered rerun per row instead of REPRO_RUNS (the tolerance's
    machinery, in less time: test_benchmark_on_bundled_models)."""
    from tendon2r_gym.evaluation import evaluator, tuning
    from tendon2r_gym.task.gains import default_gains

    stub = type("Scan", (), {"gains": default_gains()})
    monkeypatch.setattr(tuning, "tune_pd", lambda *a, **k: stub)
    monkeypatch.setattr(evaluator, "REPRO_RUNS", 1)


def test_generalist_real_runs_zero_shot_on_a_real_arm(tmp_path, monkeypatch, short_episodes):
    """An experiment file with realism values (configs/examples/my_real_arm.yaml, as
    tendon2r-identify writes one) runs generalist_real zero-shot: through tendon2r-evaluate,
    and as a row of the own-arm benchmark, where it runs on the gains of the PD tuned row."""
    arm = Path(__file__).resolve().parents[1] / "configs" / "examples" / "my_real_arm.yaml"
    out = tmp_path / "m.json"
    evaluate_main(["--policy", "ppo", "--bundle", "generalist_real", "--env-config", str(arm),
                   "--episodes", "1", "--json", str(out)])  # fmt: skip
    assert len(json.loads(out.read_text())["rms_deg"]) == 2
    _untuned(monkeypatch)
    from tendon2r_gym.app import benchmark

    seen = []
    real = benchmark.evaluate
    monkeypatch.setattr(
        benchmark, "evaluate", lambda p, kw, *a: seen.append((p, kw, *a)) or real(p, kw, *a)
    )
    rows = benchmark_main(["--env-config", str(arm), "--no-train", "--episodes", "1",
                           "--out", str(tmp_path / "out")])["rows"]  # fmt: skip
    row = next(r for r in rows if r["policy"] == "generalist_real zero-shot")
    assert "missing" not in row and len(row["rms_deg"]) == 2, row
    tuned = next(r for r in rows if r["policy"] == "PD tuned")["pd_gains"]
    ran = [kw for p, kw, *rest in seen if p == "ppo" and "generalist_real" in str(rest)]
    assert ran and all(kw.pd_gains.to_dict() == tuned for kw in ran)  # resolved configs


def test_benchmark_fine_tunes_the_generalist_on_an_arm_it_covers(
    tmp_path, monkeypatch, short_episodes
):
    """Inside the generalist's ranges, the own-arm benchmark also fine-tunes it: a row with
    its steps and wall time, trained from the bundle's weights (its run's config says so, with
    the settings it took from its source).  Run again (after a crash, or for the report), it
    continues its runs as they recorded themselves and reports the same rows; a folder whose
    runs had other hyperparameters is refused, named."""
    args = ["--env-config", "default", "--train-steps", "256", "--seeds", "0", "--episodes", "1",
            "--out", str(tmp_path / "out"), "--run-dir", str(tmp_path / "runs")]  # fmt: skip
    _untuned(monkeypatch)
    result = benchmark_main(args)
    (label,) = FINETUNED
    row = next(r for r in result["rows"] if r["policy"] == label)
    assert "rms_deg" in row and row["train_steps"] > 0 and row["train_wall_s"] > 0
    config_file = tmp_path / "runs" / label.replace(" ", "_") / "seed_0" / "config.yaml"
    config = config_file.read_text()
    recorded = yaml.safe_load(config)
    assert recorded["init_from"] == "generalist" and "arm" in recorded["env_kwargs"]["observe"]
    again = benchmark_main(args)
    assert config_file.read_text() == config
    rows = lambda result: {r["policy"]: r.get("rms_deg") for r in result["rows"]}  # noqa: E731
    assert rows(again) == rows(result)
    config_file.write_text(config.replace("tracking_sigma_deg: 0.1", "tracking_sigma_deg: 0.2"))
    with pytest.raises(ValueError, match=r"run_dir = .*generalist_fine-tuned.*\['env_kwargs'\]"):
        benchmark_main(args)


def test_a_new_baseline_is_one_registry_line(monkeypatch):
    """A policy added to the registry is a CLI choice, a benchmark row and a verdict's
    baseline, with no other change."""

    class Gentle(PDPolicy):  # a stand-in baseline: PD at half the torque
        def _torque(self, obs, M):
            return 0.5 * super()._torque(obs, M)

    entry = PolicyEntry("gentle PD", BASELINE, lambda env, _: Gentle.from_env(env))
    monkeypatch.setitem(evaluation.POLICIES, "gentle", entry)
    assert parse(EvaluateArgs, ["--policy", "gentle"]).policy == "gentle"
    rows = compare("default", {"preset": "default", "episode_duration": 0.05}, {}, [0], None)
    assert [r["policy"] for r in rows] == ["pd", "ct", "gentle"]
    assert rows[2]["rms_deg"] != rows[0]["rms_deg"]


def test_benchmark_runs_a_model_in_the_action_mode_it_trained_in(tmp_path, monkeypatch):
    """A bundle trained in joint-torque mode with an action filter runs on the preset's arm,
    reference and episodes in those settings, in the benchmark and in the generalist study,
    and its rows say so; PD's rows stay in the env's settings."""
    from research.studies import generalist as generalist_study
    from tendon2r_gym.app.report import shown_policy
    from tendon2r_gym.artifacts.model_env import settings_on
    from tendon2r_gym.evaluation.evaluator import evaluate
    from tendon2r_gym.training import Experiment, Hyperparams

    env = {"preset": "default", "episode_duration": 0.05}
    hp = Hyperparams.from_entry("default").replace(
        env_kwargs={**env, "action_mode": "joint_torque", "action_filter_tau": 0.01},
        total_timesteps=256,
        n_envs=2,
        ppo={**Hyperparams.from_entry("default").ppo, "n_steps": 64, "batch_size": 64},
        eval_freq=128,
    )
    exp = Experiment(hp, tmp_path, [0, 1], "test")
    exp.train()
    models = [exp.run_folder(s).path / "best_model.zip" for s in (0, 1)]
    rows = compare("default", env, {"ppo residual": models}, [0], None)
    learned = [r for r in rows if r["policy"].startswith("ppo residual")]
    assert len(learned) == 2 and all(r["action_mode"] == "joint_torque" for r in learned)
    assert all(r["action_filter_tau"] == 0.01 for r in learned)
    assert shown_policy(learned[0]) == "ppo residual (joint-torque mode, action_filter_tau 0.01)"
    assert all("action_mode" not in r for r in rows if r["policy"] in ("pd", "ct"))
    with pytest.raises(ValueError, match="action_mode = joint_torque there"):
        evaluate("ppo", env, [0], models[0])  # the env's own mode: refused, not run
    # One home for those settings (learned.settings_on), which the generalist study uses too.
    settings = {"action_mode": "joint_torque", "action_filter_tau": 0.01}
    assert settings_on(models[0], env) == settings
    assert settings_on(models[0], {**env, **settings}) == {}
    monkeypatch.setattr(generalist_study, "bundled_model", lambda name: models[0])
    study_rows = generalist_study.evaluate_arm(env, ["trained"], [0])
    assert study_rows["trained"]["rms_deg"] == learned[0]["rms_deg"]


def test_evaluate_runs_a_bundle_in_the_settings_it_trained_in(tmp_path):
    """tendon2r-evaluate --bundle generalist on a user's arm (a tension-mode experiment file)
    runs the model in its own action mode, as the benchmark does, and records it."""
    from pathlib import Path

    from tendon2r_gym.artifacts.bundle import bundled_model
    from tendon2r_gym.artifacts.model_env import model_settings

    arm = Path(__file__).resolve().parents[1] / "configs" / "examples" / "course_arm.yaml"
    out = tmp_path / "m.json"
    evaluate_main(["--policy", "ppo", "--bundle", "generalist", "--env-config", str(arm),
                   "--episodes", "1", "--episode-duration", "0.1", "--json", str(out)])  # fmt: skip
    recorded = json.loads(out.read_text())["env_kwargs"]
    mode = model_settings(bundled_model("generalist"))["action_mode"]
    assert recorded.get("action_mode", "tension") == mode


def _figures(record):
    """benchmark.json without what a run's timing and folders decide: the wall times, the
    model paths and the command line."""
    timing = {"eval_s", "train_wall_s", "train_wall_s_max", "model"}
    return [{k: v for k, v in r.items() if k not in timing} for r in record["rows"]]


def test_the_own_arm_benchmark_on_two_workers_gives_the_figures_of_one(tmp_path, monkeypatch):
    """--workers 2 trains a row's two seeds at once in spawned worker processes: benchmark.json
    holds the figures of --workers 1.  The row of both seeds carries its per-joint IQM with
    its interval, mean +- std and its probability of beating PD.  One learned row of a tiny
    PPO (2 envs, 64-step rollouts: the hyperparameters travel with each job), no zero-shot
    bundles and no plots (their own tests above); no short_episodes (a spawned worker does not
    see this process's patches; the arm's episodes are 0.2 s anyway)."""
    from tendon2r_gym.app import benchmark
    from tendon2r_gym.evaluation.metrics import beats
    from tendon2r_gym.training import Hyperparams

    _untuned(monkeypatch)
    monkeypatch.setattr(benchmark, "LEARNED", {"ppo scratch": "default_scratch"})
    monkeypatch.setattr(benchmark, "FINETUNED", {})
    monkeypatch.setattr(benchmark, "ZERO_SHOT", ())
    monkeypatch.setattr(benchmark, "plot_trace", lambda *a: None)
    entry = Hyperparams.from_entry

    def tiny(cls, *args, **kwargs):
        hp = entry(*args, **kwargs)
        return hp.replace(ppo={**hp.ppo, "n_steps": 64, "batch_size": 64, "n_epochs": 1},
                          n_envs=2, eval_freq=128, checkpoint_freq=128, eval_seeds=[0])  # fmt: skip

    monkeypatch.setattr(Hyperparams, "from_entry", classmethod(tiny))
    arm = tmp_path / "my_arm.yaml"
    arm.write_text(ARM)

    def run(workers):
        out = tmp_path / f"out_{workers}"
        benchmark_main(["--env-config", str(arm), "--train-steps", "256", "--seeds", "0", "1",
                        "--episodes", "1", "--out", str(out), "--run-dir",
                        str(tmp_path / f"runs_{workers}"), "--workers", str(workers)])  # fmt: skip
        return json.loads((out / "benchmark.json").read_text())

    one, two = run(1), run(2)
    words = two["command"].split()
    assert words[words.index("--workers") + 1] == "2"
    assert _figures(two) == _figures(one)
    rows = {r["policy"]: r for r in two["rows"]}
    seeds, pd = rows["ppo scratch (2 seeds)"], rows["pd"]["rms_deg"]
    stats = seeds["statistics"]
    per_seed = seeds["rms_deg_per_seed"]
    assert stats["runs"] == 2 and stats["rms_deg_iqm"] == pytest.approx(seeds["rms_deg"])
    assert stats["rms_deg_mean"] == seeds["rms_deg"]
    assert stats["rms_deg_std"] == seeds["rms_deg_std"]
    for (lo, hi), a, b in zip(stats["rms_deg_iqm_ci"], *per_seed, strict=True):
        assert min(a, b) <= lo <= hi <= max(a, b)
    assert stats["beats_pd"]["wins"] == sum(beats(r, pd) for r in per_seed)
    assert stats["beats_pd"]["pairs"] == 2 and stats["note"].startswith("2 runs: the interval")
    assert len(stats["worst_ratio_to_pd"]) == 2


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--workers", "2"], r"^--workers = 2 is invalid; allowed: 1 without --env-config"),
        (["--cluster", "auto"], r"^--cluster = 'auto' is invalid; allowed: only with --env-c"),
        (["--env-config", "{arm}", "--workers", "0"], r"^--workers = 0 is invalid"),
        (
            ["--env-config", "{arm}", "--workers", "2", "--cluster", "auto"],
            r"^--workers = 2 is invalid; allowed: 1 with --cluster",
        ),
    ],
)
def test_the_benchmark_refuses_bad_workers_before_anything_trains(tmp_path, monkeypatch, argv,
                                                                  match):  # fmt: skip
    from tendon2r_gym.evaluation import tuning

    monkeypatch.setattr(tuning, "tune_pd", lambda *a, **k: pytest.fail("tuned PD"))
    arm = tmp_path / "my_arm.yaml"
    arm.write_text(ARM)
    argv = [a.replace("{arm}", str(arm)) for a in argv]
    with pytest.raises(ValueError, match=match):
        benchmark_main([*argv, "--out", str(tmp_path / "out"), "--run-dir", str(tmp_path / "r")])
    assert not (tmp_path / "r").exists() and not (tmp_path / "out").exists()

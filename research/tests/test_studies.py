"""The studies behind results/ run end to end (tiny budgets; outputs, never timings), and the
defaults follow their results."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from research.studies import learnability, speed
from tendon2r_gym.artifacts.bundle import bundle_names
from tendon2r_gym.formatting import pair
from tendon2r_gym.simulation.mechanism import Mechanism
from tests.reading import bullets, figures, form, rows_by_name, rows_of
from tests.reading import row as named_row

RESULTS = Path(__file__).resolve().parent.parent / "results"
ABLATIONS = Path(__file__).resolve().parent.parent / "configs" / "ablations.yaml"


def test_every_ablation_entry_builds():
    """Each entry of research/configs/ablations.yaml resolves its base chain and validates
    (none holds an option the library no longer has), and each generalist ablation that the
    generalist study compares is one of them."""
    from research.studies import generalist
    from tendon2r_gym.presets import load_yaml
    from tendon2r_gym.training import Hyperparams

    names = list(load_yaml(ABLATIONS))
    assert set(generalist.ABLATIONS) <= set(names)
    for name in names:
        assert Hyperparams.from_entry(name, ABLATIONS).total_timesteps > 0, name


def test_bench_speed_writes_every_figure(tmp_path, monkeypatch):
    # The subprocess set-up with two workers instead of eight, and the native one: the same
    # plumbing, in less time on two cores.
    small = {k: {**v, "n_envs": 2} if v else v for k, v in speed.PPO_SETUPS.items()
             if "dummy" not in k}  # fmt: skip
    monkeypatch.setattr(speed, "PPO_SETUPS", small)
    argv = ["--steps", "200", "--ppo-timesteps", "512", "--eval-freq", "4096",
            "--first-win-timesteps", "512", "--vector-seconds",
            "0.05", "--repeats", "1", "--single-rounds", "1", "--num-envs", "1", "2",
            "--max-processes", "1",
            "--out", str(tmp_path)]  # fmt: skip
    result = speed.main(argv)
    saved = json.loads((tmp_path / "speed.json").read_text())
    # A figure, not a timing check: with 200 steps on a loaded machine the difference of two
    # timings may even come out negative.
    assert saved["overhead_ratio"] == result["overhead_ratio"]
    assert math.isfinite(saved["overhead_ratio"])
    for env_id in ("Tendon2R-v0", "Reacher-v5"):
        assert saved[env_id]["raw_physics_us"] > 0 and saved[env_id]["env_step_us"] > 0
    assert {f"{b}_{n}" for b in speed.BACKENDS for n in (1, 2)} - set(saved["vector"]) == {
        "async_2",
        "sb3_subproc_2",
    }, "process backends stop at --max-processes"
    assert set(saved["ppo"]) == set(speed.PPO_SETUPS)
    for run in saved["ppo"].values():
        assert run["timesteps"] >= 512 and run["peak_pss_mb"] > 0
    md = (tmp_path / "speed.md").read_text()
    from tendon2r_gym.artifacts.runs import command_line

    assert command_line(argv, "python -m research.studies.speed") in md  # what produced it
    assert set(speed.targets(saved, [1, 2])) <= set(md.splitlines()), "the targets, met or not"
    for env_id in ("Tendon2R-v0", "Reacher-v5"):
        cells = named_row(md, env_id)
        assert figures(cells[1])[0] == saved[env_id]["substeps"]
        assert figures(cells[2])[0] == pytest.approx(saved[env_id]["raw_physics_us"], abs=0.05)


def test_learnability_study_end_to_end(tmp_path, short_episodes):
    result = learnability.main(
        ["--steps", "256", "--seeds", "0", "1", "--rows", "defaults", "landed_reward",
         "--jobs", "1", "--out", str(tmp_path)]
    )  # fmt: skip
    assert [r["row"] for r in result["rows"]] == ["defaults", "landed_reward"]
    for row in result["rows"]:
        assert len(row["rms_deg_per_seed"]) == 2 and len(row["rms_deg_mean"]) == 2
    md = (tmp_path / "learnability.md").read_text()
    shown = rows_by_name(md)
    assert list(shown) == ["defaults", "landed_reward"]
    for r in result["rows"]:
        assert figures(shown[r["row"]][2]) == pytest.approx(r["rms_deg_mean"], abs=5e-4)
        assert figures(shown[r["row"]][4]) == [r["beat_pd_seeds"], 2]
    words = result["command"].split()
    assert words[words.index("--steps") + 1] == "256" and result["command"] in md


def test_learnability_rows_change_what_they_say():
    landed = learnability.row_config("landed_reward", 1000)
    assert landed.env_kwargs["tracking_form"] == "quadratic"
    assert landed.normalize["norm_reward"] is True
    assert learnability.row_config("net_256", 1000).policy_kwargs["net_arch"] == [256, 256]
    assert learnability.row_config("defaults", 1000).total_timesteps == 1000


def test_default_time_step_is_the_study_recommendation():
    """Mechanism's default integrator and sim_dt are what research/results/timestep_study.json chose
    (re-run python -m research.studies.timestep after changing the model, then update the
    default)."""
    chosen = json.loads((RESULTS / "timestep_study.json").read_text())["recommended"]
    mech = Mechanism()
    assert (mech.integrator.lower(), mech.sim_dt) == (
        chosen["integrator"].lower(),
        chosen["sim_dt"],
    )


def test_random_course_arms_are_valid_and_seeded(tmp_path):
    from research.studies import arm_sweep
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.task.arms import COURSE, draw_arms

    arms = draw_arms(3, 4)
    assert arms == draw_arms(3, 4) and arms != draw_arms(4, 4)
    for arm in arms:
        cfg = EnvConfig.from_kwargs(arm)
        for k in ("R1", "R2", "a", "b", "c"):
            lo, hi = getattr(COURSE, k)
            assert lo <= getattr(cfg.mechanism, k) <= hi
        assert cfg.mechanism.max_tendon_force >= 2 * cfg.needs.force_need * 0.99
    files = arm_sweep.arm_files(tmp_path, 2, 3, ("tension", "joint_torque"))
    names = {"default", "report_002", "pull_only", "course_0", "course_1"}
    assert {k[0] for k in files} >= names and {k[1] for k in files} == {"tension", "joint_torque"}
    cfg = EnvConfig.make(str(files["course_1", "joint_torque"]))
    assert cfg.mechanism.R1 == arms[1]["mechanism"]["R1"] and cfg.action_mode == "joint_torque"


def test_arm_sweep_summary_counts_push_pull_arms_in_tension_mode(tmp_path):
    """The summary's push-pull line counts plain PPO in tension mode on arms whose tendons
    push and pull, and never a pull-only arm or the joint-torque mode."""
    from research.studies import arm_sweep

    def arm(name, mode, pull_only, wins, rate=2):
        v = {
            "rms_deg": [0.1, 0.1],
            "beats_pd": wins,
            "tension_x_pd": 1.0,
            "tension_rate_x_pd": rate,
        }
        return {
            "arm": name, "action_mode": mode, "pd": [0.2, 0.2], "ct": [0.0, 0.0],
            "env_config": {"mechanism": {"pull_only": pull_only}},
            "ppo scratch": v, "ppo residual": {**v, "beats_pd": True},
        }  # fmt: skip

    arms = [
        arm("a", "tension", False, False),
        arm("a", "joint_torque", False, True),
        arm("b", "tension", True, True),
        arm("c", "tension", False, True, rate=12),
    ]
    result = {"command": "x", "modes": ["tension", "joint_torque"]}
    arm_sweep.write(
        {**result, "arms": {f"{a['arm']}_{a['action_mode']}": a for a in arms}}, tmp_path
    )
    md = (tmp_path / "arm_sweep.md").read_text()
    # Each count: wins, arms, wins within the smoothness limits (arm c: 12x PD's rate, over
    # plain PPO's 10x and residual PPO's 3x); then plain PPO in either mode; then plain PPO on
    # the push-pull arms in tension mode (a and c).
    counts = [figures(line) for line in bullets(md)]
    assert counts == [[2, 3, 1], [1, 1, 1], [3, 3, 2], [1, 1, 1], [3, 3], [1, 2]]
    plain = [r[4] for r in rows_of(md)]
    assert [figures(c) for c in plain] == [
        [0.1, 0.1, a["ppo scratch"]["tension_x_pd"], a["ppo scratch"]["tension_rate_x_pd"]]
        for a in arms
    ]
    lost, won, won_b, over = map(form, plain)  # a cell reads its verdict, not just figures
    assert won == won_b and len({lost, won, over}) == 3


def test_arm_sweep_only_retrains_one_row_and_keeps_the_others(tmp_path, short_episodes):
    """--only scratch trains plain PPO alone; residual PPO's cells and command stay those of
    the earlier sweep, which must hold the same arm (checked before any training)."""
    from research.studies import arm_sweep
    from tendon2r_gym.envs.env_config import EnvConfig

    runs, out = tmp_path / "runs", tmp_path / "out"
    path = arm_sweep.arm_files(runs / "arms", 0, 2027)["default", "tension"]
    config = json.loads(json.dumps(EnvConfig.make(str(path)).to_dict()))
    cell = {"rms_deg": [9.0, 9.0], "beats_pd": False, "tension_x_pd": 1.0, "tension_rate_x_pd": 1}
    arm = {"arm": "default", "action_mode": "tension", "env_config": config, "pd": [1, 1],
           "ct": [0, 0], "ppo scratch": cell, "ppo residual": cell}  # fmt: skip
    earlier = {"command": "the old sweep", "modes": ["tension"], "arms": {"default_tension": arm}}
    out.mkdir()
    (out / "arm_sweep.json").write_text(json.dumps(earlier))
    argv = ["--arms", "default", "--action-modes", "tension", "--n-random", "0", "--train-steps",
            "2048", "--episodes", "1", "--out", str(out), "--run-dir", str(runs)]  # fmt: skip
    result = arm_sweep.main([*argv, "--only", "scratch"])
    new = result["arms"]["default_tension"]
    assert new["ppo residual"] == cell and new["ppo scratch"]["rms_deg"] != cell["rms_deg"]
    assert result["commands"]["ppo residual"] == "the old sweep"
    assert result["commands"]["ppo scratch"].endswith("--only scratch")
    assert sorted(p.name for p in (runs / "default_tension").iterdir()) == ["ppo_scratch"]
    md = (out / "arm_sweep.md").read_text()  # names the command each kept row comes from
    assert result["commands"]["ppo residual"] in md.split("`")
    assert arm_sweep._produced_by(result)[0] in md.splitlines()
    arm["env_config"] = {**config, "ctrl_dt": 0.002}  # another config of the arm
    (out / "arm_sweep.json").write_text(json.dumps(earlier))
    with pytest.raises(ValueError, match="arm 'default_tension'"):
        arm_sweep.main([*argv, "--only", "residual", "--run-dir", str(tmp_path / "r2")])
    assert not (tmp_path / "r2" / "default_tension").exists()


def test_sensitivity_variants_change_one_knob():
    from research.studies.sensitivity import variant
    from tendon2r_gym.training.hyperparams import scaled_schedule

    base = variant("defaults", None)
    assert variant("lr_x3", None).ppo["learning_rate"] == scaled_schedule(
        base.ppo["learning_rate"], 3
    )
    assert scaled_schedule("lin_1e-3", 3) == "lin_0.003" and scaled_schedule(1e-3, 2) == 2e-3
    assert variant("batch_x0.25", None).ppo["batch_size"] == base.ppo["batch_size"] // 4
    assert variant("8x512", None).rollout_steps == base.rollout_steps
    assert variant("norm_reward_off", None) is None, "the shipped value is not run twice"
    assert variant("gamma_0.95", 2048).total_timesteps == 2048


def test_sensitivity_rerun_reuses_a_finished_variant(tmp_path, short_episodes):
    """A rerun with the same run folder reuses the finished run (no training is lost or
    repeated): the same summary, the best model untouched."""
    from research.studies.sensitivity import _run

    first = _run("gamma_0.95", 2048, str(tmp_path))
    best = tmp_path / "gamma_0.95" / "seed_0" / "best_model.zip"
    stamp = best.stat().st_mtime_ns
    again = _run("gamma_0.95", 2048, str(tmp_path))
    assert again["timesteps"] == first["timesteps"] >= 2048
    assert again["best_rms_deg"] == first["best_rms_deg"]
    assert best.stat().st_mtime_ns == stamp
    # its smoothness is that of the evaluation that saved the best model
    run = tmp_path / "gamma_0.95" / "seed_0"
    saved = json.loads((run / "best_metrics.json").read_text())
    row = [r for r in json.loads((run / "evaluations.json").read_text())
           if r["timesteps"] == saved["timesteps"]][-1]  # fmt: skip
    assert row["rms_deg"] == first["best_rms_deg"]
    assert (
        again["best_on_reference"]
        == first["best_on_reference"]
        == {k: row[k] for k in ("tension_x_pd", "tension_rate_x_pd", "within_limits")}
    )


def test_sensitivity_reports_the_tension_rate_against_pd(tmp_path):
    """Each row gives the best model's tension rate and its multiple of PD's on the same
    episodes, and its smoothness on the reference against the limits; both counts exclude the
    shipped entry's own row."""
    from research.studies import sensitivity

    def run(name, rms, rate, rate_x_pd=1.5):
        on_ref = {"tension_x_pd": 1.0, "tension_rate_x_pd": rate_x_pd,
                  "within_limits": rate_x_pd <= 10}  # fmt: skip
        return {"variant": name, "best_rms_deg": rms, "pd_eval_rms_deg": [0.1, 0.1],
                "best_tension_rate_N_per_s": rate, "timesteps": 10, "wall_time_s": 1.0,
                "best_on_reference": on_ref}  # fmt: skip

    result = {
        "command": "x",
        "entry": sensitivity.ENTRY,
        "runs": [
            run("defaults", [0.01, 0.01], [2.0, 2.0]),
            run("gamma_0.95", [0.2, 0.01], [6.0, 6.0]),
            run("lr_x3", [0.01, 0.01], [2.0, 2.0], rate_x_pd=12.0),
            run("epochs_5", [0.01, 0.01], [2.0, 2.0]),
        ],
        "same_as_shipped": [],
        "pd_tension_rate_N_per_s": [2.0, 2.0],
    }
    sensitivity.write(result, tmp_path)
    md = (tmp_path / "sensitivity.md").read_text()
    shown = rows_by_name(md)
    assert list(shown) == [r["variant"] for r in result["runs"]]
    beats = {name: cells[4] for name, cells in shown.items()}
    assert beats["gamma_0.95"] != beats["defaults"] == beats["lr_x3"] == beats["epochs_5"]
    for r in result["runs"]:  # the tension rate, its multiple of PD's; then on the reference
        cells = shown[r["variant"]]
        rate_x_pd = r["best_tension_rate_N_per_s"][0] / 2.0
        assert figures(cells[5]) == [*r["best_tension_rate_N_per_s"], rate_x_pd]
        on_ref = r["best_on_reference"]
        assert figures(cells[6]) == [on_ref["tension_x_pd"], on_ref["tension_rate_x_pd"]]
    kept = {form(shown[name][6]) for name in ("defaults", "gamma_0.95", "epochs_5")}
    assert len(kept) == 1 and form(shown["lr_x3"][6]) not in kept  # within the limits, or not
    # beat PD: 2 of the 3 variants (the defaults row aside), 67%, target 80%; within the
    # limits too: 1 of 3
    assert figures(md.rstrip().splitlines()[-1]) == [2, 3, 67, 80, 1, 3]


def test_generalist_study_end_to_end(tmp_path):
    """Unseen arms, PD and CT rows, the summary and the markdown (no bundle: baselines only)."""
    from research.studies import generalist
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.evaluation.metrics import worst_ratio

    out = generalist.main(
        ["--n-arms", "2", "--episodes", "1", "--bundles", "--sweep", str(tmp_path / "none"),
         "--out", str(tmp_path)]
    )  # fmt: skip
    assert set(out["arms"]) == {"unseen_0", "unseen_1"}
    text = (tmp_path / "generalist.md").read_text()
    for name, arm in out["arms"].items():
        assert arm["rows"]["ct"]["rms_deg"][0] < arm["rows"]["pd"]["rms_deg"][0]
        authority = EnvConfig.make(**arm["env_kwargs"]).needs.control_authority
        cells = next(r for r in rows_of(text) if r[0] == name)  # the arms' table
        assert cells[2] == pair(authority, ".3g")
    assert worst_ratio([1.0, 3.0], [2.0, 1.0]) == 3.0


def test_generalist_fine_tuning_curve(tmp_path, short_episodes):
    """The fine-tuning section trains the entry from the generalist and from scratch on the
    arm where the generalist is worst, and reports both curves from step 0."""
    from research.studies import generalist

    out = generalist.main(
        ["--n-arms", "2", "--episodes", "1", "--bundles", "generalist", "--sweep",
         str(tmp_path / "none"), "--finetune-arms", "1", "--finetune-steps", "256",
         "--finetune-runs", str(tmp_path / "runs"), "--out", str(tmp_path)]
    )  # fmt: skip
    (name,) = out["finetune"]
    assert name == generalist.hardest_arms(out["arms"], 1)[0]
    row = out["finetune"][name]
    for label in ("fine-tuned", "scratch"):
        assert row[label]["curve"] and row[label]["wall_time_s"] > 0
    configs = {label: yaml.safe_load((tmp_path / "runs" / name / label / "seed_0" /
                                      "config.yaml").read_text())
               for label in ("fine-tuned", "scratch")}  # fmt: skip
    assert configs["fine-tuned"]["init_from"] == "generalist"
    assert configs["scratch"]["init_from"] is None
    md = (tmp_path / "generalist.md").read_text()  # the section: step 0, then each curve's
    steps = [r for r in rows_of(md) if len(r) == 4 and r[0] == name and r[1][0].isdigit()]
    assert figures(steps[0][1]) == [0]
    start = [row["zero_shot_rms_deg"], row["pd_rms_deg"]]
    np.testing.assert_allclose([figures(c) for c in steps[0][2:]], start, rtol=0, atol=5e-4)
    curve = row["fine-tuned"]["curve"]
    assert [figures(r[1])[0] for r in steps[1:]] == [s for s, _ in curve]
    shown = [figures(r[2]) for r in steps[1:]]
    np.testing.assert_allclose(shown, [a for _, a in curve], rtol=0, atol=5e-4)


def test_realism_ablation_scores_runs_on_the_realism_arms(tmp_path, monkeypatch, short_episodes):
    """The realism ablation reads a run folder (here the bundled real_arm run, trained on
    drawn PD gains) and scores its best model on the realism study's arms (the first two)
    against PD, on each arm's tuned PD: its counts follow its own per-arm figures, and a
    folder that is not a run is refused by name."""
    import pytest

    from research.studies import realism_ablation
    from research.studies.realism import realism_arms
    from tendon2r_gym.artifacts.bundle import bundled_model
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.evaluation.metrics import beats, worst_ratio
    from tendon2r_gym.task.gains import tuned_bandwidth

    monkeypatch.setattr(realism_ablation, "realism_arms", lambda: realism_arms()[:2])
    run = bundled_model("real_arm").parent
    out = realism_ablation.main(["--runs", str(run), "--episodes", "1", "--out", str(tmp_path)])
    arms, (record,) = out["arms"], out["runs"]
    assert [a["arm"] for a in arms] == [name for name, _ in realism_arms()[:2]]
    assert record["arms_le_pd"] == sum(beats(a["runs"][0], a["pd"]) for a in arms)
    lost = [a["arm"] for a in arms if worst_ratio(a["runs"][0], a["pd"]) > 1]
    assert record["lost_to_pd"] == lost
    assert record["command"].startswith("tendon2r-train --hyperparams real_arm ")
    text = (tmp_path / "realism_ablation.md").read_text()
    per_arm = [line for line in text.splitlines() if line.startswith("| perturbed ")]
    assert len(per_arm) == len(arms) - 1
    (run_row,) = [r for r in rows_of(text) if r[0] == "1"]  # the runs' table: run 1
    assert record["hide_from_actor"][0] == "arm.density_scale"  # its critic's alone
    assert run_row[2].endswith(", ".join(record["hide_from_actor"]))
    assert run_row[3] == realism_ablation._network_and_pd(record)
    # its layers, the bandwidths it trained on and the phase they were drawn at
    assert figures(run_row[3]) == [256, 256, 9.83, 46.9, 0.45, 0.9]
    for a in arms:  # each arm's tuned PD
        tuned_cell = named_row(text, a["arm"])[2]
        bandwidth, phase = a["tuned_pd"]["bandwidth_hz"], a["tuned_pd"]["true_loop_phase_rad"]
        assert figures(tuned_cell) == [float(f"{bandwidth:.3g}"), round(phase, 2)]
    fixed = {**record, "env_kwargs": {"pd_gains": {"bandwidth_hz": 12.29}}}
    assert realism_ablation._network_and_pd(fixed).endswith("; PD 12.29 Hz")
    scheduled = {**record, "env_kwargs": {"pd_gains": {"max_delay_phase": 0.5}}}
    assert figures(realism_ablation._network_and_pd(scheduled)) == [256, 256, 0.5, 30]
    drawn = {"mechanism_ranges": ["real_arm", {"pd_bandwidth_hz": [10.0, 40.0]}]}
    shown = realism_ablation._network_and_pd({**record, "env_kwargs": drawn})
    assert figures(shown) == [256, 256, 10, 40]
    phase = {"mechanism_ranges": ["real_arm", {"pd_max_delay_phase": [0.3, 0.6]}]}
    shown = realism_ablation._network_and_pd({**record, "env_kwargs": phase})
    assert figures(shown) == [256, 256, 0.3, 0.6]
    tied = {"pd_bandwidth_hz": [10.0, 40.0], "pd_tuned_phase": [0.5, 0.7]}
    shown = realism_ablation._network_and_pd(
        {**record, "env_kwargs": {"mechanism_ranges": ["real_arm", tied]}}
    )
    assert figures(shown) == [256, 256, 10, 40, 0.5, 0.7]
    # a tuned PD's phase is the one that would draw its bandwidth (gains.tuned_bandwidth)
    tuned = realism_ablation._tuned_pd({"preset": "real_arm", "pd_gains": {"bandwidth_hz": 20}})
    arm = EnvConfig.make("real_arm")
    drawn_back = tuned_bandwidth(
        arm.mechanism, arm.observation_delay, arm.ctrl_dt, tuned["true_loop_phase_rad"]
    )
    assert tuned["bandwidth_hz"] == 20 and drawn_back == pytest.approx(20, rel=1e-12)
    with pytest.raises(ValueError, match=r"--runs = .* is invalid; allowed: run folders"):
        realism_ablation.main(["--runs", str(tmp_path), "--out", str(tmp_path)])


def test_generalist_ablation_names_each_bundles_reward_as_its_entry_sets_it():
    """The reward column reads the bundle's recorded env config: its entry's tracking form
    (the registered one if the entry sets none), its sigma if the entry changes it, and each
    weight the entry changes."""
    from research.studies import generalist
    from tendon2r_gym.artifacts.bundle import bundled_model
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.training import Hyperparams

    registered = EnvConfig.make()
    shown = [n for n in (*generalist.BUNDLES, *generalist.ABLATIONS) if n in bundle_names()]
    assert set(generalist.BUNDLES) <= set(shown)
    for name in shown:
        env = Hyperparams.from_entry(name).env_kwargs
        weights = [f"{k} {w:g}" for k, w in env.get("reward_scales", {}).items()]
        sigma = env.get("tracking_sigma_deg", registered.tracking_sigma_deg)
        sigmas = [f"sigma {sigma:g} deg"] if sigma != registered.tracking_sigma_deg else []
        form = env.get("tracking_form", registered.tracking_form)
        expected = ", ".join([form, *sigmas, *weights])
        assert generalist.reward_of(bundled_model(name)) == expected, name


def test_generalist_ablation_reads_who_saw_the_arm_from_each_run():
    """The ablation table's "arm features seen by" comes from each bundle's recorded run (its
    observation layout and hide lists), not from its name."""
    from research.studies.generalist import arm_seen_by
    from tendon2r_gym.artifacts.bundle import bundled_model

    assert arm_seen_by(bundled_model("default")) == "nobody (blind)"
    assert arm_seen_by(bundled_model("generalist")) == "actor and critic"


def test_generalist_ablation_reads_action_mode_and_network_from_each_run():
    """The ablation table's action mode, residual, its filter, network, evaluation episodes and
    optional observation entries come from each bundle's run record: what its configs/ppo.yaml
    entry trained it with."""
    from research.studies import generalist
    from tendon2r_gym.task.observation import OPTIONAL
    from tendon2r_gym.training import Hyperparams

    shown = [n for n in (*generalist.BUNDLES, *generalist.ABLATIONS) if n in bundle_names()]
    table = generalist.ablation(shown)
    for name in shown:
        hp = Hyperparams.from_entry(name)
        assert table[name]["action_mode"] == hp.env_kwargs.get("action_mode", "tension"), name
        net = hp.policy_kwargs.get("net_arch")
        assert table[name]["network"] == " x ".join(map(str, net)), name
        assert table[name]["eval_episodes"] == len(hp.eval_seeds), name
        assert table[name]["residual_filter_tau"] == hp.residual_filter_tau, name
        assert table[name]["learning_rate"] == hp.ppo["learning_rate"], name
        expected = f"{hp.residual_scale:g} x the command range"
        assert table[name]["residual"] == (expected if hp.residual_scale else "none (plain PPO)")
        observed = hp.env_kwargs.get("observe", [])
        flags = [e[0] for e, name in OPTIONAL.items() if name in observed]
        if hp.env_kwargs.get("error_units") == "action":
            flags.append("errors in action units")
        assert table[name]["observes"] == (", ".join(flags) or "none"), name
    assert generalist._rate("lin_3.0e-4") == "0.0003, linear to 0"
    assert generalist._rate(3.0e-4) == "0.0003"
    for key in ("residual_filter_tau", "learning_rate", "residual"):
        assert len({table[n][key] for n in shown}) > 1, f"the table tells {key} apart"


def test_generalist_is_compared_with_the_specialist_of_its_own_action_mode():
    """A sweep arm has one specialist per action mode: the summary scores each bundle against
    the one of the mode it runs in, and fine-tuning goes to the arms furthest from it (to the
    unseen arms furthest from PD without any)."""
    from research.studies import generalist

    mode = generalist.action_mode_of("generalist")
    other = "tension" if mode == "joint_torque" else "joint_torque"
    row = lambda rms: {"rms_deg": rms, "rms_tension_N": [1.0], "rms_tension_rate_N_per_s": [1.0]}  # noqa: E731
    arms = {
        "unseen_0": {"rows": {"pd": row([1.0, 1.0]), "generalist": row([0.5, 0.5])}},
        "unseen_1": {"rows": {"pd": row([1.0, 1.0]), "generalist": row([0.2, 0.2])}},
        "sweep_a": {
            "rows": {"pd": row([1.0, 1.0]), "generalist": row([0.1, 0.1])},
            "specialist_rms_deg": {mode: [0.01, 0.01], other: [1.0, 1.0]},
        },
        "sweep_b": {
            "rows": {"pd": row([1.0, 1.0]), "generalist": row([0.1, 0.1])},
            "specialist_rms_deg": {mode: [0.05, 0.2]},
        },
    }
    summary = generalist.summarize(arms, ["generalist"])["generalist"]
    assert (summary["beats_specialist"], summary["specialist_arms"]) == (0, 2)
    assert generalist.hardest_arms(arms, 2) == ["sweep_a", "sweep_b"]
    for name in ("sweep_a", "sweep_b"):
        arms[name]["specialist_rms_deg"] = {other: [0.01, 0.01]}
    assert generalist.summarize(arms, ["generalist"])["generalist"]["specialist_arms"] == 0
    assert generalist.hardest_arms(arms, 1) == ["unseen_0"]


def test_generalist_transient_section_shows_whole_and_settled_rms_on_sweep_arms():
    """The sweep arms' section gives each generalist seed's whole-episode and settled RMS
    beside the specialist of its action mode; unseen arms and other bundles stay out."""
    from research.studies import generalist

    mode = generalist.action_mode_of("generalist")
    row = lambda rms, settled: {"rms_deg": rms, "settled_rms_deg": settled}  # noqa: E731
    arms = {
        "unseen_0": {"rows": {"generalist": row([1.0, 1.0], [0.5, 0.5])}},
        "sweep_a": {
            "rows": {
                "generalist": row([0.0012, 0.0015], [0.0003, 0.0002]),
                "generalist@1": row([0.0011, 0.0014], [0.0004, 0.0001]),
                "generalist_scratch": row([0.1, 0.1], [0.1, 0.1]),
            },
            "specialist_rms_deg": {mode: [0.0013, 0.0009]},
        },
    }
    bundles = ["generalist", "generalist_scratch", "generalist@1"]
    lines = generalist.transient_lines(arms, bundles)
    table = [line for line in lines if line.startswith("| ")]
    head = table[0].strip("| ").split(" | ")  # a column per seed of the generalist alone
    assert [cell.split(":")[0] for cell in head[2:]] == ["generalist", "generalist@1"]
    assert table[1:] == [
        "| sweep_a | 0.0013 / 0.0009 | 0.0012 / 0.0015 (0.0003 / 0.0002) "
        "| 0.0011 / 0.0014 (0.0004 / 0.0001) |"
    ]
    assert generalist.transient_lines(arms, ["generalist_scratch"]) == []


def test_generalist_summary_holds_every_arm_to_the_smoothness_limits():
    """A median tension rate within the limit can hide arms over it: the summary counts the
    arms where a bundle keeps the smoothness limits (a residual's rate limit for a residual,
    plain PPO's for plain PPO, as its run recorded it) and those where it is also <= PD."""
    from research.studies import generalist
    from tendon2r_gym.evaluation.metrics import RATE_LIMIT_X_PD, TENSION_LIMIT_X_PD

    assert generalist.is_residual("generalist")
    assert not generalist.is_residual("generalist_scratch")

    def row(rms: float, tension: float = 1.0, rate: float = 1.0) -> dict:
        return {
            "rms_deg": [rms, rms],
            "rms_tension_N": [tension],
            "rms_tension_rate_N_per_s": [rate],
        }

    over = 1.01 * RATE_LIMIT_X_PD["residual"]  # over the residual's limit, within plain PPO's
    policies = [
        row(0.5, rate=over),  # <= PD, too fast for a residual
        row(2.0),  # smooth, worse than PD
        row(0.5, tension=1.01 * TENSION_LIMIT_X_PD),  # <= PD, too much tension
        row(0.5),  # <= PD and smooth
    ]
    arms = {
        f"unseen_{i}": {"rows": {"pd": row(1.0), "generalist": p, "generalist_scratch": p}}
        for i, p in enumerate(policies)
    }
    summary = generalist.summarize(arms, ["generalist", "generalist_scratch"])
    residual, plain = summary["generalist"], summary["generalist_scratch"]
    assert (residual["beats_pd"], residual["smooth"], residual["beats_pd_smooth"]) == (3, 2, 1)
    assert residual["max_tension_rate_x_pd"] == pytest.approx(over)
    assert residual["median_tension_rate_x_pd"] == pytest.approx(1.0)
    assert (plain["smooth"], plain["beats_pd_smooth"]) == (3, 2)


def test_generalist_study_column_runs_a_bundle_or_one_of_its_seeds():
    """A study column is a bundle (its primary seed) or NAME@SEED (another bundled seed); the
    default columns add each shipped generalist's other seeds; a bad column is a ValueError
    naming --bundles, a seed the bundle lacks one naming the seed."""
    from research.studies import generalist
    from tendon2r_gym.artifacts.bundle import bundle_meta, bundled_model

    meta = bundle_meta("generalist")
    assert generalist.model_of("generalist") == bundled_model("generalist")
    for seed in meta["seeds"]:
        assert generalist.model_of(f"generalist@{seed}") == bundled_model("generalist", seed)
    others = [s for s in meta["seeds"] if s != meta["primary_seed"]]
    assert generalist.other_seeds(["generalist"]) == [f"generalist@{s}" for s in others]
    with pytest.raises(ValueError, match="--bundles"):
        generalist.model_of("generalist@one")
    with pytest.raises(ValueError, match="seed of bundle 'generalist'"):
        generalist.model_of(f"generalist@{max(meta['seeds']) + 1}")


def test_transient_share_counts_the_first_settle_s_of_each_episode():
    """The share of the first SETTLE_S in the squared error is 1 when the error sits there
    alone and the fraction of those steps when it is even; the reward's share follows its
    kernels (log kernels weigh the head less than the squared error does)."""
    from types import SimpleNamespace

    from research.studies.transient import transient_share
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.envs.formulas import Formulas
    from tendon2r_gym.evaluation.metrics import SETTLE_S

    time = np.arange(200) * 0.001
    head = time <= SETTLE_S
    e = np.where(head[:, None], 0.03, 0.001) * np.ones((1, 2))
    only_head = SimpleNamespace(time=time, error_deg=np.where(head[:, None], e, 0.0))
    even = SimpleNamespace(time=time, error_deg=np.full((200, 2), 0.01))
    mixed = SimpleNamespace(time=time, error_deg=e)
    task = {"kernels": Formulas(EnvConfig.make(tracking_sigma_deg=0.1))}
    assert transient_share([only_head], task) == pytest.approx({"squared_error": 1, "kernels": 1})
    assert transient_share([even], task)["squared_error"] == pytest.approx(head.mean())
    assert transient_share([even, only_head], task)["squared_error"] == pytest.approx(
        (0.01**2 * head.sum() + 0.03**2 * head.sum()) / (0.01**2 * 200 + 0.03**2 * head.sum())
    )
    share = transient_share([mixed], task)
    assert share["kernels"] < share["squared_error"]


def test_transient_tracking_cost_is_minus_the_envs_tracking_term():
    """tracking_cost on an episode's errors equals minus the env's unscaled tracking term at
    each step (the task's formula, not a copy)."""
    from types import SimpleNamespace

    import gymnasium as gym

    from research.studies.transient import tracking_cost

    env = gym.make("Tendon2R-v0", tracking_sigma_deg=0.1, reward_scales={"tracking": 2.0})
    env.reset(seed=1)
    errors, rewards = [], []
    for _ in range(30):
        info = env.step(np.array([0.2, -0.1]))[4]
        errors.append(info["tracking_error_deg"])
        rewards.append(info["reward_tracking"] / 2.0)
    trace = SimpleNamespace(error_deg=np.array(errors))
    np.testing.assert_allclose(tracking_cost(env.unwrapped.formulas, trace), -np.array(rewards),
                               rtol=1e-9)  # fmt: skip


def test_transient_study_end_to_end(tmp_path):
    """On a one-arm sweep the study writes the arm's shares (each in [0, 1], the kernels'
    below the squared error's), its RMS beside the specialist's of its action mode and its
    effort and smoothness against PD; an arm outside the bundle's ranges is left out."""
    from research.studies import transient
    from research.studies.generalist import action_mode_of

    sweep = json.loads((RESULTS / "arm_sweep.json").read_text())
    keep = {k: a for k, a in sweep["arms"].items() if a["arm"] in ("course_2", "pull_only")}
    path = tmp_path / "sweep.json"
    path.write_text(json.dumps({**sweep, "arms": keep}))
    out = transient.main(["--episodes", "1", "--sweep", str(path), "--out", str(tmp_path)])
    assert list(out["arms"]) == ["sweep_course_2"]
    arm = out["arms"]["sweep_course_2"]
    share = arm["share"]
    assert 0 < share["own_reward"] < share["squared_error"] <= 1
    assert 0 < share["registered_reward"] <= 1
    mode = action_mode_of(out["bundle"])
    (specialist,) = [a["ppo residual"]["rms_deg"] for a in keep.values()
                     if a["arm"] == "course_2" and a["action_mode"] == mode]  # fmt: skip
    assert arm["specialist_rms_deg"] == specialist
    assert arm["tension_x_pd"] > 0 and arm["tension_rate_x_pd"] > 0
    text = (tmp_path / "transient.md").read_text()
    assert out["command"] in text
    (cells,) = rows_of(text)  # the one arm's row: its shares, its RMS and the specialist's
    assert cells[0] == "sweep_course_2"
    assert figures(" ".join(cells[1:4])) == pytest.approx(
        [share["squared_error"], share["own_reward"], share["registered_reward"]], abs=5e-3
    )
    assert figures(cells[6]) == pytest.approx(specialist, abs=5e-5)


def test_envelope_survey_counts_every_draw_and_reports_from_its_json(tmp_path):
    from research.studies import envelope

    result = envelope.main(["--draws", "12", "--out", str(tmp_path)])
    for s in result["surveys"]:  # each draw is valid or refused by a named field
        assert s["valid"] + sum(s["refused"].values()) == 12
    real = next(s for s in result["surveys"] if s["kind"] == "real")
    for key, n in real["stable"].items():
        assert n + sum(real["unstable"][key].values()) == real["valid"]
    md = (tmp_path / "envelope.md").read_text()
    assert md == "\n".join(envelope.lines(result)) + "\n"
    assert envelope.main(["--draws", "12", "--out", str(tmp_path), "--only-report"]) == result


def test_identification_gap_is_none_without_a_gap_and_a_ratio_with_one():
    from research.studies.identification import NO_GAP, closes, gap_closed, no_gap

    def cl(nominal, identified, true):
        return {b: {"pd_rms_deg": [v, 0.0]} for b, v in
                (("nominal", nominal), ("identified", identified), ("true", true))}  # fmt: skip

    assert gap_closed(cl(0.4, 0.15, 0.1), "pd_rms_deg") == pytest.approx(0.25 / 0.3)
    assert no_gap(cl(0.4, 0.15, 0.1), "pd_rms_deg") is None
    flat = 0.1 * (1 + NO_GAP / 2)  # the nominal choice as good as the true one
    assert gap_closed(cl(flat, 0.1, 0.1), "pd_rms_deg") is None
    assert no_gap(cl(flat, 0.1, 0.1), "pd_rms_deg") is True
    assert no_gap(cl(flat, 0.2, 0.1), "pd_rms_deg") is False
    assert gap_closed(cl(0.4, 0.15, 0.1), "residual_rms_deg") is None  # no residual row
    assert closes(cl(0.4, 0.15, 0.1), "pd_rms_deg")
    assert closes(cl(0.4, 0.05, 0.1), "pd_rms_deg")  # past the true choice, and nearer to it
    # The nominal choice beats the true one: no gap; the identified one passes if it loses at
    # most NO_GAP against the true one.
    assert gap_closed(cl(0.34, 0.70, 0.46), "pd_rms_deg") is None
    assert not closes(cl(0.34, 0.70, 0.46), "pd_rms_deg")
    assert no_gap(cl(0.34, 0.70, 0.46), "pd_rms_deg") is False
    assert no_gap(cl(0.473, 0.473, 0.501), "pd_rms_deg") is True
    assert not closes(cl(0.4, 0.2, 0.1), "pd_rms_deg")  # 67% of the gap


def test_envelope_generalists_study_runs_each_bundle_on_its_arms(
    tmp_path, monkeypatch, short_episodes
):
    """Each kind of arm gets PD tuned on it, the package's PD and each of its bundles that is
    bundled (or the error that refused the arm, with paths relative to the repository); the
    page is the report of the JSON."""
    from research.studies import envelope_generalists as study

    argv = ["--arms", "1", "--one-geometry", "1", "--episodes", "1", "--out", str(tmp_path)]
    result = study.main(argv)
    assert set(result["arms"]) == {"ideal_0", "ideal_0_pull_only", "real_0", "one_geometry_0"}
    for arm in result["arms"].values():
        rows = arm["rows"]
        assert rows["pd_tuned"]["bandwidth_hz"] > 0 and len(rows["pd"]["rms_deg"]) == 2
        assert set(rows) == {"pd", "pd_tuned", *(b for b in arm["bundles"] if b in bundle_names())}
    assert str(study.ROOT) not in json.dumps(result["arms"])
    md = (tmp_path / "envelope_generalists.md").read_text()
    assert md == "\n".join(study.lines(result)) + "\n"
    assert study.main([*argv, "--only-report"]) == result
    # --resume keeps the arms a run finished (its partial file), computing none again ...
    from tendon2r_gym.artifacts.bundle import bundled_model
    from tendon2r_gym.evaluation import evaluator, tuning

    monkeypatch.setattr(tuning, "tune_pd", lambda *a, **k: pytest.fail("tuned PD again"))
    monkeypatch.setattr(evaluator, "evaluate", lambda *a, **k: pytest.fail("recomputed a row"))
    assert study.main([*argv, "--resume"])["arms"] == json.loads(json.dumps(result["arms"]))
    # ... but measures a bundle retrained since (another model_id) again, and only it
    calls, shipped = [], study.model_id
    fake = {k: [0.0, 0.0] for k in study.KEYS}
    monkeypatch.setattr(evaluator, "evaluate", lambda *a: calls.append(a) or (fake, []))
    monkeypatch.setattr(study, "model_id", lambda b: "new" if b == "generalist" else shipped(b))
    again = study.main([*argv, "--resume"])["arms"]
    assert [(c[0], c[3]) for c in calls] == [("ppo", bundled_model("generalist"))]
    assert again["ideal_0"]["rows"]["generalist"] == {**fake, "model": "new"}
    for name, arm in result["arms"].items():
        kept = {b: r for b, r in arm["rows"].items() if (name, b) != ("ideal_0", "generalist")}
        assert {b: again[name]["rows"][b] for b in kept} == json.loads(json.dumps(kept))


def test_identification_effort_compares_the_residual_with_pd_on_the_same_gains():
    from research.studies.identification import effort_lines

    pd = {"pd_rms_deg": [0.2, 0.1], "pd_rms_tension_N": [2.0, 1.0, 1.0],
          "pd_rms_tension_rate_N_per_s": [10.0, 5.0, 5.0]}  # fmt: skip
    smooth = {"residual_rms_deg": [0.1, 0.1], "residual_rms_tension_N": [2.0, 1.0, 1.0],
              "residual_rms_tension_rate_N_per_s": [20.0, 10.0, 10.0]}  # fmt: skip
    rough = {**smooth, "residual_rms_tension_rate_N_per_s": [50.0, 25.0, 25.0]}
    row = {"arm": 0, "closed_loop": {"nominal": {**pd, **smooth}, "identified": {**pd, **rough},
                                     "true": {**pd}}}  # fmt: skip
    text = "\n".join(effort_lines([row]))
    assert rows_of(text) == [["0", "2 / 2 / 2", "10 / 10 / 10", "1 / 1 / -", "2 / 5 / -"]]
    # the residual kept the rate limit (3x PD's for a residual) on 1 of its 2 runs
    assert figures(text.splitlines()[-1]) == [1, 2]


def test_identification_ct_on_the_true_belief_is_the_registry_s_ct_on_the_true_arm():
    """CT built on the believed arm's env and rolled out on the true arm's is, for the true
    belief without model errors, the evaluator's CT on the true arm; a belief with another
    mass (a model error, which the nominal model PD and CT use leaves out) changes it."""
    from research.studies import identification as study
    from tendon2r_gym.evaluation.evaluator import evaluate

    true_kw = {"preset": "real_arm", "episode_duration": 0.5}
    gains = {"bandwidth_hz": 12.29}
    mine = study.informed_on("ct", true_kw, true_kw, gains)
    theirs, _ = evaluate("ct", {**true_kw, "pd_gains": gains}, list(range(study.EPISODES)))
    assert mine == {f"ct_{k}": theirs[k] for k in study.EFFORT}
    wrong = study.informed_on("ct", true_kw, {**true_kw, "mechanism": {"density_scale": 1.3}},
                              gains)  # fmt: skip
    assert wrong["ct_rms_deg"] != mine["ct_rms_deg"]


def test_identification_reference_gives_ct_per_belief_and_the_residual_s_ratio_to_it():
    from research.studies.identification import reference_lines

    def row(ct, residual):
        beliefs = zip(("nominal", "identified", "true"), ct, residual, strict=True)
        cl = {b: {"ct_rms_deg": [c, 0.0], **({} if r is None else {"residual_rms_deg": [r, 0.0]})}
              for b, c, r in beliefs}  # fmt: skip
        return {"arm": 3, "closed_loop": cl}

    text = "\n".join(reference_lines([row([0.4, 0.15, 0.1], [0.3, 0.075, None])]))
    assert rows_of(text) == [["3", "0.4", "0.15", "0.1", "83%", "0.500", "-"]]
    assert reference_lines([{"arm": 0, "closed_loop": {"true": {}}}]) == []  # no CT rows


def test_identification_hidden_true_sets_only_what_the_recording_does_not_show():
    from research.studies.identification import hidden_true

    identified = {"preset": "real_arm", "observation_delay": 0.001,
                  "mechanism": {"tendon_elasticity": 2700.0, "motor_tau": 0.0025,
                                "motor_delay": 0.002}}  # fmt: skip
    true_kw = {"preset": "real_arm", "observation_delay": 0.002,
               "mechanism": {"tendon_elasticity": 2823.0, "tendon_damping": 2.07,
                             "motor_tau": 0.0024, "motor_delay": 0.001}}  # fmt: skip
    fields = {"tendon_elasticity": {"identified": False, "true": 2823.0},
              "tendon_damping": {"identified": False, "true": 2.07},
              "motor_tau": {"identified": True, "true": 0.0024}}  # fmt: skip
    out = hidden_true(identified, true_kw, fields)
    assert out["mechanism"] == {"tendon_elasticity": 2823.0, "tendon_damping": 2.07,
                                "motor_tau": 0.0025, "motor_delay": 0.001}  # fmt: skip
    assert out["observation_delay"] == 0.002  # the identified 3 ms loop, split as the truth's
    assert identified["mechanism"]["tendon_elasticity"] == 2700.0  # not changed in place
    # A loop delay found shorter than the true sensor's delay: the sensor takes all of it.
    short = hidden_true({**identified, "observation_delay": 0.0,
                         "mechanism": {"motor_delay": 0.001}}, true_kw, {})  # fmt: skip
    assert short["observation_delay"] == 0.001 and short["mechanism"]["motor_delay"] == 0.0


def test_site_length_counts_the_article_s_words_only():
    from research.studies.site_length import words

    html = (
        "<html><nav>Home Env Results</nav><article><h1>The env</h1><p>It's 2R, v2 and "
        "0.002 s.<br>One<img src='x.png'> more.</p></article><footer>x y</footer></html>"
    )
    assert words(html) == 10  # The env It's 2R v2 and 0.002 s One more: no nav, no footer

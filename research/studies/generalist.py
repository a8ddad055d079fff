"""Generalist study: does one policy, trained across random arms, track arms it never saw?

    python -m research.studies.generalist      # research/results/generalist.md and .json
    python -m research.studies.generalist --n-arms 2 --episodes 1 --out runs/x      # smoke

Arms: ``--n-arms`` arms drawn with ``--arm-seed`` from the course's ranges by
tendon2r_gym.task.arms.draw_arms (training never draws from this generator: its arms come from the
envs' own seeded generators), each an experiment file; plus the arm sweep's arms
(research/results/arm_sweep.json) that lie inside the generalist's ranges, with their per-arm
specialists (the sweep's residuals, trained on that arm alone, one per action mode).

Per arm: PD, CT and each generalist bundle zero-shot (no training on the arm), on the same
evaluation seeds; the pull-only generalist on the same geometries with its preset's cables.
The fine-tuning curve: on the ``--finetune-arms`` sweep arms where the generalist is furthest
from its specialist (without the sweep: the unseen arms where it is furthest from PD), the
generalist fine-tuned against the same training from scratch, by default for a quarter of
the specialist's training steps: does it reach the specialist's error within them?

Summary per learned policy: the fraction of arms where it is <= PD on both joints, the
median worst-joint ratio of its RMS error to PD's, its RMS tension and tension rate as
multiples of PD's (median and largest), the arms where it keeps the smoothness limits
(tendon2r_gym.evaluation.metrics) and where it is also <= PD, and the fraction of arms where it is
<=
the specialist of its own action mode.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import yaml

from research.studies import joints, save_json
from tendon2r_gym.app.args import arg, parse
from tendon2r_gym.app.benchmark import GENERALISTS, LEARNED
from tendon2r_gym.artifacts.bundle import bundle_meta, bundle_names, bundled_model
from tendon2r_gym.artifacts.model_env import (
    feature_ranges,
    in_model_settings,
    model_settings,
    observes_arm,
)
from tendon2r_gym.artifacts.runs import (
    RunFolder,
    command_line,
    stem_of,
    training_record,
    training_summary,
)
from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.evaluation.evaluator import evaluate
from tendon2r_gym.evaluation.metrics import (
    RATE_LIMIT_X_PD,
    SETTLE_S,
    TENSION_LIMIT_X_PD,
    beats,
    smooth_enough,
    smoothness_x_pd,
    worst_ratio,
)
from tendon2r_gym.formatting import pair
from tendon2r_gym.policies.residual import Residual
from tendon2r_gym.presets import load_yaml, preset_path
from tendon2r_gym.task.arms import GEOMETRY, draw_arms
from tendon2r_gym.task.observation import OPTIONAL, layout_mask
from tendon2r_gym.task.rewards import REWARD_SCALES
from tendon2r_gym.training.hyperparams import LINEAR, linear_schedule
from tendon2r_gym.validation import invalid

#: The generalist bundles (configs/ppo.yaml entries of the same names: the residual, plain PPO, the
#: residual's entry on pull-only cables with action-rate weight 10 and action_rate_need), then the
#: ablations (what each changes is in its entry's comment; the ablation table reads its action mode,
#: network, learning rate, reward, arm features and evaluation episodes from its run record): the
#: residual generalist without the reference's feed-forward (generalist_action_units, the generalist
#: before observe feedforward), and that observing its errors in radians (generalist_rad, the
#: generalist before errors in action units); that with a decaying learning rate; with its action
#: rate also charged in multiples of the task's; at its constant rate with action-rate weight 1,
#: that on the registered reward's sigma (1 deg), and that without its error rate and force limit;
#: that without its residual filter; the plain generalist observing its errors in radians without
#: the feed-forward (generalist_scratch_rad, the plain generalist before them), and that blind to
#: the arm and blind to its force limit; the unfiltered residual generalist blind to the arm; an
#: earlier generalist (tension mode, blind, 64 x 64) and it with the arm's features; the "log"
#: reward at 3M steps, and on that reward and budget the arm's features seen by both networks and by
#: the critic only (privileged); the multiscale reward at 3M steps with two weights of the
#: action-rate term; on the pull-only cables that without action_rate_need, the generalist's own
#: entry at its action-rate weight (3), the earlier pull-only generalist (generalist_tension's entry
#: in joint-torque mode with a 2 ms residual filter, blind to the arm) and that in tension mode
#: without the filter (generalist_tension's reward with a 3x heavier action-rate term).
BUNDLES = GENERALISTS
ABLATIONS = (
    "generalist_action_units",
    "generalist_rad",
    "generalist_lin_lr",
    "generalist_rate_need",
    "generalist_rate1",
    "generalist_coarse",
    "generalist_unscaled",
    "generalist_unfiltered",
    "generalist_scratch_rad",
    "generalist_scratch_blind",
    "generalist_scratch_unscaled",
    "generalist_blind",
    "generalist_tension",
    "generalist_observe_arm",
    "generalist_log",
    "generalist_arm",
    "generalist_privileged",
    "generalist_multiscale",
    "generalist_multiscale_smooth",
    "generalist_pull_only_rate10",
    "generalist_pull_only_full",
    "generalist_pull_only_blind",
    "generalist_pull_only_smooth",
)

#: The pull-only generalist's preset: its arms are the unseen geometries with this preset's
#: cables (routing, pull_only, pretension), named ``unseen_<i>_pull_only``.
PULL_ONLY_PRESET = "generalist_pull_only"


def with_pull_only_cables(content: dict[str, Any]) -> dict[str, Any]:
    """Returns the experiment file ``content`` (a drawn arm) with the cables of
    PULL_ONLY_PRESET: its mechanism's fields other than the geometry."""
    cables = load_yaml(preset_path(PULL_ONLY_PRESET))["mechanism"]
    cables = {k: v for k, v in cables.items() if k not in GEOMETRY}
    return {**content, "mechanism": {**content["mechanism"], **cables}}


#: A study column names a bundle (its primary seed) or, as ``NAME@SEED``, another of its seeds.
SEED_MARK = "@"


def model_of(column: str) -> Path:
    """Returns the model a study column runs: a bundle's primary best model, or with
    ``NAME@SEED`` the best model of that bundled seed."""
    name, _, seed = column.partition(SEED_MARK)
    if not seed:
        return bundled_model(name)
    if not seed.isdigit():
        raise invalid("--bundles", column, f"a bundle's name, or NAME{SEED_MARK}SEED")
    return bundled_model(name, int(seed))


def other_seeds(bundles: list[str]) -> list[str]:
    """Returns the columns of the bundles' non-primary seeds (``NAME@SEED``)."""
    metas = {b: bundle_meta(b) for b in bundles}
    return [
        f"{b}{SEED_MARK}{s}"
        for b, meta in metas.items()
        if meta
        for s in meta["seeds"]
        if s != meta["primary_seed"]
    ]


def evaluate_arm(
    env_kwargs: dict[str, Any], bundles: list[str], seeds: list[int]
) -> dict[str, Any]:
    """Returns PD's, CT's and each bundle's metrics on one arm (a bundle that does not cover
    the arm is reported with its error, not run)."""
    rows: dict[str, Any] = {}
    for name in ("pd", "ct"):
        rows[name], _ = evaluate(name, env_kwargs, seeds)
    for bundle in bundles:
        model = model_of(bundle)
        kwargs = in_model_settings(model, env_kwargs)  # as the benchmark runs it
        try:
            rows[bundle], _ = evaluate("ppo", kwargs, seeds, model)
        except ValueError as e:  # outside the generalist's ranges
            rows[bundle] = {"error": str(e)}
    return rows


def _specialists(sweep: Path) -> dict[str, dict[str, Any]]:
    """Returns the arm sweep's arms (their tension-mode experiment file) with their residual's
    RMS (deg) in each action mode the sweep ran."""
    if not sweep.is_file():
        return {}
    out: dict[str, dict[str, Any]] = {}
    for a in json.loads(sweep.read_text())["arms"].values():
        if not a.get("ppo residual"):
            continue
        arm = out.setdefault(a["arm"], {"rms_deg": {}})
        arm["rms_deg"][a["action_mode"]] = a["ppo residual"]["rms_deg"]
        if a["action_mode"] == "tension" or "env_config" not in arm:
            arm["env_config"] = a["env_config"]
    return out


def sweep_arms(sweep: Path) -> dict[str, dict[str, Any]]:
    """Returns the study's sweep arms, ``sweep_<arm>``: each arm's ``env_kwargs`` (its
    mechanism and reference) and its specialists' ``specialist_rms_deg`` per action mode."""
    return {
        f"sweep_{name}": {
            "env_kwargs": {k: spec["env_config"][k] for k in ("mechanism", "reference")},
            "specialist_rms_deg": spec["rms_deg"],
        }
        for name, spec in _specialists(sweep).items()
    }


#: The configs/ppo.yaml entry of the sweep's residual specialists (their training steps).
SPECIALIST_ENTRY = LEARNED["ppo residual"]


def action_mode_of(bundle: str) -> str:
    """Returns the action mode a bundle trained (and runs) in, as its run recorded it."""
    return model_settings(model_of(bundle))["action_mode"]


def is_residual(bundle: str) -> bool:
    """Returns whether a bundle is a residual on PD (else plain PPO), as its run recorded it."""
    return Residual.from_record(training_record(model_of(bundle))).active


def specialist_rms(arm: dict[str, Any], mode: str) -> list[float] | None:
    """Returns the RMS (deg) of the arm's specialist in action mode ``mode``, if any."""
    return (arm.get("specialist_rms_deg") or {}).get(mode)


def summarize(arms: dict[str, Any], bundles: list[str]) -> dict[str, Any]:
    """Returns, per bundle, over the unseen arms it covers: <= PD fraction, median and worst
    worst-joint ratio to PD, median and largest RMS-tension and tension-rate ratios to PD, the
    arms where it keeps the smoothness limits (tendon2r_gym.evaluation.metrics: of a residual or of
    plain
    PPO) and those where it is also <= PD; over the sweep arms it covers: <= specialist
    fraction."""
    out = {}
    unseen = {k: a for k, a in arms.items() if k.startswith("unseen_")}
    for b in bundles:
        covered = [a for a in unseen.values() if "rms_deg" in a["rows"].get(b, {})]
        if not covered:
            continue
        ratios = [worst_ratio(a["rows"][b]["rms_deg"], a["rows"]["pd"]["rms_deg"]) for a in covered]
        tension, rate = zip(
            *(smoothness_x_pd(a["rows"][b], a["rows"]["pd"]) for a in covered), strict=True
        )
        residual = is_residual(b)
        wins = [beats(a["rows"][b]["rms_deg"], a["rows"]["pd"]["rms_deg"]) for a in covered]
        smooth = [smooth_enough(a["rows"][b], a["rows"]["pd"], residual) for a in covered]
        mode = action_mode_of(b)
        vs_spec = [
            beats(a["rows"][b]["rms_deg"], specialist_rms(a, mode))
            for a in arms.values()
            if specialist_rms(a, mode) and "rms_deg" in a["rows"].get(b, {})
        ]
        out[b] = {
            "arms": len(covered),
            "beats_pd": sum(wins),
            "median_worst_ratio_to_pd": float(np.median(ratios)),
            "max_worst_ratio_to_pd": float(np.max(ratios)),
            "median_tension_rate_x_pd": float(np.median(rate)),
            "median_tension_x_pd": float(np.median(tension)),
            "max_tension_rate_x_pd": float(np.max(rate)),
            "max_tension_x_pd": float(np.max(tension)),
            "residual": residual,
            "smooth": sum(smooth),
            "beats_pd_smooth": sum(w and s for w, s in zip(wins, smooth, strict=True)),
            "specialist_arms": len(vs_spec),
            "beats_specialist": int(sum(vs_spec)),
        }
    return out


def ablation(bundles: list[str]) -> dict[str, Any]:
    """Returns each bundle's training evaluation (primary seed: its best model's RMS on the
    entry's evaluation seeds, random arms and references, and PD's on the same episodes): the
    models compared on the random-arm env they all trained on."""
    out = {}
    for b in bundles:
        model = bundled_model(b)
        summary = training_summary(model)
        out[b] = {k: summary[k] for k in ("best_rms_deg", "pd_eval_rms_deg", "timesteps",
                                          "wall_time_s", "best_tension_rate_N_per_s")}  # fmt: skip
        out[b]["reward"] = reward_of(model)
        out[b]["arm_seen_by"] = arm_seen_by(model)
        out[b]["observes"] = optional_entries(model)
        out[b]["action_mode"] = action_mode_of(b)
        out[b]["residual_filter_tau"] = Residual.from_record(training_record(model)).filter_tau
        config = RunFolder(stem_of(model).parent).read_config()
        net = config["policy_kwargs"].get("net_arch")
        out[b]["network"] = " x ".join(map(str, net)) if net else "SB3 default"
        out[b]["eval_episodes"] = len(config["eval_seeds"])
        out[b]["learning_rate"] = config["ppo"]["learning_rate"]
        out[b]["residual"] = _residual(config)
    return out


def arm_seen_by(model_path: Path) -> str:
    """Returns which networks of a bundled model saw the drawn arm's features, as its run
    recorded them: its observation layout (observe arm) and the mask its hide_from_actor list
    gives the actor over the ``arm`` slice (observation.layout_mask, as training applies it:
    an actor that sees any of the arm's fields saw the arm); the critic sees them all."""
    recorded = training_record(model_path)["env_config"]
    if not observes_arm(recorded):
        return "nobody (blind)"
    layout = recorded["observation"]
    fields = feature_ranges(recorded).names
    hp = RunFolder(stem_of(model_path).parent).read_config()
    n_arm = layout[-1][1]  # the arm slice closes the layout
    actor = bool(layout_mask(layout, hp.get("hide_from_actor") or [], fields)[-n_arm:].any())
    return "actor and critic" if actor else "critic only"


def optional_entries(model_path: Path) -> str:
    """Returns the optional observation entries (tendon2r_gym.task.observation.OPTIONAL) a bundled
    model observed, as its run recorded its layout ("none" without any), then "errors in
    action units" where its errors were (error_units)."""
    recorded = training_record(model_path)["env_config"]
    names = {name for name, _ in recorded["observation"]}
    shown = [n for n, *_ in OPTIONAL if n in names]
    if recorded.get("error_units", EnvConfig.error_units) == "action":
        shown.append("errors in action units")
    return ", ".join(shown) or "none"


def reward_of(model_path: Path) -> str:
    """Returns the reward a bundled model trained on, as its env config records it: the
    tracking form, its sigma where it differs from the registered env's, and any weight that
    differs from the registered env's."""
    recorded = training_record(model_path)["env_config"]
    sigma = recorded.get("tracking_sigma_deg", EnvConfig.tracking_sigma_deg)
    form = [recorded["tracking_form"]]
    if sigma != EnvConfig.tracking_sigma_deg:
        form.append(f"sigma {sigma:g} deg")
    changed = [f"{k} {w:g}" for k, w in recorded["reward_scales"].items() if w != REWARD_SCALES[k]]
    return ", ".join([*form, *changed])


#: The fine-tuning curve's configs/ppo.yaml entry: the generalist residual's hyperparameters,
#: ``init_from: generalist``; "scratch" is the same entry started from fresh weights.
FINETUNE_ENTRY = "generalist_finetune"


def hardest_arms(arms: dict[str, Any], n: int, bundle: str = "generalist") -> list[str]:
    """Returns the ``n`` arms a user would fine-tune ``bundle`` on: the arms with a specialist
    in its action mode where its zero-shot worst-joint ratio to that specialist is highest;
    without any, the unseen arms where its ratio to PD is."""
    covered = {k: a for k, a in arms.items() if "rms_deg" in a["rows"].get(bundle, {})}
    mode = action_mode_of(bundle)
    ratio = {
        k: worst_ratio(a["rows"][bundle]["rms_deg"], specialist_rms(a, mode))
        for k, a in covered.items()
        if specialist_rms(a, mode)
    } or {
        k: worst_ratio(a["rows"][bundle]["rms_deg"], a["rows"]["pd"]["rms_deg"])
        for k, a in covered.items()
        if k.startswith("unseen_")
    }
    return sorted(ratio, key=ratio.get, reverse=True)[:n]


def finetune_curves(
    arms: dict[str, Any],
    names: list[str],
    run_root: Path,
    command: str,
    steps: int | None = None,
    seeds: tuple[int, ...] = (0, 1, 2),
) -> dict[str, Any]:
    """Trains FINETUNE_ENTRY on each named arm twice, one seed each: from the generalist's
    weights and normalization statistics (fine-tuned) and from fresh ones (scratch), with the
    same hyperparameters and budget (``steps``; default: a quarter of the specialist's
    training steps on an arm with a specialist, else the entry's; finished runs in
    ``run_root`` are reused).  Returns each run's curve: its training evaluations (steps, RMS
    on the entry's evaluation seeds), with the generalist zero-shot and PD on the same
    episodes at step 0; and its best model's RMS on the study's ``seeds`` (the episodes the
    specialist was scored on), beside the specialist's."""
    from tendon2r_gym.artifacts.runs import EVALUATIONS, SUMMARY
    from tendon2r_gym.presets import PPO_CONFIG
    from tendon2r_gym.training import Experiment, Hyperparams, fine_tune

    out: dict[str, Any] = {}
    specialist_steps = Hyperparams.from_entry(SPECIALIST_ENTRY).total_timesteps
    for name in names:
        folder = run_root / name
        folder.mkdir(parents=True, exist_ok=True)
        arm_file = folder / "arm.yaml"
        arm_file.write_text(yaml.safe_dump(arms[name]["env_kwargs"], sort_keys=False))
        hp = Hyperparams.from_entry(FINETUNE_ENTRY, PPO_CONFIG, str(arm_file))
        specialist = specialist_rms(arms[name], action_mode_of(hp.init_from))
        budget = steps or (specialist_steps // 4 if specialist else None)
        if budget is not None:
            hp = hp.replace(total_timesteps=budget)
        source, kwargs = bundled_model(hp.init_from), arms[name]["env_kwargs"]
        kwargs = in_model_settings(source, kwargs)  # as the benchmark runs it
        zero, _ = evaluate("ppo", kwargs, hp.eval_seeds, source)
        row: dict[str, Any] = {"zero_shot_rms_deg": zero["rms_deg"], "steps": hp.total_timesteps}
        if specialist:
            row["specialist"] = {"rms_deg": specialist, "steps": specialist_steps}
        tuned = fine_tune(hp)  # scratch: on the same env (action mode, arm slice)
        scratch = tuned.replace(init_from=None, init_log_std=None)
        for label, run_hp in (("fine-tuned", tuned), ("scratch", scratch)):
            exp = Experiment.start_or_continue(run_hp, folder / label, [0], command)
            exp.train(resume=True)
            run = exp.run_folder(0)
            summary = run.read_json(SUMMARY)
            row["pd_rms_deg"] = summary["pd_eval_rms_deg"]
            final, _ = evaluate("ppo", kwargs, list(seeds), run.best.with_suffix(".zip"))
            row[label] = {
                "curve": [[e["timesteps"], e["rms_deg"]] for e in run.read_json(EVALUATIONS)],
                "wall_time_s": summary["wall_time_s"],
                "final_rms_deg": final["rms_deg"],
            }
            if specialist:
                row[label]["reaches_specialist"] = beats(final["rms_deg"], specialist)
        out[name] = row
        print("fine-tuning", name, {k: v for k, v in row.items() if "rms" in k}, flush=True)
    return out


@dataclass
class Args:
    """The generalist study's flags."""

    n_arms: Annotated[int, arg("unseen random course arms")] = 32
    arm_seed: Annotated[int, arg("seed of the unseen arms")] = 9001
    episodes: Annotated[int, arg("evaluation seeds 0..N-1 per arm")] = 3
    bundles: Annotated[
        list[str] | None,
        arg("bundle names, or NAME@SEED for another bundled seed (default: the shipped "
            "generalists, their other seeds, then the ablations)"),
    ] = None  # fmt: skip
    sweep: Annotated[str, arg("the arm sweep's results")] = "research/results/arm_sweep.json"
    finetune_arms: Annotated[int, arg("fine-tuning curve on N arms")] = 3
    finetune_runs: Annotated[str, arg("its training run folders")] = "runs/finetune"
    finetune_steps: Annotated[
        int | None, arg("default: a quarter of the specialist's steps (else the entry's)")
    ] = None
    out: Annotated[str, arg("folder for generalist.md and .json")] = "research/results"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse(Args, argv, __doc__)
    command = command_line(argv, "python -m research.studies.generalist")
    shipped = [b for b in BUNDLES if b in bundle_names()]
    ablations = [b for b in ABLATIONS if b in bundle_names()]
    default = [*shipped, *other_seeds(shipped), *ablations]
    bundles = default if args.bundles is None else args.bundles
    seeds = list(range(args.episodes))
    arms: dict[str, dict[str, Any]] = {}
    drawn = draw_arms(args.arm_seed, args.n_arms)
    for i, content in enumerate(drawn):
        arms[f"unseen_{i}"] = {"env_kwargs": content}
    if PULL_ONLY_PRESET in bundles:
        for i, content in enumerate(drawn):
            arms[f"unseen_{i}_pull_only"] = {"env_kwargs": with_pull_only_cables(content)}
    arms.update(sweep_arms(Path(args.sweep)))
    result: dict[str, Any] = {"command": command, "bundles": bundles, "seeds": seeds, "arms": {}}
    compared = ("generalist", PULL_ONLY_PRESET, "generalist_scratch", *ABLATIONS)
    result["ablation"] = ablation([b for b in compared if b in bundle_names()])
    for name, arm in arms.items():
        arm["control_authority"] = list(EnvConfig.make(**arm["env_kwargs"]).needs.control_authority)
        arm["rows"] = evaluate_arm(arm["env_kwargs"], bundles, seeds)
        result["arms"][name] = arm
        result["summary"] = summarize(result["arms"], bundles)
        write(result, Path(args.out))
    if args.finetune_arms and "generalist" in bundles:
        names = hardest_arms(result["arms"], args.finetune_arms)
        result["finetune"] = finetune_curves(
            result["arms"], names, Path(args.finetune_runs), command, args.finetune_steps,
            tuple(seeds),
        )  # fmt: skip
        write(result, Path(args.out))
    return result


def write(result: dict[str, Any], out: Path) -> None:
    """Writes generalist.json and generalist.md."""
    save_json(out, "generalist", result)
    fmt = joints
    bundles = result["bundles"]

    def cell(row: dict[str, Any], pd: list[float]) -> str:
        if "error" in row:
            return "outside its ranges"
        mark = "<= PD" if beats(row["rms_deg"], pd) else "**WORSE**"
        return f"{fmt(row['rms_deg'])} ({mark}, {worst_ratio(row['rms_deg'], pd):.2f}x)"

    lines = [
        "# One policy for every arm: the generalists zero-shot",
        "",
        f"Produced by `{result['command']}`. RMS tracking error (deg, joint A / B) over "
        f"evaluation seeds {result['seeds']}; for a generalist, (its worst joint's RMS as a "
        "multiple of PD's). Unseen arms: drawn by tendon2r_gym.task.arms.draw_arms with a "
        "seed that "
        "training never uses; sweep arms: research/results/arm_sweep.md, with their own "
        "specialist. "
        "generalist: residual on PD in joint-torque mode, its residual through a first-order "
        "low-pass (PD's command unfiltered; the ablation table gives the time constant), "
        "seeing the arm's features, the tracking error and its rate in action units (the "
        "normalized joint torques that close the error and cancel its rate in one control "
        "step on the arm; error_units action), the reference's acceleration as the normalized "
        "joint torques that give it on the arm (observe feedforward) and its force limit, "
        "trained "
        "on the multiscale reward at sigma 0.1 deg with action-rate weight 3; "
        "generalist_scratch: plain PPO (normalized joint torques through a 2 ms action "
        "filter), seeing the arm's features, the tracking error and its rate in action "
        "units, the reference's feed-forward and its force limit; "
        "generalist_pull_only: the generalist's entry with action-rate weight 10 and the "
        "action_rate_need term on arms with "
        "three pull-only cables (its preset's), run on the unseen "
        "geometries with those cables (unseen_<i>_pull_only); each bundle runs in the action "
        "mode it trained in, and one that saw the arm's features sees each arm's. A column "
        "NAME@SEED is another training seed of that bundle (same entry; the unmarked column "
        "is its primary seed, fixed before training). The other columns are ablations (one "
        "seed each; configs/ppo.yaml's comment on each entry says "
        "what it changes, and the ablation table below gives each one's action mode, network, "
        "learning rate, reward, arm features, evaluation episodes and "
        "training steps): "
        "generalist_action_units, the generalist without the reference's feed-forward (the "
        "generalist before it observed feedforward); "
        "generalist_rad, that observing its error and error rate in radians (the "
        "generalist before error_units action); "
        "generalist_lin_lr, generalist_rad with its learning rate decaying linearly to 0; "
        "generalist_rate_need, generalist_rad with its action rate also charged in multiples "
        "of the rate its arm's reference needs (action_rate_need); "
        "generalist_rate1, generalist_rad with action-rate weight 1; generalist_coarse, that "
        "on the registered sigma (1 deg), and generalist_unscaled, that without the error's "
        "rate and the force limit (the generalist before them); generalist_unfiltered, "
        "generalist_unscaled without its residual filter; "
        "generalist_scratch_rad, the plain generalist observing its error and error rate "
        "in radians, without the feed-forward (the plain generalist before them); "
        "generalist_scratch_blind, generalist_scratch_rad without the arm's features, and "
        "generalist_scratch_unscaled, it without its force limit; "
        "generalist_blind, generalist_unfiltered without them; generalist_tension, an "
        "earlier generalist (tension mode, blind, 64 x 64), and generalist_observe_arm, it "
        "with the arm's features; generalist_log and "
        "on its reward and budget generalist_arm and "
        "generalist_privileged; generalist_multiscale and generalist_multiscale_smooth; "
        "generalist_pull_only_rate10, generalist_pull_only without the action_rate_need "
        "term (on 10M steps); generalist_pull_only_full, that at the generalist's action-rate "
        "weight (3); generalist_pull_only_blind, the earlier pull-only generalist "
        "(generalist_tension's entry in joint-torque mode, action-rate weight 3, 2 ms residual "
        "filter), and generalist_pull_only_smooth, that entry in tension mode without the "
        "filter.",
        "",
        "## Summary",
        "",
        "RMS tension and tension rate as multiples of PD's on the same episodes: the median "
        "and the largest over the arms. Smoothness limits (per arm): RMS tension at most "
        f"{TENSION_LIMIT_X_PD:g}x PD's, tension rate at most {RATE_LIMIT_X_PD['residual']:g}x "
        f"PD's for a residual on PD, {RATE_LIMIT_X_PD['plain']:g}x for plain PPO.",
        "",
        "| policy | unseen arms | <= PD on both joints | median worst-joint ratio to PD | worst | "
        "RMS tension (x PD): median / largest | tension rate (x PD): median / largest | "
        "within the smoothness limits | <= PD and within them | <= specialist of its action "
        "mode (sweep arms) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for b, s in result.get("summary", {}).items():
        kind = "residual" if s["residual"] else "plain"
        lines.append(
            f"| {b} | {s['arms']} | {s['beats_pd']} of {s['arms']} | "
            f"{s['median_worst_ratio_to_pd']:.3f} | {s['max_worst_ratio_to_pd']:.3f} | "
            f"{s['median_tension_x_pd']:.2f} / {s['max_tension_x_pd']:.2f} | "
            f"{s['median_tension_rate_x_pd']:.2f} / {s['max_tension_rate_x_pd']:.2f} | "
            f"{s['smooth']} of {s['arms']} ({kind}) | {s['beats_pd_smooth']} of {s['arms']} | "
            f"{s['beats_specialist']} of {s['specialist_arms']} |"
        )
    lines += transient_lines(result["arms"], bundles)
    if result.get("ablation"):
        lines += [
            "",
            "## Ablations: the arm's features and the reward",
            "",
            "Each generalist's training evaluation (primary seed, best model: RMS over the "
            "entry's evaluation episodes, one random course arm and reference each, the same "
            "first episodes for all, with pull-only cables for the generalist_pull_only rows; "
            "PD on them). The summary above gives each on the unseen arms, zero-shot.",
            "",
            "| generalist | arm features seen by | also observes | action mode | residual "
            "| residual filter | network | learning rate | reward (tracking form, changed "
            "weights) | evaluation episodes | RMS A / B (deg) | PD A / B (deg) | RMS tension rate "
            "(N/s) | steps | wall time (s) |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for b, a in result["ablation"].items():
            lines.append(
                f"| {b} | {a.get('arm_seen_by', '?')} | {a.get('observes', '?')} | "
                f"{a.get('action_mode', '?')} | {a.get('residual', '?')} | "
                f"{_filter(a.get('residual_filter_tau', 0.0))} | {a.get('network', '?')} | "
                f"{_rate(a.get('learning_rate', '?'))} | "
                f"{a.get('reward', '?')} | "
                f"{a.get('eval_episodes', '?')} | "
                f"{fmt(a['best_rms_deg'])} | {fmt(a['pd_eval_rms_deg'])} | "
                f"{fmt(a['best_tension_rate_N_per_s'])} | {a['timesteps']:,} | "
                f"{a['wall_time_s']:.0f} |"
            )
    lines += finetune_lines(result.get("finetune", {}))
    lines += [
        "",
        "## Per arm",
        "",
        "Control authority: each joint's EnvConfig.needs.control_authority, the most its speed "
        "changes in one control step per unit of normalized joint-torque action (rad/s).",
        "",
        "| arm | R1 / R2 / a / b / c (mm) | control authority A / B (rad/s) | PD | CT | "
        "specialist | " + " | ".join(bundles) + " |",
        "|---|---|---|---|---|---|" + "---|" * len(bundles),
    ]
    for name, arm in result["arms"].items():
        m = arm["env_kwargs"]["mechanism"]
        geo = pair([1000 * m[k] for k in ("R1", "R2", "a", "b", "c")], ".0f")
        rows = arm["rows"]
        pd = rows["pd"]["rms_deg"]
        spec = arm.get("specialist_rms_deg") or {}
        specs = "; ".join(f"{mode} {fmt(v)}" for mode, v in spec.items()) or "-"
        authority = arm.get("control_authority")
        authority = pair(authority, ".3g") if authority else "-"
        lines.append(
            f"| {name} | {geo} | {authority} | {fmt(pd)} | {fmt(rows['ct']['rms_deg'])} | "
            f"{specs} | " + " | ".join(cell(rows[b], pd) for b in bundles) + " |"
        )
    (out / "generalist.md").write_text("\n".join(lines) + "\n")


def transient_lines(arms: dict[str, Any], bundles: list[str]) -> list[str]:
    """Returns the section comparing, on the sweep arms, the generalist's (and its seeds')
    whole-episode RMS with its RMS after the reset's transient (``settled_rms_deg``), beside
    the specialist's whole-episode RMS (the sweep records no more)."""
    shown = [b for b in bundles if b.partition(SEED_MARK)[0] == "generalist"]
    if not shown:
        return []
    mode = action_mode_of(shown[0])
    rows = [
        (k, a)
        for k, a in arms.items()
        if specialist_rms(a, mode) and all("settled_rms_deg" in a["rows"].get(b, {}) for b in shown)
    ]
    if not rows:
        return []
    lines = [
        "",
        "## Sweep arms: the reset's transient",
        "",
        f"RMS error (deg, A / B) over whole episodes, and after each episode's first "
        f"{1000 * SETTLE_S:g} ms (settled: the transient that closes the reset's noise left "
        f"out; settled_rms_deg of tendon2r_gym.evaluation.metrics.tracking_metrics), for the "
        f"generalist's seeds; the specialist ({mode} mode) over whole episodes, all the sweep "
        "records.",
        "",
        "| arm | specialist | " + " | ".join(f"{b}: whole (settled)" for b in shown) + " |",
        "|---|---|" + "---|" * len(shown),
    ]
    for k, a in rows:
        cells = [
            f"{joints(a['rows'][b]['rms_deg'], 4)} ({joints(a['rows'][b]['settled_rms_deg'], 4)})"
            for b in shown
        ]
        spec = joints(specialist_rms(a, mode), 4)
        lines.append(f"| {k} | {spec} | " + " | ".join(cells) + " |")
    return lines


def _residual(config: dict[str, Any]) -> str:
    """Returns a run's residual (its recorded hyperparameters) as the ablation table shows it:
    its scale, a fraction of each command's range (tendon2r_gym.policies.residual: a tendon's in
    tension mode, a joint's in joint-torque mode), or none (plain PPO)."""
    residual = Residual.from_record(config)
    if not residual.active:
        return "none (plain PPO)"
    return f"{residual.scale:g} x the command range"


def _filter(tau: float) -> str:
    """Returns a residual filter's time constant as the ablation table shows it."""
    return f"{1000 * tau:g} ms" if tau else "none"


def _rate(learning_rate: float | str) -> str:
    """Returns a learning rate as the ablation table shows it: a number, or ``lin_<v>``
    (rl_zoo3's notation) as a linear decay from v to 0."""
    if isinstance(learning_rate, str) and learning_rate.startswith(LINEAR):
        return f"{linear_schedule(learning_rate):g}, linear to 0"
    return f"{learning_rate:g}" if isinstance(learning_rate, float | int) else learning_rate


def finetune_lines(curves: dict[str, Any]) -> list[str]:
    """Returns the fine-tuning section of generalist.md: per arm, the RMS of each joint against
    training steps, fine-tuned from the generalist and from scratch, then each best model on
    the study's episodes beside the arm's specialist."""
    if not curves:
        return []
    lines = [
        "",
        "## Fine-tuning against training from scratch",
        "",
        f"configs/ppo.yaml `{FINETUNE_ENTRY}` on the arms where the generalist zero-shot is "
        "furthest from the arm's specialist (or, without one, from PD), one seed each, for a "
        "quarter of the specialist's training steps where it has one: from the generalist's "
        "weights and normalization statistics (fine-tuned), and the same entry from fresh "
        "weights on the same env (scratch: residual on PD, so it starts at PD). RMS A / B "
        "(deg) of the training evaluations (the entry's evaluation seeds); step 0: the "
        "generalist zero-shot and PD on the same episodes. Then each run's best model on the "
        "study's episodes, those the specialist was scored on.",
        "",
        "| arm | steps | fine-tuned | scratch |",
        "|---|---|---|---|",
    ]
    for name, row in curves.items():
        lines.append(
            f"| {name} | 0 | {joints(row['zero_shot_rms_deg'])} | {joints(row['pd_rms_deg'])} |"
        )
        tuned, scratch = row["fine-tuned"]["curve"], row["scratch"]["curve"]
        for (steps, a), (_, b) in zip(tuned, scratch, strict=False):
            lines.append(f"| {name} | {steps:,} | {joints(a)} | {joints(b)} |")
        lines.append(
            f"| {name} | wall time (s) | {row['fine-tuned']['wall_time_s']:.0f} | "
            f"{row['scratch']['wall_time_s']:.0f} |"
        )
        if "final_rms_deg" in row["fine-tuned"]:
            lines.append(
                f"| {name} | best model, study's episodes | "
                f"{joints(row['fine-tuned']['final_rms_deg'])} | "
                f"{joints(row['scratch']['final_rms_deg'])} |"
            )
        if spec := row.get("specialist"):
            verdict = lambda r: "<= specialist" if r["reaches_specialist"] else "**WORSE**"  # noqa: E731
            lines.append(
                f"| {name} | specialist {joints(spec['rms_deg'])} after {spec['steps']:,} "
                f"steps; these runs: {row['steps']:,} | {verdict(row['fine-tuned'])} | "
                f"{verdict(row['scratch'])} |"
            )
    return lines


if __name__ == "__main__":
    main()

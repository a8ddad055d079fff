"""The benchmark: PD, computed torque and PPO (from scratch and residual on PD), same seeds.

- `benchmark_bundled` (``tendon2r-benchmark``, ``make benchmark``): the bundled presets
  with their bundled models, plus held-out references for the random-reference model.  (The
  shipped models on real cables, motors and sensors: ``python -m research.studies.realism``.)
- `benchmark_own_arm` (``tendon2r-benchmark --env-config my_arm.yaml``): trains both PPO
  variants on the user's experiment file, then compares all four on it.

Every learned row is evaluated on the benchmark seeds (0, 1, ...), never on the seeds that
chose its checkpoint (configs/ppo.yaml eval_seeds), and evaluated again with its commands
perturbed in their last float32 bits (its ``reproducible_to``).  The Markdown is
tendon2r_gym.app.report's, from the JSON record alone.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tendon2r_gym.app import report
from tendon2r_gym.app.plots import plot_trace
from tendon2r_gym.app.report import fmt, tol
from tendon2r_gym.artifacts import registry
from tendon2r_gym.artifacts.bundle import bundle_meta, bundle_names, bundled_model
from tendon2r_gym.artifacts.model_env import in_model_settings, settings_on
from tendon2r_gym.artifacts.runs import model_files, training_record, training_summary
from tendon2r_gym.envs.env_config import EnvConfig, resolve
from tendon2r_gym.envs.registration import make as make_env
from tendon2r_gym.evaluation.evaluator import (
    BASELINE,
    evaluate,
    jittered_rms,
    names,
    reproducible_to,
)
from tendon2r_gym.policies.residual import Residual
from tendon2r_gym.presets import DATA_DIR
from tendon2r_gym.validation import invalid

#: The learned rows: label -> the hyperparameter entry trained on your arm.  On the bundled
#: presets, each shipped model of registry group ``preset`` (tendon2r_gym/data/shipped.yaml)
#: runs under the label of its kind (`preset_models`).
LEARNED = {"ppo scratch": "default_scratch", "ppo residual": "default"}
#: The bootstrap's seed for every interval of benchmark.json (the same figures on every run).
BOOTSTRAP_SEED = 0
#: Held-out references for the generalization check (inside the training ranges of
#: configs/ppo.yaml random_reference, never drawn exactly).
HELD_OUT = [
    {"amp_deg": [12.0, 18.0], "freq_hz": [1.3, 2.2], "bias_deg": [5.0, -8.0],
     "phase_deg": [30.0, 200.0]},
    {"amp_deg": [22.0, 7.0], "freq_hz": [2.8, 0.9], "bias_deg": [-6.0, 2.0],
     "phase_deg": [90.0, 0.0]},
    {"amp_deg": [8.0, 14.0], "freq_hz": [0.7, 2.6], "bias_deg": [0.0, -12.0],
     "phase_deg": [270.0, 45.0]},
]  # fmt: skip


def compare(
    name: str,
    env_kwargs: dict[str, Any],
    learned: dict[str, list[Path]],
    seeds: list[int],
    plots: Path | None,
    progress: Any = None,
) -> list[dict[str, Any]]:
    """Returns the rows of one env: PD, CT, and per learned label its primary model and the
    mean +- std (ddof 0) over all its training seeds, with its uncertainty (`_spread`)."""
    rows = []
    config = resolve(env_kwargs)  # once for the baselines and the models' settings
    for policy in names(BASELINE):
        rows.append(policy_row(name, policy, policy, config, seeds, None, plots))
        _tick(progress)
    for label, models in learned.items():
        if not models:
            rows.append({"env": name, "policy": label, "missing": "no trained model"})
            continue
        # A model runs in the settings it was trained in (its action mode, timing...: the
        # same arm, reference and episodes as PD's), and its rows name those that differ.
        tag = settings_on(models[0], config)
        kwargs = {**env_kwargs, **tag}  # an experiment of its own: resolved once by policy_row
        per_seed = []
        for i, model in enumerate(models):
            row = policy_row(name, label, "ppo", kwargs, seeds, model, plots if i == 0 else None)
            per_seed.append({**row, **tag})
            _tick(progress)
        rows.append(per_seed[0])
        if len(per_seed) > 1:
            pd = next((r["rms_deg"] for r in rows if r["policy"] == "pd"), None)
            rows.append({**_spread(name, label, per_seed, pd), **tag})
    for row in rows:
        _print(row)
    return rows


#: The generalists (registry group ``generalist``): trained across random arms.
GENERALISTS = tuple(registry.names("generalist"))
#: The models run zero-shot on a user's arm when it lies inside their training ranges: the
#: generalists, and the residuals trained across real cables, motors and sensors (group
#: ``realism``).
ZERO_SHOT = GENERALISTS + tuple(registry.names("realism"))
#: Held-out episodes tendon2r-tune-pd tunes PD on, for the own-arm benchmark's tuned PD row.
TUNE_EPISODES = 2


#: Fine-tuning a generalist on a user's arm: row label -> configs/ppo.yaml entry (its
#: ``init_from`` names the bundle it starts from).
FINETUNED = {"generalist fine-tuned": "generalist_finetune"}


def not_covered(bundle: str, env_kwargs: dict[str, Any]) -> str | None:
    """Returns why the bundle's primary model cannot run on this arm (outside its training
    ranges, another observation...), or None if it can."""
    from tendon2r_gym.policies.learned import trained_model

    model = bundled_model(bundle)
    kwargs = in_model_settings(model, env_kwargs)
    try:
        trained_model(model, make_env(**kwargs), bundle)
    except ValueError as e:  # the model as benchmark.json records it, not this machine's path
        return str(e).replace(str(Path(model).resolve()), shown_path(model))
    return None


def generalist_rows(
    name: str, env_kwargs: dict[str, Any], seeds: list[int], tuned: dict[str, Any] | None = None
) -> list[dict]:
    """Returns a row per shipped zero-shot bundle (ZERO_SHOT) on this arm: zero-shot (no
    training on it), or ``missing`` with the reason when the arm is outside its training
    ranges.  A residual trained on drawn PD gains runs with ``tuned`` (the arm's tuned
    pd_gains), as tendon2r-tune-pd would give them to it."""
    from tendon2r_gym.artifacts.model_env import trained_on_drawn_gains

    rows = []
    for bundle in (b for b in ZERO_SHOT if b in bundle_names()):
        label, model = f"{bundle} zero-shot", bundled_model(bundle)
        on = env_kwargs
        if tuned is not None and trained_on_drawn_gains(model):
            on = {**env_kwargs, "pd_gains": tuned}
        reason = not_covered(bundle, on)
        if reason is not None:
            rows.append({"env": name, "policy": label, "missing": reason})
            continue
        tag = settings_on(model, on)  # as compare: the settings it trained in
        row = policy_row(name, label, "ppo", {**on, **tag}, seeds, model, None)
        rows.append({**row, **tag})
        _print(rows[-1])
    return rows


def policy_row(
    name: str,
    label: str,
    policy: str,
    env_kwargs: EnvConfig | dict[str, Any],
    seeds: list[int],
    model: Path | None,
    plots: Path | None,
) -> dict[str, Any]:
    """Returns one row of the benchmark: ``policy`` ("pd", "ct", or "ppo" with ``model``)
    evaluated on the env ``env_kwargs`` over ``seeds``, labelled ``name`` (the env) and
    ``label`` (the policy), with its figures' reproducibility (``rms_deg_jittered``,
    ``reproducible_to``) and a model's training summary; with ``plots``, the first episode's
    plot.  `compare` builds its rows with it; tests run a single row."""
    start = time.perf_counter()
    config = resolve(env_kwargs)  # once for the row's evaluations
    metrics, traces = evaluate(policy, config, seeds, model)
    jittered = jittered_rms(policy, config, seeds, model)
    row = {
        **metrics,
        "reproducible_to": reproducible_to(metrics["rms_deg"], jittered),
        "rms_deg_jittered": jittered,
        "env": name,
        "policy": label,
        "eval_s": round(time.perf_counter() - start, 1),
    }
    if model is not None:
        s = training_summary(model)
        row.update(
            model=shown_path(model),
            train_seed=s["seed"],
            train_steps=s["timesteps"],
            train_wall_s=s["wall_time_s"],
            first_beat_pd=s.get("first_beat_pd"),
        )
    if plots is not None:
        plot_trace(traces[0], plots / name / label.replace(" ", "_"), f"{label} on {name}")
    return row


def shown_path(path: Path) -> str:
    """Returns a model path as recorded in benchmark.json: relative to the package for a
    bundled model (``tendon2r_gym/data/models/...``), else relative to the working folder when
    it is inside it, else absolute; never the machine's absolute path of the package."""
    path = Path(path).resolve()
    for root, prefix in ((DATA_DIR.parent, "tendon2r_gym"), (Path.cwd(), ".")):
        if path.is_relative_to(root):
            return str(Path(prefix) / path.relative_to(root))
    return str(path)


def _spread(
    name: str, label: str, per_seed: list[dict[str, Any]], pd: list[float] | None = None
) -> dict[str, Any]:
    """Returns the row of a learned label over its training seeds: the mean +- std (ddof 0)
    per joint, and ``statistics`` (`uncertainty`)."""
    rms = [r["rms_deg"] for r in per_seed]
    beat = [r["first_beat_pd"] for r in per_seed]
    mean = np.mean(rms, axis=0).tolist()
    jittered = np.mean([r["rms_deg_jittered"] for r in per_seed], axis=0).tolist()
    return {
        "env": name,
        "policy": f"{label} ({len(per_seed)} seeds)",
        "training_seeds": [r["train_seed"] for r in per_seed],
        "rms_deg_per_seed": rms,
        "rms_deg": mean,
        "reproducible_to": reproducible_to(mean, jittered),
        "rms_deg_std": np.std(rms, axis=0).tolist(),
        "max_deg": np.mean([r["max_deg"] for r in per_seed], axis=0).tolist(),
        "train_steps": int(np.mean([r["train_steps"] for r in per_seed])),
        "train_wall_s": round(float(np.mean([r["train_wall_s"] for r in per_seed])), 1),
        "train_wall_s_max": max(r["train_wall_s"] for r in per_seed),
        "first_beat_pd": beat,
        "statistics": uncertainty(rms, pd),
    }


def uncertainty(rms: list[list[float]], pd: list[float] | None) -> dict[str, Any]:
    """Returns the uncertainty of a learned row over its seeds' per-joint RMS (deg), by
    tendon2r_gym.evaluation.statistics (seed BOOTSTRAP_SEED, so that benchmark.json is the
    same on every run)::

        {"runs", "confidence", "rms_deg_iqm", "rms_deg_iqm_ci" ([low, high] per joint),
         "rms_deg_mean", "rms_deg_std", "beats_pd": {"share", "low", "high", "wins", "pairs",
         "interval": "wilson"}, "worst_ratio_to_pd" (per seed), "bootstrap", "note"}

    ``note``: a sentence where it rests on fewer than statistics.MIN_RUNS runs, else None.
    Without PD's row (``pd`` None), no beats_pd and no ratios."""
    from tendon2r_gym.evaluation.statistics import summary

    s = summary(rms, pd, seed=BOOTSTRAP_SEED)
    return {key: s[of] for key, of in UNCERTAINTY_KEYS.items() if of in s}


#: The keys of a learned row's ``statistics`` -> those of statistics.summary.
UNCERTAINTY_KEYS = {
    "runs": "runs",
    "confidence": "confidence",
    "rms_deg_iqm": "iqm",
    "rms_deg_iqm_ci": "iqm_ci",
    "rms_deg_mean": "mean",
    "rms_deg_std": "std",
    "beats_pd": "beats_baseline",
    "worst_ratio_to_pd": "worst_ratio",
    "bootstrap": "bootstrap",
    "note": "note",
}


def _print(row: dict[str, Any]) -> None:
    if "missing" in row:
        print(f"{row['env']:11s} {row['policy']:24s} {row['missing']}", flush=True)
        return
    std = f" +- {fmt(row['rms_deg_std'])}" if "rms_deg_std" in row else ""
    print(
        f"{row['env']:11s} {row['policy']:24s} RMS {fmt(row['rms_deg'])}{std} deg  "
        f"max {fmt(row['max_deg'], 3)} deg  reproducible to {tol(row.get('reproducible_to'))}",
        flush=True,
    )


def _tick(progress: Any) -> None:
    if progress is not None:
        progress.update(1)


def _bundle_models(name: str) -> list[Path]:
    meta = bundle_meta(name)
    return [] if meta is None else [bundled_model(name, s) for s in meta["seeds"]]


def preset_models() -> dict[str, dict[str, list[Path]]]:
    """Returns, per preset, its shipped models of registry group ``preset`` (label -> the
    model of every seed): labelled "ppo residual" or "ppo scratch" by the model's residual, in
    LEARNED's order, or by the model's name where two of a kind share a preset.  A registered
    bundle that is not installed gets no model (its row says so)."""
    out: dict[str, dict[str, list[Path]]] = {}
    for name in registry.names("preset"):
        models, rows = _bundle_models(name), out.setdefault(registry.shipped()[name].env, {})
        if not models:
            rows[name] = []
            continue
        residual = Residual.from_record(training_record(models[0])).active
        label = "ppo residual" if residual else "ppo scratch"
        rows[name if label in rows else label] = models
    order = lambda label: (list(LEARNED).index(label) if label in LEARNED else len(LEARNED), label)  # noqa: E731
    return {
        env: dict(sorted(rows.items(), key=lambda kv: order(kv[0]))) for env, rows in out.items()
    }


def benchmark_bundled(episodes: int, out: Path, command: str) -> dict[str, Any]:
    """The bundled presets with their shipped models -> out/benchmark.md, .json, plots/."""
    out.mkdir(parents=True, exist_ok=True)
    seeds = list(range(episodes))
    rows = []
    for preset, learned in preset_models().items():
        rows += compare(preset, {"preset": preset}, learned, seeds, out / "plots")
    result = {"command": command, "rows": rows, "held_out": held_out()}
    return _write(out, result, report.bundled_page(result))


def _write(out: Path, result: dict[str, Any], lines: list[str]) -> dict[str, Any]:
    """Writes out/benchmark.json and out/benchmark.md; returns the result."""
    (out / "benchmark.json").write_text(json.dumps(result, indent=1))
    (out / "benchmark.md").write_text("\n".join(lines) + "\n")
    print("wrote", out / "benchmark.md")
    return result


def held_out() -> list[dict[str, Any]]:
    """PD and each model trained on random references (registry group ``references``:
    "ppo", or its name beside another) on HELD_OUT, with the env the first one trained on."""
    shipped = [n for n in registry.names("references") if bundle_meta(n) is not None]
    if not shipped:
        return [{"policy": "ppo", "missing": "no shipped model of random references installed"}]
    models = [bundled_model(n) for n in shipped]
    config = resolve(training_record(models[0])["env_kwargs"])
    rows = []
    # PD is the baseline that needs no knowledge of the reference.
    for label, policy, learned in [
        ("pd", "pd", None),
        *(
            ("ppo" if len(models) == 1 else n, "ppo", m)
            for n, m in zip(shipped, models, strict=True)
        ),
    ]:
        errs, jittered = [], []
        for i, ref in enumerate(HELD_OUT):
            options = {"reference": ref}
            errs.append(evaluate(policy, config, [i], learned, options)[0]["rms_deg"])
            jittered.append(jittered_rms(policy, config, [i], learned, options))
        mean = np.mean(errs, axis=0).tolist()
        rows.append(
            {"policy": label, "rms_deg_per_reference": errs, "rms_deg_mean": mean,
             "reproducible_to": reproducible_to(mean, np.mean(jittered, axis=0).tolist())}
        )  # fmt: skip
        print(f"held-out {label:4s} mean RMS {fmt(rows[-1]['rms_deg_mean'])} deg", flush=True)
    return rows


def benchmark_own_arm(
    env_config: str,
    train_steps: int | None,
    seeds: list[int],
    episodes: int,
    out: Path,
    run_dir: Path,
    command: str,
    labels: Sequence[str] | None = None,
    workers: int = 1,
    cluster: str | None = None,
) -> dict[str, Any]:
    """Trains both PPO variants on ``env_config`` (one run per seed), then compares PD, CT, PD
    tuned on the arm (tendon2r-tune-pd's gains over TUNE_EPISODES held-out episodes), them
    and the zero-shot bundles (ZERO_SHOT) on the same evaluation seeds -> out/benchmark.md,
    .json, plots/.  ``labels``: train only these learned rows (of LEARNED and FINETUNED; None:
    every one; empty: none, as ``--no-train``).

    Each (row, seed) training is one job of the executor of ``workers`` and ``cluster``
    (tendon2r_gym.training.executors.make_executor: in this process, local workers, or a Ray
    cluster, which is joined before anything else runs); a seed trains to the same bits on
    each.  The rows are trained one after another, each row's seeds at once."""
    from tendon2r_gym.training import Hyperparams
    from tendon2r_gym.training.executors import InProcess, entered, make_executor

    config = resolve(env_config)  # every error before any training
    entries = dict(LEARNED) | FINETUNED
    if labels is not None:
        if unknown := set(labels) - set(entries):
            raise invalid("labels", sorted(unknown), f"some of {list(entries)}")
        entries = {k: v for k, v in entries.items() if k in labels}
    cfgs = {k: Hyperparams.from_entry(e, env_config=env_config) for k, e in entries.items()}
    threads = max((hp.torch_threads for hp in cfgs.values()), default=1)
    executor = make_executor(workers, cluster, threads)  # --workers and --cluster checked
    with entered(executor if cfgs else InProcess()) as ex:  # an unreachable cluster: refused
        rows = _own_arm_rows(env_config, cfgs, train_steps, seeds, episodes, out, run_dir,
                             command, ex)  # fmt: skip
    result = {
        "command": command,
        "env_config": config.to_dict(),
        "force_need_N": config.needs.force_need,
        "rows": rows,
    }
    return _write(out, result, report.own_arm_page(result, env_config))


def _own_arm_rows(
    env_config: str,
    cfgs: dict[str, Any],
    train_steps: int | None,
    seeds: list[int],
    episodes: int,
    out: Path,
    run_dir: Path,
    command: str,
    executor: Any,
) -> list[dict[str, Any]]:
    """Returns the rows of `benchmark_own_arm`: PD tuned, the trainings of ``cfgs``
    (label -> hyperparameters) on ``executor``, then the comparison."""
    from tqdm.auto import tqdm

    from tendon2r_gym.evaluation.tuning import tune_pd
    from tendon2r_gym.training import Experiment
    from tendon2r_gym.training.jobs import train_experiment

    env_kwargs = {"preset": env_config}
    # PD as tendon2r-tune-pd tunes it on this arm (a lagging arm needs lower gains): before
    # any training, as every error
    tuned = tune_pd(env_kwargs, TUNE_EPISODES).gains.to_dict()
    uncovered = {}
    for label in [k for k in FINETUNED if k in cfgs]:  # only where the generalist covers the arm
        source = cfgs[label].init_from
        if source not in bundle_names():
            uncovered[label] = f"bundle {source} is not installed"
        elif (reason := not_covered(source, env_kwargs)) is not None:
            uncovered[label] = reason
        if label in uncovered:
            del cfgs[label]
    if train_steps is not None:
        cfgs = {k: hp.replace(total_timesteps=train_steps) for k, hp in cfgs.items()}
    out.mkdir(parents=True, exist_ok=True)
    learned: dict[str, list[Path]] = {}
    with tqdm(total=len(cfgs) * len(seeds) * 2 + 2, desc="benchmark", unit="task") as bar:
        for label, hp in cfgs.items():
            folder = run_dir / label.replace(" ", "_")
            exp = Experiment.start_or_continue(hp, folder, seeds, command)
            bar.set_postfix_str(f"training {label}")
            train_experiment(exp, resume=True, executor=executor)
            learned[label] = [model_files(exp.run_folder(s).best)[0] for s in seeds]
            bar.update(len(seeds))
        bar.set_postfix_str("evaluating")
        name = Path(env_config).stem
        rows = compare(name, env_kwargs, learned, list(range(episodes)), out / "plots", bar)
        row = policy_row(name, "PD tuned", "pd", {**env_kwargs, "pd_gains": tuned},
                         list(range(episodes)), None, None)  # fmt: skip
        rows.append({**row, "pd_gains": tuned})
        _print(rows[-1])
        rows += generalist_rows(name, env_kwargs, list(range(episodes)), tuned)
        rows += [{"env": name, "policy": k, "missing": v} for k, v in uncovered.items()]
    return rows

"""The shipped models' pages, for scripts/gen_docs.py: docs/models.md (the overview, from the
registry tendon2r_gym.artifacts.registry) and docs/models/<name>.md (one card per model from
its bundle's files, with its learning curve from scripts/gen_figures.py).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import gen_figures
from docs_common import ROOT, benchmark_reports, figure, header, newest_id, shown

from tendon2r_gym.app import report
from tendon2r_gym.app.markdown import code, code_block, page, pair, table
from tendon2r_gym.artifacts import registry
from tendon2r_gym.artifacts.bundle import MODELS_DIR, bundle_meta, bundled_model
from tendon2r_gym.artifacts.runs import BEST_METRICS, SUMMARY, RunFolder
from tendon2r_gym.envs.env_config import EnvConfig


def primary_run(name: str, seed: int | None = None) -> RunFolder:
    """Returns the run folder of a bundle's seed (its primary seed by default)."""
    return RunFolder(bundled_model(name, seed).parent)


def benchmark_rows(model: str, reports: dict[str, dict[str, Any]]) -> list[list[str]]:
    """Returns, for each benchmark row that ran ``model`` (its path as benchmark.json records
    it), the report, env, RMS, worst joint against PD and tension rate against PD."""
    from tendon2r_gym.evaluation.metrics import smoothness_x_pd, worst_ratio

    out = []
    for path, record in reports.items():
        rows = record.get("rows", [])
        for r in (r for r in rows if r.get("model") == model and "rms_deg" in r):
            pd = next((p for p in rows if p["env"] == r["env"] and p["policy"] == "pd"), None)
            worst = rate = "-"
            if pd is not None:
                worst = f"{worst_ratio(r['rms_deg'], pd['rms_deg']):.2f}x"
                if "rms_tension_rate_N_per_s" in r and "rms_tension_rate_N_per_s" in pd:
                    rate = f"{smoothness_x_pd(r, pd)[1]:.2f}x"
            out.append([code(path), r["env"], r["policy"], pair(r["rms_deg"], ".3g"), worst, rate])
    return out


def non_default_settings(model: Path) -> dict[str, Any]:
    """Returns the model's settings (learned.model_settings) that differ from EnvConfig's
    defaults: what the env it runs in must set, whatever the arm."""
    from tendon2r_gym.artifacts.model_env import model_settings

    defaults = {f.name: f.default for f in dataclasses.fields(EnvConfig)}
    return {k: v for k, v in model_settings(model).items() if v != defaults[k]}


#: The experiment file the CLI runs a model of each registry group on
#: (tendon2r_gym.artifacts.registry GROUPS): its own preset ({env}), or your arm for a
#: generalist; a model of another group needs its recorded env kwargs (the Python example).
CLI_ENV = {"preset": "{env}", "realism": "{env}", "generalist": "my_arm.yaml"}


def use_it(line: registry.Shipped, shown_settings: str) -> list[str]:
    """Returns how to run one shipped model: the CLI and the Python API."""
    name, env_id = line.name, newest_id()
    lines = []
    if (env := CLI_ENV.get(line.group)) is not None:
        env = env.format(env=line.env)
        command = f"tendon2r-evaluate --policy ppo --bundle {name} --env-config {env}"
        lines += [*code_block([command], "bash"), ""]
    python = [
        "import gymnasium as gym",
        "import tendon2r_gym  # registers the ids",
        "from tendon2r_gym.artifacts.bundle import bundled_model",
        "from tendon2r_gym.policies.learned import PPOPolicy",
        "from tendon2r_gym.artifacts.model_env import model_settings",
        "from tendon2r_gym.artifacts.runs import training_record",
        "",
        f'model = bundled_model("{name}")  # the primary seed; bundled_model("{name}", seed)',
        f'env = gym.make("{env_id}", **training_record(model)["env_kwargs"])  # its training env',
        "policy = PPOPolicy.load(model, env)  # raises if env is not one the model runs in",
        "obs, info = env.reset(seed=0)",
        "policy.reset(info)",
        "action, _ = policy.predict(obs)",
        "",
        "# on your own arm: the model's settings over your experiment file",
        f'env = gym.make("{env_id}", preset="my_arm.yaml", **model_settings(model))',
    ]
    return [
        *lines,
        *code_block(python, "python"),
        "",
        "`model_settings(model)` holds what the model's actions and observation need",
        f"({shown_settings}). `PPOPolicy.load` accepts your arm if the model covers it: a",
        "generalist, an arm inside its training ranges; any other model, the arm it trained on.",
        "To fine-tune a model on your arm: [Training](../training.md).",
    ]


def model_card(line: registry.Shipped, reports: dict[str, dict[str, Any]]) -> list[str]:
    """Returns one shipped model's page."""
    name = line.name
    meta = bundle_meta(name)
    run = primary_run(name)
    config = run.read_config()
    best = run.read_json(BEST_METRICS)
    summary = run.read_json(SUMMARY)
    evaluation = run.best_evaluation() or {}
    scale = config.get("residual_scale", 0.0)
    kind = f"residual on PD (residual_scale {scale:g})" if scale else "plain PPO (residual_scale 0)"
    settings = non_default_settings(bundled_model(name))
    model = f"tendon2r_gym/data/models/{name}/seed_{line.primary_seed}/best_model.zip"
    facts = [
        ("role", line.role),
        ("benchmark group", code(line.group)),
        ("entry", f"{code(line.entry)} of `tendon2r_gym/data/ppo.yaml`"),
        ("policy", kind),
        ("net_arch", code(shown(config.get("policy_kwargs", {}).get("net_arch")))),
        ("total_timesteps", config["total_timesteps"]),
        ("env kwargs", code(json.dumps(config["env_kwargs"]))),
        ("trained on", f"preset {code(line.env)}, env contract {code(line.contract)}"),
        ("model settings", ", ".join(f"{k}={shown(v)}" for k, v in settings.items()) or "-"),
        ("seeds", f"{', '.join(map(str, line.seeds))} (primary {line.primary_seed})"),
    ]
    per_seed = []
    for seed in line.seeds:
        s = primary_run(name, seed).read_json(SUMMARY)
        beat = s.get("first_beat_pd")
        per_seed.append(
            (
                seed,
                s["timesteps"],
                s["wall_time_s"],
                s["best_timesteps"],
                report.first_beat(beat),
                pair(s["best_rms_deg"], ".3g"),
            )
        )
    measured = [
        ("RMS error A / B (deg)", pair(best["rms_deg"], ".3g")),
        ("max error A / B (deg)", pair(best["max_deg"], ".3g")),
        ("PD's RMS error A / B (deg), same episodes", pair(summary.get("pd_eval_rms_deg"), ".3g")),
        ("RMS tension per tendon (N)", pair(best.get("rms_tension_N"), ".3g")),
        ("RMS tension rate per tendon (N/s)", pair(best.get("rms_tension_rate_N_per_s"), ".3g")),
        ("diverged episodes", f"{best['diverged_episodes']} of {best['episodes']}"),
    ]
    if "tension_rate_x_pd" in evaluation:
        measured.insert(
            3,
            ("tension rate x PD's (training evaluation)", f"{evaluation['tension_rate_x_pd']:.2f}"),
        )
    ran = benchmark_rows(model, reports)
    shown_settings = ", ".join(f"{k}={shown(v)}" for k, v in settings.items()) or "the defaults"
    curve = gen_figures.model_figure(name)
    lines = [
        header(f"tendon2r_gym/data/shipped.yaml and the bundle tendon2r_gym/data/models/{name}"),
        "",
        f"# {name}",
        "",
        f"{line.role[:1].upper()}{line.role[1:]}. [All shipped models](../models.md).",
        "",
        figure(curve, f"{name}: RMS error per joint during training, beside PD's", "../"),
        "",
        *table(("", "value"), facts),
        "",
        "## Training",
        "",
        *code_block(dict.fromkeys((meta["train_command"], meta["command"])), "bash"),
        "",
        *table(
            ("seed", "steps", "wall time (s)", "best at step", "first beat PD (steps / wall)",
             "best RMS A / B (deg)"),
            per_seed,
        ),  # fmt: skip
        "",
        "## Evaluation",
        "",
        f"The primary seed's best checkpoint (step {best['timesteps']}) on its training env's "
        f"evaluation episodes (seeds {', '.join(map(str, best['seeds']))}; best_metrics.json):",
        "",
        *table(("measure", "value"), measured),
    ]
    if ran:
        head = ("report", "env", "row", "RMS A / B (deg)", "worst joint x PD", "tension rate x PD")
        lines += ["", "Benchmark rows that run it ([Results](../results.md)):", ""]
        lines += table(head, ran)
    return [*lines, "", "## Use it", "", *use_it(line, shown_settings)]


def models_page(root: Path = ROOT) -> str:
    """Returns docs/models.md: the overview of every shipped model."""
    rows = []
    for name, line in registry.shipped().items():
        run = primary_run(name)
        best = run.read_json(BEST_METRICS)
        summary = run.read_json(SUMMARY)
        rows.append(
            (
                f"[{name}](models/{name}.md)",
                line.role,
                code(line.env),
                len(line.seeds),
                summary["timesteps"],
                pair(best["rms_deg"], ".3g"),
                pair(summary.get("pd_eval_rms_deg"), ".3g"),
            )
        )
    head = ("model", "role", "preset", "seeds", "steps", "RMS A / B (deg)", "PD's (deg)")
    return page(
        [
            header("tendon2r_gym/data/shipped.yaml and the bundles under tendon2r_gym/data/models"),
            "",
            "# Shipped models",
            "",
            "Every model the package ships, from one registry (`tendon2r_gym/data/shipped.yaml`).",
            f"Each is a bundle under `tendon2r_gym/data/{MODELS_DIR.name}/<name>/` of its",
            "training seeds (the first is the primary one, which `tendon2r-evaluate` and",
            "`bundled_model` use). A model loads only into an env of the contract it was trained",
            "on, up to the arm. RMS: the primary seed's best checkpoint on its evaluation",
            "episodes, beside PD's on the same episodes. Each model's page has its learning",
            "curve, training, evaluation and use.",
            "",
            *table(head, rows),
        ]
    )


def model_pages(root: Path = ROOT) -> dict[str, str]:
    """Returns docs/models/<name>.md for every shipped model."""
    reports = benchmark_reports(root)
    return {
        f"models/{name}.md": page(model_card(line, reports))
        for name, line in registry.shipped().items()
    }

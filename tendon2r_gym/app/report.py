"""The benchmark's Markdown, from its JSON record alone (tendon2r_gym.app.benchmark writes
both; scripts/gen_docs.py renders the same record into the docs' results page).

Per row: RMS and max tracking error per joint, the figure's reproducibility, tensions, their
rate of change and saturation; per learned row, its training cost and its verdict against PD
and CT.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from tendon2r_gym.app import markdown
from tendon2r_gym.artifacts.model_env import MODEL_SETTINGS
from tendon2r_gym.evaluation.evaluator import BASELINE, JITTER, REPRO_RUNS, names
from tendon2r_gym.evaluation.metrics import beats, smoothness_x_pd

#: Figures quoted from the lab reports (their own measurements), shown for comparison only.
REPORT_ROWS = {
    "default": ("report 001 (position actuators on the joints)", [0.92, 1.15], [1.85, 2.34]),
    "report_002": ("report 002 (open-loop tendon commands)", [37.5, 35.8], [60.0, 70.0]),
}
#: A figure printed to 4 decimals keeps its digits (to a unit of the last) when it changes
#: by less than this.
PRINTED = 5e-5


def fmt(pair: list[float] | None, digits: int = 4) -> str:
    """Returns per-joint figures as "A / B" with ``digits`` decimals ("-" for none)."""
    return markdown.pair(pair, f".{digits}f")


def tol(pair: list[float] | None) -> str:
    """Returns a reproducibility tolerance per joint, to two significant digits."""
    return markdown.pair(pair, ".2g")


def unsure(cell: dict[str, Any]) -> str:
    """Returns " *to x / y*" for a figure whose reruns change its printed digits, else ""."""
    t = cell.get("reproducible_to")
    return f" *to {tol(t)}*" if t is not None and max(t) >= PRINTED else ""


NOTES = [
    "Per joint (A / B): RMS and max tracking error over all steps of all episodes (the same",
    "seeds for every policy). Per tendon: RMS and peak tension (N, positive pulling), and the",
    "RMS rate of change of each tension (N/s: smoothness, what a motor must follow), the",
    "steps where some tendon pushed (negative tension); then the fraction of saturated steps.",
    "`ppo scratch` is plain PPO driving the motors (residual_scale 0); `ppo residual` adds",
    "its action to the PD command. The row without a seed count is the primary training",
    "seed (fixed before training); `(N seeds)` is the mean ± std (ddof 0) over training",
    "seeds, each evaluated on the benchmark seeds, not on the seeds that chose its",
    "checkpoint. Train wall time: one run on 2 CPU cores. First beat PD: the first",
    "evaluation during training (on the eval seeds) whose RMS was <= PD's on both joints.",
    f"Reproducible to: per joint, the largest change of the row's RMS error among {REPRO_RUNS}",
    f"reruns in which every command of its policy is scaled by 1 +- 2^{math.log2(JITTER):.0f}",
    "(float32's rounding: what another CPU's float32 kernels change in a network's action);",
    f"below {PRINTED:g} deg the figures keep their printed digits, above it the closed loop",
    "amplifies the last bits of its arithmetic. A learned policy's network runs in float64 in",
    "a fixed order of operations (tendon2r_gym.policies.inference): the same bits whatever the",
    "CPU and torch's threads.",
]


def shown_policy(row: dict[str, Any]) -> str:
    """Returns a row's policy label, with the model settings (learned.MODEL_SETTINGS) it ran
    in where they differ from the env's: "residual (joint-torque mode)"."""
    shown = [_setting(k, row[k]) for k in MODEL_SETTINGS if k in row]
    return row["policy"] + (f" ({', '.join(shown)})" if shown else "")


def _setting(name: str, value: Any) -> str:
    """Returns one model setting as a row label shows it: "joint-torque mode", "observe
    error_rate", "action_filter_tau 0.002"."""
    if name == "action_mode":
        return f"{value.replace('_', '-')} mode"
    if isinstance(value, (list, tuple)):
        return f"{name} {', '.join(map(str, value)) or 'nothing'}"
    return f"{name} {value}"


def first_beat(value: Any) -> str:
    """Returns when a training first beat PD (``first_beat_pd``), as "steps / wall s", "never",
    or a comma-separated list of them for several seeds."""
    if isinstance(value, list):
        return ", ".join(first_beat(v) for v in value)
    return "never" if value is None else f"{value['timesteps']} / {value['wall_time_s']} s"


def _by_env(rows: list[dict[str, Any]]):
    """Yields (env, its rows) in the rows' order."""
    for name in dict.fromkeys(r["env"] for r in rows):
        yield name, [r for r in rows if r["env"] == name]


def tracking_table(
    rows: list[dict[str, Any]],
    quoted: dict[str, tuple] | None = None,
    plots: Callable[[dict[str, Any]], str] | None = None,
) -> list[str]:
    """Returns the table of the rows' tracking errors (and, with ``plots``, a column of the
    links it gives each row: its figures)."""
    head = ["env", "policy", "RMS error A / B (deg)", "reproducible to (deg)", "max error (deg)"]
    out = []
    for name, group in _by_env(rows):
        for r in group:
            if "missing" in r:
                cells = [name, r["policy"], r["missing"], "", ""]
            else:
                std = f" ± {fmt(r['rms_deg_std'])}" if "rms_deg_std" in r else ""
                cells = [name, shown_policy(r), f"{fmt(r['rms_deg'])}{std}",
                         tol(r.get("reproducible_to")), fmt(r["max_deg"], 3)]  # fmt: skip
            out.append([*cells, plots(r)] if plots else cells)
        if quoted and name in quoted:
            label, rms, mx = quoted[name]
            quote = [name, f"*quoted: {label}*", fmt(rms, 2), "", fmt(mx, 2)]
            out.append([*quote, ""] if plots else quote)
    return markdown.table([*head, "plots"] if plots else head, out)


#: The tracking table under its earlier name.
table = tracking_table


def effort_table(rows: list[dict[str, Any]]) -> list[str]:
    """Returns the table of the rows' tensions per tendon: RMS, peak, RMS rate of change, the
    steps with a pushing tendon and the fraction of saturated steps."""
    head = ["env", "policy", "RMS tension (N)", "peak tension (N)", "RMS tension rate (N/s)",
            "steps pushing", "saturated"]  # fmt: skip
    out = [
        [name, shown_policy(r), fmt(r.get("rms_tension_N")), fmt(r.get("max_tension_N")),
         fmt(r.get("rms_tension_rate_N_per_s"), 2), r.get("negative_tension_steps", ""),
         fmt(r.get("saturated_fraction"), 3)]
        for name, group in _by_env(rows)
        for r in group
        if "rms_tension_N" in r
    ]  # fmt: skip
    return markdown.table(head, out)


def training_table(rows: list[dict[str, Any]]) -> list[str]:
    """Returns the table of the learned rows' training cost: steps, wall time and the first
    evaluation that beat PD."""
    head = ["env", "policy", "train steps", "train wall (s)", "first beat PD (steps / wall)"]
    out = [
        [name, shown_policy(r), r["train_steps"], r.get("train_wall_s", ""),
         first_beat(r.get("first_beat_pd"))]
        for name, group in _by_env(rows)
        for r in group
        if "train_steps" in r
    ]  # fmt: skip
    return markdown.table(head, out)


def seeds_table(rows: list[dict[str, Any]]) -> list[str]:
    """Returns the table of the learned rows over their training seeds (their ``statistics``,
    tendon2r_gym.evaluation.statistics): the interquartile mean of the RMS error per joint
    with its stratified-bootstrap interval, the share of seeds that beat PD on both joints
    with its Wilson interval, each seed's worst-joint ratio to PD, and a note where the
    seeds are too few for the intervals to mean much."""
    head = ["env", "policy", "seeds", "IQM RMS A / B (deg)", "interval A / B (deg)",
            "beats PD (interval)", "worst joint / PD per seed"]  # fmt: skip
    out, notes = [], {}
    for name, group in _by_env(rows):
        for r in group:
            if not (s := r.get("statistics")):
                continue
            low, high = zip(*s["rms_deg_iqm_ci"], strict=True)
            beat = s.get("beats_pd")
            share = (f"{beat['wins']} of {beat['pairs']} ({beat['low']:.2f}–{beat['high']:.2f})"
                     if beat else "-")  # fmt: skip
            ratios = ", ".join(f"{x:.2f}" for x in s.get("worst_ratio_to_pd", [])) or "-"
            out.append([name, shown_policy(r), s["runs"], fmt(s["rms_deg_iqm"]),
                        f"{fmt(list(low))} – {fmt(list(high))}", share, ratios])  # fmt: skip
            if s.get("note"):
                notes.setdefault(s["note"], None)
    if not out:
        return []
    confidence = next(r["statistics"]["confidence"] for r in rows if r.get("statistics"))
    return [
        *markdown.table(head, out),
        "",
        f"Intervals at {confidence:.0%}: the IQM's by a stratified bootstrap over the seeds, the "
        "share's by Wilson's score interval.",
        *(f"{note[0].upper()}{note[1:]}." for note in notes),
    ]


def tables(
    rows: list[dict[str, Any]],
    quoted: dict[str, tuple] | None = None,
    plots: Callable[[dict[str, Any]], str] | None = None,
    h: str = "###",
) -> list[str]:
    """Returns the rows' three tables under their ``h`` headings: tracking, effort and (if a
    row was trained) training."""
    lines = [f"{h} Tracking", "", *tracking_table(rows, quoted, plots), "",
             f"{h} Effort", "", *effort_table(rows)]  # fmt: skip
    if any("train_steps" in r for r in rows):
        lines += ["", f"{h} Training cost", "", *training_table(rows)]
    if seeds := seeds_table(rows):
        lines += ["", f"{h} Over training seeds", "", *seeds]
    return lines


def verdicts(rows: list[dict[str, Any]]) -> list[str]:
    """Returns, per env and learned row, whether its RMS is <= PD's on both joints, and its
    worst-joint ratio to every other baseline of the registry."""
    lines = []
    baselines = names(BASELINE)
    for name in dict.fromkeys(r["env"] for r in rows):
        by = {r["policy"]: r for r in rows if r["env"] == name and "rms_deg" in r}
        if "pd" not in by:
            continue
        for label, r in by.items():
            if label in baselines or "train_steps" not in r:  # a baseline (PD tuned too)
                continue
            pd = by["pd"]["rms_deg"]
            wins = beats(r["rms_deg"], pd)
            ratios = "".join(
                f"; {max(p / c for p, c in zip(r['rms_deg'], by[b]['rms_deg'], strict=True)):.1f}x"
                f" {b.upper()}"
                for b in baselines
                if b != "pd" and b in by
            )
            smooth = ""
            if "rms_tension_N" in r and "rms_tension_N" in by["pd"]:
                tension, rate = smoothness_x_pd(r, by["pd"])
                smooth = f"; tension {tension:.1f}x PD's, tension rate {rate:.1f}x PD's"
            lines.append(
                f"- {name}, {shown_policy(r)}: RMS {fmt(r['rms_deg'])} vs PD {fmt(pd)}"
                f" deg: {'<= PD on both joints' if wins else 'WORSE than PD on at least one joint'}"
                f"{ratios}{smooth}; trained {r['train_steps']} steps in {r['train_wall_s']} s"
                + (f" (slowest seed {r['train_wall_s_max']} s)" if "train_wall_s_max" in r else "")
            )
    return lines


def tension_comparison(rows: list[dict[str, Any]]) -> list[str]:
    """Returns lines comparing the pull-only preset's tensions and steps with a pushing tendon
    with the push-pull default's, per policy, and the pull-only targets."""
    by = {(r["env"], r["policy"]): r for r in rows if "rms_deg" in r and "rms_tension_N" in r}
    lines = []
    for (env, policy), r in by.items():
        if env != "pull_only" or (base := by.get(("default", policy))) is None:
            continue
        lines.append(
            f"- {policy}: RMS tension {fmt(r['rms_tension_N'], 3)} N (peak "
            f"{max(r['max_tension_N']):.3f} N, least {min(r['min_tension_N']):.3f} N, "
            f"{r['negative_tension_steps']} steps with a pushing tendon) against push-pull "
            f"{fmt(base['rms_tension_N'], 3)} N (peak {max(base['max_tension_N']):.3f} N, "
            f"{base['negative_tension_steps']} of {base['steps']} steps pushing)."
        )
    limits = {"pd": 0.3, "ct": 0.02}
    for policy, limit in limits.items():
        if (r := by.get(("pull_only", policy))) is not None:
            ok = max(r["rms_deg"]) <= limit and r["negative_tension_steps"] == 0
            lines.append(
                f"- Target {policy.upper()} <= {limit} deg RMS per joint with no pushing "
                f"tendon: **{'met' if ok else 'MISSED'}** ({fmt(r['rms_deg'])} deg)."
            )
    return lines


def bundled_sections(
    result: dict[str, Any],
    level: int = 2,
    notes: list[str] = NOTES,
    plots: Callable[[dict[str, Any]], str] | None = None,
) -> list[str]:
    """Returns the sections of the bundled presets' report (``tendon2r-benchmark``) from its
    JSON record, their headings at ``level``: ``notes`` on how to read it, its tables (with
    ``plots``, each row's links to its figures) and the verdicts."""
    rows, h = result["rows"], "#" * level
    lines = [
        *notes,
        "",
        *tables(rows, REPORT_ROWS, plots, h),
        "",
        f"{h} Against PD and computed torque",
        "",
        "Learned rows against PD (RMS <= PD on both joints?) and against computed torque:",
        "",
        *verdicts(rows),
        "",
        f"{h} Pull-only tendons (preset `pull_only`, routing n_plus_1) against push-pull `default`",
        "",
        *tension_comparison(rows),
    ]
    if held := result.get("held_out"):
        lines += [
            "",
            f"{h} Held-out references (generalization)",
            "",
            "PD and the residual trained on random references (`random_reference`) on fixed",
            "references it never trained on (`tendon2r_gym.app.benchmark.HELD_OUT`):",
            "",
            *markdown.table(
                ["policy", "mean RMS error A / B (deg)", "reproducible to (deg)"],
                (
                    [
                        r["policy"],
                        r.get("missing") or fmt(r["rms_deg_mean"]),
                        tol(r.get("reproducible_to")),
                    ]
                    for r in held
                ),
            ),  # fmt: skip
        ]
    return lines


def bundled_page(result: dict[str, Any]) -> list[str]:
    """Returns results/benchmark.md."""
    return [
        "# Benchmark: PD vs computed torque vs PPO on the bundled presets",
        "",
        f"Produced by `{result['command']}`; every figure comes from that run except the rows",
        "marked *quoted*, which are the lab reports' own figures.",
        "",
        *bundled_sections(result),
    ]


def without_partial_smoothness(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Returns rows for `verdicts`, which compares tensions when a row has
    ``rms_tension_N``: a row recorded without its tension rate keeps its errors only."""
    rate, tension = "rms_tension_rate_N_per_s", "rms_tension_N"
    return [r if rate in r else {k: v for k, v in r.items() if k != tension} for r in rows]


def own_arm_sections(
    result: dict[str, Any],
    notes: list[str] = NOTES,
    plots: Callable[[dict[str, Any]], str] | None = None,
    level: int = 2,
) -> list[str]:
    """Returns an own-arm report's body (``tendon2r-benchmark --env-config FILE``): ``notes``,
    its tables under headings at ``level`` (with ``plots``, each row's links to its figures)
    and the verdicts."""
    rows = result["rows"]
    mech = result.get("env_config", {}).get("mechanism", {})
    lines = [f"Produced by `{result['command']}`."]
    if "force_need_N" in result and "max_tendon_force" in mech:
        lines.append(
            f"Force limit {mech['max_tendon_force']:g} N; inverse dynamics of the reference "
            f"needs {result['force_need_N']:.3g} N."
        )
    return [*lines, "", *notes, "", *tables(rows, plots=plots, h="#" * level), "",
            *verdicts(without_partial_smoothness(rows))]  # fmt: skip


def own_arm_page(result: dict[str, Any], env_config: str) -> list[str]:
    """Returns an own-arm report's benchmark.md."""
    return [f"# Benchmark on {env_config}", "", *own_arm_sections(result)]


def _by_key(record: dict[str, Any]) -> dict[tuple[str, str], dict[str, Any]]:
    rows = {(r["env"], r["policy"]): r for r in record.get("rows", [])}
    rows |= {("held-out", r["policy"]): r for r in record.get("held_out", [])}
    return rows


def differences(ours: dict[str, Any], theirs: dict[str, Any]) -> list[str]:
    """Returns how a rerun's benchmark record ``theirs`` differs from ``ours`` beyond each
    row's reproducibility: a row missing on either side, or an RMS error per joint that moved
    by more than the larger of the two rows' ``reproducible_to`` (the rows' other figures
    follow their errors).  Empty when every row reproduces."""
    a, b = _by_key(ours), _by_key(theirs)
    out = [f"{k[0]}, {k[1]}: only in one record" for k in sorted(set(a) ^ set(b))]
    for key in sorted(set(a) & set(b)):
        x, y = a[key], b[key]
        rms = "rms_deg_mean" if "rms_deg_mean" in x else "rms_deg"
        if rms not in x or rms not in y:
            if (rms in x) != (rms in y):
                out.append(f"{key[0]}, {key[1]}: ran in one record only")
            continue
        zero = [0.0] * len(x[rms])
        limit = np.maximum(x.get("reproducible_to", zero), y.get("reproducible_to", zero))
        moved = np.abs(np.subtract(x[rms], y[rms]))
        if np.any(moved > limit):
            out.append(
                f"{key[0]}, {key[1]}: RMS {fmt(x[rms])} then {fmt(y[rms])} deg, moved by "
                f"{tol(moved)} where it is reproducible to {tol(limit)}"
            )
    return out

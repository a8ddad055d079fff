"""Identification on synthetic arms: does tendon2r-identify find the hidden realism values,
do its intervals hold them, and what does the fit buy in closed loop?

    python -m research.studies.identification   # research/results/identification.md and .json
    python -m research.studies.identification --arm-set out_of_sample --workers 2

The nominal arm is the ``real_arm`` preset.  Each of ARMS true arms draws its hidden values
(every PERTURBATIONS field but the motor's mass, which a datasheet gives: the rotor's inertia)
from ``np.random.default_rng(SEED)``, drawn again if the env refuses the arm (its integrator
could not integrate it), as a training's draw would be.  Each one plays tendon2r-excite's
excitation of the nominal arm for DURATION s (the recording seeded by its index), and
tendon2r-identify fits the default fields to it.  Reported per arm: each field's relative
error, whether its 95% interval holds the truth, whether it was flagged; the loop delay
found; the fit's seconds.

In closed loop, on the true arm (EPISODES held-out episodes of its reference):

- PD tuned (tendon2r-tune-pd) on the nominal, the identified and the true arm;
- the realism residual (bundle ``real_arm``), its PD tuned as above and its arm features
  (what it observes of the arm) those of the nominal, the identified and the true arm;
- both again on the identified arm with what the recording does not show at its true values
  (hidden_true): how much of the gap left is out of the recording's reach.

The gap closed is (nominal - identified) / (nominal - true) of the worst joint's RMS error,
where the nominal choice loses more than NO_GAP against the true one.

Each true arm is one job (``arm_job``) of an executor (tendon2r_gym.training.executors):
``--workers N`` runs N arms at once in local processes, ``--cluster auto`` (or HOST:PORT) on a
Ray cluster.  An arm's row depends only on the arm and its index (the recording's seed), so
the results are the same on every executor (the fit's seconds aside); each job then fits with
one thread unless ``--threads`` says otherwise (the fit does not depend on it).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np

from tendon2r_gym.app.args import arg, parse
from tendon2r_gym.formatting import pair

NOMINAL, ARMS, SEED, DURATION, EPISODES = "real_arm", 16, 2026, 10.0, 2
RESIDUAL = "real_arm"
OUT = Path("research/results")
#: The arm sets (``--arm-set``): ``study``, the arms above; ``out_of_sample``, new arms (their
#: own seed) whose nominal values are wrong where the default fit does not expect it: the
#: motor's mass off the nominal by up to +-MASS_OFF (relative), and a loop delay of 0 to
#: MAX_LOOP_DELAY s split at random between the motor and the sensor.
ARM_SETS = {"study": SEED, "out_of_sample": 2027}
MASS_OFF, MAX_LOOP_DELAY = 0.5, 0.003


def true_arms(n: int = ARMS, seed: int = SEED, out_of_sample: bool = False) -> list[dict[str, Any]]:
    """Returns the env kwargs of ``n`` true arms (module docstring; ``out_of_sample``: ARM_SETS'
    out-of-sample arms)."""
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.simulation.realism import PERTURBATIONS

    nominal = EnvConfig.make(NOMINAL)
    rng = np.random.default_rng(seed)
    dt = nominal.ctrl_dt
    arms: list[dict[str, Any]] = []
    while len(arms) < n:
        drawn = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in PERTURBATIONS.items()}
        if out_of_sample:
            loop = float(rng.uniform(0.0, MAX_LOOP_DELAY))
            drawn["observation_delay"] = float(rng.uniform(0.0, loop))
            drawn["motor_delay"] = loop - drawn["observation_delay"]
            off = float(rng.uniform(-MASS_OFF, MASS_OFF))
            drawn["motor_mass"] = nominal.mechanism.motor_mass * (1.0 + off)
        for k in ("motor_delay", "observation_delay"):
            drawn[k] = round(drawn[k] / dt) * dt
        if not out_of_sample:
            drawn.pop("motor_mass")
        mech = {k: v for k, v in drawn.items() if k in nominal.mechanism.to_dict()}
        arm = {
            "preset": NOMINAL,
            "mechanism": mech,
            "observation_noise": [drawn["observation_noise_angle"],
                                  drawn["observation_noise_speed"]],
            "observation_delay": drawn["observation_delay"],
        }  # fmt: skip
        try:  # drawn again if the env refuses it, as a training's draw would be
            EnvConfig.make(**arm)
        except ValueError:
            continue
        arms.append(arm)
    return arms


#: What each closed-loop row records: tracking, control effort and smoothness (the
#: residual's against PD's on the same arm and episodes: smoothness_x_pd).
EFFORT = ("rms_deg", "rms_tension_N", "rms_tension_rate_N_per_s")


def _worst(rms: list[float]) -> float:
    return float(max(rms))


def closed_loop(true_kw: dict[str, Any], beliefs: dict[str, dict[str, Any]],
                tuned: dict[str, dict[str, Any]]) -> dict[str, Any]:  # fmt: skip
    """PD and the residual on the true arm, tuned and informed by each belief: the residual
    is loaded on the believed arm's env (its arm features and its PD's gains are then the
    believed ones) and rolled out on the true arm's."""
    from tendon2r_gym.evaluation.evaluator import evaluate

    seeds = list(range(EPISODES))
    out: dict[str, Any] = {}
    for name, belief in beliefs.items():
        on = {**true_kw, "pd_gains": tuned[name]}
        pd, _ = evaluate("pd", on, seeds)
        out[name] = {"pd_bandwidth_hz": tuned[name]["bandwidth_hz"],
                     **{f"pd_{k}": pd[k] for k in EFFORT}}  # fmt: skip
        for informed in INFORMED:
            out[name].update(informed_on(informed, true_kw, belief, tuned[name]))
    return out


#: The controllers built on the believed arm and rolled out on the true one: the realism
#: residual (bundle RESIDUAL), and CT, what a control engineer builds from the same belief (the
#: believed arm's inverse dynamics, model errors included (``modelled``), its loop delay's
#: gain schedule, PD tuned's feedback).
INFORMED = ("residual", "ct")


def modelled(belief: dict[str, Any]) -> dict[str, Any]:
    """Returns the believed arm with its model errors folded into its nominal values (density
    times ``density_scale``, joint damping plus ``extra_joint_damping``): PD's and CT's
    model of an arm is its nominal one (``Mechanism.ideal``), and a control engineer's model of
    an identified arm holds what the identification found."""
    from tendon2r_gym.envs.env_config import EnvConfig

    mech = EnvConfig.make(**belief).mechanism
    folded = {"density": mech.true_density, "density_scale": 1.0,
              "joint_damping": mech.true_joint_damping, "extra_joint_damping": 0.0}  # fmt: skip
    return {**belief, "mechanism": {**belief.get("mechanism", {}), **folded}}


def informed_on(name: str, true_kw: dict[str, Any], belief: dict[str, Any],
                gains: dict[str, Any]) -> dict[str, Any]:  # fmt: skip
    """One of INFORMED on the true arm, with PD's ``gains``, built on the believed arm's env
    (the residual's arm features, CT's model are then the believed ones): ``<name>_<EFFORT>``,
    or ``<name>_missing`` with the reason if the believed arm lies outside the residual's
    training ranges."""
    from tendon2r_gym.artifacts.bundle import bundled_model
    from tendon2r_gym.envs.registration import make as make_env
    from tendon2r_gym.evaluation.evaluator import make_policy
    from tendon2r_gym.evaluation.metrics import tracking_metrics
    from tendon2r_gym.evaluation.rollout import rollouts

    built_on = belief if name == "residual" else modelled(belief)
    probe = make_env(**{**built_on, "pd_gains": gains})
    try:
        policy = (make_policy("ppo", probe, bundled_model(RESIDUAL)) if name == "residual"
                  else make_policy(name, probe))  # fmt: skip
    except ValueError as e:
        return {f"{name}_missing": str(e).split(": ", 1)[-1]}
    finally:
        probe.close()
    res = tracking_metrics(rollouts(policy, {**true_kw, "pd_gains": gains}, list(range(EPISODES))))
    return {f"{name}_{k}": res[k] for k in EFFORT}


def hidden_true(identified: dict[str, Any], true_kw: dict[str, Any],
                fields: dict[str, dict[str, Any]]) -> dict[str, Any]:  # fmt: skip
    """Returns the identified arm with what the recording does not show at its true values:
    each flagged field, and how the loop delay splits into the motor's and the sensor's (the
    identified loop delay is kept)."""
    out = json.loads(json.dumps(identified))
    mech = out.setdefault("mechanism", {})
    for name, f in fields.items():
        if not f["identified"]:
            mech[name] = f["true"]
    loop = mech.get("motor_delay", 0.0) + out.get("observation_delay", 0.0)
    obs = min(true_kw.get("observation_delay", 0.0), loop)
    out["observation_delay"], mech["motor_delay"] = obs, round(loop - obs, 12)
    return out


#: The nominal choice's loss against the true one: a gap only past this fraction of the true
#: choice's error.  Within it the nominal choice is already as good, and a ratio of two small
#: differences says nothing.  Where the nominal choice beats the true one there is no gap
#: either: each tuning picks on its own held-out episodes, and the true arm's choice need not
#: be the best on these.  Without a gap, the identified choice passes if it loses at most this
#: fraction against the true one.
NO_GAP = 0.05
#: The three choices of a closed-loop row: made on the nominal, the identified, the true arm.
BELIEFS = ("nominal", "identified", "true")


def _choices(cl: dict[str, Any], key: str) -> tuple[float, float, float] | None:
    """Returns the worst joint's RMS error (nominal, identified, true), or None if a choice
    is missing."""
    if any(key not in cl[b] for b in BELIEFS):
        return None
    nom, idf, tru = (_worst(cl[b][key]) for b in BELIEFS)
    return nom, idf, tru


def gap_closed(cl: dict[str, Any], key: str) -> float | None:
    """Returns (nominal - identified) / (nominal - true) of the worst joint's RMS error, or
    None if a choice is missing or there is no gap (NO_GAP)."""
    if (c := _choices(cl, key)) is None:
        return None
    nom, idf, tru = c
    return None if nom <= (1 + NO_GAP) * tru else (nom - idf) / (nom - tru)


def closes(cl: dict[str, Any], key: str) -> bool:
    """Whether the identified choice closes at least 80% of a gap (gap_closed; past 100% it
    beats the true choice)."""
    g = gap_closed(cl, key)
    return g is not None and g >= 0.8


def no_gap(cl: dict[str, Any], key: str) -> bool | None:
    """Returns, on an arm without a gap (NO_GAP), whether the identified choice loses at most
    NO_GAP against the true one (None if there is a gap or a choice is missing)."""
    if (c := _choices(cl, key)) is None:
        return None
    nom, idf, tru = c
    return idf <= (1 + NO_GAP) * tru if nom <= (1 + NO_GAP) * tru else None


def ideal_check(threads: int | None, duration: float | None = None) -> dict[str, Any]:
    """The default (ideal) arm, recorded noise-free with its excitation and identified with
    the default fields: what comes back for each field (nominal: density_scale 1, the loop
    delay 0, the others 0)."""
    from tendon2r_gym.app.excitation import design, record
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.identification.identify import identify

    duration = DURATION if duration is None else duration
    arm = EnvConfig.make("default")
    signal, _ = design(arm, duration)
    ident = identify([record(arm, "pd", duration, 0, signal)], arm, None, threads)
    return {
        "fields": {e.field: {"nominal": e.nominal, "value": e.value, "half_width": e.half_width,
                             "identified": e.identified, "used": e.used}
                   for e in ident.estimates},
        "skipped": ident.skipped,
        "loop_delay_ms": ident.loop_delay_s * 1e3,
        "seconds": ident.seconds,
    }  # fmt: skip


@dataclass(frozen=True)
class ArmJob:
    """One true arm of the study: its index (the recording's seed), its env kwargs, the
    excitation, the gains PD is tuned to on the nominal arm, the fit's threads and the
    recording's seconds."""

    index: int
    kwargs: dict[str, Any]
    signal: Any  # the excitation (tendon2r_gym.app.excitation.MultiSine)
    tuned_nominal: dict[str, Any]
    threads: int | None
    duration: float = DURATION


def study(n: int, threads: int | None, partial: Path | None = None,
          resume: bool = False, executor: Any = None,
          duration: float | None = None, arm_set: str = "study") -> dict[str, Any]:  # fmt: skip
    """The study on ``n`` true arms (module docstring), each arm one job of ``executor``
    (None: one after another in this process); the rows written to ``partial`` as each ends,
    and with ``resume`` those it holds kept."""
    from research.studies.identification import arm_job  # by name, also under python -m
    from tendon2r_gym.app.excitation import design
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.evaluation.tuning import tune_pd

    duration = DURATION if duration is None else duration
    nominal = EnvConfig.make(NOMINAL)
    signal, _ = design(nominal, duration)
    tuned_nominal = tune_pd({"preset": NOMINAL}, 2).gains.to_dict()
    rows = json.loads(partial.read_text()) if resume and partial and partial.is_file() else []
    done = {r["arm"] for r in rows}  # done before a crash or Ctrl-C
    jobs = [ArmJob(i, kw, signal, tuned_nominal, threads, duration)
            for i, kw in enumerate(true_arms(n, ARM_SETS[arm_set], arm_set != "study"))
            if i not in done]  # fmt: skip

    def record(_: int, row: dict[str, Any]) -> None:  # in this process, as each arm ends
        rows.append(row)
        rows.sort(key=lambda r: r["arm"])
        if partial is not None:  # what is done survives a crash or Ctrl-C
            partial.write_text(json.dumps(rows, indent=1) + "\n")
        ok = all((not f["identified"]) or (abs(f["rel_error"]) <= 0.1 and f["covered"])
                 for f in row["fields"].values())  # fmt: skip
        print(f"arm {row['arm']:2d}: {row['seconds']:5.1f} s, fields ok {ok}, delay "
              f"{row['loop_delay_ms']}, gap {row['gap_closed']}", flush=True)  # fmt: skip

    labels = [f"arm {job.index}" for job in jobs]
    if executor is None:
        for k, job in enumerate(jobs):
            record(k, arm_job(job))
    else:
        executor.map(arm_job, jobs, labels, record)
    return {"nominal": NOMINAL, "arms": n, "seed": ARM_SETS[arm_set], "arm_set": arm_set,
            "duration_s": duration,
            "episodes": EPISODES, "ideal": ideal_check(threads, duration),
            "rows": rows}  # fmt: skip


def arm_job(job: ArmJob) -> dict[str, Any]:
    """An executor's job: one true arm's row (module docstring)."""
    from tendon2r_gym.app.excitation import record
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.evaluation.tuning import tune_pd
    from tendon2r_gym.identification.identify import identify

    i, kw, nominal_kw = job.index, job.kwargs, {"preset": NOMINAL}
    nominal = EnvConfig.make(NOMINAL)
    truth_cfg = EnvConfig.make(**kw)
    rec = record(truth_cfg, "pd", job.duration, seed=i, signal=job.signal)
    rec.source = f"true arm {i}"
    ident = identify([rec], nominal, None, job.threads)
    fields = {}
    for e in ident.estimates:
        true = float(getattr(truth_cfg.mechanism, e.field))
        fields[e.field] = {
            "true": true, "nominal": e.nominal, "value": e.value, "half_width": e.half_width,
            "identified": e.identified, "used": e.used,
            "rel_error": (e.value - true) / true if true else math.inf,
            "covered": bool(e.interval[0] <= true <= e.interval[1]),
        }  # fmt: skip
    true_loop = truth_cfg.mechanism.motor_delay + truth_cfg.observation_delay
    beliefs = {"nominal": nominal_kw, "identified": {"preset": NOMINAL, **ident.changes},
               "true": kw}  # fmt: skip
    tuned = {"nominal": job.tuned_nominal}
    for b in ("identified", "true"):
        tuned[b] = tune_pd(beliefs[b], 2).gains.to_dict()
    cl = closed_loop(kw, beliefs, tuned)
    # What is left once the recording's blind spots are filled in: a fourth belief.
    hidden = {"hidden_true": hidden_true(beliefs["identified"], kw, fields)}
    tuned["hidden_true"] = tune_pd(hidden["hidden_true"], 2).gains.to_dict()
    cl.update(closed_loop(kw, hidden, tuned))
    row = {
        "arm": i, "seconds": ident.seconds, "fields": fields,
        "identified": beliefs["identified"],
        "loop_delay_ms": {"true": true_loop * 1e3, "found": ident.loop_delay_s * 1e3,
                          "identified": ident.delay_identified},
        "closed_loop": cl,
        "gap_closed": {k: gap_closed(cl, f"{k}_rms_deg") for k in ("pd", *INFORMED)},
    }  # fmt: skip
    return row


def lines(result: dict[str, Any]) -> list[str]:
    """Returns identification.md."""
    rows = result["rows"]
    names = list(rows[0]["fields"]) if rows else []
    arm_set = result.get("arm_set", "study")
    stem, flag = ("identification", "") if arm_set == "study" else (
        f"identification_{arm_set}", f" --arm-set {arm_set}")  # fmt: skip
    out = [
        "# Identification on synthetic arms"
        + ("" if arm_set == "study" else f" ({arm_set.replace('_', ' ')})"),
        "",
        f"Generated by `python -m research.studies.identification{flag}` from "
        f"`research/results/{stem}.json`: {result['arms']} true arms"
        + (
            f" (the first {result['arms']} of {result['of']}: the run was stopped there)"
            if result.get("of", result["arms"]) != result["arms"]
            else ""
        )
        + " about the "
        f"`{result['nominal']}` preset (seed {result['seed']}), {result['duration_s']:g} s of "
        f"tendon2r-excite's excitation each, identified with the default fields.",
        "",
        "## Fields",
        "",
        "Relative error of each field (a flagged field: `-`), and `*` where its 95% interval "
        "misses the truth.",
        "",
        "| arm | seconds | " + " | ".join(names) + " | loop delay (true / found, ms) |",
        "|---|---|" + "---|" * len(names) + "---|",
    ]
    good = 0
    for r in rows:
        cells = []
        ok = True
        for n in names:
            f = r["fields"][n]
            if not f["identified"]:
                cells.append("-")
                continue
            miss = abs(f["rel_error"]) > 0.1 or not f["covered"]
            ok &= not miss
            cells.append(f"{f['rel_error']:+.1%}{'' if f['covered'] else ' *'}")
        d = r["loop_delay_ms"]
        ok &= (not d["identified"]) or abs(d["true"] - d["found"]) < 1e-9
        good += ok
        shown = f"{d['true']:g} / {d['found']:g}" + ("" if d["identified"] else " (flagged)")
        out.append(f"| {r['arm']} | {r['seconds']:.1f} | " + " | ".join(cells) + f" | {shown} |")
    unflagged = [f for r in rows for f in r["fields"].values() if f["identified"]]
    held = sum(f["covered"] for f in unflagged)
    delays = sum((not r["loop_delay_ms"]["identified"])
                 or abs(r["loop_delay_ms"]["true"] - r["loop_delay_ms"]["found"]) < 1e-9
                 for r in rows)  # fmt: skip
    flagged = {n: sum(not r["fields"][n]["identified"] for r in rows) for n in names}
    secs = [r["seconds"] for r in rows]
    out += [
        "",
        f"Arms on which every unflagged field is within 10% and inside its interval, and the "
        f"loop delay (if not flagged) is the true one: **{good} of {len(rows)}**.",
        f"Unflagged fields whose 95% interval holds the true value: **{held} of "
        f"{len(unflagged)}** ({held / max(len(unflagged), 1):.0%}). The loop delay is the true "
        f"one or flagged as not told apart on **{delays} of {len(rows)}** arms.",
        "Flagged per field: " + ", ".join(f"{n} {k}" for n, k in flagged.items()) + ".",
        f"Seconds per identification: median {np.median(secs):.1f}, max {max(secs):.1f} "
        "(wall time in the study's process, on a machine that other jobs may have shared).",
        "",
        "## An arm without realism",
        "",
        "The `default` preset (rigid cables, no lag, no delay, exact masses), recorded "
        "noise-free with its own excitation, identified with the default fields "
        "(those its model can vary):",
        "",
        "| field | nominal | identified | 95% half-width |",
        "|---|---|---|---|",
        *[
            f"| {k} | {f['nominal']:.4g} | {f['value']:.4g} | {f['half_width']:.3g} |"
            for k, f in result["ideal"]["fields"].items()
        ],
        f"| loop delay (ms) | 0 | {result['ideal']['loop_delay_ms']:g} | |",
        "",
        "## Closed loop on the true arm",
        "",
        "Worst joint's RMS error (deg), with the choice made on the nominal, the identified "
        "and the true arm; gap closed = (nominal - identified) / (nominal - true). An arm "
        f"whose nominal choice loses at most {NO_GAP:.0%} against the true one, or beats it "
        "(each tuning picks on its own held-out episodes, not on these), has no gap to close: "
        f"its identified choice passes if it loses at most {NO_GAP:.0%} against the true one.",
        "",
        "The last two columns: the residual informed by the identified arm with what the "
        "recording does not show at its true values (each flagged field, and how the loop "
        "delay splits into the motor's and the sensor's), on PD tuned on that arm: how much "
        "of what is left is out of the recording's reach.",
        "",
        "| arm | PD nominal | PD identified | PD true | PD gap closed | residual nominal | "
        "residual identified | residual true | residual gap closed | residual, hidden true "
        "| its gap closed |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        cl = r["closed_loop"]
        pd = [_worst(cl[b]["pd_rms_deg"]) for b in BELIEFS]
        res = [_worst(cl[b]["residual_rms_deg"]) if "residual_rms_deg" in cl[b] else math.nan
               for b in BELIEFS]  # fmt: skip
        gp, gr = (_gap_cell(cl, f"{k}_rms_deg") for k in ("pd", "residual"))
        missing = [f"{b}: {cl[b]['residual_missing']}" for b in BELIEFS
                   if "residual_missing" in cl[b]]  # fmt: skip
        if missing:
            gr += " (residual refused the arm: " + "; ".join(missing) + ")"
        hid, gh = _hidden(cl)
        out.append(f"| {r['arm']} | " + " | ".join(f"{v:.3g}" for v in pd) + f" | {gp} | "
                   + " | ".join(f"{v:.3g}" for v in res) + f" | {gr} | {hid} | {gh} |")  # fmt: skip
    views = [v for r in rows if (v := _hidden_view(r["closed_loop"])) is not None]
    if views:
        fine = sum(closes(v, "residual_rms_deg") or bool(no_gap(v, "residual_rms_deg"))
                   for v in views)  # fmt: skip
        out.append(
            f"\nThe residual, hidden true: the gap closed (or, without a gap, within "
            f"{NO_GAP:.0%} of the true choice) on {fine} of {len(views)} arms."
        )
    for key, label in (("pd", "PD"), ("residual", "residual"), ("ct", "CT")):
        cls = [r["closed_loop"] for r in rows]
        gaps = [g for cl in cls if (g := gap_closed(cl, f"{key}_rms_deg")) is not None]
        flat = [f for cl in cls if (f := no_gap(cl, f"{key}_rms_deg")) is not None]
        if not gaps and not flat:  # a study without this row
            continue
        line = f"\n{label}: "
        if gaps:
            at = sum(closes(cl, f"{key}_rms_deg") for cl in cls)
            line += (
                f"median gap closed {np.median(gaps):.0%}, {at} of {len(gaps)} arms with a "
                "gap at 80% or more (past 100%, the identified choice beats the true one)"
            )
        if flat:
            line += (
                f"{'; ' if gaps else ''}{len(flat)} arms without a gap, the identified "
                f"choice losing at most {NO_GAP:.0%} against the true one on {sum(flat)}"
            )
        out.append(line + ".")
    return out + reference_lines(rows) + effort_lines(rows)


def reference_lines(rows: list[dict[str, Any]]) -> list[str]:
    """The classical reference: CT built on each belief (INFORMED), beside PD and the residual
    on the same belief, and each learned row's ratio to it."""
    if not any("ct_rms_deg" in r["closed_loop"]["true"] for r in rows):
        return []  # a study without this row
    out = [
        "",
        "## The classical reference: CT on each belief",
        "",
        "CT built on the nominal, the identified and the true arm (its inverse dynamics, its "
        "loop delay's gain schedule, the feedback of PD tuned on it), on the true arm: what a "
        "control engineer builds from the same identification. Worst joint's RMS error (deg); "
        "the residual's ratio to CT on the same belief.",
        "",
        "| arm | CT nominal | CT identified | CT true | CT gap closed | residual / CT, "
        "identified | residual / CT, true |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        cl = r["closed_loop"]
        if (ct := _choices(cl, "ct_rms_deg")) is None:
            continue
        ratios = [
            f"{_worst(cl[b]['residual_rms_deg']) / c:.3f}" if "residual_rms_deg" in cl[b] else "-"
            for b, c in zip(BELIEFS[1:], ct[1:], strict=True)
        ]
        cells = [f"{v:.3g}" for v in ct] + [_gap_cell(cl, "ct_rms_deg"), *ratios]
        out.append(f"| {r['arm']} | " + " | ".join(cells) + " |")
    return out


def _gap_cell(cl: dict[str, Any], key: str) -> str:
    """A table's gap-closed cell (gap_closed, or no_gap's verdict without a gap)."""
    g, none = gap_closed(cl, key), no_gap(cl, key)
    if g is not None:
        return f"{g:.0%}"
    if none is None:
        return "n/a"
    return f"no gap, identified {'within' if none else 'beyond'} {NO_GAP:.0%} of true"


def _hidden_view(cl: dict[str, Any]) -> dict[str, Any] | None:
    """Returns the closed loop with the hidden-true belief as the identified one (None if the
    row has none): the gap it closes."""
    return {**cl, "identified": cl["hidden_true"]} if "hidden_true" in cl else None


def _hidden(cl: dict[str, Any]) -> tuple[str, str]:
    """The table's residual, hidden true cells: its error and its gap closed."""
    if (view := _hidden_view(cl)) is None:
        return "-", "-"
    h = view["identified"]
    if "residual_rms_deg" not in h:
        return f"refused ({h['residual_missing']})", "n/a"
    return f"{_worst(h['residual_rms_deg']):.3g}", _gap_cell(view, "residual_rms_deg")


def effort_lines(rows: list[dict[str, Any]]) -> list[str]:
    """The closed loop's control effort and smoothness: PD's RMS tension and tension rate
    (the largest over the tendons), and the residual's as multiples of PD's on the same arm,
    gains and episodes (smoothness_x_pd), with the count within its limits."""
    from tendon2r_gym.evaluation.metrics import smoothness_x_pd, within_limits

    out = [
        "",
        "## Control effort and smoothness on the true arm",
        "",
        "PD's RMS tension (N) and tension rate (N/s), the largest over the tendons; the "
        "residual's as multiples of PD's with the same gains (nominal / identified / true).",
        "",
        "| arm | PD tension | PD tension rate | residual tension x PD | residual rate x PD |",
        "|---|---|---|---|---|",
    ]
    within, runs = 0, 0
    for r in rows:
        cl = r["closed_loop"]
        pd = {b: {k: cl[b][f"pd_{k}"] for k in EFFORT} for b in BELIEFS}
        res = {}
        for b in BELIEFS:
            if "residual_rms_deg" in cl[b]:
                res[b] = smoothness_x_pd({k: cl[b][f"residual_{k}"] for k in EFFORT}, pd[b])
                within += within_limits(*res[b], residual=True)
                runs += 1

        def cells(values: list[float | None]) -> str:
            return pair(values, ".3g")

        out.append(
            f"| {r['arm']} | {cells([max(pd[b]['rms_tension_N']) for b in BELIEFS])} | "
            f"{cells([max(pd[b]['rms_tension_rate_N_per_s']) for b in BELIEFS])} | "
            f"{cells([res[b][0] if b in res else None for b in BELIEFS])} | "
            f"{cells([res[b][1] if b in res else None for b in BELIEFS])} |"
        )
    out += ["", f"The residual keeps the smoothness limits on {within} of its {runs} runs."]
    return out


@dataclass
class Args:
    """The identification study (module docstring)."""

    arms: Annotated[int, arg("how many true arms")] = ARMS
    arm_set: Annotated[str, arg(f"which arms, of {list(ARM_SETS)} (ARM_SETS)")] = "study"
    threads: Annotated[int | None, arg("rollout threads (default: every core)")] = None
    out: Annotated[str, arg("folder of identification.md and .json")] = str(OUT)
    only_report: Annotated[bool, arg("rewrite the .md from the .json")] = False
    from_partial: Annotated[
        bool, arg("write the .json and .md from the arms done so far (identification.partial.json)")
    ] = False
    resume: Annotated[
        bool, arg("continue after the arms done so far (identification.partial.json)")
    ] = False
    workers: Annotated[int, arg("fit this many arms at once in local worker processes")] = 1
    cluster: Annotated[
        str | None, arg("fit the arms on a Ray cluster: auto (or RAY_ADDRESS) or HOST:PORT")
    ] = None


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from tendon2r_gym.training.executors import InProcess, entered, make_executor

    args = parse(Args, argv)
    executor = make_executor(args.workers, args.cluster, 1)  # --workers, --cluster checked
    # jobs at once: one fit thread each unless --threads says otherwise (same fit)
    job_threads = args.threads if isinstance(executor, InProcess) else args.threads or 1
    if args.arm_set not in ARM_SETS:
        raise ValueError(f"--arm-set {args.arm_set!r} is invalid; allowed: {list(ARM_SETS)}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = "identification" + ("" if args.arm_set == "study" else f"_{args.arm_set}")
    if args.only_report:
        result = json.loads((out / f"{stem}.json").read_text())
    elif args.from_partial:
        rows = json.loads((out / f"{stem}.partial.json").read_text())
        result = {"nominal": NOMINAL, "arms": len(rows), "of": args.arms,
                  "seed": ARM_SETS[args.arm_set], "arm_set": args.arm_set,
                  "duration_s": DURATION, "episodes": EPISODES, "ideal": ideal_check(args.threads),
                  "rows": rows}  # fmt: skip
        (out / f"{stem}.json").write_text(json.dumps(result, indent=1) + "\n")
    else:
        with entered(executor) as ex:
            result = study(args.arms, job_threads, out / f"{stem}.partial.json",
                           args.resume, ex, arm_set=args.arm_set)  # fmt: skip
        (out / f"{stem}.json").write_text(json.dumps(result, indent=1) + "\n")
    (out / f"{stem}.md").write_text("\n".join(lines(result)) + "\n")
    return result


if __name__ == "__main__":
    main()

"""Candidate models on the envelope study's arms, before anything ships: each run's best model
zero-shot on the arms that research/results/envelope_generalists.json measured, against the PD
tuned there (its gains and rows are read back, not tuned again), with that study's summary.

    python -m research.studies.candidates --models real_arm_memory=runs/real_arm_memory/seed_0
    # -> research/results/candidates.md and candidates.json

``--models NAME=RUN`` names a run folder (its best model) or a model zip; ``--kinds`` picks the
study's arms (``one_geometry`` by default: the real_arm geometry's 8 arms).  A residual trained
on drawn PD gains runs on PD tuned, as in the study.  The shipped bundles' rows of the study are
shown beside the candidates, from the same file.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from tendon2r_gym.app.args import arg, parse

OUT = Path("research/results")
STUDY = OUT / "envelope_generalists.json"
KINDS = ("ideal", "real", "one_geometry")


def kind_of(arm: str) -> str:
    """Returns the kind of a study's arm name (``real_3`` -> ``real``)."""
    return "one_geometry" if arm.startswith("one_geometry") else arm.split("_")[0]


def model_path(value: str) -> Path:
    """Returns the model zip of a run folder (its best model) or of a zip path."""
    from tendon2r_gym.artifacts.runs import RunFolder, model_files

    path = Path(value)
    return path if path.suffix == ".zip" else model_files(RunFolder(path).best)[0]


#: The classical references (`evaluate_baselines`).
REFERENCES = ("ct", "ct_floor")
#: What the floor switches off: the delays, the motor lag and the pulley friction.
FLOOR = {"motor_delay": 0.0, "motor_tau": 0.0, "tendon_friction": 0.0}


def tuned(arm: dict[str, Any]) -> dict[str, Any]:
    """Returns the arm's kwargs with the gains of the PD tuned recorded on it."""
    from research.studies.envelope_generalists import recorded_gains

    kwargs = arm["kwargs"]
    return {**kwargs, "pd_gains": recorded_gains(kwargs, arm["rows"]["pd_tuned"])}


def floor(kwargs: dict[str, Any]) -> dict[str, Any]:
    """Returns the arm without its delays, motor lag and pulley friction (FLOOR), with the
    gains PD schedules on it (the arm's own, not the ones tuned on its delays)."""
    mechanism = {**kwargs.get("mechanism", {}), **FLOOR}
    return {**kwargs, "mechanism": mechanism, "observation_delay": 0.0}


def evaluate_baselines(arm: dict[str, Any], seeds: list[int]) -> dict[str, Any]:
    """Returns the classical references on one arm: CT (the nominal model's inverse dynamics
    plus PD tuned's feedback) and the floor, CT on the arm without delays, lag and friction."""
    from research.studies.envelope_generalists import KEYS
    from tendon2r_gym.evaluation.evaluator import evaluate

    out = {}
    for name, kwargs in (("ct", tuned(arm)), ("ct_floor", floor(arm["kwargs"]))):
        metrics, _ = evaluate("ct", kwargs, seeds)
        out[name] = {k: metrics[k] for k in KEYS}
    return out


def evaluate_candidate(arm: dict[str, Any], model: Path, seeds: list[int]) -> dict[str, Any]:
    """Returns one model's metrics on one arm of the study, on the PD tuned recorded there."""
    from research.studies.envelope_generalists import KEYS
    from research.studies.realism import on_its_pd
    from tendon2r_gym.artifacts.model_env import in_model_settings
    from tendon2r_gym.evaluation.evaluator import evaluate

    kwargs = arm["kwargs"]
    try:
        on = in_model_settings(model, on_its_pd(kwargs, tuned(arm), model))
        metrics, _ = evaluate("ppo", on, seeds, model)
    except ValueError as e:  # outside its ranges
        return {"error": str(e)}
    return {k: metrics[k] for k in KEYS}


def summary(
    rows: list[tuple[dict[str, Any], dict[str, Any]]],
    residual: bool,
    references: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Returns the envelope study's summary of (row, PD tuned's row) pairs (its
    against_pd_tuned), with each arm's worst-joint ratio and the median worst-joint ratio to
    each classical reference (``references``: per pair, name -> row)."""
    import numpy as np

    from research.studies.envelope_generalists import against_pd_tuned
    from tendon2r_gym.evaluation.metrics import worst_ratio

    done = [(r, t) for r, t in rows if "error" not in r]
    out: dict[str, Any] = {"arms": len(rows), "refused": len(rows) - len(done)}
    if not done:
        return out
    to = {}
    for name in sorted(references[0]) if references else []:
        to[name] = float(np.median([worst_ratio(r["rms_deg"], ref[name]["rms_deg"])
                                    for (r, _), ref in zip(rows, references, strict=True)
                                    if "error" not in r]))  # fmt: skip
    return {
        **out,
        **against_pd_tuned(done, residual),
        "ratios": [worst_ratio(r["rms_deg"], t["rms_deg"]) for r, t in done],
        "median_ratio_to": to,
    }


def lines(result: dict[str, Any]) -> list[str]:
    """Returns candidates.md."""
    out = [
        "# Candidate models on the envelope study's arms",
        "",
        f"Produced by `{result['command']}` (research/studies/candidates.py), on the arms of "
        f"`{result['study']}` ({', '.join(result['kinds'])}), evaluation seeds "
        f"{result['seeds']}, against PD tuned on each arm. Worst-joint ratio: the model's worse "
        "joint's RMS error as a multiple of PD tuned's; tension and tension rate as multiples "
        "of PD tuned's.",
        "",
        "| model | kind | arms | refused | <= PD tuned on both joints | worst-joint ratio: "
        "median / largest | per arm | RMS tension (x PD tuned), median | tension rate (x PD "
        "tuned): median / largest | within the smoothness limits | median worst-joint ratio "
        "to CT / to the floor |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, kinds in result["summary"].items():
        for kind, s in kinds.items():
            if "median_ratio" not in s:
                out.append(f"| {name} | {kind} | {s['arms']} | {s['refused']} | - | - | - | - "
                           "| - | - | - |")  # fmt: skip
                continue
            per_arm = ", ".join(f"{x:.2f}" for x in s["ratios"])
            out.append(
                f"| {name} | {kind} | {s['arms']} | {s['refused']} | {s['beats_pd_tuned']} of "
                f"{s['arms'] - s['refused']} | {s['median_ratio']:.3f} / {s['max_ratio']:.3f} | "
                f"{per_arm} | {s['median_tension_x']:.2f} | {s['median_rate_x']:.2f} / "
                f"{s['max_rate_x']:.2f} | {s['smooth']} of {s['arms'] - s['refused']} | "
                f"{s['median_ratio_to']['ct']:.3f} / {s['median_ratio_to']['ct_floor']:.3f} |"
            )
    models = ", ".join(f"`{k}`: `{v}`" for k, v in result["models"].items())
    return [
        *out,
        "",
        f"Models: {models}. `ct`: computed torque (the nominal model's inverse dynamics) with PD "
        "tuned's gains, what a control engineer builds from the same arm model; `ct_floor`: "
        "computed torque on the same arm with its delays, motor lag and pulley friction switched "
        "off (and the gains PD schedules there), what the actuators and sensors cost.",
    ]


@dataclass
class Args:
    """Candidate models on the envelope study's arms (module docstring)."""

    models: Annotated[list[str], arg("NAME=RUN (a run folder) or NAME=ZIP, one or more")] = field(
        default_factory=list
    )
    kinds: Annotated[list[str], arg(f"the study's arms: some of {', '.join(KINDS)}")] = field(
        default_factory=lambda: ["one_geometry"]
    )
    study: Annotated[str, arg("the envelope study's results file")] = str(STUDY)
    out: Annotated[str, arg("folder of candidates.md and candidates.json")] = str(OUT)
    only_report: Annotated[bool, arg("rewrite the .md from the .json")] = False


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from research.studies import computed_or_read, one_or_more
    from tendon2r_gym.artifacts.runs import command_line, training_record
    from tendon2r_gym.policies.residual import Residual
    from tendon2r_gym.validation import invalid

    args = parse(Args, argv, __doc__)
    command = command_line(sys.argv[1:] if argv is None else argv,
                           "python -m research.studies.candidates")  # fmt: skip
    out = Path(args.out)

    def compute() -> dict[str, Any]:
        models = {}
        for item in one_or_more("--models", args.models, "NAME=RUN, one or more"):
            name, _, path = item.partition("=")
            if not name or not path or not Path(path).exists():
                raise invalid("--models", item, "NAME=RUN: a name and an existing run or zip")
            models[name] = model_path(path)
        for kind in one_or_more("--kinds", args.kinds, f"some of {KINDS}"):
            if kind not in KINDS:
                raise invalid("--kinds", kind, f"one of {KINDS}")
        study = json.loads(Path(args.study).read_text())
        arms = {k: v for k, v in study["arms"].items() if kind_of(k) in args.kinds}
        seeds = study["seeds"]
        rows: dict[str, dict[str, Any]] = {name: {} for name in (*REFERENCES, *models)}
        for arm_name, arm in arms.items():
            for name, row in evaluate_baselines(arm, seeds).items():
                rows[name][arm_name] = row
            for name, model in models.items():
                rows[name][arm_name] = evaluate_candidate(arm, model, seeds)
                print(arm_name, name, rows[name][arm_name].get("rms_deg"), flush=True)
        shipped = {b for arm in arms.values() for b in arm["rows"] if b not in ("pd", "pd_tuned")}
        table: dict[str, dict[str, Any]] = {}
        for name in [*REFERENCES, *sorted(shipped), *models]:
            residual = (
                name not in REFERENCES
                and Residual.from_record(
                    training_record(models[name]) if name in models else _bundled(name)
                ).active
            )
            for kind in args.kinds:
                on = [a for a, arm in arms.items()
                      if kind_of(a) == kind and (name in rows or name in arm["rows"])]  # fmt: skip
                pairs = [(_row(name, a, arms[a], rows), arms[a]["rows"]["pd_tuned"]) for a in on]
                refs = [{r: rows[r][a] for r in REFERENCES} for a in on]
                if pairs:
                    table.setdefault(name, {})[kind] = summary(pairs, residual, refs)
        return {"command": command, "study": args.study, "kinds": args.kinds, "seeds": seeds,
                "models": {k: str(v) for k, v in models.items()}, "rows": rows,
                "summary": table}  # fmt: skip

    result = computed_or_read(out, "candidates", args.only_report, compute)
    (out / "candidates.md").write_text("\n".join(lines(result)) + "\n")
    print("wrote", out / "candidates.md")
    return result


def _row(name: str, arm_name: str, arm: dict[str, Any], rows: dict[str, Any]) -> dict[str, Any]:
    """Returns a candidate's row on an arm, or a shipped bundle's as the study recorded it."""
    return rows[name][arm_name] if name in rows else arm["rows"][name]


def _bundled(name: str) -> dict[str, Any]:
    from tendon2r_gym.artifacts.bundle import bundled_model
    from tendon2r_gym.artifacts.runs import training_record

    return training_record(bundled_model(name))


if __name__ == "__main__":
    main()

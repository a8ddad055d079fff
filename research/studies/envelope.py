"""The envelope of arms that users bring: which of its arms are valid, how much of each
reference fits their workspace, and which of them an integrator can integrate with real
cables, motors and sensors.

    python -m research.studies.envelope   # research/results/envelope.md and .json

ENVELOPE is the envelope that "One policy for every real arm" asks the generalists to cover
(pulley diameters 0.008-0.06 m, links 0.025-0.12 m, amplitudes up to 60 deg, frequencies
0.3-5 Hz, biases within 50 deg).  DRAWS arms are drawn uniformly from it (seed SEED), on two
nominal arms:

- ``ideal``: the generalist preset's mechanism (rigid push-pull cables);
- ``real``: the real_arm preset's (pull-only n + 1 cables), each arm with its cables, motors
  and sensors drawn from the realism ranges (tendon2r_gym.simulation.realism.PERTURBATIONS)
  too.

For each arm: whether the Mechanism accepts it (else the field it names), whether the
reference's bias fits its workspace at zero amplitude, and the share of the drawn amplitude
that fitting it to the workspace keeps.  For the real arms: whether the stability check
(tendon2r_gym.simulation.stability) accepts the arm at each of SETTINGS (integrator, sim_dt),
and else the field it names.  An env that draws arms redraws a refused one, so a refusal
narrows what a policy trains on.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np

from research.studies import computed_or_read
from tendon2r_gym.app.args import arg, parse
from tendon2r_gym.task.arms import GEOMETRY, ArmRanges

ENVELOPE = ArmRanges(
    R1=(0.008, 0.06), R2=(0.008, 0.06), a=(0.025, 0.12), b=(0.025, 0.12), c=(0.025, 0.12),
    amp_deg=(0.0, 60.0), bias_deg=(-50.0, 50.0), freq_hz=(0.3, 5.0),
)  # fmt: skip
DRAWS, SEED = 1000, 2029
NOMINALS = {"ideal": "generalist", "real": "real_arm"}
SETTINGS = (("RK4", 1e-3), ("RK4", 5e-4), ("RK4", 2.5e-4), ("implicitfast", 1e-3),
            ("implicitfast", 5e-4))  # fmt: skip
OUT = Path("research/results")


def _field(error: ValueError) -> str:
    return str(error).split(" = ", 1)[0].removeprefix("Mechanism.")


def survey(kind: str, draws: int = DRAWS, seed: int = SEED) -> dict[str, Any]:
    """Returns the counts of the module docstring for ``draws`` arms of ``kind``."""
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.simulation.model import build_model
    from tendon2r_gym.simulation.realism import PERTURBATIONS
    from tendon2r_gym.simulation.stability import check_stability
    from tendon2r_gym.task.reference import Reference

    nominal = EnvConfig.make(NOMINALS[kind])
    base = nominal.mechanism
    rng = np.random.default_rng(seed)
    u = lambda r: float(rng.uniform(*r))  # noqa: E731
    refused: Counter[str] = Counter()
    stable = {f"{i} {dt:g}": 0 for i, dt in SETTINGS}
    unstable: dict[str, Counter[str]] = {k: Counter() for k in stable}
    kept: list[float] = []
    valid = 0
    for _ in range(draws):
        geometry = {k: u(getattr(ENVELOPE, k)) for k in GEOMETRY}
        realism = ({k: u(r) for k, r in PERTURBATIONS.items() if k in base.to_dict()}
                   if kind == "real" else {})  # fmt: skip
        ref = Reference(
            amp_deg=(u(ENVELOPE.amp_deg), u(ENVELOPE.amp_deg)),
            bias_deg=(u(ENVELOPE.bias_deg), u(ENVELOPE.bias_deg)),
            freq_hz=(u(ENVELOPE.freq_hz), u(ENVELOPE.freq_hz)),
        )
        try:
            mech = base.replace(**geometry)
        except ValueError as e:
            refused[_field(e)] += 1
            continue
        try:
            fitted = ref.fit_to_workspace(mech, warn=False)
        except ValueError:
            refused["reference.bias_deg (outside the workspace)"] += 1
            continue
        valid += 1
        drawn = sum(ref.amp_deg)
        kept.append(sum(fitted.amp_deg) / drawn if drawn > 0 else 1.0)
        if kind != "real":
            continue
        for integrator, dt in SETTINGS:
            key = f"{integrator} {dt:g}"
            real = mech.replace(**realism, integrator=integrator, sim_dt=dt)
            try:
                check_stability(build_model(real.ideal()), real)
                stable[key] += 1
            except ValueError as e:
                unstable[key][_field(e)] += 1
    out: dict[str, Any] = {
        "kind": kind, "nominal": NOMINALS[kind], "draws": draws, "valid": valid,
        "refused": dict(refused.most_common()),
        "amplitude_kept": {"median": float(np.median(kept)), "p10": float(np.percentile(kept, 10))},
    }  # fmt: skip
    if kind == "real":
        out["stable"] = stable
        out["unstable"] = {k: dict(c.most_common()) for k, c in unstable.items()}
    return out


def lines(result: dict[str, Any]) -> list[str]:
    """Returns envelope.md."""
    env = result["envelope"]
    out = [
        "# The envelope of arms users bring",
        "",
        f"Generated by `python -m research.studies.envelope` from `research/results/envelope.json`"
        f": {result['draws']} arms drawn uniformly (seed {result['seed']}) from pulley diameters "
        f"{env['R1'][0]:g}-{env['R1'][1]:g} m, links {env['a'][0]:g}-{env['a'][1]:g} m, "
        f"amplitudes up to {env['amp_deg'][1]:g} deg, frequencies {env['freq_hz'][0]:g}-"
        f"{env['freq_hz'][1]:g} Hz and biases within {env['bias_deg'][1]:g} deg.",
        "",
        "## Valid arms",
        "",
        "| nominal arm | valid | refused (field: arms) | amplitude kept by the workspace "
        "(median / 10th percentile) |",
        "|---|---|---|---|",
    ]
    for s in result["surveys"]:
        refused = ", ".join(f"{k}: {v}" for k, v in s["refused"].items()) or "none"
        kept = s["amplitude_kept"]
        out.append(f"| {s['kind']} (`{s['nominal']}`) | {s['valid']} of {s['draws']} | "
                   f"{refused} | {kept['median']:.0%} / {kept['p10']:.0%} |")  # fmt: skip
    real = next(s for s in result["surveys"] if s["kind"] == "real")
    out += [
        "",
        "## Real cables: what the integrator can integrate",
        "",
        f"Of the {real['valid']} valid real arms (cables, motors and sensors drawn from the "
        "realism ranges), those the stability check accepts; the others are refused by the "
        "field it names.",
        "",
        "| integrator | sim_dt (s) | accepted | refused (field: arms) |",
        "|---|---|---|---|",
    ]
    for key, n in real["stable"].items():
        integrator, dt = key.split()
        refused = ", ".join(f"{k}: {v}" for k, v in real["unstable"][key].items()) or "none"
        out.append(f"| {integrator} | {dt} | {n} of {real['valid']} "
                   f"({n / max(real['valid'], 1):.1%}) | {refused} |")  # fmt: skip
    return out


@dataclass
class Args:
    """The envelope survey (module docstring)."""

    draws: Annotated[int, arg("arms drawn per nominal arm")] = DRAWS
    out: Annotated[str, arg("folder of envelope.md and .json")] = str(OUT)
    only_report: Annotated[bool, arg("rewrite the .md from the .json")] = False


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse(Args, argv)
    out = Path(args.out)
    result = computed_or_read(out, "envelope", args.only_report, lambda: {
        "draws": args.draws, "seed": SEED,
        "envelope": {k: list(getattr(ENVELOPE, k)) for k in
                     (*GEOMETRY, "amp_deg", "bias_deg", "freq_hz")},
        "surveys": [survey(kind, args.draws) for kind in NOMINALS],
    })  # fmt: skip
    (out / "envelope.md").write_text("\n".join(lines(result)) + "\n")
    return result


if __name__ == "__main__":
    main()

"""The generalists on unseen arms of the envelope that users bring, ideal and real.

    python -m research.studies.envelope_generalists  # research/results/envelope_generalists.*

Arms (each an experiment file; drawn with SEED, which training never uses: its arms come from
the envs' own seeded generators):

- ``ideal_<i>``: ``--arms`` arms of the envelope (tendon2r_gym.task.arms.ENVELOPE) by
  ``draw_arms``, with the generalist preset's rigid cables.  The ideal generalists run on
  them, and the pull-only generalist on the same geometries with its preset's cables
  (``ideal_<i>_pull_only``).
- ``real_<i>``: ``--arms`` arms drawn as the ``generalist_real`` entry's env draws them
  (tendon2r_gym/data/ppo.yaml: the envelope, and the cables, motors, sensors and model errors
  of the realism ranges), on the real_arm preset's pull-only cables.
- ``one_geometry_<i>``: ``--one-geometry`` arms of the real_arm preset's geometry and reference
  with the realism ranges drawn (research.studies.realism.perturbed_arms, another seed): the
  arms where the one-geometry realism residual (the ``real_arm`` bundle) applies, beside
  ``generalist_real``.

On each arm: PD as ``tendon2r-tune-pd`` tunes it there (held-out episodes), the package's PD,
and each bundle zero-shot on the same evaluation seeds.  A residual trained on drawn PD gains
(generalist_real, real_arm) runs on the tuned PD, as on a user's tuned arm; the others on the
PD they trained with.  Summary per bundle, against PD tuned on the same arm: arms where it is
<= PD tuned on both joints, the median and largest worst-joint ratio, its RMS tension and
tension rate as multiples of PD tuned's (median and largest), and the arms where it keeps the
smoothness limits (tendon2r_gym.evaluation.metrics).

Each arm is one job (``arm_job``) of an executor (tendon2r_gym.training.executors):
``--workers N`` runs N arms at once in local processes, ``--cluster auto`` (or HOST:PORT) on a
Ray cluster.  An arm's rows depend only on the arm, its bundles and the evaluation seeds, so
the results are the same on every executor; the partial file is written as each arm ends.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import numpy as np

from research.studies import computed_or_read
from research.studies.generalist import PULL_ONLY_PRESET, with_pull_only_cables
from tendon2r_gym.app.args import arg, parse

SEED = 9029
IDEAL = ("generalist", "generalist_scratch")
REAL, ONE_GEOMETRY = "generalist_real", "real_arm"
#: Held-out episodes PD is tuned on per arm (tendon2r_gym.evaluation.tuning's own seeds).
TUNE_EPISODES = 2
OUT = Path("research/results")
ROOT = Path(__file__).resolve().parents[2]


def ideal_arms(n: int, seed: int) -> dict[str, dict[str, Any]]:
    """Returns the ideal arms and their pull-only twins, by name."""
    from tendon2r_gym.task.arms import ENVELOPE, draw_arms

    out = {}
    for i, arm in enumerate(draw_arms(seed, n, ENVELOPE)):
        out[f"ideal_{i}"] = {"kwargs": arm, "bundles": list(IDEAL)}
        out[f"ideal_{i}_pull_only"] = {"kwargs": with_pull_only_cables(arm),
                                       "bundles": [PULL_ONLY_PRESET]}  # fmt: skip
    return out


def real_arms(n: int, seed: int) -> dict[str, dict[str, Any]]:
    """Returns ``n`` arms drawn as generalist_real's training env draws them, by name."""
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.task.arms import draw_episode_arm
    from tendon2r_gym.training import Hyperparams

    kwargs = Hyperparams.from_entry(REAL).env_kwargs
    env = EnvConfig.make(**kwargs)
    rng = np.random.default_rng(seed)
    out = {}
    for i in range(n):
        arm = draw_episode_arm(env, rng).to_dict()
        content = {"preset": kwargs["preset"], "mechanism": arm["mechanism"],
                   "reference": arm["reference"], "fit_to_workspace": True,
                   "observation_noise": arm["observation_noise"],
                   "observation_delay": arm["observation_delay"]}  # fmt: skip
        out[f"real_{i}"] = {"kwargs": content, "bundles": [REAL]}
    return out


def one_geometry_arms(n: int, seed: int) -> dict[str, dict[str, Any]]:
    """Returns ``n`` perturbed real_arm arms (research.studies.realism), by name."""
    from research.studies.realism import perturbed_arms

    return {f"one_geometry_{i}": {"kwargs": kw, "bundles": [REAL, ONE_GEOMETRY]}
            for i, kw in enumerate(perturbed_arms("real_arm", n, seed))}  # fmt: skip


KEYS = ("rms_deg", "rms_tension_N", "rms_tension_rate_N_per_s")


def model_id(bundle: str) -> str:
    """Returns the first 12 hex digits of the sha256 of ``bundle``'s shipped model: a row
    records the model it measured, and ``--resume`` measures a bundle again once it is
    retrained."""
    import hashlib

    from tendon2r_gym.artifacts.bundle import bundled_model

    return hashlib.sha256(bundled_model(bundle).read_bytes()).hexdigest()[:12]


def recorded_gains(kwargs: dict[str, Any], pd_tuned: dict[str, Any]) -> dict[str, Any]:
    """Returns the gains of the PD tuned recorded on an arm (its row ``pd_tuned``): tune_pd's
    bandwidth, with the arm's other gains (as tune_pd keeps them)."""
    from tendon2r_gym.envs.env_config import resolve
    from tendon2r_gym.task.gains import gains_of

    base = gains_of(resolve(kwargs).pd_gains).to_dict()
    return {**base, "bandwidth_hz": pd_tuned["bandwidth_hz"]}


def evaluate_arm(
    kwargs: dict[str, Any], bundles: list[str], seeds: list[int], done: dict[str, Any] | None = None
) -> dict[str, Any]:
    """Returns PD tuned's, PD's and each bundle's metrics on one arm (a bundle that refuses
    the arm is reported with its error).  ``done``: the rows of an earlier run on the same
    arm, whose PD rows and the rows of bundles not retrained since (model_id) are kept."""
    from research.studies.realism import on_its_pd
    from tendon2r_gym.artifacts.bundle import bundle_names, bundled_model
    from tendon2r_gym.artifacts.model_env import in_model_settings
    from tendon2r_gym.evaluation.evaluator import evaluate
    from tendon2r_gym.evaluation.tuning import tune_pd

    if done is not None:  # tune_pd's choice, as recorded
        rows = {k: done[k] for k in ("pd_tuned", "pd")}
        gains = recorded_gains(kwargs, rows["pd_tuned"])
    else:
        scan = tune_pd(kwargs, TUNE_EPISODES)
        gains, rows = scan.gains.to_dict(), {}
        for name, on in (("pd_tuned", {**kwargs, "pd_gains": gains}), ("pd", kwargs)):
            metrics, _ = evaluate("pd", on, seeds)
            rows[name] = {k: metrics[k] for k in KEYS}
        rows["pd_tuned"]["bandwidth_hz"] = scan.chosen
    tuned = {**kwargs, "pd_gains": gains}
    for bundle in [b for b in bundles if b in bundle_names()]:  # those bundled
        model, shipped = bundled_model(bundle), model_id(bundle)
        if done is not None and done.get(bundle, {}).get("model") == shipped:
            rows[bundle] = done[bundle]
            continue
        try:
            on = in_model_settings(model, on_its_pd(kwargs, tuned, model))
            metrics, _ = evaluate("ppo", on, seeds, model)
            rows[bundle] = {k: metrics[k] for k in KEYS}
        except ValueError as e:  # outside its ranges; paths relative to the repository
            rows[bundle] = {"error": str(e).replace(f"{ROOT}/", "")}
        rows[bundle]["model"] = shipped
    return rows


@dataclass(frozen=True)
class ArmJob:
    """One arm of the study: evaluate_arm's arguments."""

    name: str
    kwargs: dict[str, Any]
    bundles: list[str]
    seeds: list[int]
    done: dict[str, Any] | None = None


def arm_job(job: ArmJob) -> dict[str, Any]:
    """An executor's job: evaluate_arm on one arm."""
    return evaluate_arm(job.kwargs, job.bundles, job.seeds, job.done)


def against_pd_tuned(
    pairs: list[tuple[dict[str, Any], dict[str, Any]]], residual: bool
) -> dict[str, Any]:
    """Returns the summary of a model's (row, PD tuned's row) pairs on the arms it ran: the
    arms where it is <= PD tuned on both joints, its worst-joint ratio to PD tuned (median,
    largest), its RMS tension and tension rate as multiples of PD tuned's (median, largest),
    and the arms where it keeps the smoothness limits."""
    from tendon2r_gym.evaluation.metrics import beats, smooth_enough, smoothness_x_pd, worst_ratio

    ratio = [worst_ratio(r["rms_deg"], t["rms_deg"]) for r, t in pairs]
    tension, rate = zip(*(smoothness_x_pd(r, t) for r, t in pairs), strict=True)
    return dict(
        beats_pd_tuned=sum(beats(r["rms_deg"], t["rms_deg"]) for r, t in pairs),
        median_ratio=float(np.median(ratio)), max_ratio=float(np.max(ratio)),
        median_tension_x=float(np.median(tension)), max_tension_x=float(np.max(tension)),
        median_rate_x=float(np.median(rate)), max_rate_x=float(np.max(rate)),
        smooth=sum(smooth_enough(r, t, residual) for r, t in pairs),
    )  # fmt: skip


def summarize(arms: dict[str, Any]) -> dict[str, Any]:
    """Returns, per bundle and kind of arm, the module docstring's summary against PD tuned."""
    from tendon2r_gym.artifacts.bundle import bundled_model
    from tendon2r_gym.artifacts.runs import training_record
    from tendon2r_gym.evaluation.metrics import worst_ratio
    from tendon2r_gym.policies.residual import Residual

    out: dict[str, Any] = {}
    for name, arm in arms.items():
        kind = name.split("_")[0] if not name.startswith("one_geometry") else "one_geometry"
        for bundle, row in arm["rows"].items():
            if bundle in ("pd", "pd_tuned"):
                continue
            s = out.setdefault(
                f"{bundle} on {kind}",
                {"bundle": bundle, "kind": kind, "arms": 0, "refused": 0, "rows": []},
            )
            s["arms"] += 1
            if "error" in row:
                s["refused"] += 1
            else:
                s["rows"].append((row, arm["rows"]["pd_tuned"], arm["rows"]["pd"]))
    for s in out.values():
        rows = s.pop("rows")
        if not rows:  # it refused every arm
            continue
        residual = Residual.from_record(training_record(bundled_model(s["bundle"]))).active
        vs_pd = [worst_ratio(r["rms_deg"], p["rms_deg"]) for r, _, p in rows]
        s.update(
            residual=residual,
            **against_pd_tuned([(r, t) for r, t, _ in rows], residual),
            median_ratio_to_pd=float(np.median(vs_pd)),
        )
    return out


def lines(result: dict[str, Any]) -> list[str]:
    """Returns envelope_generalists.md."""
    from tendon2r_gym.evaluation.metrics import beats

    out = [
        "# The generalists on the envelope's unseen arms",
        "",
        f"Produced by `{result['command']}` (research/studies/envelope_generalists.py says how "
        f"the arms are drawn): seed {result['seed']}, evaluation seeds {result['seeds']}. "
        "Against PD as `tendon2r-tune-pd` tunes it on each arm: the arms where the bundle is "
        "<= it on both joints, its worst joint's RMS error as a multiple of PD tuned's (median "
        "and largest; and the median against the package's PD), its RMS tension and tension "
        "rate as multiples of PD tuned's, and the arms within the smoothness limits (RMS "
        "tension <= 1.5x, tension rate <= 3x for a residual, 10x for plain PPO).",
        "",
        "| bundle | arms | refused | <= PD tuned on both joints | worst-joint ratio to PD "
        "tuned: median / largest | median ratio to PD | RMS tension (x PD tuned): median / "
        "largest | tension rate (x PD tuned): median / largest | within the smoothness limits |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for label, s in result["summary"].items():
        if s["arms"] == s["refused"]:
            out.append(f"| {label} | {s['arms']} | {s['refused']} | - | - | - | - | - | - |")
            continue
        ran = s["arms"] - s["refused"]
        out.append(
            f"| {label} | {s['arms']} | {s['refused']} | {s['beats_pd_tuned']} of {ran} | "
            f"{s['median_ratio']:.3f} / {s['max_ratio']:.3f} | {s['median_ratio_to_pd']:.3f} | "
            f"{s['median_tension_x']:.2f} / {s['max_tension_x']:.2f} | "
            f"{s['median_rate_x']:.2f} / {s['max_rate_x']:.2f} | {s['smooth']} of {ran} |"
        )
    above = [(n, b, a["rows"]["pd_tuned"]["rms_deg"], r["rms_deg"])
             for n, a in result["arms"].items() for b, r in a["rows"].items()
             if b not in ("pd", "pd_tuned") and "rms_deg" in r
             and not beats(r["rms_deg"], a["rows"]["pd_tuned"]["rms_deg"])]  # fmt: skip
    if above:
        out += ["", "## Arms where a bundle is above PD tuned", "",
                "RMS error of joints A / B (deg).", "",
                "| arm | bundle | PD tuned | bundle |", "|---|---|---|---|"]  # fmt: skip
        out += [f"| {n} | {b} | {t[0]:.3g} / {t[1]:.3g} | {r[0]:.3g} / {r[1]:.3g} |"
                for n, b, t, r in above]  # fmt: skip
    refusals = {f"{n}: {b}": r["error"] for n, a in result["arms"].items()
                for b, r in a["rows"].items() if "error" in r}  # fmt: skip
    if refusals:
        out += ["", "## Refused arms", ""]
        out += [f"- {k}: {v}" for k, v in refusals.items()]
    return out


@dataclass
class Args:
    """The study's flags (module docstring)."""

    arms: Annotated[int, arg("ideal and real arms, each")] = 32
    one_geometry: Annotated[int, arg("arms of the real_arm geometry")] = 8
    episodes: Annotated[int, arg("evaluation seeds 0..N-1 per arm")] = 3
    kinds: Annotated[list[str], arg("ideal, real, one_geometry")] = field(
        default_factory=lambda: ["ideal", "real", "one_geometry"]
    )
    out: Annotated[str, arg("folder of envelope_generalists.md and .json")] = str(OUT)
    only_report: Annotated[bool, arg("rewrite the .md from the .json")] = False
    resume: Annotated[
        bool,
        arg(
            "keep the arms an earlier run finished (envelope_generalists.partial.json, else "
            ".json), measuring again only the bundles retrained since"
        ),
    ] = False
    workers: Annotated[int, arg("evaluate this many arms at once in local worker processes")] = 1
    cluster: Annotated[
        str | None, arg("evaluate the arms on a Ray cluster: auto (or RAY_ADDRESS) or HOST:PORT")
    ] = None


def earlier_arms(out: Path, partial: Path) -> dict[str, Any]:
    """Returns the arms of an earlier run: its partial file (a run that stopped), else its
    saved results, else none."""
    if partial.is_file():
        return json.loads(partial.read_text())
    saved = out / "envelope_generalists.json"
    return json.loads(saved.read_text())["arms"] if saved.is_file() else {}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from research.studies.envelope_generalists import arm_job  # by name, also under -m
    from tendon2r_gym.artifacts.runs import command_line
    from tendon2r_gym.training.executors import entered, make_executor, without_executor_flags

    args = parse(Args, argv, __doc__)
    executor = make_executor(args.workers, args.cluster, 1)  # --workers, --cluster checked
    # the same results, and the same command recorded, on every executor
    command = command_line(without_executor_flags(sys.argv[1:] if argv is None else argv),
                           "python -m research.studies.envelope_generalists")  # fmt: skip
    seeds = list(range(args.episodes))

    out = Path(args.out)
    partial = out / "envelope_generalists.partial.json"

    def compute() -> dict[str, Any]:
        draws = {"ideal": lambda: ideal_arms(args.arms, SEED),
                 "real": lambda: real_arms(args.arms, SEED),
                 "one_geometry": lambda: one_geometry_arms(args.one_geometry, SEED)}  # fmt: skip
        done = earlier_arms(out, partial) if args.resume else {}
        drawn = {name: arm for kind in args.kinds for name, arm in draws[kind]().items()}
        same = {name: name in done and done[name]["kwargs"] == json.loads(json.dumps(arm["kwargs"]))
                for name, arm in drawn.items()}  # fmt: skip
        jobs = [ArmJob(name, arm["kwargs"], arm["bundles"], seeds,
                       done[name]["rows"] if same[name] else None)
                for name, arm in drawn.items()]  # fmt: skip
        finished: dict[str, Any] = {}

        def record(i: int, rows: dict[str, Any]) -> None:  # in this process, as each arm ends
            name = jobs[i].name
            finished[name] = {**drawn[name], "rows": rows}
            if same[name] and rows == done[name]["rows"]:
                return  # done by an earlier run, every bundle as shipped now
            shown = {b: r.get("rms_deg", "refused") for b, r in rows.items()}
            print(name, json.dumps(shown), flush=True)
            out.mkdir(parents=True, exist_ok=True)  # a crash or Ctrl-C keeps these
            partial.write_text(json.dumps({**done, **finished}, indent=1) + "\n")

        with entered(executor) as ex:
            results = ex.map(arm_job, jobs, [f"arm {job.name}" for job in jobs], record)
        arms = {job.name: {**drawn[job.name], "rows": rows}
                for job, rows in zip(jobs, results, strict=True)}  # fmt: skip
        return {"command": command, "seed": SEED, "seeds": seeds, "arms": arms,
                "summary": summarize(arms)}  # fmt: skip

    result = computed_or_read(out, "envelope_generalists", args.only_report, compute)
    (out / "envelope_generalists.md").write_text("\n".join(lines(result)) + "\n")
    return result


if __name__ == "__main__":
    main()

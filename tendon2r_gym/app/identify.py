"""Console commands for a physical arm: excite it, record it, identify it.

    tendon2r-excite     the excitation to play on the arm, and its rehearsal on the nominal arm
    tendon2r-record     a recording from the simulator: any arm, policy, realism and noise
    tendon2r-identify   fit the arm's realism fields to recordings (mujoco.sysid)

The recording format and the walk-through are on the docs' "Identify your arm" page.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from tendon2r_gym.app.args import arg, parse, run


# -- tendon2r-excite -----------------------------------------------------------------------------
@dataclass
class ExciteArgs:
    """The excitation to play on your arm: PD tracking a multi-sine reference, kept within the
    force limit and the joint range on the nominal arm.

    tendon2r-excite --env-config my_arm.yaml --out runs/excite/

    Writes plan.csv (time, q_des_A, q_des_B, dq_des_A, dq_des_B: the reference to track, rad),
    plan.yaml (its sines and the bandwidth of the PD to track it with) and rehearsal.csv (the
    recording of PD tracking it on the nominal arm: what your logger should produce).
    """

    env_config: Annotated[str, arg("preset name or experiment file: the nominal arm")]
    out: Annotated[str, arg("folder for plan.csv, plan.yaml and rehearsal.csv")]
    duration: Annotated[float, arg("seconds (10 s is enough for the default fields)")] = 10.0


def excite_main(argv: list[str] | None = None) -> dict[str, Any]:
    import numpy as np
    import yaml

    from tendon2r_gym.app.excitation import design
    from tendon2r_gym.envs.env_config import resolve
    from tendon2r_gym.validation import number

    args = parse(ExciteArgs, argv)
    number("--duration", args.duration, 0.0, 3600.0, lo_open=True)
    signal, rehearsal = design(resolve(args.env_config), args.duration)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = [np.concatenate([[t], *signal.q(t)]) for t in rehearsal.time]
    header = "time,q_des_A,q_des_B,dq_des_A,dq_des_B"
    np.savetxt(out / "plan.csv", np.array(rows), delimiter=",", header=header, comments="",
               fmt="%.17g")  # fmt: skip
    plan = {"env_config": args.env_config, "duration_s": args.duration, **signal.to_dict()}
    (out / "plan.yaml").write_text(yaml.safe_dump(plan, sort_keys=False))
    rehearsal.save(out / "rehearsal.csv")
    peak = float(np.abs(rehearsal.command).max())
    print(f"wrote {out}/plan.csv, plan.yaml, rehearsal.csv (peak command {peak:.3g} N)")
    return plan


# -- tendon2r-record -----------------------------------------------------------------------------
@dataclass
class RecordArgs:
    """A recording from the simulator, in the recording format: rehearse the loop on any arm.

    tendon2r-record --env-config real_arm --out runs/rec/real_arm.csv --excitation
    tendon2r-record --env-config my_arm.yaml --policy pd --duration 5 --out runs/rec/pd.csv

    --excitation tracks tendon2r-excite's multi-sine for the arm (else the experiment file's
    reference); realism, noise and delays come from the experiment file.
    """

    env_config: Annotated[str, arg("preset name or experiment file: the arm to simulate")]
    out: Annotated[str, arg("the CSV file to write")]
    policy: Annotated[str, arg("a tendon2r-evaluate policy (pd, ct, a bundle name...)")] = "pd"
    model: Annotated[str | None, arg("a model file, for a learned policy")] = None
    duration: Annotated[float, arg("seconds")] = 10.0
    seed: Annotated[int, arg("the episode's seed (noise and reset)")] = 0
    excitation: Annotated[
        str | None, arg("track tendon2r-excite's excitation of this arm (nominal experiment file)")
    ] = None
    tensions: Annotated[bool, arg("also write the cables' tensions (tension_<i>)")] = False


def record_main(argv: list[str] | None = None) -> Path:
    from tendon2r_gym.app.excitation import design, record
    from tendon2r_gym.envs.env_config import resolve

    args = parse(RecordArgs, argv)
    signal = design(resolve(args.excitation), args.duration)[0] if args.excitation else None
    config = resolve(args.env_config)
    rec = record(config, args.policy, args.duration, args.seed, signal, args.tensions, args.model)
    path = rec.save(args.out)
    print(f"wrote {path} ({len(rec.time)} rows)")
    return path


# -- tendon2r-identify ---------------------------------------------------------------------------
@dataclass
class IdentifyArgs:
    """Fit your arm's realism fields to recordings of it (mujoco.sysid): cable stiffness,
    damping and friction, motor lag, mass and delay, sensor delay, link mass scale, joint
    damping.

    tendon2r-identify --recording rec.csv --env-config my_arm.yaml --out my_arm_identified.yaml
    tendon2r-identify --recording a.csv b.csv --env-config my_arm.yaml --out id.yaml \\
        --fit motor_tau density_scale

    Prints each field with its 95% interval, widened to hold its fits on held-out pieces (a
    field the recordings cannot pin down to 10% is flagged, and keeps its nominal value), the
    loop delay (with each delay's fit where several are not told apart), and writes the
    identified arm's experiment file and, beside it, the toolbox's HTML report (--report to
    place it elsewhere).
    """

    recording: Annotated[list[str], arg("one or more recordings of the arm (CSV)")]
    env_config: Annotated[str, arg("preset name or experiment file: the nominal arm")]
    out: Annotated[str, arg("the identified arm's experiment file (YAML)")]
    fit: Annotated[
        list[str] | None, arg("the fields to fit (default: the realism fields of the arm)")
    ] = None
    report: Annotated[str | None, arg("the HTML report (default: --out with .html)")] = None
    threads: Annotated[int | None, arg("rollout threads (default: every core)")] = None


def identify_main(argv: list[str] | None = None) -> Any:
    try:
        import scipy  # noqa: F401
        from mujoco.sysid.report import builder  # noqa: F401
    except ImportError as e:
        raise ValueError(
            f"tendon2r-identify needs MuJoCo's sysid toolbox ({e.name} is missing): "
            'pip install "tendon2r_gym[identify]"'
        ) from None
    from tendon2r_gym.envs.env_config import resolve
    from tendon2r_gym.identification.identify import identify, load_recordings
    from tendon2r_gym.identification.report import save_experiment, save_html

    args = parse(IdentifyArgs, argv)
    config = resolve(args.env_config)
    recs = load_recordings(args.recording, config)
    ident = identify(recs, config, args.fit, args.threads)
    print("\n".join(ident.lines()))
    out = save_experiment(ident, args.out, args.env_config)
    html = save_html(ident, args.report or Path(args.out).with_suffix(".html"))
    print(f"wrote {out} and {html}")
    return ident


excite = run(excite_main)
record = run(record_main)
identify = run(identify_main)

"""The model tools: a picture (or MuJoCo's viewer) of a mechanism, the MJCF XML of the model the
env steps, and shipped bundles made from finished runs.

    tendon2r-view       a picture (or MuJoCo's viewer) of a mechanism
    tendon2r-export     the MJCF XML of the model the env steps
    tendon2r-bundle     copy finished runs into the bundled models"""

from __future__ import annotations

import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

from tendon2r_gym.app.args import arg, parse, run
from tendon2r_gym.artifacts.files import TRUST_HELP

if typing.TYPE_CHECKING:
    from tendon2r_gym.envs.env_config import EnvConfig


# -- tendon2r-view / tendon2r-export / tendon2r-bundle -------------------------------------------
#: The largest side (px) of an image ``tendon2r-view`` renders (the env's render limit).
MAX_IMAGE_SIDE = 16384


@dataclass
class ViewArgs:
    """A static view of a mechanism (the reports' task 3): MuJoCo's passive viewer, or a PNG.

    tendon2r-view --env-config default
    tendon2r-view --save out.png       # headless PNG from the side camera
    """

    env_config: Annotated[str, arg("preset name or experiment file")] = "default"
    save: Annotated[str | None, arg("write a PNG instead of opening the viewer")] = None
    q_deg: Annotated[list[float], arg("pose: joint A and joint B (deg, in the joint range)")] = (
        field(default_factory=lambda: [20.0, -35.0])
    )
    width: Annotated[int, arg(f"PNG width (px, 1 to {MAX_IMAGE_SIDE})")] = 800
    height: Annotated[int, arg(f"PNG height (px, 1 to {MAX_IMAGE_SIDE})")] = 600


def view_main(argv: list[str] | None = None) -> Path | None:
    import mujoco
    import numpy as np

    from tendon2r_gym.envs.env_config import resolve
    from tendon2r_gym.simulation.model import CAMERA, build_model
    from tendon2r_gym.validation import integer, pair

    args = parse(ViewArgs, argv)
    integer("--width", args.width, 1, MAX_IMAGE_SIDE)
    integer("--height", args.height, 1, MAX_IMAGE_SIDE)
    mech = resolve(args.env_config).mechanism
    q_deg = pair("--q-deg", args.q_deg, *mech.joint_range_deg)
    model = build_model(mech)
    model.vis.global_.offwidth, model.vis.global_.offheight = args.width, args.height
    data = mujoco.MjData(model)
    data.qpos[:2] = np.radians(q_deg)  # the arm's joints (elastic cables' spools follow)
    mujoco.mj_forward(model, data)  # positions only: the mechanism is shown, not simulated
    if args.save:
        import imageio.v2 as imageio

        with mujoco.Renderer(model, args.height, args.width) as renderer:
            renderer.update_scene(data, camera=CAMERA)
            image = renderer.render()
        Path(args.save).parent.mkdir(parents=True, exist_ok=True)
        imageio.imwrite(args.save, image)
        print("wrote", args.save)
        return Path(args.save)
    import mujoco.viewer

    with mujoco.viewer.launch_passive(model, data) as viewer:
        while viewer.is_running():
            viewer.sync()
    return None


@dataclass
class ExportArgs:
    """Write the MJCF XML of the model the Tendon2R env steps for an env config: MuJoCo's
    MjModel.from_xml_path compiles it to the env's own MjModel, every number exactly.

    tendon2r-export --env-config real_arm --out build/real_arm.xml

    The XML holds the geometry, the masses and inertias (density_scale), the joints' damping
    (extra_joint_damping), the cables (tendon_elasticity with their rest and slack lengths,
    tendon_damping, tendon_friction), the motors' spools (motor_mass), gains and lag
    (motor_tau), the time step and the integrator.  Each actuator's ctrl is its motor's
    normalized command in [-1, 1]; the env applies an action for ctrl_dt / sim_dt steps.

    What the env does in its Python step is not in the XML (its top comment lists this
    config's values): the mechanism's tendon2r_gym.simulation.realism.STEP_FIELDS,
    observation_noise and observation_delay (what the policy observes), action_filter_tau and
    action_mode joint_torque (what an action becomes), the reset to rest (cables at their rest
    tension, motor lags at the rest command), and with mechanism_ranges the new arm of every
    episode (the XML is the config's nominal arm).
    """

    env_config: Annotated[str, arg("preset name or experiment file")] = "default"
    out: Annotated[str | None, arg("output file (default build/<name>.xml)")] = None


def export_note(cfg: EnvConfig, name: str) -> str:
    """Returns the exported XML's top comment: its env config, how the env steps the model,
    and what of ``cfg`` the env does in Python (ExportArgs)."""
    from tendon2r_gym.envs.timing import Timing

    mech, timing = cfg.mechanism, Timing.of(cfg)
    lines = [
        f"Tendon2R-v0's model of {name} (tendon2r-export), exactly as the env steps it.",
        "ctrl: each motor's normalized command in [-1, 1]; an action holds it for ctrl_dt "
        f"{cfg.ctrl_dt:g} s = {timing.n_substeps} x timestep.",
    ]
    python = []
    from tendon2r_gym.simulation.realism import STEP_FIELDS

    python += [
        f"{k} {getattr(mech, k):g} ({what})" for k, what in STEP_FIELDS.items() if getattr(mech, k)
    ]
    if timing.sensed:
        noise, delay = list(cfg.observation_noise), cfg.observation_delay
        python.append(f"observation_noise {noise}, observation_delay {delay:g} s")
    if cfg.action_filter_tau > 0:
        python.append(f"action_filter_tau {cfg.action_filter_tau:g} s")
    if cfg.action_mode != "tension":
        python.append(f"action_mode {cfg.action_mode}")
    if mech.elastic or mech.motor_tau > 0:
        python.append("the reset to rest (tendon2r_gym.simulation.realism.Drive.settle)")
    if cfg.mechanism_ranges is not None:
        python.append("mechanism_ranges: a new arm every episode; this is the nominal one")
    if python:
        lines += ["The env does in Python, not in this file:", *(f"  {p}" for p in python)]
    return "\n".join(lines)


def export_main(argv: list[str] | None = None) -> Path:
    from tendon2r_gym.envs.env_config import resolve
    from tendon2r_gym.simulation.model import to_xml

    args = parse(ExportArgs, argv)
    cfg = resolve(args.env_config)
    name = Path(args.env_config).stem
    out = Path(args.out or f"build/{name}.xml")
    xml = to_xml(cfg.mechanism, export_note(cfg, name))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(xml)
    print("wrote", out)
    return out


@dataclass
class BundleArgs:
    """Copy finished training runs into the bundled models (the first run is the primary one).

    tendon2r-bundle --name default --runs runs/default/seed_0 runs/default/seed_1
    tendon2r-bundle --name default --replace --runs runs/default/seed_0

    --name is required: a plain name (letters, digits, '_', '.', '-'), one folder under the
    models root.  A bundle of that name is replaced only with --replace, and only once the new
    one is complete (written beside it, then renamed into place): a failure leaves it intact.

    A bundle holds no pickle.  A run of an earlier version, whose VecNormalize statistics are
    a pickle, is bundled only with --trust-pickle (its statistics converted to plain arrays):
    unpickling a file can run code, so only for runs you trained yourself.
    """

    name: Annotated[str | None, arg("bundle name, e.g. default (required)")] = None
    runs: Annotated[list[str], arg("run folders written by tendon2r-train")] = field(
        default_factory=lambda: []
    )
    replace: Annotated[bool, arg("replace the bundle of that name")] = False
    root: Annotated[str | None, arg("models folder (default: the package's bundled models)")] = None
    trust_pickle: Annotated[bool, arg(TRUST_HELP)] = False


def bundle_main(argv: list[str] | None = None) -> Path:
    from tendon2r_gym.artifacts.bundle import bundle_runs, check_destination
    from tendon2r_gym.artifacts.runs import command_line
    from tendon2r_gym.presets import MODELS_DIR
    from tendon2r_gym.validation import invalid

    args = parse(BundleArgs, argv)
    root = Path(args.root) if args.root is not None else MODELS_DIR
    check_destination(args.name, args.replace, root, field="--name", flag="--replace")
    if not args.runs:
        raise invalid("--runs", args.runs, "one or more run folders")
    command = command_line(argv, "tendon2r-bundle")
    runs = [Path(r) for r in args.runs]
    dest = bundle_runs(runs, args.name, command, root, args.replace, args.trust_pickle)
    print("bundled", len(args.runs), "run(s) into", dest)
    return dest


view = run(view_main)


export = run(export_main)


bundle = run(bundle_main)

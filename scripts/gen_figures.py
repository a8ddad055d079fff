"""Draws the docs' figures (docs/images/) from the results' JSON files and the code.

    python scripts/gen_figures.py          # redraws each figure whose inputs changed
    python scripts/gen_figures.py --check  # exits 1, naming each figure whose inputs changed

``scripts/gen_docs.py`` (``make docs``) runs it first.  Each figure is drawn from named input
files; ``docs/images/figures.json`` records the hash of those inputs (and of this script) for
every figure, so the check needs no drawing: a figure is stale when its inputs' hash is not
the one it was drawn from.  PNGs are written by matplotlib's Agg backend without a timestamp
or version in their metadata, so the same inputs and versions give the same bytes.

- ``results_rms.png``: RMS error per joint of PD, CT, plain and residual PPO on each bundled
  preset (results/benchmark.json), log scale, each training seed a dot.
- ``results_profile.png``: the performance profile of plain and residual PPO over their
  training seeds on the bundled presets (results/benchmark.json): the fraction of runs whose
  worst-joint RMS ratio to PD is <= tau, with stratified bootstrap bands (presets as strata).
- ``mechanism_geometry.png`` and ``mechanism_routings.png``: the default arm's links, pulleys
  and tendon paths from its compiled MuJoCo model (tendon2r_gym.simulation.model.build_model),
  and one panel per named routing.
- ``models/<name>.png``: each shipped model's learning curve (its seeds' evaluations.json).
- ``identify_excitation.png``: what ``tendon2r-excite`` writes for the default arm: the
  multi-sine plan and PD's rehearsal of it, with the tendon commands.
"""

from __future__ import annotations

import hashlib
import json
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "tendon2r_gym"
#: The figures' folder under docs/.
IMAGES = "images"
MANIFEST = "figures.json"
RESULTS_FIGURE = "results_rms.png"
PROFILE_FIGURE = "results_profile.png"
GEOMETRY_FIGURE = "mechanism_geometry.png"
ROUTINGS_FIGURE = "mechanism_routings.png"
IDENTIFY_FIGURE = "identify_excitation.png"
#: PNG metadata: no software version or time, so that equal inputs give equal bytes.
METADATA = {"Software": None}
DPI = 100
JOINTS = ("joint A", "joint B")
#: The benchmark's policies in the results chart: (row label, legend, colour).
POLICIES = (
    ("pd", "PD", "tab:gray"),
    ("ct", "computed torque", "tab:blue"),
    ("ppo scratch", "plain PPO", "tab:orange"),
    ("ppo residual", "residual PPO", "tab:green"),
)
#: The pose (deg) at which the mechanism is drawn.
POSE_DEG = (30.0, 45.0)
#: The code the mechanism drawings depend on (besides this script).
MECHANISM_INPUTS = (
    "tendon2r_gym/simulation/model.py",
    "tendon2r_gym/simulation/routing.py",
    "tendon2r_gym/simulation/mechanism.py",
    "tendon2r_gym/data/presets/default.yaml",
)


def model_figure(name: str) -> str:
    """Returns a shipped model's learning-curve figure, relative to docs/images."""
    return f"models/{name}.png"


def save(fig: plt.Figure, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, metadata=METADATA)
    plt.close(fig)


# -- the results ---------------------------------------------------------------------------------
def draw_results(root: Path, path: Path) -> None:
    """The bundled presets' RMS error per joint and policy, log scale; a learned policy's bar is
    its primary seed, its dots each training seed."""
    rows = json.loads((root / "results" / "benchmark.json").read_text())["rows"]
    envs = list(dict.fromkeys(r["env"] for r in rows))
    by = {(r["env"], r["policy"]): r for r in rows if "rms_deg" in r}
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    width = 0.8 / len(POLICIES)
    for j, ax in enumerate(axes):
        for k, (label, legend, colour) in enumerate(POLICIES):
            x = np.arange(len(envs)) + (k - (len(POLICIES) - 1) / 2) * width
            heights = [by[(e, label)]["rms_deg"][j] if (e, label) in by else np.nan for e in envs]
            ax.bar(x, heights, width, color=colour, label=legend)
            for xi, env in zip(x, envs, strict=True):
                seeds = next(
                    (r for (e, p), r in by.items() if e == env and p.startswith(f"{label} (")),
                    None,
                )
                if seeds is not None and "rms_deg_per_seed" in seeds:
                    values = [s[j] for s in seeds["rms_deg_per_seed"]]
                    ax.plot([xi] * len(values), values, "o", ms=3.5, mfc="white", mec="black",
                            mew=0.8)  # fmt: skip
        ax.set(yscale="log", title=JOINTS[j], xticks=range(len(envs)), xticklabels=envs)
        ax.grid(axis="y", which="major", alpha=0.3)
    axes[0].set_ylabel("RMS tracking error (deg)")
    axes[1].legend(loc="upper right", fontsize=8)
    fig.suptitle("RMS error per joint on each bundled preset (dots: each training seed)")
    fig.tight_layout()
    save(fig, path)


def profile_ratios(rows: list[dict]) -> dict[str, dict[str, list[float]]]:
    """Returns, per learned policy of the chart (POLICIES) and preset, each training seed's
    worst-joint RMS ratio to the preset's PD (the rows' ``rms_deg_per_seed``)."""
    from tendon2r_gym.evaluation.statistics import worst_ratios

    pd = {r["env"]: r["rms_deg"] for r in rows if r["policy"] == "pd" and "rms_deg" in r}
    out: dict[str, dict[str, list[float]]] = {}
    for label, legend, _ in POLICIES[2:]:
        runs = {r["env"]: r["rms_deg_per_seed"] for r in rows
                if r["policy"].startswith(f"{label} (") and "rms_deg_per_seed" in r
                and r["env"] in pd}  # fmt: skip
        if runs:
            out[legend] = worst_ratios(runs, {env: pd[env] for env in runs})
    return out


def draw_profile(root: Path, path: Path) -> None:
    """The performance profile of the learned rows over their training seeds and presets."""
    from tendon2r_gym.app.benchmark import BOOTSTRAP_SEED
    from tendon2r_gym.app.plots import plot_performance_profile
    from tendon2r_gym.evaluation.statistics import performance_profile

    rows = json.loads((root / "results" / "benchmark.json").read_text())["rows"]
    profile = performance_profile(profile_ratios(rows), seed=BOOTSTRAP_SEED)
    colors = {legend: colour for _, legend, colour in POLICIES}
    plot_performance_profile(profile, path, "Learned policies over seeds and presets", colors)


# -- the mechanism -------------------------------------------------------------------------------
@dataclass
class Drawn:
    """The compiled model's points at a pose, in the x-z plane (mm)."""

    joints: dict[str, np.ndarray]
    effector: np.ndarray
    pulleys: list[tuple[np.ndarray, float]]
    paths: list[list[np.ndarray]]


def arm_at(routing: str, pose_deg: tuple[float, float] = POSE_DEG) -> tuple[Drawn, object]:
    """Returns the default arm with ``routing``, compiled and posed, and its Mechanism."""
    import warnings

    import mujoco

    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.simulation.model import build_model

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mech = EnvConfig.make("default", mechanism={"routing": routing}).mechanism
    model = build_model(mech)
    data = mujoco.MjData(model)
    data.qpos[:2] = np.radians(pose_deg)
    mujoco.mj_forward(model, data)
    xz = lambda p: np.array([p[0], p[2]]) * 1e3  # noqa: E731
    joints = {model.joint(i).name: xz(data.xanchor[i]) for i in range(2)}
    pulleys = [(xz(data.geom(n).xpos), model.geom(n).size[0] * 1e3) for n in ("pulley1", "pulley2")]
    points, objects = data.wrap_xpos.reshape(-1, 3), data.wrap_obj.reshape(-1)
    paths = []
    for t in range(model.ntendon):
        adr, num = data.ten_wrapadr[t], data.ten_wrapnum[t]
        path: list[np.ndarray] = []
        for k in range(adr, adr + num):
            obj = objects[k]
            if obj >= 0 and path and k > adr and objects[k - 1] == obj:  # around a pulley
                centre = xz(data.geom_xpos[obj])
                path += arc(centre, path[-1], xz(points[k]))
            path.append(xz(points[k]))
        paths.append(path)
    return Drawn(joints, xz(data.site("effector").xpos), pulleys, paths), mech


def arc(centre: np.ndarray, a: np.ndarray, b: np.ndarray, n: int = 24) -> list[np.ndarray]:
    """Returns points on the shorter arc about ``centre`` from ``a`` to ``b``."""
    ta = np.arctan2(*(a - centre)[::-1])
    tb = np.arctan2(*(b - centre)[::-1])
    d = (tb - ta + np.pi) % (2 * np.pi) - np.pi
    r = 0.5 * (np.linalg.norm(a - centre) + np.linalg.norm(b - centre))
    return [centre + r * np.array([np.cos(t), np.sin(t)]) for t in ta + d * np.linspace(0, 1, n)]


TENDON_COLOURS = ("tab:red", "tab:purple", "tab:blue")


def draw_arm(ax: plt.Axes, drawn: Drawn, labels: bool) -> None:
    """Draws the wall, links, pulleys and tendon paths of an arm."""
    a, b = drawn.joints["A"], drawn.joints["B"]
    ax.plot([0, 0], [-25, 25], color="0.3", lw=4, solid_capstyle="butt")
    ax.plot([0, a[0], b[0], drawn.effector[0]], [0, a[1], b[1], drawn.effector[1]], color="0.35",
            lw=3, solid_capstyle="round", zorder=1)  # fmt: skip
    for (centre, radius), colour in zip(drawn.pulleys, ("gold", "orange"), strict=True):
        ax.add_patch(plt.Circle(centre, radius, color=colour, alpha=0.6, zorder=2))
    for t, path in enumerate(drawn.paths):
        p = np.array(path)
        ax.plot(p[:, 0], p[:, 1], color=TENDON_COLOURS[t % 3], lw=1.3, zorder=3,
                label=f"tendon {t + 1}")  # fmt: skip
    for name, point in drawn.joints.items():
        ax.plot(*point, "ko", ms=4, zorder=4)
        if labels:
            ax.annotate(f"joint {name}", point, xytext=(4, -12), textcoords="offset points")
    ax.set(aspect="equal", xlabel="x (mm)", ylabel="z (mm)")
    ax.grid(alpha=0.2)


def draw_geometry(root: Path, path: Path) -> None:
    """The default arm at POSE_DEG with its links, pulleys, angles and tendon paths named."""
    drawn, mech = arm_at("asymmetric")
    fig, ax = plt.subplots(figsize=(8, 5))
    draw_arm(ax, drawn, labels=True)
    a, b, e = drawn.joints["A"], drawn.joints["B"], drawn.effector
    mid = lambda p, q: 0.5 * (p + q)  # noqa: E731
    for text, at in (("a", mid(np.zeros(2), a)), ("c", mid(a, b)), ("b", mid(b, e))):
        ax.annotate(text, at, xytext=(-10, 6), textcoords="offset points", fontsize=13,
                    fontstyle="italic")  # fmt: skip
    for (centre, radius), name in zip(drawn.pulleys, ("R1", "R2"), strict=True):
        ax.annotate(f"{name} = {2 * radius:g} mm (diameter)", centre + [radius, -radius],
                    xytext=(6, -14), textcoords="offset points", fontsize=9)  # fmt: skip
    q1, q2 = np.radians(POSE_DEG)
    for centre, start, span, name in ((a, 0.0, q1, "q1"), (b, q1, q2, "q2")):
        ts = np.linspace(start, start + span, 30)
        r = 0.35 * mech.c * 1e3
        ax.plot(centre[0] + r * np.cos(ts), centre[1] + r * np.sin(ts), "k:", lw=1)
        ax.plot([centre[0], centre[0] + 1.3 * r * np.cos(start)],
                [centre[1], centre[1] + 1.3 * r * np.sin(start)], "k:", lw=0.8)  # fmt: skip
        tip = centre + 1.1 * r * np.array([np.cos(start + span / 2), np.sin(start + span / 2)])
        ax.annotate(name, tip, fontsize=11, fontstyle="italic")
    ax.annotate("wall (x = 0)", (0, -25), xytext=(4, -4), textcoords="offset points")
    ax.annotate("effector", e, xytext=(4, 4), textcoords="offset points")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(f"The default arm at q = ({POSE_DEG[0]:g}°, {POSE_DEG[1]:g}°), routing "
                 f"{mech.routing!r}")  # fmt: skip
    fig.tight_layout()
    save(fig, path)


def draw_routings(root: Path, path: Path) -> None:
    """One panel per named routing on the default arm at POSE_DEG, each tendon's sides."""
    from tendon2r_gym.simulation.routing import ROUTINGS

    fig, axes = plt.subplots(1, len(ROUTINGS), figsize=(3.2 * len(ROUTINGS), 3.6))
    for ax, (name, sides) in zip(axes, ROUTINGS.items(), strict=True):
        drawn, _ = arm_at(name)
        draw_arm(ax, drawn, labels=False)
        shown = ", ".join(f"({s1:+d}, {s2:+d})" if s2 else f"({s1:+d}, 0)" for s1, s2 in sides)
        ax.set_title(f"{name}\n{shown}", fontsize=10)
        ax.legend(loc="lower right", fontsize=7)
    for ax in axes:
        ax.set(xlim=(-10, 175), ylim=(-30, 130))
    fig.suptitle("The routings: each tendon's side on (pulley 1, pulley 2), +1 over, -1 under")
    fig.tight_layout()
    save(fig, path)


# -- the shipped models --------------------------------------------------------------------------
def model_inputs(name: str) -> list[str]:
    """Returns the files a model's learning curve is drawn from: its seeds' records."""
    from tendon2r_gym.artifacts.registry import shipped

    line = shipped()[name]
    base = f"tendon2r_gym/data/models/{name}"
    files = ("evaluations.json", "summary.json")
    return [f"{base}/seed_{s}/{f}" for s in line.seeds for f in files]


def draw_model(root: Path, path: Path, name: str) -> None:
    """A shipped model's RMS error per joint at each evaluation during training, one line per
    seed, with PD's on the same episodes."""
    from tendon2r_gym.artifacts.registry import shipped

    line = shipped()[name]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4), sharey=True)
    for seed in line.seeds:
        folder = root / "tendon2r_gym" / "data" / "models" / name / f"seed_{seed}"
        evals = json.loads((folder / "evaluations.json").read_text())
        summary = json.loads((folder / "summary.json").read_text())
        steps = [e["timesteps"] for e in evals]
        for j, ax in enumerate(axes):
            ax.plot(steps, [e["rms_deg"][j] for e in evals], marker=".", lw=1,
                    label=f"seed {seed}")  # fmt: skip
            if seed == line.seeds[0] and summary.get("pd_eval_rms_deg"):
                ax.axhline(summary["pd_eval_rms_deg"][j], color="0.4", ls="--", lw=1, label="PD")
    for j, ax in enumerate(axes):
        ax.set(yscale="log", title=JOINTS[j], xlabel="training steps")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("RMS error (deg)")
    axes[1].legend(fontsize=8)
    fig.suptitle(f"{name}: evaluation RMS error during training")
    fig.tight_layout()
    save(fig, path)


# -- identification ------------------------------------------------------------------------------
#: tendon2r-excite's run drawn on the identify page: the default arm, 4 s.
EXCITE = ("default", 4.0)


def draw_excitation(root: Path, path: Path) -> None:
    """What ``tendon2r-excite --env-config default --duration 4`` writes: the plan's q_des
    (plan.csv) and PD's rehearsal of it on the nominal arm (rehearsal.csv: angles, commands)."""
    from tendon2r_gym.app.excitation import design

    signal, rehearsal = design(*EXCITE)
    t = rehearsal.time
    plan = np.array([signal.q(x)[0] for x in t])
    fig, axes = plt.subplots(2, 1, figsize=(10, 5), sharex=True)
    for j in range(2):
        axes[0].plot(t, np.degrees(plan[:, j]), "k--", lw=1)
        axes[0].plot(t, np.degrees(rehearsal.q[:, j]), lw=0.9, label=f"{JOINTS[j]}")
    axes[0].set(ylabel="angle (deg)", title="plan.csv (dashed) and rehearsal.csv's angles")
    axes[0].legend(fontsize=8, loc="upper right")
    for i in range(rehearsal.command.shape[1]):
        axes[1].plot(t, rehearsal.command[:, i], lw=0.7, label=f"tendon {i + 1}")
    axes[1].set(xlabel="time (s)", ylabel="command (N)", title="rehearsal.csv's commands")
    axes[1].legend(fontsize=8, loc="upper right")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(f"tendon2r-excite --env-config {EXCITE[0]} --duration {EXCITE[1]:g}")
    fig.tight_layout()
    save(fig, path)


# -- the figures, their inputs and the manifest --------------------------------------------------
@dataclass(frozen=True)
class Figure:
    """A figure: the files it is drawn from (repository paths) and how it is drawn."""

    inputs: tuple[str, ...]
    draw: Callable[[Path, Path], None]


def figures(root: Path = ROOT) -> dict[str, Figure]:
    """Returns every figure by its path under docs/images."""
    from tendon2r_gym.artifacts.registry import shipped

    out = {
        RESULTS_FIGURE: Figure(("results/benchmark.json",), draw_results),
        PROFILE_FIGURE: Figure(
            (
                "results/benchmark.json",
                "tendon2r_gym/evaluation/statistics.py",
                "tendon2r_gym/app/plots.py",
            ),
            draw_profile,
        ),  # fmt: skip
        GEOMETRY_FIGURE: Figure(MECHANISM_INPUTS, draw_geometry),
        ROUTINGS_FIGURE: Figure(MECHANISM_INPUTS, draw_routings),
        IDENTIFY_FIGURE: Figure(
            ("tendon2r_gym/identification/excitation.py", "tendon2r_gym/data/presets/default.yaml"),
            draw_excitation,
        ),
    }
    for name in shipped():
        out[model_figure(name)] = Figure(
            tuple(model_inputs(name)),
            lambda root, path, name=name: draw_model(root, path, name),
        )
    return out


def inputs_hash(root: Path, figure: Figure) -> str:
    """Returns the hash of a figure's inputs: this script and each input file, by path."""
    digest = hashlib.sha256(Path(__file__).read_bytes())
    for name in figure.inputs:
        path = root / name
        digest.update(name.encode() + b"\0" + (path.read_bytes() if path.is_file() else b"-"))
    return digest.hexdigest()[:16]


def manifest(root: Path) -> dict[str, str]:
    path = root / "docs" / IMAGES / MANIFEST
    return json.loads(path.read_text()) if path.is_file() else {}


def stale(root: Path = ROOT) -> list[str]:
    """Returns the figures that are missing or were drawn from other inputs, and the images
    under docs/images that no figure draws."""
    done, folder = manifest(root), root / "docs" / IMAGES
    wanted = figures(root)
    out = [
        name
        for name, fig in wanted.items()
        if not (folder / name).is_file() or done.get(name) != inputs_hash(root, fig)
    ]
    out += [
        p.relative_to(folder).as_posix()
        for p in sorted(folder.rglob("*.png"))
        if p.relative_to(folder).as_posix() not in wanted
    ]
    return out


def write(root: Path = ROOT) -> list[str]:
    """Redraws the stale figures, removes the images no figure draws, records the manifest;
    returns the figures it touched."""
    folder = root / "docs" / IMAGES
    wanted = figures(root)
    touched = stale(root)
    for name in touched:
        if name in wanted:
            wanted[name].draw(root, folder / name)
            print("wrote", folder / name)
        else:
            (folder / name).unlink()
            print("removed", folder / name, file=sys.stderr)
    hashes = {name: inputs_hash(root, fig) for name, fig in wanted.items()}
    folder.mkdir(parents=True, exist_ok=True)
    manifest_text = json.dumps(hashes, indent=1, sort_keys=True) + "\n"
    if manifest(root) != hashes or not (folder / MANIFEST).is_file():
        (folder / MANIFEST).write_text(manifest_text)
        print("wrote", folder / MANIFEST)
    return touched


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "--check" in argv:
        if out := stale(ROOT):
            print("stale figures (run python scripts/gen_figures.py):", *out, sep="\n  ")
            return 1
        print("figures up to date")
        return 0
    write(ROOT)
    return 0


if __name__ == "__main__":
    sys.exit(main())

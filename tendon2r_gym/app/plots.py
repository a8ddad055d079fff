"""Figures like the reports' (matplotlib, headless) and rollout videos (imageio)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from tendon2r_gym.evaluation.rollout import Trace  # noqa: E402

JOINT_NAMES = ("joint A", "joint B")


def plot_trace(trace: Trace, out_dir: str | Path, title: str) -> list[Path]:
    """Writes tracking.png (desired vs actual and the error per joint), forces.png and
    effector_path.png for one rollout; returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t = trace.time
    fig, axes = plt.subplots(2, 2, figsize=(11, 6), sharex=True)
    for j in range(2):
        axes[0, j].plot(t, np.degrees(trace.q_des[:, j]), "k--", lw=1.2, label="desired")
        axes[0, j].plot(t, np.degrees(trace.q[:, j]), lw=1.0, label="actual")
        axes[0, j].set(title=f"{JOINT_NAMES[j]}", ylabel="angle (deg)")
        axes[0, j].legend(loc="upper right")
        axes[1, j].plot(t, trace.error_deg[:, j], color="tab:red", lw=0.8)
        rms = np.sqrt(np.mean(trace.error_deg[:, j] ** 2))
        axes[1, j].set(
            ylabel="error q_des - q (deg)",
            xlabel="time (s)",
            title=f"RMS {rms:.4f} deg, max {np.abs(trace.error_deg[:, j]).max():.4f}",
        )
    fig.suptitle(title)
    fig.tight_layout()
    paths = [out / "tracking.png"]
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(8, 3.5))
    for i in range(trace.tendon_tension.shape[1]):
        ax.plot(t, trace.tendon_tension[:, i], lw=0.9, label=f"tendon {i + 1}")
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set(xlabel="time (s)", ylabel="tension (N, > 0 pulls)", title=f"{title}: tendon tensions")
    ax.legend()
    fig.tight_layout()
    paths.append(out / "forces.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(5, 5))
    ax.plot(trace.effector_pos[:, 0] * 1e3, trace.effector_pos[:, 1] * 1e3, lw=0.8)
    ax.set(xlabel="x (mm)", ylabel="z (mm)", title=f"{title}: effector path", aspect="equal")
    fig.tight_layout()
    paths.append(out / "effector_path.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def save_video(frames: list[np.ndarray], path: str | Path, fps: int) -> Path:
    """Writes frames as mp4 (or gif, by the suffix) with imageio."""
    import imageio.v2 as imageio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".gif":
        imageio.mimsave(path, frames, duration=1000 / fps, loop=0)
    else:
        imageio.mimsave(path, frames, fps=fps, macro_block_size=1)
    return path


def plot_performance_profile(
    profile: dict,
    path: str | Path,
    title: str = "Performance profile",
    colors: dict[str, str] | None = None,
) -> Path:
    """Writes a performance profile (tendon2r_gym.evaluation.statistics.performance_profile's
    data) as a PNG: per policy, the fraction of runs whose worst-joint RMS ratio to PD is <=
    tau, against tau on a log axis, with its bootstrap band; PD's own ratio (tau = 1) marked.
    ``colors``: a matplotlib colour per policy (default: the colour cycle's).  The file's
    bytes depend only on the data (no software version in its metadata)."""
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tau = np.asarray(profile["tau"], dtype=float)
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for policy, curve in profile["curves"].items():
        (line,) = ax.step(tau, curve["fraction"], where="post", lw=1.4,
                          color=(colors or {}).get(policy),
                          label=f"{policy} ({curve['runs']} runs)")  # fmt: skip
        if curve.get("low") is not None:
            ax.fill_between(tau, curve["low"], curve["high"], step="post", alpha=0.2,
                            color=line.get_color(), lw=0)  # fmt: skip
    ax.axvline(1.0, color="k", lw=0.6, ls=":")
    confidence = profile.get("confidence")
    band = f", {confidence:.0%} bootstrap bands" if confidence is not None else ""
    ax.set(xscale="log", ylim=(-0.02, 1.02), title=f"{title}{band}",
           xlabel="tau: worst-joint RMS / PD's", ylabel="fraction of runs <= tau")  # fmt: skip
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata={"Software": None})
    plt.close(fig)
    return path

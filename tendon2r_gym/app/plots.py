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

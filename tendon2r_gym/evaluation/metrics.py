"""Tracking metrics over rollouts: what the reports measured, per joint."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from tendon2r_gym.evaluation.rollout import Trace

SATURATION = 0.999  # |normalized command| at or above this counts as saturated
#: The reset's transient (s): ``settled_rms_deg`` is the RMS error after this much of each
#: episode, once the reset's noise (reset_noise_scale) has been closed.  At a millidegree, the
#: first steps after a reset can make most of an episode's RMS.
SETTLE_S = 0.02


def settled(trace: Trace) -> np.ndarray:
    """Returns which steps of an episode come after its first SETTLE_S (the reset's
    transient)."""
    return trace.time > trace.time[0] + SETTLE_S


def beats(rms_deg: Sequence[float], baseline_rms_deg: Sequence[float]) -> bool:
    """Returns whether a policy's RMS error is <= the baseline's on every joint (the
    project's "beats PD")."""
    return all(p <= d for p, d in zip(rms_deg, baseline_rms_deg, strict=True))


def worst_ratio(rms_deg: Sequence[float], baseline_rms_deg: Sequence[float]) -> float:
    """Returns the larger of the joints' RMS errors as a multiple of the baseline's (<= 1:
    `beats` the baseline)."""
    return float(max(r / b for r, b in zip(rms_deg, baseline_rms_deg, strict=True)))


def rms_ratio(values: Sequence[float], baseline: Sequence[float]) -> float:
    """Returns the RMS over entries (tendons) of ``values`` divided by the baseline's."""
    return float(np.sqrt(np.mean(np.square(values))) / np.sqrt(np.mean(np.square(baseline))))


#: Smoothness limits of a learned policy against PD on the same episodes ("Learning that
#: holds"): its RMS tension at most TENSION_LIMIT_X_PD times PD's, and its RMS tension rate at
#: most RATE_LIMIT_X_PD times PD's, for a residual on PD and for plain PPO.
TENSION_LIMIT_X_PD = 1.5
RATE_LIMIT_X_PD = {"residual": 3.0, "plain": 10.0}


def smoothness_x_pd(row: dict[str, Any], pd_row: dict[str, Any]) -> tuple[float, float]:
    """Returns a policy's RMS tension and RMS tension rate as multiples of PD's (two
    `tracking_metrics` results on the same episodes)."""
    return (
        rms_ratio(row["rms_tension_N"], pd_row["rms_tension_N"]),
        rms_ratio(row["rms_tension_rate_N_per_s"], pd_row["rms_tension_rate_N_per_s"]),
    )


def smooth_enough(row: dict[str, Any], pd_row: dict[str, Any], residual: bool) -> bool:
    """Returns whether a policy keeps the smoothness limits against PD's (TENSION_LIMIT_X_PD,
    RATE_LIMIT_X_PD of a residual on PD or of plain PPO)."""
    return within_limits(*smoothness_x_pd(row, pd_row), residual)


def within_limits(tension_x_pd: float, rate_x_pd: float, residual: bool) -> bool:
    """Returns whether RMS tension and tension rate, as multiples of PD's, keep the limits
    (TENSION_LIMIT_X_PD, RATE_LIMIT_X_PD of a residual on PD or of plain PPO)."""
    limit = RATE_LIMIT_X_PD["residual" if residual else "plain"]
    return tension_x_pd <= TENSION_LIMIT_X_PD and rate_x_pd <= limit


def selection_rank(evaluation: dict[str, Any]) -> tuple[int, float]:
    """Ranks a training evaluation (an evaluations.json row: ``rms_deg``, ``beats_pd``,
    ``within_limits``) for the best model, lower first: the evaluations <= PD on both joints
    within the smoothness limits, then the rest; within each, by mean RMS error over the
    joints.  A policy whose tensions chatter is kept only while no smooth one beats PD."""
    ok = evaluation["beats_pd"] and evaluation.get("within_limits", False)
    return (0 if ok else 1, float(np.mean(evaluation["rms_deg"])))


def tracking_metrics(traces: Sequence[Trace]) -> dict[str, list[float] | float | int]:
    """Returns per-joint RMS and max error (deg), per-tendon RMS, peak and least tension (N),
    the RMS rate of change of each tension (N/s, smoothness), the steps with a negative
    (pushing) tension and the fraction of saturated steps, over all steps of all episodes,
    plus per-episode RMS errors and the RMS error after each episode's first SETTLE_S."""
    err = np.concatenate([t.error_deg for t in traces])
    after = np.concatenate([t.error_deg[settled(t)] for t in traces])
    tension = np.concatenate([t.tendon_tension for t in traces])
    action = np.concatenate([t.action for t in traces])
    per_episode = np.array([np.sqrt(np.mean(t.error_deg**2, axis=0)) for t in traces])
    # Smoothness: how fast each tension changes (N/s, so that it does not depend on ctrl_dt).
    rate = np.concatenate(
        [np.diff(t.tendon_tension, axis=0) / np.diff(t.time)[:, None] for t in traces]
    )
    return {
        "rms_deg": np.sqrt(np.mean(err**2, axis=0)).tolist(),
        "max_deg": np.max(np.abs(err), axis=0).tolist(),
        "settled_rms_deg": np.sqrt(np.mean(after**2, axis=0)).tolist(),
        "rms_tension_N": np.sqrt(np.mean(tension**2, axis=0)).tolist(),
        "max_tension_N": np.max(np.abs(tension), axis=0).tolist(),
        "min_tension_N": np.min(tension, axis=0).tolist(),
        "rms_tension_rate_N_per_s": np.sqrt(np.mean(rate**2, axis=0)).tolist(),
        "negative_tension_steps": int(np.sum(np.any(tension < 0, axis=1))),
        "saturated_fraction": np.mean(np.abs(action) >= SATURATION, axis=0).tolist(),
        "episode_rms_deg_mean": per_episode.mean(axis=0).tolist(),
        "episode_rms_deg_std": per_episode.std(axis=0).tolist(),
        "episodes": len(traces),
        "steps": int(err.shape[0]),
        "diverged_episodes": int(sum(t.diverged for t in traces)),
        "seeds": [t.seed for t in traces],
    }

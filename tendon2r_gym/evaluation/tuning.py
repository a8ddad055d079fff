"""PD tuning that any user can run on their own arm: a scan of the closed-loop bandwidth.

PD's gains (tendon2r_gym.task.gains) are closed-loop quantities that carry over between ideal
arms, but a real arm's motor lag and delays (tendon2r_gym.simulation.realism) take phase out of the
loop:
the default 30 Hz bandwidth can then oscillate or diverge.  `tune_pd` rolls PD out at
each bandwidth of a geometric grid through the default one (ratio GRID_RATIO, from
MIN_BANDWIDTH_HZ up to the cap ``max_bandwidth_fraction / ctrl_dt``) on held-out episodes
(seeds TUNE_SEED, ... : never the evaluation's 0, 1, 2) and keeps the bandwidth whose worst
episode, and the next grid point's, has the least worst-joint RMS error: a gain margin of one
grid step, so that the chosen gains are not on the edge of instability.  On an env that draws
arms (``mechanism_ranges``) the episodes draw different arms, so the gains hold across them.

``scan="max_delay_phase"`` scans instead the phase that each arm's loop delay may take at its
bandwidth (tendon2r_gym.task.gains: gains scheduled on the known delays), on a geometric grid of
the same ratio from MIN_DELAY_PHASE to MAX_DELAY_PHASE rad, with the bandwidth at the cap of
the control rate, so that the phase alone sets each arm's bandwidth below it.

``tendon2r-tune-pd --env-config my_arm.yaml --out my_arm_tuned.yaml`` writes the experiment
file with the tuned ``pd_gains``; PD, CT and a residual trained on that file use them.

Each grid point's episodes are one job (``scan_point``) of an executor
(tendon2r_gym.training.executors: ``tendon2r-tune-pd --workers N`` or ``--cluster``): a point
depends only on its gains and its seeds, so the scan is the same on every executor.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from tendon2r_gym.envs.env_config import EnvConfig, resolve
from tendon2r_gym.evaluation.evaluator import evaluate
from tendon2r_gym.evaluation.metrics import tracking_metrics
from tendon2r_gym.task.gains import Gains, default_gains, gains_of
from tendon2r_gym.validation import invalid

#: Ratio of neighbouring bandwidths on the grid (and the gain margin the choice keeps).
GRID_RATIO = 1.25
#: The lowest bandwidth scanned (Hz): slower than the course's slowest reference is useless.
MIN_BANDWIDTH_HZ = 4.0
#: The delay phases scanned (rad): from a tenth of a radian up to where a loop with a delay
#: has no phase margin left (pi / 2 for a PD's lead at most, taken by the delay alone).
MIN_DELAY_PHASE, MAX_DELAY_PHASE = 0.1, math.pi / 2
#: What tune_pd can scan.
SCANS = ("bandwidth_hz", "max_delay_phase")
#: First seed of the tuning episodes (the benchmark evaluates on seeds 0, 1, 2).
TUNE_SEED = 1000


@dataclass(frozen=True)
class Scan:
    """The worst-joint RMS error (deg) of each episode at each value of the scanned gain
    (``field``: bandwidth_hz in Hz, or max_delay_phase in rad), and the choice."""

    field: str
    values: tuple[float, ...]
    worst_deg: tuple[tuple[float, ...], ...]  # [value][episode]
    chosen: float
    gains: Gains

    def lines(self) -> list[str]:
        """Returns the scan as a small table, the chosen value marked."""
        out = [f"{self.field} | worst episode's worst-joint RMS (deg)"]
        for value, worst in zip(self.values, self.worst_deg, strict=True):
            mark = "  <- chosen" if value == self.chosen else ""
            out.append(f"{value:{len(self.field)}.4g} | {max(worst):.4f}{mark}")
        return out


def bandwidth_grid(config: EnvConfig) -> list[float]:
    """Returns the scanned bandwidths (Hz): the package default's (data/pd.yaml) times
    GRID_RATIO^k, from MIN_BANDWIDTH_HZ up to the cap of the control rate (the env's
    ``max_bandwidth_fraction`` / ctrl_dt).  The same grid whatever the env's own bandwidth,
    so that tuning a tuned file finds the same gains."""
    cap = gains_of(config.pd_gains).max_bandwidth_fraction / config.ctrl_dt
    base = min(default_gains().bandwidth_hz, cap)
    lo = math.ceil(math.log(MIN_BANDWIDTH_HZ / base, GRID_RATIO) - 1e-9)
    hi = math.floor(math.log(cap / base, GRID_RATIO) + 1e-9)
    return [round(base * GRID_RATIO**k, 6) for k in range(lo, hi + 1)]


def delay_phase_grid() -> list[float]:
    """Returns the scanned delay phases (rad): MIN_DELAY_PHASE times GRID_RATIO^k up to
    MAX_DELAY_PHASE."""
    n = math.floor(math.log(MAX_DELAY_PHASE / MIN_DELAY_PHASE, GRID_RATIO) + 1e-9)
    return [round(MIN_DELAY_PHASE * GRID_RATIO**k, 6) for k in range(n + 1)]


@dataclass(frozen=True)
class ScanPoint:
    """One job of a scan: PD on ``config`` (the env's, the point's gains set) over ``seeds``.
    The config is resolved: a node that cannot see the experiment file (a Ray cluster) runs
    it as it is."""

    config: EnvConfig
    seeds: tuple[int, ...]


def scan_point(job: ScanPoint) -> tuple[float, ...]:
    """An executor's job: the worst-joint RMS error (deg) of each of ``job.seeds``'s episodes
    of PD on ``job.config``."""
    _, traces = evaluate("pd", job.config, list(job.seeds))
    return tuple(max(tracking_metrics([t])["rms_deg"]) for t in traces)


def tune_pd(
    env: EnvConfig | Mapping[str, Any],
    episodes: int = 3,
    scan: str = "bandwidth_hz",
    executor: Any = None,
) -> Scan:
    """Scans PD's ``scan`` gain (one of SCANS) on ``episodes`` held-out episodes of the env
    ``env`` (an EnvConfig, or env kwargs: resolved once; see the module docstring) and
    returns the scan with the chosen gains (the env's others kept).  ``executor``: runs each
    grid point as one job (tendon2r_gym.training.executors; None: one after another in this
    process); the scan is the same on every executor."""
    if scan not in SCANS:
        raise invalid("scan", scan, f"one of {SCANS}")
    config = resolve(env)
    if config.mechanism_ranges is not None and config.mechanism_ranges.draws_gains:
        raise invalid(
            "mechanism_ranges",
            config.mechanism_ranges.to_dict(),
            "ranges that leave PD's gains alone: they are drawn per episode here, so a scan "
            "would not set them",
        )
    base = gains_of(config.pd_gains).to_dict()
    if scan == "bandwidth_hz":
        grid = bandwidth_grid(config)
    else:  # the phase alone sets the bandwidth, below the control rate's cap
        grid = delay_phase_grid()
        base["bandwidth_hz"] = max(bandwidth_grid(config))
    seeds = tuple(range(TUNE_SEED, TUNE_SEED + episodes))
    jobs = [ScanPoint(replace(config, pd_gains=gains_of({**base, scan: value})), seeds)
            for value in grid]  # fmt: skip
    if executor is None:
        worst = [scan_point(job) for job in jobs]
    else:
        worst = executor.map(scan_point, jobs, [f"{scan} {value:g}" for value in grid])
    # The next grid point must hold too (the last one is the cap: nothing above it).
    score = [max(*w, *(worst[i + 1] if i + 1 < len(worst) else w)) for i, w in enumerate(worst)]
    best = min(range(len(grid)), key=score.__getitem__)
    gains = Gains.from_dict({**base, scan: grid[best]})
    return Scan(scan, tuple(grid), tuple(worst), grid[best], gains)

"""Results that carry their uncertainty: the interquartile mean (IQM) of runs with a stratified
bootstrap interval, the probability of beating PD, and performance profiles (Agarwal et al.
2021, "Deep RL at the edge of the statistical precipice").  No torch; scipy (the ``train``
extra) is imported by the functions that bootstrap.

Conventions:

- A run's score is one number per joint (its RMS tracking error, deg).  ``runs`` is a list of
  runs (one stratum: the seeds of one arm), or a mapping stratum -> runs (an arm or a task ->
  its seeds).  Every run has the same joints.
- IQM: per joint, the mean of the runs left after dropping the ``n // 4`` lowest and the
  ``n // 4`` highest of the ``n`` pooled runs (``scipy.stats.trim_mean(x, 0.25)``, the paper's
  and rliable's convention): exactly the middle 50% when ``n`` is a multiple of 4, a little
  more otherwise (``n = 10``: the middle 6), and the plain mean below 4 runs.
- Intervals: the percentile bootstrap of ``scipy.stats.bootstrap`` (``method="percentile"``,
  as the paper), stratified: each stratum is resampled within itself with its own number of
  runs, and the statistic is taken on the pooled resample.  A run's joints are resampled
  together.  Reproducible from ``seed`` (``numpy.random.default_rng(seed)``).  A stratum needs
  2 or more runs (one run does not vary under resampling: pool single runs as one stratum).
- Mean +- std: ddof 0, as the project reports elsewhere.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from statistics import NormalDist
from typing import Any

import numpy as np

from tendon2r_gym.evaluation.metrics import beats, worst_ratio
from tendon2r_gym.validation import integer, invalid, number

#: Below this many runs an interval is wide and rough (`few_runs_note`).
MIN_RUNS = 5
CONFIDENCE = 0.95
N_RESAMPLES = 9999
#: Resamples drawn at once: bounds the memory of a large study, and fixes the order of the
#: random draws (with several strata, a result depends on it).
BATCH = 1000

Runs = Sequence[Sequence[float]] | Mapping[str, Sequence[Sequence[float]]]


@dataclass(frozen=True)
class Estimate:
    """A statistic per joint (or per threshold) with its interval."""

    value: list[float]
    low: list[float]
    high: list[float]

    def pairs(self) -> list[list[float]]:
        """Returns ``[[low, high], ...]``, one pair per joint."""
        return [[lo, hi] for lo, hi in zip(self.low, self.high, strict=True)]


# -- input ------------------------------------------------------------------------------------
def _scores(field: str, run: Any) -> np.ndarray:
    """Returns one run's per-joint scores as a 1-D float array, or raises naming ``field``."""
    allowed = "a run: a finite number per joint (a list of them)"
    try:
        values = np.atleast_1d(np.asarray(run, dtype=float))
    except (TypeError, ValueError):
        raise invalid(field, run, allowed) from None
    if values.ndim != 1 or values.size == 0:
        raise invalid(field, run, allowed)
    for j, v in enumerate(values):
        if not math.isfinite(v):
            raise invalid(f"{field}[{j}]", float(v), "a finite number")
    return values


def _stratum(field: str, runs: Any, joints: int | None) -> np.ndarray:
    """Returns one stratum's runs as an array (runs, joints), or raises naming ``field``."""
    if isinstance(runs, (str, bytes, Mapping)) or not hasattr(runs, "__len__") or not len(runs):
        raise invalid(field, runs, "a non-empty list of runs, each a list of per-joint scores")
    rows = []
    for i, run in enumerate(runs):
        values = _scores(f"{field}[{i}]", run)
        joints = values.size if joints is None else joints
        if values.size != joints:
            raise invalid(
                f"{field}[{i}]", values.tolist(), f"{joints} per-joint scores, as the first run has"
            )
        rows.append(values)
    return np.stack(rows)


def strata(runs: Runs, field: str = "runs", min_runs: int = 1) -> dict[str, np.ndarray]:
    """Returns ``runs`` as stratum name -> array (runs, joints) (a plain list: one stratum,
    ``""``), every run with the same joints and each stratum with at least ``min_runs`` runs;
    raises a ValueError naming the field, the value and what is allowed."""
    if isinstance(runs, Mapping):
        if not runs:
            raise invalid(field, dict(runs), "a non-empty mapping stratum -> runs")
        named = {str(k): v for k, v in runs.items()}
        fields = {k: f"{field}[{k!r}]" for k in named}
    else:
        named, fields = {"": runs}, {"": field}
    out: dict[str, np.ndarray] = {}
    joints = None
    for name, stratum in named.items():
        out[name] = _stratum(fields[name], stratum, joints)
        joints = out[name].shape[1]
        if len(out[name]) < min_runs:
            raise invalid(
                fields[name],
                out[name].tolist(),
                f"{min_runs} or more runs in each stratum (one run does not vary under the "
                "bootstrap: pool single runs as one stratum)",
            )
    return out


def _options(seed: int, confidence: float, n_resamples: int) -> None:
    integer("seed", seed, 0, 2**63 - 1)
    number("confidence", confidence, 0.0, 1.0, lo_open=True, hi_open=True)
    integer("n_resamples", n_resamples, 1, 10**7)


# -- statistics -------------------------------------------------------------------------------
def iqm(scores: Any, axis: int = 0) -> np.ndarray:
    """Returns the interquartile mean along ``axis``: the mean after dropping the ``n // 4``
    lowest and ``n // 4`` highest values (``scipy.stats.trim_mean(scores, 0.25, axis)``)."""
    x = np.sort(np.asarray(scores, dtype=float), axis=axis)
    n = x.shape[axis]
    if n == 0:
        raise invalid("scores", x.tolist(), "one or more scores along the axis")
    cut = n // 4
    return np.take(x, np.arange(cut, n - cut), axis=axis).mean(axis=axis)


def bootstrap(
    samples: Sequence[np.ndarray],
    statistic: Callable[[np.ndarray], np.ndarray],
    seed: int = 0,
    confidence: float = CONFIDENCE,
    n_resamples: int = N_RESAMPLES,
) -> tuple[np.ndarray, np.ndarray]:
    """Returns the stratified percentile bootstrap interval (low, high) of ``statistic`` (of
    an array (..., runs), reducing its last axis) on the pooled runs of ``samples`` (one array
    (runs, ...) per stratum, each resampled within itself), with scipy.stats.bootstrap."""
    from scipy import stats

    def pooled(*resampled: np.ndarray, axis: int = -1) -> np.ndarray:
        return statistic(np.moveaxis(np.concatenate(resampled, axis=axis), axis, -1))

    rng = np.random.default_rng(seed)
    # scipy >= 1.15 takes ``rng``; older versions ``random_state`` (a Generator in both)
    key = "rng" if "rng" in inspect.signature(stats.bootstrap).parameters else "random_state"
    result = stats.bootstrap(
        tuple(samples),
        pooled,
        n_resamples=n_resamples,
        batch=BATCH,
        vectorized=True,
        axis=0,
        confidence_level=confidence,
        method="percentile",
        **{key: rng},
    )
    low, high = result.confidence_interval
    return np.asarray(low, dtype=float), np.asarray(high, dtype=float)


def iqm_interval(
    runs: Runs,
    seed: int = 0,
    confidence: float = CONFIDENCE,
    n_resamples: int = N_RESAMPLES,
) -> Estimate:
    """Returns the IQM of the pooled runs per joint with its stratified bootstrap interval."""
    _options(seed, confidence, n_resamples)
    samples = list(strata(runs, min_runs=2).values())
    value = iqm(np.concatenate(samples), axis=0)
    low, high = bootstrap(samples, lambda x: iqm(x, axis=-1), seed, confidence, n_resamples)
    return Estimate(value.tolist(), low.tolist(), high.tolist())


def mean_std(runs: Runs) -> tuple[list[float], list[float]]:
    """Returns the mean and the standard deviation (ddof 0) of the pooled runs, per joint."""
    pooled = np.concatenate(list(strata(runs).values()))
    return pooled.mean(axis=0).tolist(), pooled.std(axis=0).tolist()


def wilson(wins: int, trials: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Returns the Wilson score interval of a share ``wins / trials``."""
    integer("trials", trials, 1, 10**12)
    integer("wins", wins, 0, trials)
    number("confidence", confidence, 0.0, 1.0, lo_open=True, hi_open=True)
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    p, n = wins / trials, trials
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    low = 0.0 if wins == 0 else max(0.0, centre - half)
    high = 1.0 if wins == trials else min(1.0, centre + half)
    return low, high


def _baselines(baseline: Any, groups: dict[str, np.ndarray], field: str) -> dict[str, np.ndarray]:
    """Returns the baseline's per-joint scores for each stratum of ``groups``: one for all (a
    list) or one per stratum (a mapping with the same names)."""
    joints = next(iter(groups.values())).shape[1]
    if isinstance(baseline, Mapping):
        named = {str(k): v for k, v in baseline.items()}
        if set(named) != set(groups):
            raise invalid(field, sorted(named), f"one baseline per stratum: {sorted(groups)}")
        fields = {k: f"{field}[{k!r}]" for k in named}
    else:
        named = {k: baseline for k in groups}
        fields = dict.fromkeys(groups, field)
    out = {}
    for name, values in named.items():
        scores = _scores(fields[name], values)
        if scores.size != joints or not np.all(scores > 0):
            raise invalid(fields[name], scores.tolist(), f"{joints} per-joint scores, each > 0")
        out[name] = scores
    return out


def beat_probability(runs: Runs, baseline: Any, confidence: float = CONFIDENCE) -> dict[str, Any]:
    """Returns the probability of beating PD: the share of (arm, seed) pairs whose score is <=
    the baseline's on every joint (tendon2r_gym.evaluation.metrics.beats), with its Wilson score
    interval over the pairs (taken as independent trials; unlike a bootstrap, it does not
    collapse to a point when every pair wins or every pair loses).  ``baseline``: PD's
    per-joint scores, one list for all runs or a mapping stratum -> list (each arm's PD).

    Returns ``{"share", "low", "high", "wins", "pairs", "interval": "wilson"}``."""
    groups = strata(runs)
    pd = _baselines(baseline, groups, "baseline")
    wins = sum(beats(run, pd[name]) for name, rows in groups.items() for run in rows)
    pairs = sum(len(rows) for rows in groups.values())
    low, high = wilson(wins, pairs, confidence)
    share = {"share": wins / pairs, "low": low, "high": high}
    return {**share, "wins": wins, "pairs": pairs, "interval": "wilson"}


def worst_ratios(runs: Runs, baseline: Any) -> dict[str, list[float]]:
    """Returns, per stratum, each run's worst-joint ratio to the baseline (PD):
    tendon2r_gym.evaluation.metrics.worst_ratio (<= 1: the run beats it)."""
    groups = strata(runs)
    pd = _baselines(baseline, groups, "baseline")
    return {k: [worst_ratio(run, pd[k]) for run in rows] for k, rows in groups.items()}


def _ratios(field: str, ratios: Any) -> list[np.ndarray]:
    """Returns a policy's ratios (a list, or a mapping stratum -> list) as one array per
    stratum, each ratio a finite number > 0, at least 2 per stratum."""
    if isinstance(ratios, Mapping):
        named = {f"{field}[{k!r}]": v for k, v in ratios.items()}
    else:
        named = {field: ratios}
    if not named:
        raise invalid(field, dict(ratios), "a non-empty mapping stratum -> ratios")
    out = []
    for at, values in named.items():
        if not isinstance(values, (list, tuple, np.ndarray)) or len(values) < 2:
            raise invalid(at, values, "a list of 2 or more ratios > 0 (a run's RMS over PD's)")
        out.append(
            np.array([number(f"{at}[{i}]", v, 0.0, lo_open=True) for i, v in enumerate(values)])
        )
    return out


def default_taus(ratios: Sequence[np.ndarray], points: int = 101) -> np.ndarray:
    """Returns thresholds spaced evenly in log from the smallest ratio to the largest (both
    included, so that every curve reaches 1), with 1 (PD's own) among them."""
    pooled = np.concatenate(ratios)
    lo, hi = min(pooled.min(), 1.0), max(pooled.max(), 1.0)
    return np.unique(np.concatenate([np.geomspace(lo, hi, points), pooled, [1.0]]))


def performance_profile(
    ratios: Mapping[str, Any],
    taus: Sequence[float] | None = None,
    seed: int = 0,
    confidence: float = CONFIDENCE,
    n_resamples: int = N_RESAMPLES,
) -> dict[str, Any]:
    """Returns performance-profile data: per policy, for each threshold tau, the fraction of
    its runs whose worst-joint RMS ratio to PD (`worst_ratios`) is <= tau, with a
    stratified bootstrap band (pointwise percentile intervals; each is non-decreasing in tau).
    ``ratios``: policy -> its runs' ratios (a list, or a mapping stratum -> list).  ``taus``:
    default `default_taus` over every policy's ratios.

    Returns ``{"tau": [...], "curves": {policy: {"fraction", "low", "high", "runs"}},
    "confidence": ...}``."""
    _options(seed, confidence, n_resamples)
    if not isinstance(ratios, Mapping) or not ratios:
        raise invalid("ratios", ratios, "a non-empty mapping policy -> its runs' ratios to PD")
    samples = {str(p): _ratios(f"ratios[{p!r}]", r) for p, r in ratios.items()}
    if taus is None:
        grid = default_taus([s for group in samples.values() for s in group])
    else:
        grid = np.asarray([number(f"taus[{i}]", t, 0.0, lo_open=True) for i, t in enumerate(taus)])
        if grid.size == 0 or np.any(np.diff(grid) <= 0):
            raise invalid("taus", list(taus), "a non-empty increasing list of numbers > 0")
    curves = {}
    for policy, groups in samples.items():
        hits = [(g[:, None] <= grid[None, :]).astype(float) for g in groups]  # (runs, taus)
        fraction = np.concatenate(hits).mean(axis=0)
        low, high = bootstrap(hits, lambda x: x.mean(axis=-1), seed, confidence, n_resamples)
        curves[policy] = {
            "fraction": fraction.tolist(),
            "low": low.tolist(),
            "high": high.tolist(),
            "runs": int(sum(g.size for g in groups)),
        }
    return {"tau": grid.tolist(), "curves": curves, "confidence": confidence}


def few_runs_note(runs: int, what: str = "the interval") -> str | None:
    """Returns a short sentence for a figure that rests on fewer than MIN_RUNS runs (its
    interval is wide, and why), or None from MIN_RUNS runs on."""
    integer("runs", runs, 0, 10**12)
    if runs >= MIN_RUNS:
        return None
    return (
        f"{runs} run{'' if runs == 1 else 's'}: {what} is wide; a bootstrap over so few runs "
        f"has few distinct resamples, and it needs {MIN_RUNS} or more runs to mean much"
    )


def summary(
    runs: Runs,
    baseline: Any = None,
    seed: int = 0,
    confidence: float = CONFIDENCE,
    n_resamples: int = N_RESAMPLES,
) -> dict[str, Any]:
    """Returns, as plain data, the runs' per-joint IQM with its interval and mean +- std, and
    with ``baseline`` (PD's per-joint scores) the probability of beating it and each run's
    worst-joint ratio to it::

        {"runs", "strata", "confidence", "iqm", "iqm_ci", "mean", "std",
         "beats_baseline": {...} (beat_probability), "worst_ratio": [...],
         "bootstrap": {"method", "n_resamples", "seed"}, "note": str | None}
    """
    groups = strata(runs, min_runs=2)
    estimate = iqm_interval(groups, seed, confidence, n_resamples)
    mean, std = mean_std(groups)
    n = sum(len(g) for g in groups.values())
    out: dict[str, Any] = {
        "runs": n,
        "strata": len(groups),
        "confidence": confidence,
        "iqm": estimate.value,
        "iqm_ci": estimate.pairs(),
        "mean": mean,
        "std": std,
    }
    if baseline is not None:
        out["beats_baseline"] = beat_probability(groups, baseline, confidence)
        out["worst_ratio"] = [r for rs in worst_ratios(groups, baseline).values() for r in rs]
    method = "percentile, stratified" if len(groups) > 1 else "percentile"
    out["bootstrap"] = {"method": method, "n_resamples": n_resamples, "seed": seed}
    out["note"] = few_runs_note(n)
    return out

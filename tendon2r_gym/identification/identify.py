"""Identify an arm's realism fields from recordings, with ``mujoco.sysid``'s least squares.

The fit (tendon2r_gym.identification.fit) replays short pieces of the recordings on candidate
arms, and tendon2r_gym.identification.problem fits the fields to them with the toolbox's
box-constrained Gauss-Newton (``mujoco.sysid.optimize``).  This module chooses the fields,
finds where to start and the loop delay, and judges each result:

- each field's 95% interval is the cluster-robust one (one cluster per piece:
  fit.cluster_covariance), t-distributed with (pieces - fields) degrees of freedom, and
  simultaneous: the fields' intervals hold their true values together with 95% probability
  (Bonferroni: each at 1 - 0.05 / fields), since a user reads them together;
- a field is *identified* if that interval is within ``IDENTIFIED_WITHIN`` of its value and the
  value is off its bounds and off the integrator's limit (EDGE_STEP); otherwise it is
  flagged, and the identified arm keeps its nominal value unless the interval excludes it
  (then the fit is the better guess, and the arm takes it);
- the delays: commands and angles show only the loop delay, ``motor_delay +
  observation_delay`` (a command held back d steps and a measurement d steps late move the
  replay alike), found in whole control steps by the least fitted residual.  Each delay's fit
  starts from the coarse start (the best point of GRID: far from the truth, Gauss-Newton
  lands in another basin), and again from the nominal values or another delay's fit where
  one of them fits that delay better than the first fit (the fields absorb a wrong delay, and
  a fit started there may stay in its basin); the best fit is kept.  A neighbouring
  delay, fitted too, is told apart if it leaves larger residuals on the pieces (a one-sided
  paired t-test over them at 95%); the delay is identified if every neighbour is.  The fields
  are fitted at the best delay either way, and their intervals hold their fits at each delay
  not told apart.  A delay left out of ``fit`` is known and keeps its nominal value, the
  other taking the rest of the loop delay; with both fitted, the identified arm splits it
  evenly (``motor_delay`` takes an odd step).  PD tuning sees only the loop; the realism
  residuals observe each delay.  A delay that some contiguous block of the pieces fits best
  is not told apart either (tendon2r_gym.identification.holdout.fold_delays), and each delay
  not told apart has its fields' fit reported;
- the fit is checked on held-out pieces (tendon2r_gym.identification.holdout): a field's
  interval is widened to hold its fits on the folds, and every field is flagged where the
  held-out pieces' residual is far above the in-sample one (the model misses something);
- ``motor_mass`` and ``motor_tau`` are both flagged where their fits' correlation is beyond
  MASS_LAG_CORRELATION: the fit cannot tell the mass from the lag.
"""

from __future__ import annotations

import itertools
import math
import os
import time
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.envs.timing import Timing
from tendon2r_gym.identification import recording
from tendon2r_gym.identification.fit import (
    ANGLE_UNIT,
    PIECE_S,
    Pieces,
    cluster_covariance,
)
from tendon2r_gym.identification.holdout import Holdout, cross_validate, fold_delays
from tendon2r_gym.identification.problem import (
    EDGE_STEP,
    MAX_DELAY_S,
    ROUNDS,
    STAGES,
    XTOL,
    Problem,
    Stage,
    bounds,
)
from tendon2r_gym.identification.recording import Recording
from tendon2r_gym.identification.result import FIELDS, Estimate, Identification
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.validation import integer, invalid

#: The delays: whole control steps, identified as their sum.
DELAYS = ("motor_delay", "observation_delay")
#: The fields fitted by default.  ``motor_mass`` among them: it is a guess on a real arm, and
#: left out while off it shifts the others.  Measured on real_arm with its nominal motor mass
#: 35% low and a 2 ms motor delay (5 s of the excitation): without it, the cable stiffness
#: ended on its bound, the lag 52% long (flagged) and the loop delay a step short (flagged);
#: with it, every field within 2% and the delay right, the mass's fit correlated -0.20 with
#: the lag's.  Where the two cannot be told apart, both are flagged (MASS_LAG_CORRELATION).
DEFAULT_FIT = (
    "tendon_elasticity",
    "tendon_damping",
    "tendon_friction",
    "motor_tau",
    "motor_mass",
    "motor_delay",
    "observation_delay",
    "density_scale",
    "extra_joint_damping",
)
#: A field is identified if its 95% interval's half-width is within this fraction of it.
IDENTIFIED_WITHIN = 0.1
#: The motor mass and lag are flagged, as not told apart, beyond this correlation of their
#: fits (cluster-robust covariance).
MASS_LAG_CORRELATION = 0.95
#: The coarse start: about this many pieces, spread over the recordings, on which a grid of
#: the fields that dominate the replay far from the truth is tried (multiples of their
#: nominal values, within their bounds).  Dry friction several times too high sticks the
#: cables, a mass twice too light doubles every acceleration: from there Gauss-Newton lands
#: in another basin, with the lag and the stiffness absorbing the miss.
COARSE_PIECES = 10
GRID = {
    "density_scale": (0.5, 0.7, 1.0, 1.4, 2.0, 2.8),
    "tendon_friction": (0.2, 0.5, 1.0, 2.0, 5.0),
}


def load_recordings(paths: Sequence[str | os.PathLike], config: EnvConfig) -> list[Recording]:
    """Reads and checks each recording against the arm of ``config`` (identify checks that
    together they are long enough)."""
    mech = config.mechanism
    force = float(mech.max_tendon_force)
    return [recording.load(p, mech.n_tendons, config.ctrl_dt, force, mech.pull_only) for p in paths]


def check_pieces(recs: Sequence[Recording], config: EnvConfig, n_fields: int, first: int) -> None:
    """Raises a ValueError naming the recordings if a stage of the fit would have fewer pieces
    than the fitted fields and two more (their intervals would have no degrees of freedom)."""
    for stage in STAGES:
        pieces = Pieces(list(recs), config.ctrl_dt, 0, stage.piece_s, stage.spacing_s, first)
        if len(pieces) < n_fields + 2:
            need = first * config.ctrl_dt + (n_fields + 2) * stage.spacing_s
            raise ValueError(
                f"recording {', '.join(r.source for r in recs)}: too short to fit {n_fields} "
                f"field{'s' * (n_fields != 1)}; they give {len(pieces)} pieces of "
                f"{stage.piece_s} s every {stage.spacing_s} s, and the fit needs {n_fields + 2} "
                f"(about {need:.3g} s of recording; 10 s of tendon2r-excite's excitation is plenty)"
            )


def _worse(other: np.ndarray, best: np.ndarray) -> bool:
    """Whether the pieces' fitted residuals at another delay (``other``, per piece) are
    larger than at the best one: a one-sided paired t-test over the pieces at 95% (the
    pieces are independent; the rows within one are not)."""
    from scipy import stats

    diff = other - best
    n = diff.size
    sd = float(np.std(diff, ddof=1)) if n > 1 else 0.0
    if sd == 0.0:
        return bool(diff.mean() > 0)
    return float(diff.mean() / (sd / math.sqrt(n))) >= float(stats.t.ppf(0.95, n - 1))


def _fields(asked: list[str], mech: Mechanism, explicit: bool):
    """Returns (continuous fields, their bounds, skipped fields and why)."""
    names, box, skipped = [], {}, {}
    if len(set(asked)) != len(asked):
        raise invalid("fit", list(asked), f"distinct names from {list(FIELDS)}")
    for name in asked:
        if name not in FIELDS:
            raise invalid("fit", name, f"names from {list(FIELDS)}")
        if name in DELAYS:
            continue
        b = bounds(name, mech)
        if isinstance(b, str):
            if explicit:
                raise invalid("fit", name, f"a field the nominal arm can vary: {b}")
            skipped[name] = b
        else:
            names.append(name)
            box[name] = b
    return names, box, skipped


class _Delays(NamedTuple):
    """What the loop delay's search found (_search_delay)."""

    best: int  # the delay (control steps) of the least fitted residual
    told: set[int]  # the delays not told apart from it (it included)
    fits: dict[int, np.ndarray]  # each fitted delay's fit on the subset's pieces
    costs: dict[int, float]  # and its cost
    per_piece: dict[int, np.ndarray]  # and its cost per piece


def _coarse_start(prob: Problem, d: int) -> tuple[np.ndarray, float]:
    """Returns the point of GRID (the other fields nominal) whose replay at loop delay ``d``
    misses the coarse pieces (COARSE_PIECES) least, and the RMS miss (rad) of the nominal
    values there: the residual before the fit."""
    x0, cfg = prob.x0, prob.config
    seconds = sum(len(r.time) for r in prob.recordings) * cfg.ctrl_dt
    coarse = Stage(PIECE_S, max(PIECE_S, seconds / COARSE_PIECES), 0)
    axes = [
        [(i, v) for v in GRID[n]] if x0[i] > 0 else [(i, x0[i])]
        for i, n in enumerate(prob.names)
        if n in GRID
    ]
    best, least, nominal = x0, math.inf, math.nan
    for point in itertools.product(*axes):
        x = x0.copy()
        for i, v in point:
            lo, hi, s = prob.box[prob.names[i]]
            x[i] = min(max(v * x0[i], lo / s), hi / s)
        if not prob.stable(prob.arm(x)):
            continue
        prob.pieces(d, x, coarse, 1)
        cost = prob.cost(x)
        if np.array_equal(x, x0):
            entries = 2 * len(prob.rep.pieces) * prob.rep.pieces.length
            nominal = math.sqrt(cost / entries) * ANGLE_UNIT
        if cost < least:
            best, least = x, cost
    return best, nominal


class _Profiles:
    """Each loop delay's fit on the subset's pieces, and its cost per piece and in all."""

    def __init__(self, prob: Problem, start: np.ndarray) -> None:
        self.prob, self.start = prob, start
        self.fits: dict[int, np.ndarray] = {}
        self.costs: dict[int, float] = {}
        self.per_piece: dict[int, np.ndarray] = {}

    def profile(self, k: int) -> None:
        """Fits loop delay ``k`` from the coarse start, then from the nominal values and each
        fit at another delay that fits delay k better before its fit than that fit does after;
        the best fit is kept.  (A fit at another delay has absorbed that delay: from it, the fit
        at k may stay in its basin, though it starts with a smaller miss than the coarse
        start.)"""
        prob, start, subset = self.prob, self.start, STAGES[0]
        prob.pieces(k, start, subset)
        self.fits[k] = prob.fit(start, subset, ROUNDS)
        self.per_piece[k] = prob.piece_costs(self.fits[k])
        others = [prob.x0, *[v for j, v in self.fits.items() if j != k]]
        for y in [y for y in others if not np.array_equal(y, start)]:
            prob.pieces(k, y, subset, 1)
            if prob.cost(y) < self.per_piece[k].sum():
                prob.rep.refine_starts(prob.arm(y), 1)  # the second pass of prob.pieces
                z = prob.fit(y, subset, ROUNDS)
                if (c := prob.piece_costs(z)).sum() < self.per_piece[k].sum():
                    self.fits[k], self.per_piece[k] = z, c
        self.costs[k] = float(self.per_piece[k].sum())


def _scan_costs(prob: Problem, scan: range, x: np.ndarray) -> dict[int, float]:
    """Returns each delay's cost at ``x`` on the subset's pieces, before any fit."""
    scanned = {}
    for k in scan:
        prob.pieces(k, x, STAGES[0], 1)
        scanned[k] = prob.cost(x)
    return scanned


def _walk(profiles: _Profiles, scan: range, best: int) -> int:
    """Returns the delay of the least fitted residual, walking downhill from ``best``."""
    while True:
        for k in (best - 1, best + 1):
            if k in scan and k not in profiles.costs:
                profiles.profile(k)
        better = min(profiles.costs, key=profiles.costs.get)
        if better == best:
            return best
        best = better


def _told_apart(profiles: _Profiles, scan: range, best: int) -> set[int]:
    """Returns the delays not told apart from ``best`` (_worse), grown from it while a
    neighbour is not worse."""
    told = {best}
    grow = True
    while grow:
        grow = False
        for k in sorted(told):
            for n in (k - 1, k + 1):
                if n in scan and n not in told:
                    if n not in profiles.costs:
                        profiles.profile(n)
                    if not _worse(profiles.per_piece[n], profiles.per_piece[best]):
                        told.add(n)
                        grow = True
    return told


def _search_delay(prob: Problem, scan: range, start: np.ndarray) -> _Delays:
    """Finds the loop delay among ``scan`` on the subset's pieces: a scan at ``start`` (the
    coarse start), a fit at the best delay, the scan again at that fit, then a walk to the
    least fitted residual (the lag, the cables' stretch and the delay trade off: each delay is
    fitted), and the delays around it that the pieces do not tell apart from it (_worse)."""
    scanned = _scan_costs(prob, scan, start)
    profiles = _Profiles(prob, start)
    best = min(scanned, key=scanned.get)
    profiles.profile(best)
    told = {best}
    if len(scan) > 1:  # the scan again at that fit: the nominal values may mislead it
        scanned = _scan_costs(prob, scan, profiles.fits[best])
        if (best := min(scanned, key=scanned.get)) not in profiles.costs:
            profiles.profile(best)
        best = _walk(profiles, scan, best)
        told = _told_apart(profiles, scan, best)
        told |= fold_delays(profiles.per_piece)  # a block of pieces that prefers another
    return _Delays(best, told, profiles.fits, profiles.costs, profiles.per_piece)


def _delay_scan(config: EnvConfig, asked: list[str]) -> tuple[range, int]:
    """Returns the loop delays (control steps) to search and the nominal loop delay.  With a
    delay fitted, up to MAX_DELAY_S (or twice the nominal loop delay), else only the nominal
    one; a delay left out of ``fit`` is known: it keeps its nominal value, and the loop delay
    is at least that long (the other takes the rest)."""
    kept = _kept(config)
    nominal_steps = sum(kept.values())
    max_d = max(round(MAX_DELAY_S / config.ctrl_dt), 2 * nominal_steps)
    max_d = max_d if any(n in DELAYS for n in asked) else nominal_steps
    return range(sum(kept[n] for n in DELAYS if n not in asked), max_d + 1), nominal_steps


def _kept(config: EnvConfig) -> dict[str, int]:
    """The nominal delays (control steps)."""
    timing = Timing.of(config)
    return {"motor_delay": timing.delay_steps, "observation_delay": timing.observation_delay_steps}


def _final_fit(prob: Problem, d: int, x: np.ndarray) -> np.ndarray:
    """Returns the fit on every piece at loop delay ``d`` from the subset's fit ``x``.  A fit
    held at the integrator's limit may be stuck there (the optimizer cannot slide along it): it
    is fitted again with the limiting fields (those check_stability names) from their nominal
    values, and the better fit is kept."""
    final, n = STAGES[1], len(prob.names)
    prob.pieces(d, x, final)  # every piece, from the subset's fit
    x = prob.fit(x, final, ROUNDS)
    step = EDGE_STEP * np.eye(n)
    limiting = {
        prob.limiting(prob.arm(x + sign * step[i])) for i in range(n) for sign in (-1, 1)
    } - {None}
    pinned = [i for i, name in enumerate(prob.names) if name in limiting]
    if not pinned:
        return x
    held = prob.cost(x)
    retry = x.copy()
    retry[pinned] = prob.x0[pinned]
    prob.pieces(d, retry, final)
    y = prob.fit(retry, final, ROUNDS)
    if prob.cost(y) < held:
        return y
    prob.pieces(d, x, final)
    return x


def _covariance(prob: Problem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Returns the residual at the fit ``x``, its Jacobian by forward differences, and the
    fields' cluster-robust covariance there (scaled)."""
    n = len(prob.names)
    r = prob.residual(x)[0][0]
    if not n:
        return r, np.zeros((r.size, 0)), np.zeros((0, 0))
    cols = np.tile(x[:, None], (1, n)) + 1e-6 * np.eye(n)
    J = (prob.residual(cols)[0][0] - r[:, None]) / 1e-6
    return r, J, cluster_covariance(J, r, len(prob.rep.pieces))


def _estimates(
    prob: Problem, x: np.ndarray, cov: np.ndarray, spread: np.ndarray, hold: Holdout | None
) -> list[Estimate]:
    """Judges each field at the fit ``x`` (module docstring); ``spread``: its fits' largest
    change over the delays not told apart (scaled), which widens its interval, as do the
    folds' fits (``hold``: tendon2r_gym.identification.holdout)."""
    from scipy import stats

    k, P = len(prob.names), len(prob.rep.pieces)
    tq = float(stats.t.ppf(1 - 0.025 / max(k, 1), max(P - k, 1)))
    folds = np.zeros(k) if hold is None else hold.spread
    out = [_estimate(prob, x, i, tq, cov[i, i], spread[i], folds[i]) for i in range(k)]
    if hold is not None and not hold.predicts:
        why = f"does not predict held-out pieces ({hold.ratio:.2g}x the in-sample residual)"
        for e in out:
            _flag(e, why)
    _flag_mass_and_lag(prob, cov, out)
    return out


def _estimate(
    prob: Problem, x: np.ndarray, i: int, tq: float, var: float, spread: float, fold: float
) -> Estimate:
    """Judges field ``i`` of the fit ``x``: ``tq`` the t-quantile of its interval, ``var`` its
    variance, ``spread`` its fits' spread over the delays and ``fold`` its folds' largest move
    (all scaled): the interval holds every fold's fit."""
    name = prob.names[i]
    lo, hi, s = prob.box[name]
    value = min(max(float(x[i] * s), lo), hi)
    half = float(tq * math.sqrt(max(var, 0.0)) * s)
    half = max(half, XTOL * abs(value)) + float(spread * s)  # no finer than the fit
    half = max(half, float(fold * s))
    at_bound = min(value - lo, hi - value) <= 1e-3 * (hi - lo)
    at_limit = prob.at_limit(x, i)
    ok = half <= IDENTIFIED_WITHIN * abs(value) and not (at_bound or at_limit)
    why = _why_not(ok, at_bound, at_limit, f"+-{half:.3g} {FIELDS[name][0]}")
    nominal = float(getattr(prob.mech, name))
    # Too wide to identify, yet the recording rules the nominal value out: the fit is the
    # better guess, and the identified arm takes it.
    used = ok or not (at_bound or at_limit) and abs(nominal - value) > half
    return Estimate(name, nominal, value, half, ok, why, used)


def _flag_mass_and_lag(prob: Problem, cov: np.ndarray, out: list[Estimate]) -> None:
    """Flags ``motor_mass`` and ``motor_tau`` when the fit cannot tell them apart: their
    correlation beyond MASS_LAG_CORRELATION."""
    names = prob.names
    if "motor_mass" not in names or "motor_tau" not in names:
        return
    i, j = names.index("motor_mass"), names.index("motor_tau")
    rho = cov[i, j] / math.sqrt(max(cov[i, i] * cov[j, j], 1e-300))
    if abs(rho) > MASS_LAG_CORRELATION:
        for k, other in ((i, "motor_tau"), (j, "motor_mass")):
            _flag(out[k], f"not told from {other} (correlation {rho:.2f})")


def _flag(e: Estimate, why: str) -> None:
    """Flags ``e`` (keeping an earlier reason): the identified arm takes its fit only where
    its interval excludes the nominal value."""
    e.why = e.why or why
    e.used = e.used and (not e.identified or abs(e.nominal - e.value) > e.half_width)
    e.identified = False


def _why_not(ok: bool, at_bound: bool, at_limit: bool, width: str) -> str:
    """Why a field is not identified ('' if it is): its bound, the integrator's limit, or its
    interval's ``width``."""
    if ok:
        return ""
    if at_bound:
        return "at its bound"
    if at_limit:
        return "at the integrator's limit"
    return width


def _changes(
    config: EnvConfig, asked: list[str], estimates: list[Estimate], noise: tuple, d: int
) -> dict[str, Any]:
    """Returns the identified arm's changes to the nominal experiment file: the fields it
    takes, the sensors' noise, and with a delay fitted the loop delay ``d`` (steps) split as
    the module docstring says (the best one, even if others are not told apart: the fields
    fit it)."""
    values = {e.field: e.value for e in estimates if e.used}
    out: dict[str, Any] = {"mechanism": values}
    speed = config.observation_noise[1] if noise[1] is None else noise[1]
    out["observation_noise"] = [noise[0], speed]
    if any(n in DELAYS for n in asked):
        obs = round(_observation_steps(config, asked, d) * config.ctrl_dt, 12)
        values["motor_delay"] = round(d * config.ctrl_dt - obs, 12)
        out["observation_delay"] = obs
    return out


def _observation_steps(config: EnvConfig, asked: list[str], d: int) -> int:
    """The sensor's share (steps) of the loop delay ``d``: its nominal one if not fitted, the
    rest of the motor's nominal one if that is not fitted, else half (the motor the odd step)."""
    kept = _kept(config)
    if "observation_delay" not in asked:
        return kept["observation_delay"]
    if "motor_delay" not in asked:
        return d - kept["motor_delay"]
    return d // 2


def identify(
    recordings: Sequence[Recording],
    config: EnvConfig,
    fit: Sequence[str] | None = None,
    threads: int | None = None,
) -> Identification:
    """Fits the fields ``fit`` (default DEFAULT_FIT, less those the nominal arm's model
    cannot vary) of the arm of ``config`` to ``recordings`` (module docstring).  ``fit`` may
    hold only delays: the loop delay is then found on the nominal arm."""
    began = time.perf_counter()
    asked = list(DEFAULT_FIT if fit is None else fit)
    names, box, skipped = _fields(asked, config.mechanism, fit is not None)
    if not names and not any(n in DELAYS for n in asked):
        raise invalid("fit", asked, "at least one field the nominal arm can vary, or a delay")
    if threads is not None:
        integer("threads", threads, 1, 1024)
    prob = Problem(recordings, config, names, box, threads or os.cpu_count() or 1)
    scan, nominal_steps = _delay_scan(config, asked)
    prob.first = max(prob.first, scan.stop)  # after the longest delay searched
    check_pieces(recordings, config, len(names), prob.first)
    start, before = _coarse_start(prob, nominal_steps)
    delays = _search_delay(prob, scan, start)
    ident = _judge(prob, asked, delays, scan)
    ident.skipped = skipped
    ident.residual_rms_rad = (before, ident.residual_rms_rad[1])
    ident.seconds = time.perf_counter() - began
    ident.extras["start"] = start
    return ident


def _judge(prob: Problem, asked: list[str], delays: _Delays, scan: range) -> Identification:
    """The final fit at the best loop delay of ``delays``, its intervals, hold-out check and
    the identified arm's changes (identify fills in its time, start and skipped fields)."""
    config = prob.config
    d, told, fits = delays.best, delays.told, delays.fits
    x = _final_fit(prob, d, fits[d])
    fit_delay = any(n in DELAYS for n in asked)
    delay_ok = fit_delay and told == {d} and d < scan.stop - 1
    # A field's fit at each delay not told apart widens its interval (the delay is a
    # nuisance the fields are conditional on).
    spread = np.max([np.abs(fits[k] - fits[d]) for k in told], axis=0)
    r, J, cov = _covariance(prob, x)
    hold = cross_validate(prob, x, J, r) if prob.names else None
    estimates = _estimates(prob, x, cov, spread, hold)
    noise = prob.rep.noise(prob.arm(x))
    return Identification(
        estimates=estimates,
        loop_delay_s=d * config.ctrl_dt,
        delay_identified=bool(delay_ok),
        delay_range_s=(min(told) * config.ctrl_dt, max(told) * config.ctrl_dt),
        delay_fits={
            round(k * config.ctrl_dt, 12): dict(zip(prob.names, fits[k] * prob.scales, strict=True))
            for k in sorted(told)
        },
        holdout_rms_rad=None if hold is None else (hold.in_rms_rad, hold.out_rms_rad),
        changes=_changes(config, asked, estimates, noise, d),
        skipped={},
        noise=noise,
        pieces=len(prob.rep.pieces),
        residual_rms_rad=(math.nan, math.sqrt(float(np.sum(r**2)) / r.size) * ANGLE_UNIT),
        seconds=math.nan,
        sources=[rec.source for rec in prob.recordings],
        extras={
            "problem": prob,
            "x": x,
            "cov": cov,
            "costs": delays.costs,
            "fits": fits,
            "holdout": hold,
        },
    )

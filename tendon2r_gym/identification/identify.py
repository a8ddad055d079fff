"""Identify an arm's realism fields from recordings, with ``mujoco.sysid``'s least squares.

The fit (tendon2r_gym.identification.fit) replays short pieces of the recordings on candidate
arms.  This module chooses the fields and their bounds, finds the loop delay, runs the
toolbox's box-constrained Gauss-Newton (``mujoco.sysid.optimize``, MuJoCo's own
``minimize.least_squares``), and judges each result:

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
  not told apart.  The identified arm splits the loop delay evenly (``motor_delay`` takes an
  odd step): the loop that PD tuning and the policies see is the same.
"""

from __future__ import annotations

import io
import itertools
import math
import os
import time
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.identification import recording
from tendon2r_gym.identification.fit import (
    ANGLE_UNIT,
    PIECE_S,
    Pieces,
    Replay,
    cluster_covariance,
)
from tendon2r_gym.identification.recording import Recording
from tendon2r_gym.identification.result import FIELDS, Estimate, Identification
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.simulation.model import build_model
from tendon2r_gym.simulation.stability import check_stability
from tendon2r_gym.validation import integer, invalid, invalid_field

#: The delays: whole control steps, identified as their sum.
DELAYS = ("motor_delay", "observation_delay")
DEFAULT_FIT = (
    "tendon_elasticity", "tendon_damping", "tendon_friction", "motor_tau", "motor_delay",
    "observation_delay", "density_scale", "extra_joint_damping",
)  # fmt: skip
#: A field is identified if its 95% interval's half-width is within this fraction of it.
IDENTIFIED_WITHIN = 0.1
#: The longest loop delay searched (s).
MAX_DELAY_S = 0.01


class Stage(NamedTuple):
    """One stage of the fit: pieces this long (s), starting this far apart (s), and the most
    Gauss-Newton iterations: the delay's scan and fits on a subset, then every piece."""

    piece_s: float
    spacing_s: float
    max_iters: int


STAGES = (Stage(PIECE_S, 5 * PIECE_S, 4), Stage(PIECE_S, 2 * PIECE_S, 4))
#: The coarse start: about this many pieces, spread over the recordings, on which a grid of
#: the fields that dominate the replay far from the truth is tried (multiples of their
#: nominal values, within their bounds).  Dry friction several times too high sticks the
#: cables, a mass twice too light doubles every acceleration: from there Gauss-Newton lands
#: in another basin, with the lag and the stiffness absorbing the miss.
COARSE_PIECES = 10
GRID = {"density_scale": (0.5, 0.7, 1.0, 1.4, 2.0, 2.8),
        "tendon_friction": (0.2, 0.5, 1.0, 2.0, 5.0)}  # fmt: skip
#: Gauss-Newton stops when a step is below this fraction of the fields (scaled): the
#: intervals are never narrower.
XTOL = 1e-4
#: A fit this close (scaled) to an arm the integrator cannot integrate (the env refuses it:
#: tendon2r_gym.simulation.stability) is held there by that limit, not by the recording: the
#: fields that cross it within this step are flagged, as at a bound.
EDGE_STEP = 1e-3
#: Gauss-Newton's regularizer on the scaled problem (unit columns): its least nonzero value
#: and the factor it grows by after a step that does not lower the cost (the toolbox's
#: 1e-6 and 10**0.1 take some 50 rollouts to reach a useful value each time a step fails).
MU = (1e-3, 10.0)
#: Rounds of each stage: a fit of max_iters, then the pieces' starts refined at it; no
#: more rounds once a fit lowers the cost by less than ROUND_GAIN (a fraction of it).
ROUNDS = 3
ROUND_GAIN = 1e-3


def bounds(name: str, mech: Mechanism) -> tuple[float, float, float] | str:
    """Returns (low, high, scale) of a field on the nominal arm ``mech``, or why the nominal
    arm's model cannot vary it (its layout would change)."""
    v = float(getattr(mech, name))
    force = float(mech.max_tendon_force)
    if name in ("tendon_elasticity", "motor_mass"):
        if not mech.elastic:
            return "the nominal arm's cables are rigid (tendon_elasticity: 0)"
        return v / 5, v * 5, v
    if name == "tendon_damping":
        scale = v if v > 0 else (1.0 if mech.elastic else 0.01 * force)
        return 0.0, 10 * scale, scale
    if name == "tendon_friction":
        if mech.elastic and v == 0:
            return "the nominal arm's elastic cables have no friction (tendon_friction: 0)"
        scale = v if v > 0 else 0.01 * force
        return (1e-3 * scale if mech.elastic else 0.0), min(10 * scale, 0.5 * force), scale
    if name == "motor_tau":
        if v == 0:
            return "the nominal arm's motors do not lag (motor_tau: 0)"
        return max(v / 5, 0.5 * mech.sim_dt), v * 5, v
    if name == "density_scale":
        return 0.2 * v, 5 * v, v
    if name == "extra_joint_damping":
        scale = max(v, 1e-5)
        return 0.0, 10 * scale, scale
    raise invalid("fit", name, f"names from {list(FIELDS)}")


def load_recordings(paths: Sequence[str | os.PathLike], config: EnvConfig) -> list[Recording]:
    """Reads and checks each recording against the arm of ``config`` (identify checks that
    together they are long enough)."""
    mech = config.mechanism
    force = float(mech.max_tendon_force)
    return [recording.load(p, mech.n_tendons, config.ctrl_dt, force, mech.pull_only)
            for p in paths]  # fmt: skip


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


class _Problem:
    """The fit's state: the fields, their bounds and scales, and the current pieces."""

    def __init__(self, recordings: Sequence[Recording], config: EnvConfig,
                 names: list[str], box: dict[str, tuple[float, float, float]],
                 threads: int) -> None:  # fmt: skip
        self.recordings, self.config, self.names, self.box = list(recordings), config, names, box
        self.mech, self.threads = config.mechanism, threads
        self.scales = np.array([box[n][2] for n in names])
        self.x0 = np.array([float(getattr(self.mech, n)) for n in names]) / self.scales
        self.rep: Replay | None = None
        self.nominal_model = build_model(self.mech.ideal())  # what the stability check reads
        #: The first row of a piece at any delay tried: every delay's pieces are the same.
        self.first = round(MAX_DELAY_S / config.ctrl_dt) + 1

    def arm(self, x: np.ndarray) -> Mechanism:
        """The nominal arm with the fields at scaled values ``x``."""
        values = {  # within the bounds: the optimizer's last bit may cross one
            n: min(max(float(v), self.box[n][0]), self.box[n][1])
            for n, v in zip(self.names, x * self.scales, strict=True)
        }
        return self.mech.replace(**values)

    def pieces(self, d: int, x: np.ndarray, stage: Stage, passes: int = 2) -> Replay:
        """Sets and returns the pieces of ``stage`` at loop delay ``d``, their starts refined
        on the arm at ``x``."""
        cfg = self.config
        pieces = Pieces(self.recordings, cfg.ctrl_dt, d, stage.piece_s, stage.spacing_s,
                        first=self.first)  # fmt: skip
        self.rep = Replay(pieces, cfg.n_substeps, self.threads)
        self.rep.refine_starts(self.arm(x), passes)
        return self.rep

    def cost(self, x: np.ndarray) -> float:
        return float(np.sum(self.piece_costs(x)))

    def piece_costs(self, x: np.ndarray) -> np.ndarray:
        """Each piece's sum of squared residuals at ``x``."""
        return np.sum(self.rep.residual([self.arm(x)])[0] ** 2, axis=-1)

    def residual(self, x: np.ndarray, _params: Any = None, **_: Any):
        """The toolbox's residual function: one column per column of ``x`` (batched finite
        differences).  An arm the env would refuse (its integrator cannot integrate it:
        tendon2r_gym.simulation.stability) gets a residual of 1e6 everywhere."""
        cols = x.reshape(len(self.names), -1)
        arms = [self.arm(cols[:, k]) for k in range(cols.shape[1])]
        ok = [self.stable(a) for a in arms]
        r = np.full((len(arms), len(self.rep.pieces), 2 * self.rep.pieces.length), 1e6)
        if any(ok):
            r[np.array(ok)] = self.rep.residual([a for a, g in zip(arms, ok, strict=True) if g])
        r = r.reshape(cols.shape[1], -1).T
        return [r[:, 0] if x.ndim == 1 else r], None, None

    def stable(self, mech: Mechanism) -> bool:
        """Whether the env accepts ``mech``: its integrator can integrate it."""
        return self.limiting(mech) is None

    def limiting(self, mech: Mechanism) -> str | None:
        """The field that keeps the integrator from integrating ``mech`` (None if it can)."""
        try:
            check_stability(self.nominal_model, mech)
        except ValueError as e:
            return invalid_field(e)
        return None

    def at_limit(self, x: np.ndarray, i: int) -> bool:
        """Whether field ``i`` of the fit ``x`` is at the integrator's limit (EDGE_STEP)."""
        step = EDGE_STEP * np.eye(len(x))[i]
        return not (self.stable(self.arm(x - step)) and self.stable(self.arm(x + step)))

    def fit(self, x: np.ndarray, stage: Stage, rounds: int) -> np.ndarray:
        """Returns the fit from ``x`` on the current pieces: up to ``rounds`` times a
        Gauss-Newton fit of ``stage.max_iters`` iterations (mujoco.sysid.optimize,
        box-constrained), then the starts refined at it (ROUND_GAIN)."""
        from absl import logging
        from mujoco import sysid

        logging.set_verbosity(logging.ERROR)  # its notes on starting at a bound (0 damping)
        for _ in range(rounds if self.names else 0):
            params = sysid.ParameterDict()
            for i, n in enumerate(self.names):
                lo, hi, s = self.box[n]
                params.add(sysid.Parameter(n, self.x0[i], lo / s, hi / s))
                params[n].value[:] = x[i]
            try:
                opt, _ = sysid.optimize(
                    params, self.residual, optimizer="mujoco", verbose=False,
                    max_iters=stage.max_iters, eps=1e-6, xtol=XTOL, x_scale="jac",
                    mu_min=MU[0], mu_factor=MU[1], output=io.StringIO(),
                    iter_callback=_stop_when_flat,
                )  # fmt: skip
                y = opt.as_vector()
            except _Flat as flat:
                y = flat.x
            moved = self.cost(y) < (1 - ROUND_GAIN) * self.cost(x)
            x = y
            self.rep.refine_starts(self.arm(x), 1)
            if not moved:  # converged: another round would start where this one did
                break
        return x


class _Flat(Exception):
    """Raised by _stop_when_flat with the point it stops at."""

    def __init__(self, x: np.ndarray) -> None:
        self.x = x


def _stop_when_flat(trace: list) -> None:
    """The toolbox's iteration callback: stops Gauss-Newton (raising _Flat) once a step lowers
    the cost by less than ROUND_GAIN of it (the toolbox stops only on the step's size, which
    a cost this flat may not shrink), at the point before that step."""
    log = trace[-1]
    if log.reduction < ROUND_GAIN * log.objective:
        raise _Flat(np.asarray(log.candidate, dtype=float).reshape(-1))


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


def _coarse_start(prob: _Problem, d: int) -> tuple[np.ndarray, float]:
    """Returns the point of GRID (the other fields nominal) whose replay at loop delay ``d``
    misses the coarse pieces (COARSE_PIECES) least, and the RMS miss (rad) of the nominal
    values there: the residual before the fit."""
    x0, cfg = prob.x0, prob.config
    seconds = sum(len(r.time) for r in prob.recordings) * cfg.ctrl_dt
    coarse = Stage(PIECE_S, max(PIECE_S, seconds / COARSE_PIECES), 0)
    axes = [[(i, v) for v in GRID[n]] if x0[i] > 0 else [(i, x0[i])]
            for i, n in enumerate(prob.names) if n in GRID]  # fmt: skip
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


def _search_delay(prob: _Problem, scan: range, start: np.ndarray) -> _Delays:
    """Finds the loop delay among ``scan`` on the subset's pieces: a scan at ``start`` (the
    coarse start), a fit at the best delay, the scan again at that fit, then a walk to the
    least fitted residual (the lag, the cables' stretch and the delay trade off: each delay is
    fitted), and the delays around it that the pieces do not tell apart from it (_worse)."""
    subset, x0 = STAGES[0], prob.x0
    scanned = {}
    for k in scan:
        prob.pieces(k, start, subset, 1)
        scanned[k] = prob.cost(start)
    fits: dict[int, np.ndarray] = {}
    costs: dict[int, float] = {}
    per_piece: dict[int, np.ndarray] = {}

    def profile(k: int) -> None:
        # From the coarse start, then from the nominal values and each fit at another delay
        # that fits delay k better before its fit than that fit does after; the best fit
        # is kept.  (A fit at another delay has absorbed that delay: from it, the fit at k
        # may stay in its basin, though it starts with a smaller miss than the coarse start.)
        prob.pieces(k, start, subset)
        fits[k] = prob.fit(start, subset, ROUNDS)
        per_piece[k] = prob.piece_costs(fits[k])
        for y in [*([] if start is x0 else [x0]), *[v for j, v in fits.items() if j != k]]:
            prob.pieces(k, y, subset, 1)
            if prob.cost(y) < per_piece[k].sum():
                prob.pieces(k, y, subset)
                z = prob.fit(y, subset, ROUNDS)
                if (c := prob.piece_costs(z)).sum() < per_piece[k].sum():
                    fits[k], per_piece[k] = z, c
        costs[k] = float(per_piece[k].sum())

    several = len(scan) > 1
    best = min(scanned, key=scanned.get)
    profile(best)
    if several:  # the scan again at that fit: the nominal values may mislead it
        for k in scan:
            prob.pieces(k, fits[best], subset, 1)
            scanned[k] = prob.cost(fits[best])
        if (best := min(scanned, key=scanned.get)) not in costs:
            profile(best)
    while several:  # walk downhill to the least fitted residual
        for k in (best - 1, best + 1):
            if k in scanned and k not in costs:
                profile(k)
        better = min(costs, key=costs.get)
        if better == best:
            break
        best = better
    told = {best}  # grown while a neighbour is not worse
    grow = several
    while grow:
        grow = False
        for k in sorted(told):
            for n in (k - 1, k + 1):
                if n in scanned and n not in told:
                    if n not in costs:
                        profile(n)
                    if not _worse(per_piece[n], per_piece[best]):
                        told.add(n)
                        grow = True
    return _Delays(best, told, fits, costs)


def identify(
    recordings: Sequence[Recording],
    config: EnvConfig,
    fit: Sequence[str] | None = None,
    threads: int | None = None,
) -> Identification:
    """Fits the fields ``fit`` (default DEFAULT_FIT, less those the nominal arm's model
    cannot vary) of the arm of ``config`` to ``recordings`` (module docstring)."""
    from scipy import stats

    began = time.perf_counter()
    mech = config.mechanism
    asked = list(DEFAULT_FIT if fit is None else fit)
    names, box, skipped = _fields(asked, mech, fit is not None)
    fit_delay = any(n in DELAYS for n in asked)
    if threads is not None:
        integer("threads", threads, 1, 1024)
    prob = _Problem(recordings, config, names, box, threads or os.cpu_count() or 1)
    x0 = prob.x0
    nominal_steps = config.delay_steps + config.observation_delay_steps

    max_d = max(round(MAX_DELAY_S / config.ctrl_dt), 2 * nominal_steps)
    max_d = max_d if fit_delay else nominal_steps
    prob.first = max(prob.first, max_d + 1)
    check_pieces(recordings, config, len(names), prob.first)
    final = STAGES[1]
    scan = range(max_d + 1) if fit_delay else range(nominal_steps, nominal_steps + 1)
    start, before = _coarse_start(prob, nominal_steps)
    delays = _search_delay(prob, scan, start)
    d, told, fits = delays.best, delays.told, delays.fits
    prob.pieces(d, fits[d], final)  # every piece, from the subset's fit
    x = prob.fit(fits[d], final, ROUNDS)
    # A fit held at the integrator's limit may be stuck there (the optimizer cannot slide
    # along it): it is fitted again with the limiting fields (those check_stability names)
    # from their nominal values, and the better fit is kept.
    step = EDGE_STEP * np.eye(len(names))
    limiting = {prob.limiting(prob.arm(x + sign * step[i]))
                for i in range(len(names)) for sign in (-1, 1)} - {None}  # fmt: skip
    pinned = [i for i, n in enumerate(names) if n in limiting]
    if pinned:
        held = prob.cost(x)
        retry = x.copy()
        retry[pinned] = x0[pinned]
        prob.pieces(d, retry, final)
        y = prob.fit(retry, final, ROUNDS)
        if prob.cost(y) < held:
            x = y
        else:
            prob.pieces(d, x, final)
    delay_ok = fit_delay and told == {d} and d < max_d
    # A field's fit at each delay not told apart widens its interval (the delay is a
    # nuisance the fields are conditional on).
    spread = np.max([np.abs(fits[k] - fits[d]) for k in told], axis=0)

    # The Jacobian at the fit (forward differences), and the robust covariance.
    P = len(prob.rep.pieces)
    r = prob.residual(x)[0][0]
    if names:
        cols = np.tile(x[:, None], (1, len(names))) + 1e-6 * np.eye(len(names))
        J = (prob.residual(cols)[0][0] - r[:, None]) / 1e-6
        cov = cluster_covariance(J, r, P)
    else:
        cov = np.zeros((0, 0))
    tq = float(stats.t.ppf(1 - 0.025 / max(len(names), 1), max(P - len(names), 1)))
    estimates, values = [], {}
    for i, n in enumerate(names):
        lo, hi, s = box[n]
        value = min(max(float(x[i] * s), lo), hi)
        half = float(tq * math.sqrt(max(cov[i, i], 0.0)) * s)
        half = max(half, XTOL * abs(value)) + float(spread[i] * s)  # no finer than the fit
        at_bound = min(value - lo, hi - value) <= 1e-3 * (hi - lo)
        at_limit = prob.at_limit(x, i)
        ok = half <= IDENTIFIED_WITHIN * abs(value) and not (at_bound or at_limit)
        why = ("" if ok else "at its bound" if at_bound
               else "at the integrator's limit" if at_limit
               else f"+-{half:.3g} {FIELDS[n][0]}")  # fmt: skip
        nominal = float(getattr(mech, n))
        # Too wide to identify, yet the recording rules the nominal value out: the fit is
        # the better guess, and the identified arm takes it.
        used = ok or not (at_bound or at_limit) and abs(nominal - value) > half
        estimates.append(Estimate(n, nominal, value, half, ok, why, used))
        if used:
            values[n] = value
    loop = d * config.ctrl_dt
    noise = prob.rep.noise(prob.arm(x))
    out: dict[str, Any] = {"mechanism": values}
    out["observation_noise"] = [noise[0], config.observation_noise[1] if noise[1] is None
                                else noise[1]]  # fmt: skip
    if fit_delay:  # the best one, even if others are not told apart: the fields fit it
        obs = round(d // 2 * config.ctrl_dt, 12)  # only the sum shows: split evenly
        values["motor_delay"] = round(loop - obs, 12)
        out["observation_delay"] = obs
    return Identification(
        estimates=estimates,
        loop_delay_s=loop,
        delay_identified=bool(delay_ok),
        delay_range_s=(min(told) * config.ctrl_dt, max(told) * config.ctrl_dt),
        changes=out,
        skipped=skipped,
        noise=noise,
        pieces=P,
        residual_rms_rad=(
            before,
            math.sqrt(float(np.sum(r**2)) / r.size) * ANGLE_UNIT,
        ),
        seconds=time.perf_counter() - began,
        sources=[rec.source for rec in recordings],
        extras={"problem": prob, "x": x, "cov": cov, "costs": delays.costs, "fits": fits,
                "start": start},
    )

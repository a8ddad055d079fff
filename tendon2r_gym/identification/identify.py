"""Identify an arm's realism fields from recordings, with ``mujoco.sysid``'s least squares.

The fit (tendon2r_gym.identification.fit) replays short pieces of the recordings on candidate
arms.  This module chooses the fields and their bounds, finds the loop delay, runs the
toolbox's box-constrained Gauss-Newton (``mujoco.sysid.optimize``, MuJoCo's own
``minimize.least_squares``), and judges each result:

- each field's 95% interval is the cluster-robust one (one cluster per piece:
  fit.cluster_covariance), t-distributed with (pieces - fields) degrees of freedom;
- a field is *identified* if that interval is within ``IDENTIFIED_WITHIN`` of its value and the
  value is off its bounds; otherwise it is flagged, no number is reported for it, and the
  identified arm keeps its nominal value;
- the delays: commands and angles show only the loop delay, ``motor_delay +
  observation_delay`` (a command held back d steps and a measurement d steps late move the
  replay alike), found in whole control steps by the least residual.  It is identified if
  each neighbouring delay leaves a residual larger by the 95% quantile of chi-square(1) per
  piece.  The identified arm keeps the nominal ``observation_delay`` (or the whole loop delay
  if less) and gives the rest to ``motor_delay``: the loop that PD tuning and the policies see
  is the same.
"""

from __future__ import annotations

import io
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
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
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.validation import invalid

#: The fields a fit can change: unit, and what a user cannot measure with a ruler.
FIELDS: dict[str, tuple[str, str]] = {
    "tendon_elasticity": ("N/m", "cable stiffness EA / L"),
    "tendon_damping": ("N s/m", "cable damping"),
    "tendon_friction": ("N", "cable friction on the pulleys"),
    "motor_tau": ("s", "motor lag"),
    "motor_mass": ("kg", "motor and spool mass along the cable"),
    "density_scale": ("1", "link mass scale"),
    "extra_joint_damping": ("N m s/rad", "extra joint damping"),
    "motor_delay": ("s", "motor delay"),
    "observation_delay": ("s", "sensor delay"),
}
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
#: Rounds of each stage: a fit of max_iters, then the pieces' starts refined at it.
ROUNDS = 3
CHI2_95 = 3.841  # chi-square(1) 95% quantile


@dataclass
class Estimate:
    """One field's result (SI units)."""

    field: str
    nominal: float
    value: float
    half_width: float  # of the 95% interval; inf if the data cannot bound it
    identified: bool
    why: str = ""

    @property
    def unit(self) -> str:
        return FIELDS[self.field][0]

    @property
    def interval(self) -> tuple[float, float]:
        return self.value - self.half_width, self.value + self.half_width


@dataclass
class Identification:
    """What :func:`identify` found, and the identified arm's experiment settings."""

    estimates: list[Estimate]
    loop_delay_s: float
    delay_identified: bool
    config: dict[str, Any]  # the identified arm's experiment file (EnvConfig keyword arguments)
    skipped: dict[str, str]  # asked-for fields the nominal arm's model cannot vary, and why
    pieces: int
    residual_rms_rad: tuple[float, float]  # before and after the fit (projected)
    seconds: float
    sources: list[str] = field(default_factory=list)
    extras: dict[str, Any] = field(default_factory=dict, repr=False)  # for the report

    def lines(self) -> list[str]:
        """The printed table."""
        out = [f"{'field':<20} {'nominal':>11} {'identified':>11} {'95% interval':>27}  unit"]
        for e in self.estimates:
            if e.identified:
                lo, hi = e.interval
                shown, ci = f"{e.value:11.4g}", f"[{lo:.4g}, {hi:.4g}]"
            else:
                shown, ci = f"{'-':>11}", f"not identifiable ({e.why})"
            out.append(f"{e.field:<20} {e.nominal:11.4g} {shown} {ci:>27}  {e.unit}")
        status = "identified" if self.delay_identified else "not identifiable"
        out.append(
            f"{'loop delay':<20} {'':>11} {self.loop_delay_s * 1e3:11.4g} {status:>27}  ms "
            "(motor_delay + observation_delay: only their sum shows)"
        )
        for name, why in self.skipped.items():
            out.append(f"{name:<20} skipped: {why}")
        before, after = self.residual_rms_rad
        out.append(
            f"{self.pieces} pieces of {PIECE_S} s; angle residual {before:.3g} -> {after:.3g} rad "
            f"RMS; {self.seconds:.1f} s"
        )
        return out


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


def load_recordings(
    paths: Sequence[str | os.PathLike], config: EnvConfig, n_fields: int
) -> list[Recording]:
    """Reads and checks each recording against the arm of ``config``; together they must
    hold at least one piece per fitted field and two more."""
    mech = config.mechanism
    one = recording.load  # each file on its own first: the error names it
    recs = [
        one(p, mech.n_tendons, config.ctrl_dt, float(mech.max_tendon_force), mech.pull_only)
        for p in paths
    ]
    need = (n_fields + 2) * PIECE_S + MAX_DELAY_S
    have = sum(r.duration for r in recs)
    if have < need:
        raise ValueError(
            f"recording {', '.join(map(str, paths))}: {have:g} s in all; fitting {n_fields} "
            f"fields needs at least {need:g} s (one {PIECE_S} s piece per field and two more)"
        )
    return recs


def identify(
    recordings: Sequence[Recording],
    config: EnvConfig,
    fit: Sequence[str] | None = None,
    threads: int | None = None,
) -> Identification:
    """Fits the fields ``fit`` (default DEFAULT_FIT, less those the nominal arm's model
    cannot vary) of the arm of ``config`` to ``recordings`` (module docstring)."""
    from mujoco import sysid
    from scipy import stats

    began = time.perf_counter()
    mech = config.mechanism
    asked = list(DEFAULT_FIT if fit is None else fit)
    for name in asked:
        if name not in FIELDS:
            raise invalid("fit", name, f"names from {list(FIELDS)}")
    skipped: dict[str, str] = {}
    names, box = [], {}
    for name in asked:
        if name in DELAYS:
            continue
        b = bounds(name, mech)
        if isinstance(b, str):
            if fit is not None:
                raise invalid("fit", name, f"a field the nominal arm can vary: {b}")
            skipped[name] = b
        else:
            names.append(name)
            box[name] = b
    fit_delay = any(n in DELAYS for n in asked)
    threads = threads or os.cpu_count() or 1
    n_sub = config.n_substeps
    nominal_steps = config.delay_steps + config.observation_delay_steps

    scales = np.array([box[n][2] for n in names])

    def arm(x: np.ndarray) -> Mechanism:
        return mech.replace(**{n: float(v) for n, v in zip(names, x * scales, strict=True)})

    x0 = np.ones(len(names))  # the nominal values, scaled
    for i, n in enumerate(names):
        x0[i] = float(getattr(mech, n)) / scales[i]

    def replay_at(d: int, x: np.ndarray, stage: Stage, passes: int = 2) -> Replay:
        pieces = Pieces(list(recordings), config.ctrl_dt, d, stage.piece_s, stage.spacing_s)
        rep = Replay(pieces, mech, n_sub, threads)
        rep.refine_starts(arm(x), passes)
        return rep

    def cost(rep: Replay, x: np.ndarray) -> float:
        return float(np.sum(rep.residual([arm(x)]) ** 2))

    rep: Replay

    def residual_fn(x: np.ndarray, _params: Any, **_: Any):
        cols = x.reshape(len(names), -1)
        r = rep.residual([arm(cols[:, k]) for k in range(cols.shape[1])])
        r = r.reshape(cols.shape[1], -1).T
        return [r[:, 0] if x.ndim == 1 else r], None, None

    def fitted(x: np.ndarray, stage: Stage) -> np.ndarray:
        if not names:
            return x
        params = sysid.ParameterDict()
        for i, n in enumerate(names):
            lo, hi, s = box[n]
            params.add(sysid.Parameter(n, x0[i], lo / s, hi / s))
            params[n].value[:] = x[i]
        opt, _ = sysid.optimize(
            params, residual_fn, optimizer="mujoco", verbose=False, max_iters=stage.max_iters,
            eps=1e-6, xtol=1e-4, x_scale="jac", output=io.StringIO(),
        )  # fmt: skip
        return opt.as_vector()

    # The loop delay: a scan at the nominal values on a subset of the pieces, then a fit at
    # the best delay and each neighbour (the lag, the cables' stretch and the delay trade
    # off): the least fitted residual wins.
    max_d = round(MAX_DELAY_S / config.ctrl_dt) if fit_delay else nominal_steps
    scan_stage, final = STAGES
    scan = range(max_d + 1) if fit_delay else [nominal_steps]
    scanned = {k: cost(replay_at(k, x0, scan_stage, 1), x0) for k in scan}
    best = min(scanned, key=scanned.get)
    fits, costs = {}, {}

    def profile(k: int, start: np.ndarray, rounds: int) -> None:
        nonlocal rep
        rep = replay_at(k, start, scan_stage)
        x_k = start
        for _ in range(rounds):  # the starts follow the fit
            x_k = fitted(x_k, scan_stage)
            rep.refine_starts(arm(x_k), 1)
        fits[k], costs[k] = x_k, cost(rep, x_k)

    profile(best, x0, ROUNDS)
    while fit_delay:  # each neighbour from the best fit; move while one does better
        for k in (best - 1, best + 1):
            if k in scanned and k not in costs:
                profile(k, fits[best], 1)
        better = min(costs, key=costs.get)
        if better == best:
            break
        best = better
    d = min(costs, key=costs.get)
    P0 = len(rep.pieces)
    before = math.sqrt(scanned[d] / (P0 * 2 * (rep.pieces.length - rep.pieces.settle)))
    before *= ANGLE_UNIT
    rep = replay_at(d, fits[d], final)  # every piece, from the subset's fit
    x = fits[d]
    for _ in range(ROUNDS):
        x = fitted(x, final)
        rep.refine_starts(arm(x), 1)  # the starts and directions at the fit

    # The Jacobian at the optimum (forward differences), and the robust covariance.
    P = len(rep.pieces)
    r = residual_fn(x, None)[0][0]
    eps = 1e-6
    cols = np.tile(x[:, None], (1, len(names))) + eps * np.eye(len(names))
    J = (residual_fn(cols, None)[0][0] - r[:, None]) / eps if names else np.zeros((r.size, 0))
    cov = cluster_covariance(J, r, P) if names else np.zeros((0, 0))
    tq = float(stats.t.ppf(0.975, max(P - len(names), 1)))
    estimates = []
    values = {}
    for i, n in enumerate(names):
        lo, hi, s = box[n]
        value, half = float(x[i] * s), float(tq * math.sqrt(max(cov[i, i], 0.0)) * s)
        at_bound = min(value - lo, hi - value) <= 1e-3 * (hi - lo)
        ok = half <= IDENTIFIED_WITHIN * abs(value) and not at_bound
        why = "" if ok else ("at its bound" if at_bound else f"+-{half:.3g} {FIELDS[n][0]}")
        estimates.append(Estimate(n, float(getattr(mech, n)), value, half, ok, why))
        if ok:
            values[n] = value
    total = costs[d]  # stage one's fitted costs at each tried delay
    delay_ok = fit_delay and all(
        (costs[k] - total) / (total / P0) >= CHI2_95 for k in (d - 1, d + 1) if k in costs
    )
    loop = d * config.ctrl_dt
    if fit_delay and delay_ok:
        obs = min(config.observation_delay, loop)
        values["observation_delay"], values["motor_delay"] = obs, round(loop - obs, 12)
    out = config.to_dict()
    mech_dict = {**out["mechanism"], **{k: v for k, v in values.items() if k not in DELAYS}}
    out["mechanism"] = mech_dict
    if "motor_delay" in values:
        mech_dict["motor_delay"] = values["motor_delay"]
        out["observation_delay"] = values["observation_delay"]
    after = math.sqrt(float(np.sum(r**2)) / r.size) * ANGLE_UNIT
    return Identification(
        estimates=estimates,
        loop_delay_s=loop,
        delay_identified=bool(delay_ok),
        config=out,
        skipped=skipped,
        pieces=P,
        residual_rms_rad=(before, after),
        seconds=time.perf_counter() - began,
        sources=[r_.source for r_ in recordings],
        extras={"replay": rep, "x": x, "x0": x0, "names": names, "scales": scales,
                "cov": cov, "costs": costs, "scanned": scanned, "arm": arm},
    )  # fmt: skip

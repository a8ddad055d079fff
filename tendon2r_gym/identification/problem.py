"""The least-squares problem of an identification: the fields fitted, their bounds and
scales, and the toolbox's box-constrained Gauss-Newton (``mujoco.sysid.optimize``, MuJoCo's
own ``minimize.least_squares``) on the pieces' replay (tendon2r_gym.identification.fit), in
rounds with the pieces' starts refined between them.  Candidates that the env would refuse
(its integrator cannot integrate them) get the largest residual.

The search of the loop delay and the judgement of each field are in
tendon2r_gym.identification.identify.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.envs.timing import Timing
from tendon2r_gym.identification.fit import PIECE_S, Pieces, Replay
from tendon2r_gym.identification.recording import Recording
from tendon2r_gym.identification.result import FIELDS
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.simulation.model import build_model
from tendon2r_gym.simulation.stability import check_stability
from tendon2r_gym.validation import invalid, invalid_field

#: The longest loop delay searched (s).
MAX_DELAY_S = 0.01


class Stage(NamedTuple):
    """One stage of the fit: pieces this long (s), starting this far apart (s), and the most
    Gauss-Newton iterations: the delay's scan and fits on a subset, then every piece."""

    piece_s: float
    spacing_s: float
    max_iters: int


STAGES = (Stage(PIECE_S, 5 * PIECE_S, 4), Stage(PIECE_S, 2 * PIECE_S, 4))
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
        scale = _damping_scale(v, mech)
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


def _damping_scale(v: float, mech: Mechanism) -> float:
    """The cables' damping scale: the nominal value, else 1 N s/m on elastic cables, else 1% of
    the force limit."""
    if v > 0:
        return v
    if mech.elastic:
        return 1.0
    return 0.01 * float(mech.max_tendon_force)


class Problem:
    """The fit's state: the fields, their bounds and scales, and the current pieces."""

    def __init__(
        self,
        recordings: Sequence[Recording],
        config: EnvConfig,
        names: list[str],
        box: dict[str, tuple[float, float, float]],
        threads: int,
    ) -> None:
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
        pieces = Pieces(
            self.recordings, cfg.ctrl_dt, d, stage.piece_s, stage.spacing_s, first=self.first
        )
        self.rep = Replay(pieces, Timing.of(cfg).n_substeps, self.threads)
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
        n = len(self.names)
        cols = np.reshape(x, (n, -1)) if n else np.zeros((0, 1))  # no field: the nominal arm
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
                    params,
                    self.residual,
                    optimizer="mujoco",
                    verbose=False,
                    max_iters=stage.max_iters,
                    eps=1e-6,
                    xtol=XTOL,
                    x_scale="jac",
                    mu_min=MU[0],
                    mu_factor=MU[1],
                    output=io.StringIO(),
                    iter_callback=_stop_when_flat,
                )
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

"""The fit: short open-loop pieces of the recordings, replayed on candidate arms by
``mujoco.rollout``, their joint angles compared with the measured ones.

Why pieces.  The arm is open-loop unstable to small errors: one rollout over seconds grows a
1e-10 change of the commands to tenths of a radian, so a fit over a whole recording stays where
it starts.  Each piece (``PIECE_S`` long) starts from the recording's state at its first row:

- the joints' angles and speeds from a Savitzky-Golay fit of the measured angles (``SMOOTH_S``
  wide, cubic);
- the motor lags' states by filtering the commands before it (the candidate's ``motor_tau``);
- each elastic cable stretched to carry its motor's force, still relative to the arm;

and its first ``SETTLE_S`` are left out of the comparison, in which the cables' and motors'
fast modes forget their approximate start.

The start's angles and speeds are still estimates: their errors grow along the piece, as a
change of the parameters would.  Two steps remove them.  Each piece's start is refined by
Gauss-Newton steps on its own residual (Replay.refine_starts), and the comparison is projected
off the four directions in which the angle trajectory moves with the start's (q, dq) (variable
projection), computed by finite differences.  Both are redone at each round's fit
(tendon2r_gym.identification.identify): a fit is then insensitive to the starts, to first
order.

The residual is in units of ``ANGLE_UNIT`` rad, one entry per joint and compared row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from tendon2r_gym.identification.recording import Recording
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.simulation.model import build_model
from tendon2r_gym.simulation.realism import Drive

PIECE_S = 0.1
SETTLE_S = 0.02
SMOOTH_S = 0.031
ANGLE_UNIT = 1e-4
#: The finite-difference steps of the start's angle (rad) and speed (rad/s) for the projection.
START_STEP = (1e-6, 1e-4)
_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS


def start_estimates(rec: Recording, ctrl_dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Returns (q, dq) at every row: a cubic Savitzky-Golay fit of the measured angles."""
    from scipy.signal import savgol_filter

    window = max(5, 2 * round(SMOOTH_S / ctrl_dt / 2) + 1)
    q = savgol_filter(rec.q, window, 3, axis=0, mode="interp")
    dq = savgol_filter(rec.q, window, 3, deriv=1, delta=ctrl_dt, axis=0, mode="interp")
    return q, dq


@dataclass
class Pieces:
    """The pieces of a set of recordings at one loop delay (whole control steps)."""

    recordings: list[Recording]
    ctrl_dt: float
    delay: int
    piece_s: float = PIECE_S
    #: Seconds between the pieces' starts (default: piece_s, back to back).
    spacing_s: float | None = None
    #: The first piece's first row (default: the first whose commands are all recorded).
    first: int | None = None
    starts: list[tuple[int, int]] = field(default_factory=list)  # (recording, first row)
    length: int = 0
    settle: int = 0
    _normalized: tuple[tuple, list[np.ndarray]] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.length = max(2, round(self.piece_s / self.ctrl_dt))
        self.settle = round(SETTLE_S / self.ctrl_dt)
        self._est = [start_estimates(r, self.ctrl_dt) for r in self.recordings]
        for i, rec in enumerate(self.recordings):
            T = len(rec.time)
            first = self.delay + 1 if self.first is None else max(self.first, self.delay + 1)
            every = max(self.length, round((self.spacing_s or self.piece_s) / self.ctrl_dt))
            self.starts += [(i, s) for s in range(first, T - self.length, every)]

    def __len__(self) -> int:
        return len(self.starts)

    def normalized(self, mech: Mechanism) -> list[np.ndarray]:
        """Returns each recording's commands as the motors' normalized commands on ``mech``
        (they depend only on its force limit and command map, which no fit changes: kept)."""
        key = (mech.command_map, float(mech.max_tendon_force))
        if self._normalized is None or self._normalized[0] != key:
            (gain, offset), force = key
            self._normalized = key, [(r.command / force - offset) / gain for r in self.recordings]
        return self._normalized[1]

    def commands(self, mech: Mechanism) -> np.ndarray:
        """Returns the normalized commands each piece's motors apply (P, length, n_tendons):
        the commands sent ``delay`` rows before."""
        u = self.normalized(mech)
        return np.array(
            [u[i][s - self.delay : s - self.delay + self.length] for i, s in self.starts]
        )

    def measured(self, speeds: bool = False) -> np.ndarray:
        """Returns the measured angles (or with ``speeds`` the measured speeds) each piece is
        compared with (P, length, 2): rows first + 1 .. first + length."""
        cols = [r.dq if speeds else r.q for r in self.recordings]
        return np.array([cols[i][s + 1 : s + 1 + self.length] for i, s in self.starts])

    def lag_states(self, mech: Mechanism, n_sub: int) -> np.ndarray:
        """Returns each piece's motor lag states at its first row (P, n_tendons): the applied
        commands before it through the candidate's lag, from the first command."""
        h = mech.sim_dt / mech.motor_tau
        step = (
            1.0 - math.exp(-h)
            if mech.integrator != "RK4"
            else 1.0 - (1 - h + h * h / 2 - h**3 / 6 + h**4 / 24)
        )
        keep = (1.0 - step) ** n_sub  # one control step of n_sub physics steps
        M = max(1, round(30 * mech.motor_tau / self.ctrl_dt))  # older rows weigh < e^-30
        weights = (1.0 - keep) * keep ** np.arange(M - 1, -1, -1)
        out = []
        for i, u in enumerate(self.normalized(mech)):
            padded = np.concatenate([np.repeat(u[:1], M, axis=0), u])  # at rest before
            rows = [s - self.delay for j, s in self.starts if j == i]
            windows = np.stack([padded[r : r + M] for r in rows])  # the M rows before each
            out.append(keep**M * windows[:, 0] + np.einsum("m,pmn->pn", weights, windows))
        return np.concatenate(out)


class Replay:
    """Rolls the pieces out on candidate arms (one MjModel per candidate, each over every
    piece, in one threaded ``mujoco.rollout`` call)."""

    def __init__(self, pieces: Pieces, n_sub: int, threads: int) -> None:
        self.pieces, self.n_sub = pieces, n_sub
        self.threads = threads
        self._measured = pieces.measured()
        self._start = []
        for i, s in pieces.starts:
            q, dq = pieces._est[i]
            self._start.append((q[s], dq[s]))
        self.projection: np.ndarray | None = None  # (P, 2 length, 4) orthonormal

    def initial_states(
        self, model: mujoco.MjModel, mech: Mechanism, shift: np.ndarray | None = None
    ) -> np.ndarray:
        """Returns each piece's full physics state on ``model`` (P, nstate); ``shift``
        (P, 4) moves each start's (q, dq)."""
        data = mujoco.MjData(model)
        drive = Drive(model, mech)
        gain, offset = mech.command_map
        force = float(mech.max_tendon_force)
        acts = self.pieces.lag_states(mech, self.n_sub) if mech.motor_tau > 0 else None
        ctrl = self.pieces.commands(mech)[:, 0]
        size = mujoco.mj_stateSize(model, _STATE)
        out = np.empty((len(self.pieces), size))
        for p, (q, dq) in enumerate(self._start):
            q, dq = np.array(q), np.array(dq)
            if shift is not None:
                q, dq = q + shift[p, :2], dq + shift[p, 2:]
            mujoco.mj_resetData(model, data)
            act = acts[p] if acts is not None else ctrl[p]
            tension = force * (gain * act + offset)
            drive.settle(data, q, dq, tension=tension)
            if acts is not None:
                data.act[:] = acts[p]
            mujoco.mj_getState(model, data, out[p], _STATE)
        return out

    def angles(
        self,
        mechs: list[Mechanism],
        shifts: list[np.ndarray | None] | None = None,
        speeds: bool = False,
    ) -> np.ndarray:
        """Returns the predicted angles (len(mechs), P, length, 2) of every piece on each
        candidate arm (a diverged rollout is reset by MuJoCo: its angles miss widely)."""
        pieces, n_sub = self.pieces, self.n_sub
        shifts = shifts or [None] * len(mechs)
        models, states = [], []
        built: dict[int, mujoco.MjModel] = {}  # one model per distinct arm
        for mech, shift in zip(mechs, shifts, strict=True):
            if id(mech) not in built:
                built[id(mech)] = build_model(mech)
            model = built[id(mech)]
            models += [model] * len(pieces)
            states.append(self.initial_states(model, mech, shift))
        ctrl = np.repeat(pieces.commands(mechs[0]), n_sub, axis=1)
        ctrl = np.tile(ctrl, (len(mechs), 1, 1))
        datas = [mujoco.MjData(models[0]) for _ in range(self.threads)]
        # A candidate the integrator cannot integrate diverges: MuJoCo resets it (its angles
        # then miss the recording widely) and warns, which would print once per rollout.
        warned = mujoco.get_mju_user_warning()
        mujoco.set_mju_user_warning(lambda _message: None)
        try:
            state, _ = mj_rollout.rollout(models, datas, np.concatenate(states), ctrl)
        finally:
            mujoco.set_mju_user_warning(warned)
        # After each control step; time comes first, then qpos, then qvel.
        first = 1 + models[0].nq if speeds else 1
        q = state[:, n_sub - 1 :: n_sub, first : first + 2]
        return q.reshape(len(mechs), len(pieces), pieces.length, 2)

    def noise(self, mech: Mechanism) -> tuple[float, float | None]:
        """Returns the sensors' noise std on ``mech`` (the fit): of the angles, and of the
        speeds (None without measured speeds), from each measured signal's difference with
        its replay after the settling rows.  Their third differences are used: a white
        noise's variance grows 20-fold there, while the replay's smooth errors (a poor fit's,
        or the start's) vanish, so a poor fit does not inflate the angles' estimate.  The
        speeds' replay still misses a wrong arm's response to each step's command (a
        mass that is off by half adds about a fifth to the speeds' estimate)."""
        pieces, settle = self.pieces, self.pieces.settle

        def std(replayed: np.ndarray, measured: np.ndarray) -> float:
            third = np.diff((replayed - measured)[:, settle:], n=3, axis=1)
            return float(np.sqrt(np.mean(third**2) / 20.0))

        angle = std(self.angles([mech])[0], self._measured)
        if any(rec.dq is None for rec in pieces.recordings):
            return angle, None
        return angle, std(self.angles([mech], speeds=True)[0], pieces.measured(speeds=True))

    def set_projection(self, mech: Mechanism) -> tuple[np.ndarray, np.ndarray]:
        """Computes each piece's start directions at ``mech`` (module docstring); returns the
        angles there (P, 2 length) and the directions before orthonormalization."""
        P = len(self.pieces)
        shifts: list[np.ndarray | None] = [None]
        for k in range(4):
            s = np.zeros((P, 4))
            s[:, k] = START_STEP[k // 2]
            shifts.append(s)
        q = self.angles([mech] * 5, shifts)
        base = q[0].reshape(P, -1)
        cols = np.stack(
            [(q[k + 1].reshape(P, -1) - base) / START_STEP[k // 2] for k in range(4)], axis=2
        )
        cols[:, : 2 * self.pieces.settle] = 0.0
        cols = np.nan_to_num(cols)
        self.projection = np.linalg.qr(cols)[0]  # (P, 2 length, 4)
        return base, cols

    def refine_starts(self, mech: Mechanism, passes: int = 2) -> None:
        """Moves each piece's start (q, dq) by the Gauss-Newton step that best explains its
        residual on ``mech`` (``passes`` times): the start's errors are then small enough for
        the projection's linearization even where the smoothed estimate misses fast motion.
        The projection is the last step's directions (set at ``mech`` if ``passes`` is 0):
        the start moves little, and setting them again would cost as much as a pass."""
        for _ in range(passes):
            base, cols = self.set_projection(mech)
            err = np.nan_to_num(base - self._measured.reshape(len(self.pieces), -1))
            err[:, : 2 * self.pieces.settle] = 0.0
            for p, (q, dq) in enumerate(self._start):
                step = np.linalg.lstsq(cols[p], -err[p], rcond=None)[0]
                self._start[p] = (q + step[:2], dq + step[2:])
        if passes < 1:  # else the last pass's directions serve: the start moved little
            self.set_projection(mech)

    def residual(self, mechs: list[Mechanism]) -> np.ndarray:
        """Returns the residual of each candidate (len(mechs), P, 2 length): predicted minus
        measured angles over each piece after its settling rows, in ANGLE_UNIT, projected off
        the start directions (a non-finite entry is 1e6)."""
        q = self.angles(mechs)
        P = len(self.pieces)
        r = (q - self._measured[None]) / ANGLE_UNIT
        r[:, :, : self.pieces.settle] = 0.0
        r = r.reshape(len(mechs), P, -1)
        if self.projection is not None:
            Qm = self.projection
            r = r - np.einsum("pik,cpk->cpi", Qm, np.einsum("pik,cpi->cpk", Qm, r))
        return np.where(np.isfinite(r), r, 1e6)


def cluster_covariance(J: np.ndarray, r: np.ndarray, groups: int) -> np.ndarray:
    """Returns the parameter covariance of a least-squares fit with Jacobian ``J`` (rows
    grouped into ``groups`` equal consecutive pieces) and residual ``r``, robust to errors
    correlated within a piece (the sandwich estimator with one cluster per piece, and the
    small-sample factor G / (G - 1)): the toolbox's white-noise interval assumes independent
    rows, which the start's errors are not."""
    H_inv = np.linalg.pinv(J.T @ J)
    scores = np.einsum("gri,gr->gi", J.reshape(groups, -1, J.shape[1]), r.reshape(groups, -1))
    meat = scores.T @ scores * groups / max(groups - 1, 1)
    return H_inv @ meat @ H_inv

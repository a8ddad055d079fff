"""Actuation: tendon moment arms, whether the tendons can drive both joints, and how joint
torques become tendon tensions.

Conventions.  J = dL/dq is the moment-arm matrix, one row per tendon, one column per joint.  A
tendon's *tension* t is positive when it pulls; pulling shortens the tendon, so the joint
torques are tau = -J^T t (MuJoCo: a positive tendon-actuator force lengthens the tendon, so the
motor force is -t).

Tension distribution (:func:`distribute`).  The minimum-norm tensions are
t0 = -J (J^T J + lam^2 I)^-1 tau (lam^2 = damping |J|_F^2 keeps them finite near singular
configurations).  Push-pull motors apply t0.  Pull-only motors add a multiple of a strictly
positive null vector n of J^T, which changes no joint torque:  t = t0 + alpha n, with alpha
the smallest value that keeps every tension >= the pretension.  Such an n exists exactly when
the rows of J *positively span* the torque plane (:func:`positive_span`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import mujoco
import numpy as np

if TYPE_CHECKING:
    from tendon2r_gym.reference import Reference

#: ``max_tendon_force: auto`` is this many times the peak force that inverse dynamics of the
#: reference needs: PD's feedback and the start-up transient need room above feed-forward.
FORCE_HEADROOM = 2.0


def cond(J: np.ndarray) -> float:
    """Returns the 2-norm condition number of an n x 2 moment-arm matrix (closed form on the
    2 x 2 Gram matrix J^T J, no SVD; inf if rank deficient)."""
    rows = (J if isinstance(J, np.ndarray) else np.asarray(J, dtype=np.float64)).tolist()
    g11 = g22 = g12 = 0.0  # scalar math: this runs in every env step's info
    for a, b in rows:
        g11 += a * a
        g22 += b * b
        g12 += a * b
    tr, det = g11 + g22, g11 * g22 - g12 * g12
    if not math.isfinite(tr) or det <= 1e-300 * max(tr * tr, 1e-300):
        return math.inf
    disc = math.sqrt(max(tr * tr - 4.0 * det, 0.0))
    return math.sqrt((tr + disc) / (tr - disc)) if tr > disc else math.inf


def positive_span(J: np.ndarray) -> tuple[bool, float]:
    """Returns (whether the rows of J positively span the plane, margin in rad).

    Pulling tendons can produce any joint torque exactly when their rows leave no angular gap
    of pi or more: the margin is pi minus the largest gap between consecutive row directions
    (> 0 when they span; for two tendons it is at most 0)."""
    rows = [r for r in np.asarray(J, dtype=np.float64).reshape(-1, 2) if np.hypot(*r) > 1e-12]
    if len(rows) < 3:
        return False, min(0.0, math.pi - _max_gap(rows)) if rows else -math.pi
    margin = math.pi - _max_gap(rows)
    return margin > 1e-9, margin


def _max_gap(rows: Sequence[np.ndarray]) -> float:
    angles = sorted(math.atan2(r[1], r[0]) for r in rows)
    gaps = [b - a for a, b in itertools.pairwise(angles)]
    return max([*gaps, 2 * math.pi - (angles[-1] - angles[0])])


def nominal_moment_arms(sides: Sequence[Sequence[int]], r1: float, r2: float) -> np.ndarray:
    """Returns the moment arms of straight tendons on the pulleys: rows (-s1 r1, -s2 r2)."""
    return np.array([(-s1 * r1, -s2 * r2) for s1, s2 in sides], dtype=np.float64)


def positive_span_of_sides(
    sides: Sequence[Sequence[int]], r1: float, r2: float
) -> tuple[bool, str]:
    """Returns whether a routing's nominal moment arms positively span, and why not."""
    if len(sides) < 3:
        return False, (
            f"{len(sides)} pull-only tendons cannot reverse a joint torque; they need n + 1 = 3 "
            "tendons whose moment arms positively span the torque plane"
        )
    spans, margin = positive_span(nominal_moment_arms(sides, r1, r2))
    if not spans:
        return False, (
            f"its moment arms do not positively span the torque plane (margin {margin:.3g} "
            "rad); tendons that wrap both pulleys give corners (+-r1, +-r2), which span only on "
            "the boundary: add a tendon that ends on link c (side 0 on pulley 2)"
        )
    return True, ""


def null_direction(J: np.ndarray) -> np.ndarray | None:
    """Returns a unit null vector n of J^T with every entry > 0, or None if none exists.

    Three tendons have a one-dimensional null space (the cross product of J's columns); more
    tendons use the sum of the positive null vectors of every spanning triple."""
    J = np.asarray(J, dtype=np.float64)
    total = np.zeros(len(J))
    for idx in itertools.combinations(range(len(J)), 3):
        sub = J[list(idx)]
        n = np.cross(sub[:, 0], sub[:, 1])
        if np.all(n > 0) or np.all(n < 0):
            total[list(idx)] += np.abs(n) / np.linalg.norm(n)
    if not np.all(total > 0):
        return None
    return total / np.linalg.norm(total)


def distribute(
    J: np.ndarray,
    tau: np.ndarray,
    pull_only: bool,
    pretension: float = 0.0,
    damping: float = 0.0,
) -> np.ndarray:
    """Returns the tendon tensions t (N, positive pulling) with -J^T t = tau (see the module
    docstring), for one configuration (J (n, 2), tau (2,)) or a batch (J (B, n, 2), tau
    (B, 2)).  Pull-only tensions are >= pretension where J positively spans; where J is zero
    or singular there is no force (pull-only: the pretension)."""
    J, tau = np.asarray(J, dtype=np.float64), np.asarray(tau, dtype=np.float64)
    single = J.ndim == 2
    if single:
        J, tau = J[None], tau[None]
    gram = np.einsum("bki,bkj->bij", J, J)
    lam2 = damping * (gram[:, 0, 0] + gram[:, 1, 1])  # damping |J|_F^2
    a11, a22, a12 = gram[:, 0, 0] + lam2, gram[:, 1, 1] + lam2, gram[:, 0, 1]
    det = a11 * a22 - a12 * a12
    ok = det > 1e-300 * np.maximum(a11 * a22, 1e-300)  # closed-form 2 x 2 solve where regular
    det = np.where(ok, det, 1.0)
    x = np.stack([a22 * tau[:, 0] - a12 * tau[:, 1], a11 * tau[:, 1] - a12 * tau[:, 0]], 1)
    t = np.where(ok[:, None], -np.einsum("bki,bi->bk", J, x / det[:, None]), 0.0)
    if pull_only:
        t = _pretension_shift(J, t, pretension)
    return t[0] if single else t


def _pretension_shift(J: np.ndarray, t: np.ndarray, pretension: float) -> np.ndarray:
    """Adds to each row of tensions the multiple of the positive null vector of J^T that lifts
    the least tension to the pretension; rows without one are only floored at it."""
    if J.shape[1] == 3:  # the null vector is the cross product of J's columns
        n = np.cross(J[:, :, 0], J[:, :, 1])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        n *= np.where(n[:, :1] < 0, -1.0, 1.0)
        spans = np.all(n > 0, axis=1)
    else:
        null = [null_direction(j) for j in J]
        spans = np.array([v is not None for v in null])
        n = np.array([v if v is not None else np.ones(J.shape[1]) for v in null])
    safe = np.where(spans[:, None], n, 1.0)
    shift = np.max((pretension - t) / safe, axis=1, keepdims=True)
    return np.where(spans[:, None], t + shift * n, np.maximum(t, pretension))


class MomentArms:
    """Reads the dense moment-arm matrix J = dL/dq (m, one row per tendon, one column per
    joint) out of MjData, as last computed (by mj_fwdPosition, mj_forward or mj_step).

    MuJoCo 4 stores ten_J sparse, with the model's row pattern: a tendon that ends on link c
    has no entry for joint B.  When every row is full, the sparse layout is the dense one and
    :meth:`dense` returns a view (no copy on the hot path)."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self._data = data
        self._shape = (model.ntendon, model.nv)
        self._full = bool(np.all(model.ten_J_rownnz == model.nv))
        self._view = data.ten_J.reshape(self._shape) if self._full else None
        self._pattern = (model.ten_J_rownnz, model.ten_J_rowadr, model.ten_J_colind)
        self._buf = np.zeros(self._shape)

    def dense(self) -> np.ndarray:
        """Returns J (a view into MjData when every row is full, else a reused buffer)."""
        if self._full:
            return self._view
        mujoco.mju_sparse2dense(self._buf, self._data.ten_J, *self._pattern)
        return self._buf


class ActuationAnalysis:
    """Moment arms and inertia of a model at any joint configuration, on a private MjData."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self._J = MomentArms(model, self.data)

    def set_configuration(self, q: np.ndarray) -> None:
        """Runs the position stage of the model at joint angles q (rad)."""
        self.data.qpos[:] = q
        mujoco.mj_fwdPosition(self.model, self.data)

    def moment_arms(self, q: np.ndarray) -> np.ndarray:
        """Returns the tendon moment-arm matrix J(q) = dL/dq (m), shape (ntendon, nv)."""
        self.set_configuration(q)
        return self._J.dense().copy()

    def condition_number(self, q: np.ndarray) -> float:
        """Returns cond(J(q)): 1 is ideal, large means the tendons cannot drive both joints."""
        return cond(self.moment_arms(q))

    def span_margin(self, q: np.ndarray) -> float:
        """Returns the positive-span margin (rad) of J(q): > 0 when pull-only tendons can
        produce any joint torque there."""
        return positive_span(self.moment_arms(q))[1]

    def grid(self, q1: np.ndarray, q2: np.ndarray, fn) -> np.ndarray:
        """Returns fn(q) on the grid q1 x q2 (rad), shape (len(q1), len(q2))."""
        return np.array([[fn(np.array([a, b])) for b in q2] for a in q1])


def force_need(
    model: mujoco.MjModel,
    references: Sequence[Reference],
    pull_only: bool = False,
    pretension: float = 0.0,
    grid: int = 24,
) -> float:
    """Returns the peak tendon tension (N) that inverse dynamics needs to follow any of
    ``references`` exactly, over every combination of the two joints' phases.

    Each joint j moves as q = bias + amp sin(theta_j); the torques tau come from mj_inverse at
    (q, dq, ddq) on a ``grid`` x ``grid`` grid of (theta_A, theta_B), and the tensions from
    :func:`distribute` (with the pretension for pull-only tendons).  Taking every phase pair
    bounds the need of any start time, phase and episode length."""
    data = mujoco.MjData(model)
    arms = MomentArms(model, data)
    theta = np.linspace(0.0, 2.0 * np.pi, grid, endpoint=False)
    s = np.stack(np.meshgrid(np.sin(theta), np.sin(theta), indexing="ij"), -1).reshape(-1, 2)
    c = np.stack(np.meshgrid(np.cos(theta), np.cos(theta), indexing="ij"), -1).reshape(-1, 2)
    peak = 0.0
    for ref in references:
        amp, bias, w = ref._amp, ref._bias, ref._omega
        for si, ci in zip(s, c, strict=True):
            data.qpos[:] = bias + amp * si
            data.qvel[:] = amp * w * ci
            data.qacc[:] = -amp * w * w * si
            mujoco.mj_inverse(model, data)
            t = distribute(arms.dense(), data.qfrc_inverse, pull_only, pretension)
            peak = max(peak, float(np.max(np.abs(t))))
    return peak

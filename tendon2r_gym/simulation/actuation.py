"""Actuation: tendon moment arms, whether the tendons can drive both joints, and how joint
torques become tendon tensions.

Conventions.  J = dL/dq is the moment-arm matrix, one row per tendon, one column per joint.  A
tendon's *tension* t is positive when it pulls; pulling shortens the tendon, so the joint
torques are tau = -J^T t (MuJoCo: a positive tendon-actuator force lengthens the tendon, so the
motor force is -t).

Tension distribution (`distribute`).  The minimum-norm tensions are
t0 = -J (J^T J + lam^2 I)^-1 tau (lam^2 = damping |J|_F^2 keeps them finite near singular
configurations).  Push-pull motors apply t0.  Pull-only motors add a multiple of a strictly
positive null vector n of J^T, which changes no joint torque:  t = t0 + alpha n, with alpha
the smallest value that keeps every tension >= the pretension.  Such an n exists exactly when
the rows of J *positively span* the torque plane (tendon2r_gym.simulation.routing.positive_span).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import cached_property
from typing import Any

import mujoco
import numpy as np

from tendon2r_gym.ops import SCALAR, Ops
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.simulation.model import build_model
from tendon2r_gym.simulation.routing import null_direction, positive_span

#: Damping of the tension distribution's inverse, relative to |J|_F^2 (PD's default, and the
#: env's in ``action_mode="joint_torque"``).
FORCE_DAMPING = 1e-3


def cond(J: np.ndarray) -> float:
    """Returns the 2-norm condition number of an n x 2 moment-arm matrix (closed form on the
    2 x 2 Gram matrix J^T J, no SVD; inf if rank deficient)."""
    rows = (J if isinstance(J, np.ndarray) else np.asarray(J, dtype=np.float64)).tolist()
    return cond_of_rows(SCALAR, rows)


def cond_of_rows(ops: Ops, rows: Sequence[Sequence[Any]]) -> Any:
    """Returns cond(J) from J's rows [(dL_k/dq1, dL_k/dq2), ...]: floats (``ops`` SCALAR) or
    arrays over N arms (BATCH), the same bits either way; inf where J is rank deficient."""
    g11 = g22 = g12 = 0.0
    for a, b in rows:
        g11 += a * a
        g22 += b * b
        g12 += a * b
    tr, det = g11 + g22, g11 * g22 - g12 * g12
    disc = ops.sqrt(ops.maximum(tr * tr - 4.0 * det, 0.0))
    regular = ops.isfinite(tr) & (det > 1e-300 * ops.maximum(tr * tr, 1e-300)) & (tr > disc)
    return ops.where(regular, ops.sqrt((tr + disc) / ops.where(regular, tr - disc, 1.0)), math.inf)


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
    `dense` returns a view (no copy on the hot path)."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self._data = data
        self._shape = (model.ntendon, model.nv)
        self._full = bool(np.all(model.ten_J_rownnz == model.nv))
        self._view = data.ten_J.reshape(self._shape) if self._full else None
        self._ideal = self._shape == (model.nu, 2)
        # Otherwise, a realistic model (tendon2r_gym.simulation.realism) has spool joints after the
        # arm's
        # two and passive friction tendons after the motors' ones, and a tendon may end before
        # joint B: J keeps the motors' rows (one motor per tendon) and the arm's columns,
        # gathered from where they sit in the sparse ten_J (the pattern is the model's), or
        # from a zero appended after it where a tendon does not span the joint (index nnz).
        nnz = data.ten_J.size
        at = {
            (i, int(model.ten_J_colind[adr])): adr
            for i in range(model.nu)
            for adr in range(model.ten_J_rowadr[i], model.ten_J_rowadr[i] + model.ten_J_rownnz[i])
        }
        self._pairs = [tuple(at.get((i, j), nnz) for j in (0, 1)) for i in range(model.nu)]

    def dense(self) -> np.ndarray:
        """Returns J (n_tendons, 2): a view into MjData when every row is full and the model
        has only the arm's joints and the motors' tendons, else a new array of the motor
        tendons' rows over the arm's joints."""
        if self._full and self._ideal:
            return self._view
        return np.array(self.rows())

    def rows(self) -> list[Sequence[float]]:
        """Returns `dense`'s rows as Python floats, the same bits (what cond_of_rows
        takes; the env's info reads them at every step, so no array is built)."""
        if self._full and self._ideal:
            return self._view.tolist()
        flat = [*self._data.ten_J.tolist(), 0.0]
        return [(flat[i], flat[j]) for i, j in self._pairs]


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


class TorqueToTension:
    """Joint torques -> normalized tendon commands for one mechanism, or one per row of a batch
    (`follow`: random arms), from a private copy of each nominal model
    (`Mechanism.ideal`, never the env's MjData): the moment arms at q,
    `distribute`, then the inverse of `Mechanism.command_map` (push-pull: -t / F;
    pull-only: 2 t / F - 1, F = max_tendon_force), clipped to [-1, 1].  PD and computed
    torque command the tendons through it, and so does the env in
    ``action_mode="joint_torque"``."""

    def __init__(self, mechanism: Mechanism, damping: float = FORCE_DAMPING) -> None:
        self.damping = damping
        self.mechanisms: list[Mechanism] = []
        self._models: list[mujoco.MjModel] = []
        self._batches: dict[int, _Kinematics] = {}
        self.follow([mechanism])

    def follow(self, mechanisms: Sequence[Mechanism]) -> None:
        """Controls the arms ``mechanisms``: one for every row of a batch, or one per row (N
        arms, each with its own model; an unchanged arm keeps its model)."""
        mechanisms = list(mechanisms)
        old = self.mechanisms
        if len(old) == len(mechanisms) and all(
            a is b for a, b in zip(old, mechanisms, strict=True)
        ):
            return
        kept = dict(zip(map(id, old), self._models, strict=True))
        # The nominal model: a controller's model of the arm knows no stretch, lag, friction or
        # model error (density_scale, extra_joint_damping).
        self._models = [kept.get(id(m)) or build_model(m.ideal()) for m in mechanisms]
        self.mechanisms = mechanisms
        self.mechanism = mechanisms[0]
        self.model = self._models[0]
        self.data = mujoco.MjData(self.model)
        self._arms = MomentArms(self.model, self.data)
        self._M = np.zeros((self.model.nv, self.model.nv))
        self._pull_only = self.mechanism.pull_only
        self._command_map = self.mechanism.command_map
        per_arm = lambda name: np.array([getattr(m, name) for m in mechanisms])[:, None]  # noqa: E731
        if len(mechanisms) == 1:
            self._max_force, self._pretension = (
                self.mechanism.max_tendon_force,
                self.mechanism.pretension,
            )
        else:
            self._max_force, self._pretension = per_arm("max_tendon_force"), per_arm("pretension")
        for n, batch in self._batches.items():
            batch.set_models(self._models if len(self._models) == n else None)
        self.__dict__.pop("max_torque", None)  # a cached_property of the arms

    def model_of(self, row: int) -> mujoco.MjModel:
        """Returns the nominal model of a batch's row (the one model of a single arm)."""
        return self._models[row if len(self._models) > 1 else 0]

    def kinematics(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Returns the moment arms J (N, n_tendons, 2) and the inertia M (N, 2, 2) at the joint
        angles q (N, 2), from the private models (one mujoco.batch call for N > 1)."""
        if len(q) == 1 and len(self._models) == 1:
            self.data.qpos[:] = q[0]
            mujoco.mj_fwdPosition(self.model, self.data)
            mujoco.mj_fullM(self.model, self.data, self._M)
            return self._arms.dense()[None].copy(), self._M[None].copy()
        if len(self._models) not in (1, len(q)):
            raise ValueError(
                f"joint angles of {len(q)} arms are invalid; allowed: 1 or the "
                f"{len(self._models)} arms this controller follows"
            )
        batch = self._batches.get(len(q))
        if batch is None:
            batch = self._batches[len(q)] = _Kinematics(self.model, len(q))
            batch.set_models(self._models if len(self._models) == len(q) else None)
        return batch(q)

    def command(self, J: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Returns the clipped normalized commands (N, n_tendons) whose tensions give the joint
        torques tau (N, 2) through the moment arms J (N, n_tendons, 2)."""
        t = distribute(J, tau, self._pull_only, self._pretension, self.damping)
        gain, offset = self._command_map
        u = (t / self._max_force - offset) / gain
        return np.clip(u, -1.0, 1.0).astype(np.float32)

    @cached_property
    def max_torque(self) -> np.ndarray:
        """The torque (N m) each joint alone reaches at q = 0 before a tendon saturates, with
        push-pull tendons of limit F: F / max_k |(J^+)^T_kj| (J^+ the pseudo-inverse, J
        (J^T J)^-1 when J has full rank); the scale of a normalized joint-torque action, (2,)
        or (N, 2) per arm.  A joint that no tendon spans gets 0."""
        J, _ = self.kinematics(np.zeros((len(self._models), 2)))
        out = max_joint_torque(J, np.reshape(self._max_force, (-1, 1)))
        return out[0] if len(self._models) == 1 else out

    def joint_torque_command(self, q: np.ndarray, action: np.ndarray) -> np.ndarray:
        """Returns the tendon commands (N, n_tendons) of normalized joint torques ``action``
        (N, 2) at the joint angles q (N, 2): ``action_mode="joint_torque"`` in both envs."""
        J, _ = self.kinematics(q)
        return self.command(J, self.max_torque * action)


def max_joint_torque(J: np.ndarray, max_force: Any) -> np.ndarray:
    """Returns the torque (N m) each joint alone reaches before a tendon of limit
    ``max_force`` (N) saturates, through the moment arms J (..., n_tendons, 2): F / max_k
    |(J^+)^T_kj|, 0 for a joint that no tendon spans (`TorqueToTension.max_torque`)."""
    peak = np.max(np.abs(np.linalg.pinv(J)), axis=-1)  # (..., 2): per joint
    return np.where(peak > 0, max_force / np.where(peak > 0, peak, 1.0), 0.0)


class _Kinematics:
    """M(q) and J(q) of N configurations in one mujoco.batch forward call (position stage)."""

    def __init__(self, model: mujoco.MjModel, n: int) -> None:
        from mujoco import batch as mj_batch

        self.batch = mj_batch.Batch(model, n, nthread=1)
        self.set_models = self.batch.set_models
        self.qpos = self.batch.bind("qpos")
        self.M, self.J = self.batch.bind("M"), self.batch.bind("ten_J")  # bound before calls
        self.m_idx = _sparse_index(model.M_rownnz, model.M_rowadr, model.M_colind)
        self.j_idx = _sparse_index(model.ten_J_rownnz, model.ten_J_rowadr, model.ten_J_colind)
        self.shapes = (model.nv, model.nv), (model.ntendon, model.nv)

    def __call__(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.qpos[:] = q
        self.batch.forward(stage=mujoco.mjtStage.mjSTAGE_POS.value)
        n = len(q)
        M, J = np.zeros((n, *self.shapes[0])), np.zeros((n, *self.shapes[1]))
        (mr, mc), (jr, jc) = self.m_idx, self.j_idx
        M[:, mr, mc] = self.M
        M[:, mc, mr] = self.M  # the lower triangle is stored: mirror it
        J[:, jr, jc] = self.J
        return J, M


def _sparse_index(rownnz: np.ndarray, rowadr: np.ndarray, colind: np.ndarray):
    """Returns (rows, cols) of each stored entry of a MuJoCo sparse matrix."""
    rows = np.concatenate([np.full(nnz, r) for r, nnz in enumerate(rownnz)]).astype(int)
    pairs = zip(rowadr, rownnz, strict=True)
    cols = np.concatenate([colind[a : a + nnz] for a, nnz in pairs]).astype(int)
    return rows, cols


def sparse_rows(model: mujoco.MjModel) -> list[tuple[int | None, ...]]:
    """Returns, per motor's tendon and arm joint, the index of its entry in MuJoCo's sparse
    ten_J (None where the tendon does not span that joint: its moment arm is 0)."""
    rows = []
    for k in range(model.nu):  # one motor per tendon; passive friction tendons come after
        entries: list[int | None] = [None] * model.nv
        start = model.ten_J_rowadr[k]
        for idx in range(start, start + model.ten_J_rownnz[k]):
            entries[model.ten_J_colind[idx]] = int(idx)
        rows.append(tuple(entries[:2]))  # the arm's joints (spools come after)
    return rows

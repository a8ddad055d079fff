"""Actuation analysis: tendon moment arms and how well two tendons can drive two joints."""

from __future__ import annotations

import math
from collections.abc import Sequence

import mujoco
import numpy as np

from tendon2r_gym.reference import Reference


def cond2(J: np.ndarray) -> float:
    """Returns the 2-norm condition number of a 2x2 matrix (closed form, no SVD; inf if
    singular).  The singular values satisfy s^2 = (T +- sqrt(T^2 - 4 det^2)) / 2, T = |J|_F^2."""
    a, b, c, d = np.asarray(J, dtype=np.float64).ravel().tolist()
    t = a * a + b * b + c * c + d * d
    det = abs(a * d - b * c)
    if det <= 1e-300 * max(t, 1e-300) or not math.isfinite(t):
        return math.inf
    s_max_sq = (t + math.sqrt(max(t * t - 4.0 * det * det, 0.0))) / 2.0
    return s_max_sq / det  # s_max / s_min with s_min = det / s_max


def moment_arms_from_data(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """Returns the tendon moment-arm matrix J = dL/dq (m), one row per tendon, one column per
    joint, as last computed in ``data`` (by mj_fwdPosition, mj_forward or mj_step)."""
    return data.ten_J.reshape(model.ntendon, model.nv)


class ActuationAnalysis:
    """Moment arms and inertia of a model at any joint configuration, on a private MjData."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self._M = np.zeros((model.nv, model.nv))

    def set_configuration(self, q: np.ndarray) -> None:
        """Runs the position stage of the model at joint angles q (rad)."""
        self.data.qpos[:] = q
        mujoco.mj_fwdPosition(self.model, self.data)

    def moment_arms(self, q: np.ndarray) -> np.ndarray:
        """Returns the tendon moment-arm matrix J(q) = dL/dq (m), shape (ntendon, nv)."""
        self.set_configuration(q)
        return moment_arms_from_data(self.model, self.data).copy()

    def condition_number(self, q: np.ndarray) -> float:
        """Returns cond(J(q)): 1 is ideal, large means the tendons cannot drive both joints."""
        return cond2(self.moment_arms(q))

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """Returns the joint-space inertia matrix M(q) (kg m^2)."""
        self.set_configuration(q)
        mujoco.mj_fullM(self.model, self.data, self._M)
        return self._M.copy()

    def condition_map(self, q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
        """Returns cond(J) on the grid q1 x q2 (rad), shape (len(q1), len(q2))."""
        out = np.empty((len(q1), len(q2)))
        for i, a in enumerate(q1):
            for j, b in enumerate(q2):
                out[i, j] = self.condition_number(np.array([a, b]))
        return out


#: ``max_tendon_force: auto`` is this many times the peak force that inverse dynamics of the
#: reference needs: PD's feedback and the start-up transient need room above feed-forward.
FORCE_HEADROOM = 2.0


def force_need(model: mujoco.MjModel, references: Sequence[Reference], grid: int = 24) -> float:
    """Returns the peak tendon force (N) that inverse dynamics needs to follow any of
    ``references`` exactly, over every combination of the two joints' phases.

    Each joint j moves as q = bias + amp sin(theta_j); the torques tau come from mj_inverse at
    (q, dq, ddq) on a ``grid`` x ``grid`` grid of (theta_A, theta_B), and the tendon forces from
    the minimum-norm solution of J^T f = tau.  Taking every phase pair bounds the need of any
    start time, phase and episode length."""
    data = mujoco.MjData(model)
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
            J = moment_arms_from_data(model, data)
            f = np.linalg.lstsq(J.T, data.qfrc_inverse, rcond=None)[0]
            peak = max(peak, float(np.max(np.abs(f))))
    return peak

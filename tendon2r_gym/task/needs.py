"""What an arm needs to follow its references, from inverse dynamics of its nominal model.

`Needs` holds, over a set of references (the episode's, the corners of its ranges and a
floor motion): the peak tendon force, each joint's peak torque and torque rate, each joint's
control authority at the arm's force limit, and the actions that change the joints' speeds
(rate_to_action).  EnvConfig sizes ``max_tendon_force: auto`` from `force_needs` and
keeps an arm's Needs; the task scales rewards, observations and residuals by them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import mujoco
import numpy as np

from tendon2r_gym.simulation.actuation import MomentArms, distribute, max_joint_torque
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.simulation.model import build_model
from tendon2r_gym.simulation.stability import check_stability
from tendon2r_gym.task.reference import Reference


@dataclass(frozen=True)
class Needs:
    """An arm's needs over its references (the last one a floor motion, left out of the
    force and torque needs where the arm's references need more) at its force limit."""

    #: Peak tendon force (N) that inverse dynamics of the references needs (the pretension, if
    #: more, for pull-only tendons).
    force_need: float
    #: Peak torque (N m) of each joint that inverse dynamics of the references needs (the
    #: reset info's ``torque_need_Nm``).
    torque_need: tuple[float, float]
    #: Peak rate (N m / s) of each joint's torque that inverse dynamics of the references
    #: needs: the scale of the ``action_rate_need`` reward term (Formulas.rate_need_inverse).
    torque_rate_need: tuple[float, float]
    #: Each joint's control authority (rad/s per unit of normalized joint-torque action): the
    #: most its speed changes in one control step per unit of action on it alone, ctrl_dt
    #: max_torque_j (M(q)^-1)_jj (TorqueToTension.max_torque at this force limit) at the q
    #: of the references where the arm is lightest.  A derivative gain that is stable on
    #: one arm chatters on an arm of far more authority.
    control_authority: tuple[float, float]
    #: The normalized joint-torque actions that change the joints' speeds by dq (rad/s) in
    #: one control step, diag(1 / max_torque) M(q) / ctrl_dt, as a 2 x 2 matrix (rows: the
    #: actions) at the first reference's bias: the unit of ``error_units: action``.  Each
    #: joint's action moves the other's speed too, on some arms several times its own; in
    #: these units a policy's gain acts alike on every arm.  Infinite for a joint no tendon
    #: spans.
    rate_to_action: tuple[tuple[float, float], tuple[float, float]]

    @classmethod
    def of(cls, mech: Mechanism, refs: tuple[Reference, ...], ctrl_dt: float) -> Needs:
        """Returns the needs of ``mech`` (its force limit resolved) over ``refs``."""
        per_ref, torque_per_newton, inertia = _physics(
            mech.replace(max_tendon_force=1.0), tuple(refs)
        )
        torque = np.max([t for _, t, _, _ in per_ref], axis=0)
        rate = np.max([r for _, _, r, _ in per_ref], axis=0)
        inverse_inertia = np.max([m for *_, m in per_ref], axis=0)
        max_torque = mech.max_tendon_force * torque_per_newton
        authority = ctrl_dt * max_torque * inverse_inertia
        with np.errstate(divide="ignore"):  # a joint no tendon spans: no action moves it
            to_action = inertia / (ctrl_dt * max_torque[:, None])
        return cls(
            force_need=force_needs(mech, refs)[0],
            torque_need=(float(torque[0]), float(torque[1])),
            torque_rate_need=(float(rate[0]), float(rate[1])),
            control_authority=(float(authority[0]), float(authority[1])),
            rate_to_action=tuple(tuple(float(x) for x in row) for row in to_action),
        )


def force_needs(mech: Mechanism, refs: tuple[Reference, ...]) -> tuple[float, float]:
    """Returns the peak tendon force (N) that ``refs`` but the last need (with the pretension
    for pull-only tendons), and that of the last (the floor motion)."""
    per_ref, _, _ = _physics(mech.replace(max_tendon_force=1.0), tuple(refs))
    *needs, floor_need = [f for f, _, _, _ in per_ref]
    need = max(needs)
    if mech.pull_only:
        need = max(need, mech.pretension)
    return need, floor_need


@lru_cache(maxsize=64)
def _physics(
    mech: Mechanism, refs: tuple[Reference, ...]
) -> tuple[tuple[tuple[float, np.ndarray, np.ndarray, np.ndarray], ...], np.ndarray, np.ndarray]:
    """Checks that MuJoCo compiles ``mech`` and that the integrator can integrate it; returns,
    from the nominal model (no stretch, lag or friction: inverse dynamics of the arm), for
    each reference its force need (N), each joint's torque need (N m), torque-rate need (N m /
    s) and peak (M^-1)_jj (1 / (kg m^2)); each joint's torque per newton of force limit (N m /
    N, max_joint_torque at q = 0); and the inertia M (kg m^2, 2 x 2) at the first reference's
    bias."""
    model = build_model(mech)
    if mech.realistic:
        model = build_model(mech.ideal())
    check_stability(model, mech)
    out = []
    for r in refs:
        J, tau, inverse_inertia = inverse_dynamics_grid(model, [r])
        out.append(
            (
                peak_tension(J, tau, mech.pull_only, mech.pretension),
                np.max(np.abs(tau), 0),
                np.max(np.abs(torque_rate(tau, r)), 0),
                np.max(inverse_inertia, 0),
            )
        )
    data = mujoco.MjData(model)
    mujoco.mj_fwdPosition(model, data)  # q = 0
    unit_torque = max_joint_torque(MomentArms(model, data).dense(), 1.0)
    data.qpos[:2] = refs[0].bias_rad
    mujoco.mj_fwdPosition(model, data)
    inertia = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, inertia)
    return tuple(out), unit_torque, inertia[:2, :2]


def force_need(
    model: mujoco.MjModel,
    references: Sequence[Reference],
    pull_only: bool = False,
    pretension: float = 0.0,
    grid: int = 24,
) -> float:
    """Returns the peak tendon tension (N) that inverse dynamics needs to follow any of
    ``references`` exactly, over every combination of the two joints' phases: the tensions of
    `inverse_dynamics_grid`'s torques from tendon2r_gym.simulation.actuation.distribute (with
    the
    pretension for pull-only tendons)."""
    J, tau, _ = inverse_dynamics_grid(model, references, grid)
    return peak_tension(J, tau, pull_only, pretension)


def peak_tension(J: np.ndarray, tau: np.ndarray, pull_only: bool, pretension: float) -> float:
    """Returns the peak tendon tension (N) that gives the joint torques ``tau`` (K, 2) through
    the moment arms ``J`` (K, n_tendons, 2): tendon2r_gym.simulation.actuation.distribute, one
    batch."""
    return float(np.max(np.abs(distribute(J, tau, pull_only, pretension))))


def inverse_dynamics_grid(
    model: mujoco.MjModel, references: Sequence[Reference], grid: int = 24
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Returns the moment arms J (K, n_tendons, 2), the joint torques tau (K, 2) that inverse
    dynamics needs to follow ``references`` and the diagonal of the inverse inertia M(q)^-1
    (K, 2) at every combination of the two joints' phases.  Each joint j moves as q = bias +
    amp sin(theta_j); tau comes from mj_inverse at (q, dq, ddq) on a ``grid`` x ``grid`` grid
    of (theta_A, theta_B).  Taking every phase pair bounds the need of any start time, phase
    and episode length."""
    data = mujoco.MjData(model)
    arms = MomentArms(model, data)
    theta = np.linspace(0.0, 2.0 * np.pi, grid, endpoint=False)
    s = np.stack(np.meshgrid(np.sin(theta), np.sin(theta), indexing="ij"), -1).reshape(-1, 2)
    c = np.stack(np.meshgrid(np.cos(theta), np.cos(theta), indexing="ij"), -1).reshape(-1, 2)
    J, tau = [], []
    M = np.zeros((len(references) * len(s), model.nv, model.nv))
    for ref in references:
        amp, bias, w = ref.amp_rad, ref.bias_rad, ref.omega_array
        for q, dq, ddq in zip(bias + amp * s, amp * w * c, -amp * w * w * s, strict=True):
            data.qpos[:], data.qvel[:], data.qacc[:] = q, dq, ddq
            mujoco.mj_inverse(model, data)
            J.append(arms.dense().copy())
            tau.append(data.qfrc_inverse.copy())
            mujoco.mj_fullM(model, data, M[len(tau) - 1])
    inverse_inertia = np.diagonal(np.linalg.inv(M), axis1=1, axis2=2)[:, :2]
    return np.array(J), np.array(tau), inverse_inertia


def torque_rate(tau: np.ndarray, ref: Reference) -> np.ndarray:
    """Returns the rate (N m / s) of the joint torques ``tau`` (grid^2, 2) of one reference on
    `inverse_dynamics_grid`'s phase grid: d tau / dt = omega_A d tau / d theta_A + omega_B
    d tau / d theta_B, each partial a periodic central difference over the grid."""
    grid = math.isqrt(len(tau))
    t = tau.reshape(grid, grid, -1)
    step = 2.0 * (2.0 * math.pi / grid)
    d_a = (np.roll(t, -1, axis=0) - np.roll(t, 1, axis=0)) / step
    d_b = (np.roll(t, -1, axis=1) - np.roll(t, 1, axis=1)) / step
    w = ref.omega_array
    return (w[0] * d_a + w[1] * d_b).reshape(tau.shape)

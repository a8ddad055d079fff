"""Numerical stability: can the chosen integrator and sim_dt integrate this mechanism?

The criterion linearizes the unactuated arm about configurations over the joint range: with
M(q) the joint inertia and J(q) the tendon moment arms,

- damping rate   lambda = max eig(M^-1 D), D = (joint_damping + extra_joint_damping) I
  + tendon_damping J^T J,
  counting only the terms the integrator treats explicitly (MuJoCo's Euler integrates joint
  damping implicitly; implicit and implicitfast integrate all damping implicitly);
- stiffness rate omega  = sqrt(max eig(M^-1 tendon_stiffness J^T J));
- cable rate omega_c    = sqrt(tendon_elasticity (1 / motor_mass + max eig(J M^-1 J^T))), the
  highest frequency of a series-elastic cable between its spool and the arm (an upper bound:
  the spool's and the arm's mobilities add), held to the stiffness limit; a series-elastic
  cable's damping acts across the same two mobilities, so its rate is
  tendon_damping (1 / motor_mass + max eig(J M^-1 J^T));
- motor lag rate   1 / motor_tau, the motor filter's own mode (decoupled from the arm: the
  force follows the filter's state), which RK4 integrates explicitly (dyntype filter) and the
  other integrators exactly (filterexact, never unstable).

``model`` is the nominal (ideal) model of the mechanism: its two joints and its tendons; the
true inertia is the nominal one times ``density_scale`` (every mass is a geom's density times
its volume).

A run is accepted if lambda * sim_dt, omega * sim_dt and the lag rate * sim_dt stay below the
integrator's limits in `LIMITS`.  The study ``python -m research.studies.stability_limits``
(in the repository) measures them on the compiled default mechanism at sim_dt = 1 ms (bisection
on each parameter until a 2 s episode diverges); the limits are set 20% below: for RK4
divergence started at lambda dt = 4.9-5.2 and omega dt = 3.4; for Euler at 4.4 (tendon damping)
and 1.9; for implicitfast at omega dt = 1.9; for implicit at 1.0.  MuJoCo's implicit
integrators (and Euler for joint damping) integrate damping implicitly: it diverges there only
at values thousands of times larger.
"""

from __future__ import annotations

import functools
import math
from collections import OrderedDict
from typing import NamedTuple

import mujoco
import numpy as np

from tendon2r_gym.simulation.actuation import MomentArms
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.validation import invalid


class Limits(NamedTuple):
    """An integrator's limits on rate x sim_dt (see the module docstring)."""

    damping: float  #: the arm's damping rate
    stiffness: float  #: the stiffness and cable rates
    explicit: tuple[str, ...]  #: the arm's damping terms that the integrator treats explicitly
    cable_damping: float  #: a series-elastic cable's damping rate (spool and arm)
    lag: float  #: the motor lag's rate (filterexact, outside RK4: exact, never unstable)


#: Measured divergence (research.studies.stability_limits) of cable damping: RK4 at rate x
#: sim_dt 3.6, Euler at 2.0 (implicitfast and implicit integrate it); of the motor lag: RK4 at
#: 2.79, the edge of RK4's stability on the negative real axis (2.785).  Each limit is 20% below.
LIMITS: dict[str, Limits] = {
    "RK4": Limits(4.0, 2.7, ("joint_damping", "tendon_damping"), 2.9, 2.2),
    "Euler": Limits(3.5, 1.5, ("tendon_damping",), 1.6, math.inf),
    "implicitfast": Limits(math.inf, 1.5, (), math.inf, math.inf),
    "implicit": Limits(math.inf, 0.8, (), math.inf, math.inf),
}


#: The joint-range maxima of the arm's mobilities by nominal arm (mobility_maxima), kept for
#: the last few arms: a fit or a training checks many arms of one geometry.
_MAXIMA: OrderedDict[tuple[Mechanism, int], tuple[float, float]] = OrderedDict()
_MAXIMA_KEPT = 64


def mobility_maxima(model: mujoco.MjModel, mech: Mechanism, grid: int = 7) -> tuple[float, float]:
    """Returns, over a grid of the joint range, the largest eigenvalue of J M^-1 J^T (the
    tendons' mobility) and of M^-1 (the joints'), at density_scale 1: only the nominal arm's
    geometry sets them (``model``: build_model(mech.ideal()))."""
    key = (mech.ideal(), grid)
    if key in _MAXIMA:
        _MAXIMA.move_to_end(key)
        return _MAXIMA[key]
    data = mujoco.MjData(model)
    arms = MomentArms(model, data)
    M = np.zeros((model.nv, model.nv))
    tendon = joint = 0.0
    lo, hi = mech.joint_range_rad
    for q1 in np.linspace(lo, hi, grid):
        for q2 in np.linspace(lo, hi, grid):
            data.qpos[:] = (q1, q2)
            mujoco.mj_fwdPosition(model, data)
            mujoco.mj_fullM(model, data, M)
            Minv = np.linalg.inv(M)
            J = arms.dense()
            tendon = max(tendon, float(np.max(np.abs(np.linalg.eigvals(Minv @ J.T @ J)))))
            joint = max(joint, float(np.max(np.abs(np.linalg.eigvals(Minv)))))
    _MAXIMA[key] = tendon, joint
    if len(_MAXIMA) > _MAXIMA_KEPT:
        _MAXIMA.popitem(last=False)
    return tendon, joint


def rates(model: mujoco.MjModel, mech: Mechanism, grid: int = 7) -> dict[str, float]:
    """Returns, over a grid of the joint range, the largest rate (1/s) that each of
    joint_damping, tendon_damping, tendon_stiffness, tendon_elasticity and motor_tau alone
    gives (``model``: the nominal model, build_model(mech.ideal())).  Each grows with its
    field and with a mobility, so each is largest where the mobility is (mobility_maxima)."""
    tendon, joint = (m / mech.density_scale for m in mobility_maxima(model, mech, grid))
    spool = 1.0 / mech.motor_mass if mech.elastic else 0.0  # the spool's mobility
    return {
        "joint_damping": mech.true_joint_damping * joint,
        "tendon_damping": mech.tendon_damping * (spool + tendon),
        "tendon_stiffness": math.sqrt(mech.tendon_stiffness * tendon),
        "tendon_elasticity": math.sqrt(mech.tendon_elasticity * (spool + tendon)),
        "motor_tau": 1.0 / mech.motor_tau if mech.motor_tau > 0 else 0.0,
    }


def check_stability(model: mujoco.MjModel, mech: Mechanism) -> None:
    """Raises a ValueError naming the field, its limit and the fix if the integrator cannot
    integrate ``mech`` at its sim_dt (see the module docstring for the criterion)."""
    limits = LIMITS[mech.integrator]
    damp_max, stiff_max = limits.damping, limits.stiffness
    r = rates(model, mech)
    dt = mech.sim_dt
    fix = "a smaller sim_dt, or integrator: implicitfast (damping is then implicit)"
    # A series-elastic cable's damping acts on its spool: it has its own limit.
    explicit = [k for k in limits.explicit if not (mech.elastic and k == "tendon_damping")]
    damping = sum(r[k] for k in explicit)
    if damping * dt > damp_max:
        field = max(explicit, key=lambda k: r[k])
        value = getattr(mech, field)
        if field == "joint_damping" and mech.extra_joint_damping > 0:
            field, value = "joint_damping + extra_joint_damping", mech.true_joint_damping
        limit = value * damp_max / (damping * dt)
        raise invalid(
            f"Mechanism.{field}",
            value,
            f"<= {limit:.3g} for {mech.integrator} at sim_dt = {dt} s (damping rate "
            f"{damping:.3g}/s x sim_dt must stay <= {damp_max}; fix: {fix})",
        )
    cable = r["tendon_damping"] if mech.elastic else 0.0
    if cable * dt > limits.cable_damping:
        raise invalid(
            "Mechanism.tendon_damping",
            mech.tendon_damping,
            f"<= {mech.tendon_damping * limits.cable_damping / (cable * dt):.3g} N s/m for "
            f"{mech.integrator} at sim_dt = {dt} s (a series-elastic cable's damping rate "
            f"{cable:.3g}/s x sim_dt must stay <= {limits.cable_damping}; fix: {fix}, or a "
            "larger motor_mass)",
        )
    for field, fix in (
        ("tendon_stiffness", "a smaller sim_dt"),
        ("tendon_elasticity", "a smaller sim_dt or a larger motor_mass"),
    ):
        if r[field] * dt > stiff_max:
            value = getattr(mech, field)
            limit = value * (stiff_max / (r[field] * dt)) ** 2
            raise invalid(
                f"Mechanism.{field}",
                value,
                f"<= {limit:.3g} N/m for {mech.integrator} at sim_dt = {dt} s (stiffness rate "
                f"{r[field]:.3g} rad/s x sim_dt must stay <= {stiff_max}; fix: {fix})",
            )
    lag_max = limits.lag
    if r["motor_tau"] * dt > lag_max:
        raise invalid(
            "Mechanism.motor_tau",
            mech.motor_tau,
            f">= {dt / lag_max:.3g} s for {mech.integrator} at sim_dt = {dt} s (lag rate "
            f"1 / motor_tau x sim_dt must stay <= {lag_max}; fix: a smaller sim_dt, or 0 for "
            "no lag, or integrator: implicitfast, which integrates the lag exactly)",
        )


@functools.lru_cache(maxsize=64)  # an experiment is resolved many times: one check per arm
def stable_sim_dt(mech: Mechanism, ctrl_dt: float, max_substeps: int) -> float:
    """Returns the step a mechanism whose sim_dt was left out gets: its own (the default) if
    the integrator keeps it stable, else the largest ctrl_dt / k below it (k <= max_substeps)
    that it does; its own if none does (the check then names the field and the fix).  A step
    that can be integrated never changes, so no config that was accepted changes."""
    from tendon2r_gym.simulation.model import build_model

    model = build_model(mech.ideal())
    first = max(1, math.ceil(ctrl_dt / mech.sim_dt - 1e-9))  # the substeps at its own step
    for k in range(first, max_substeps + 1):
        candidate = mech if k == first else mech.replace(sim_dt=ctrl_dt / k)
        try:
            check_stability(model, candidate)
        except ValueError:
            continue
        return candidate.sim_dt
    return mech.sim_dt

"""Where each integrator starts to diverge: the measurement behind
tendon2r_gym.simulation.stability.LIMITS.

    python -m research.studies.stability_limits   # per integrator and field, the threshold

For each integrator and each of joint_damping, tendon_damping and tendon_stiffness, bisects (in
log scale) the smallest value at which a 2 s unactuated episode of the default mechanism at
sim_dt = 1 ms diverges (a non-finite or > 1e4 rad/s velocity or actuator state, or MuJoCo's
bad-acceleration warning), and prints it with its rate x sim_dt
(tendon2r_gym.simulation.stability.rates).
Two more cases use the real_arm preset's series-elastic cables: ``cable_damping``
(tendon_damping across a spool and the arm) and ``motor_tau`` (the largest lag that diverges,
with the motors held at a constant command).  LIMITS are set 20% below these rates.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass
from typing import Annotated

import mujoco
import numpy as np

from tendon2r_gym.app.args import arg, parse
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.simulation.model import build_model
from tendon2r_gym.simulation.stability import LIMITS, rates

FIELDS = ("joint_damping", "tendon_damping", "tendon_stiffness", "cable_damping", "motor_tau")
#: The series-elastic cables of the cases that need them: the real_arm preset's spools and a
#: cable soft enough for every integrator (its rate x sim_dt is 0.5).
ELASTIC = {"tendon_elasticity": 400.0, "motor_mass": 0.002, "routing": "n_plus_1",
           "pull_only": True, "pretension": 0.02}  # fmt: skip


def mechanism(case: str, integrator: str, value: float) -> Mechanism:
    """Returns the default mechanism with ``case`` set to ``value``."""
    if case == "cable_damping":
        return Mechanism(integrator=integrator, tendon_damping=value, **ELASTIC)
    if case == "motor_tau":
        return Mechanism(integrator=integrator, motor_tau=value, **ELASTIC)
    return Mechanism(max_tendon_force=0.5, integrator=integrator, **{case: value})


def diverges(mech: Mechanism, steps: int = 2000) -> bool:
    """Returns whether an episode from a moving start, the motors held at half their range,
    diverges."""
    model = build_model(mech)
    data = mujoco.MjData(model)
    data.qpos[:2], data.qvel[:2] = (0.3, -0.4), (5.0, -5.0)
    data.ctrl[:] = 0.5 if mech.motor_tau > 0 else 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(steps):
            mujoco.mj_step(model, data)
            bad = data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number
            state = np.concatenate([data.qvel, data.act])
            if bad or not np.all(np.abs(state) < 1e4):
                return True
    return False


def threshold(case: str, integrator: str, iterations: int) -> float | None:
    """Returns the smallest diverging value of ``case`` (for motor_tau the largest: a short
    lag diverges), or None if none in its range diverges."""
    make = lambda v: mechanism(case, integrator, v)  # noqa: E731
    small_diverges = case == "motor_tau"
    lo, hi = 1e-9, 1.0 if small_diverges else 1e9  # Mechanism.motor_tau is at most 1 s
    if not diverges(make(lo if small_diverges else hi)):
        return None
    for _ in range(iterations):
        mid = math.sqrt(lo * hi)
        if diverges(make(mid)) == small_diverges:
            lo = mid
        else:
            hi = mid
    return lo if small_diverges else hi


@dataclass
class Args:
    """The stability limits' flags."""

    iterations: Annotated[int, arg("bisection steps (log scale)")] = 40


def main(argv: list[str] | None = None) -> dict:
    args = parse(Args, argv, __doc__)
    out: dict = {}
    for integrator in LIMITS:
        for field in FIELDS:
            value = threshold(field, integrator, args.iterations)
            row: dict = {"threshold": value}
            if value is not None:
                mech = mechanism(field, integrator, value)
                key = "tendon_damping" if field == "cable_damping" else field
                row["rate_x_sim_dt"] = rates(build_model(mech.ideal()), mech)[key] * mech.sim_dt
            out[f"{integrator}/{field}"] = row
            print(integrator, field, row, flush=True)
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()

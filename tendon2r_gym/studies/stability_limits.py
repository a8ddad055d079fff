"""Where each integrator starts to diverge: the measurement behind tendon2r_gym.stability.LIMITS.

    python scripts/stability_limits.py        # prints, per integrator and field, the threshold

For each integrator and each of joint_damping, tendon_damping and tendon_stiffness, bisects (in
log scale) the smallest value at which a 2 s unactuated episode of the default mechanism at
sim_dt = 1 ms diverges (a non-finite or > 1e4 rad/s velocity, or MuJoCo's bad-acceleration
warning), and prints it with its rate x sim_dt (tendon2r_gym.stability.rates).  LIMITS are set
20% below these rates.
"""

from __future__ import annotations

import argparse
import json
import math
import warnings

import mujoco
import numpy as np

from tendon2r_gym.mechanism import Mechanism
from tendon2r_gym.model import build_model
from tendon2r_gym.stability import LIMITS, rates

FIELDS = ("joint_damping", "tendon_damping", "tendon_stiffness")


def diverges(mech: Mechanism, steps: int = 2000) -> bool:
    """Returns whether an unactuated episode from a moving start diverges."""
    model = build_model(mech)
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = (0.3, -0.4), (5.0, -5.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(steps):
            mujoco.mj_step(model, data)
            bad = data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number
            if bad or not np.all(np.abs(data.qvel) < 1e4):
                return True
    return False


def threshold(field: str, integrator: str, iterations: int) -> float | None:
    """Returns the smallest diverging value of ``field`` (None: none up to 1e9)."""
    make = lambda v: Mechanism(max_tendon_force=0.5, integrator=integrator, **{field: v})  # noqa: E731
    lo, hi = 1e-9, 1e9
    if not diverges(make(hi)):
        return None
    for _ in range(iterations):
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if diverges(make(mid)) else (mid, hi)
    return hi


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--iterations", type=int, default=40, help="bisection steps (log scale)")
    args = p.parse_args(argv)
    out: dict = {}
    for integrator in LIMITS:
        for field in FIELDS:
            value = threshold(field, integrator, args.iterations)
            row: dict = {"threshold": value}
            if value is not None:
                mech = Mechanism(max_tendon_force=0.5, integrator=integrator, **{field: value})
                row["rate_x_sim_dt"] = rates(build_model(mech), mech)[field] * mech.sim_dt
            out[f"{integrator}/{field}"] = row
            print(integrator, field, row, flush=True)
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()

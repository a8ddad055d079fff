"""Shared fixtures: mechanism parameter sets the physics tests run on."""

import os

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

# Tests render and load models in one process: tendon2r_gym.llvm explains the load order.
from tendon2r_gym.llvm import load_triton  # noqa: E402

load_triton()

from tendon2r_gym import Mechanism  # noqa: E402

#: The default, report 002's mechanism, and two sets with other pulley/link proportions.
MECHANISMS = {
    "default": Mechanism(max_tendon_force=0.5),
    "report_002": Mechanism(R1=0.013, R2=0.045, a=0.040, b=0.042, c=0.087, max_tendon_force=1.5),
    "big_pulley1": Mechanism(R1=0.03, R2=0.01, a=0.02, b=0.12, c=0.06, max_tendon_force=1.0),
    "long_links": Mechanism(R1=0.02, R2=0.02, a=0.1, b=0.03, c=0.2, max_tendon_force=1.0),
    "pull_only": Mechanism(routing="n_plus_1", pull_only=True, max_tendon_force=1.0),
}


@pytest.fixture(params=sorted(MECHANISMS))
def mech(request) -> Mechanism:
    return MECHANISMS[request.param]

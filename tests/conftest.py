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


#: Seconds per episode under :func:`short_episodes`.
SHORT_EPISODE_S = 0.2


def shortened(base: type) -> type:
    """Returns a subclass of the vector env ``base`` whose episodes last SHORT_EPISODE_S: a
    resolved config (its ``preset``) is replaced with that duration, env kwargs get it."""
    import dataclasses

    from tendon2r_gym.envs.env_config import EnvConfig

    class Short(base):
        shortened = True

        def __init__(self, num_envs, *args, **kwargs):
            preset = args[0] if args else kwargs.get("preset")
            if not isinstance(preset, EnvConfig):
                kwargs = {**kwargs, "episode_duration": SHORT_EPISODE_S}
            elif args:  # a resolved config: its episodes shortened
                args = (dataclasses.replace(preset, episode_duration=SHORT_EPISODE_S), *args[1:])
            else:
                kwargs["preset"] = dataclasses.replace(preset, episode_duration=SHORT_EPISODE_S)
            super().__init__(num_envs, *args, **kwargs)

    return Short


@pytest.fixture
def short_episodes(monkeypatch):
    """Every vector env (evaluation rollouts, training, studies) runs SHORT_EPISODE_S episodes
    instead of its config's: for the tests of a command's end-to-end plumbing (files, rows,
    pages), whose properties do not depend on how long an episode is.  A model still loads
    against its full env contract; only the rollouts are shorter."""
    from tendon2r_gym.envs import vector_env

    monkeypatch.setattr(vector_env, "Tendon2RVectorEnv", shortened(vector_env.Tendon2RVectorEnv))

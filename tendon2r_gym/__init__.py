"""tendon2r_gym: a Gymnasium environment for a tendon-driven 2R planar arm in MuJoCo.

Data flows one way: Mechanism -> build_model -> Tendon2REnv -> policy -> rollout -> metrics.
"""

import gymnasium as gym

# First: on OSMesa it loads triton before mujoco (see tendon2r_gym.llvm).
from tendon2r_gym import llvm  # noqa: F401
from tendon2r_gym.actuation import ActuationAnalysis, cond
from tendon2r_gym.env import Tendon2REnv
from tendon2r_gym.env_config import EnvConfig
from tendon2r_gym.mechanism import Mechanism
from tendon2r_gym.model import build_model, build_spec, to_xml
from tendon2r_gym.reference import Reference, ReferenceRanges
from tendon2r_gym.routing import ROUTINGS, positive_span

__all__ = [
    "ROUTINGS",
    "ActuationAnalysis",
    "EnvConfig",
    "Mechanism",
    "Reference",
    "ReferenceRanges",
    "Tendon2REnv",
    "build_model",
    "build_spec",
    "cond",
    "positive_span",
    "to_xml",
]
__version__ = "0.1.0"

# No max_episode_steps here: the entry point wraps the env in a TimeLimit of
# episode_duration / ctrl_dt steps, so episode length has one source of truth.
# Tendon2RResidual-v0 is the same env under a second id, only so that rl_zoo3's hyperparameter
# file (keyed by env id) can hold a residual entry; that entry's env_wrapper adds
# tendon2r_gym.learned.ResidualPDWrapper (configs/rl_zoo3/ppo.yml).
for _id in ("Tendon2R-v0", "Tendon2RResidual-v0"):
    if _id not in gym.registry:
        gym.register(
            id=_id,
            entry_point="tendon2r_gym.env:make_env",
            vector_entry_point="tendon2r_gym.vector_env:Tendon2RVectorEnv",
        )

"""tendon2r_gym: a Gymnasium environment for a tendon-driven 2R planar arm in MuJoCo.

Data flows one way: Mechanism -> build_model -> Tendon2REnv -> policy -> rollout -> metrics.
"""

import gymnasium as gym

from tendon2r_gym.actuation import ActuationAnalysis, cond2
from tendon2r_gym.env import Tendon2REnv
from tendon2r_gym.env_config import EnvConfig
from tendon2r_gym.mechanism import ROUTINGS, Mechanism
from tendon2r_gym.model import build_model, build_spec, to_xml
from tendon2r_gym.reference import Reference, ReferenceRanges

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
    "cond2",
    "to_xml",
]
__version__ = "0.1.0"

if "Tendon2R-v0" not in gym.registry:
    # No max_episode_steps here: the entry point wraps the env in a TimeLimit of
    # episode_duration / ctrl_dt steps, so episode length has one source of truth.
    gym.register(id="Tendon2R-v0", entry_point="tendon2r_gym.env:make_env")

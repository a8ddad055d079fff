"""tendon2r_gym: a Gymnasium environment for a tendon-driven 2R planar arm in MuJoCo.

Data flows one way, through one subpackage per stage: ``simulation`` (arm parameters -> MuJoCo
model), ``task`` (reference, gains, rewards, observation), ``envs`` (EnvConfig, the single and
vector envs), ``policies`` (PD, CT, trained models), ``evaluation`` (rollouts, metrics),
``training`` (PPO) and ``app`` (the console commands, the benchmark and its report).
"""

import gymnasium as gym

# First: on OSMesa it loads triton before mujoco (see tendon2r_gym.llvm).
from tendon2r_gym import llvm  # noqa: F401
from tendon2r_gym.envs.env import Tendon2REnv
from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.simulation.actuation import ActuationAnalysis, cond
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.simulation.model import build_model, build_spec, to_xml
from tendon2r_gym.simulation.routing import ROUTINGS, positive_span
from tendon2r_gym.task.reference import Reference, ReferenceRanges

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
__version__ = "0.6.2"

#: The env's versions, each frozen (Gymnasium's rule: a change that can change learning results
#: is a new version; CHANGELOG.md says what each changed; tendon2r_gym.policies.contract pins them).
#: Each id's defaults, over its preset's values: v1 is what the shipped plain-PPO entries learn
#: on (training starts off the reference; the tracking error's rate is observed); v0 is the
#: earlier default, kept for code that names it.
VERSIONS: dict[str, dict[str, object]] = {
    "v0": {},
    "v1": {"reset_noise_scale": 0.02, "observe": ("error_rate",)},
}
LATEST = "Tendon2R-v1"

# No max_episode_steps here: the entry point wraps the env in a TimeLimit of
# episode_duration / ctrl_dt steps, so episode length has one source of truth.
# Tendon2RResidual-<v> is the same env under a second id, only so that rl_zoo3's hyperparameter
# file (keyed by env id) can hold a residual entry; that entry's env_wrapper adds
# tendon2r_gym.policies.residual.ResidualPDWrapper (configs/rl_zoo3/ppo.yml).
for _version, _defaults in VERSIONS.items():
    for _name in ("Tendon2R", "Tendon2RResidual"):
        _id = f"{_name}-{_version}"
        if _id not in gym.registry:
            gym.register(
                id=_id,
                entry_point="tendon2r_gym.envs.registration:make_env",
                vector_entry_point="tendon2r_gym.envs.vector_env:Tendon2RVectorEnv",
                kwargs=dict(_defaults),
            )

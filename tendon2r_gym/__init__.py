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
__version__ = "0.9.0"

#: The env's versions, each frozen (Gymnasium's rule: a change that can change learning results
#: is a new version; CHANGELOG.md says what each changed; tendon2r_gym.envs.contract pins them).
#: Each id's defaults, over its preset's values: v2 is what ordinary PPO settings learn (the
#: clients study, research/results/clients.md); v1 is what the shipped plain-PPO entries learn
#: on (training starts off the reference; the tracking error's rate is observed); v0 is the
#: earlier default, kept for code that names it.
VERSIONS: dict[str, dict[str, object]] = {
    "v0": {},
    "v1": {"reset_noise_scale": 0.02, "observe": ("error_rate",)},
    "v2": {"reset_noise_scale": 0.02, "observe": ("error_rate",), "action_filter_tau": 0.002},
}
LATEST = "Tendon2R-v2"
#: The residual id's own defaults over its version's, from v2 on: PD inside
#: (tendon2r_gym.policies.residual.make_residual_env), the action a correction of each joint's
#: torque in multiples of the torque the reference needs of it.
RESIDUAL: dict[str, object] = {
    "action_mode": "joint_torque",
    "action_filter_tau": 0.0,
    "residual_scale": 1.0,
    "residual_units": "need",
}
#: The versions whose residual id is the plain env under a second id (kept so that rl_zoo3's
#: hyperparameter file, keyed by env id, can hold a residual entry whose env_wrapper adds
#: tendon2r_gym.policies.residual.ResidualPDWrapper: configs/rl_zoo3/ppo.yml).
SECOND_ID_RESIDUAL = ("v0", "v1")

# No max_episode_steps here: the entry points wrap the env in a TimeLimit of
# episode_duration / ctrl_dt steps, so episode length has one source of truth.
ENV_ENTRY = "tendon2r_gym.envs.registration:make_env"
RESIDUAL_ENTRY = "tendon2r_gym.policies.residual:make_residual_env"
VECTOR_ENTRY = "tendon2r_gym.envs.vector_env:Tendon2RVectorEnv"


def _register(env_id: str, entry: str, kwargs: dict[str, object], vector: bool) -> None:
    """Registers ``env_id`` once (without ``vector``: Gymnasium's own vector env of it)."""
    if env_id not in gym.registry:
        vector_entry = VECTOR_ENTRY if vector else None
        gym.register(env_id, entry, vector_entry_point=vector_entry, kwargs=dict(kwargs))


for _version, _defaults in VERSIONS.items():
    _register(f"Tendon2R-{_version}", ENV_ENTRY, _defaults, vector=True)
    if _version in SECOND_ID_RESIDUAL:
        _register(f"Tendon2RResidual-{_version}", ENV_ENTRY, _defaults, vector=True)
    else:  # PD inside
        _register(f"Tendon2RResidual-{_version}", RESIDUAL_ENTRY, {**_defaults, **RESIDUAL}, False)

"""tendon2r_gym: a Gymnasium environment for a tendon-driven 2R planar arm in MuJoCo.

Data flows one way: Mechanism -> build_model -> Tendon2REnv -> policy -> rollout -> metrics.
"""

from tendon2r_gym.actuation import ActuationAnalysis, cond2
from tendon2r_gym.mechanism import ROUTINGS, Mechanism
from tendon2r_gym.model import build_model, build_spec, to_xml
from tendon2r_gym.reference import Reference, ReferenceRanges

__all__ = [
    "ROUTINGS",
    "ActuationAnalysis",
    "Mechanism",
    "Reference",
    "ReferenceRanges",
    "build_model",
    "build_spec",
    "cond2",
    "to_xml",
]
__version__ = "0.1.0"

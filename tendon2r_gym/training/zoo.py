"""rl_zoo3's hyperparameter file, generated from ours (configs/ppo.yaml), so that the zoo
trains what the benchmark trains: the same env kwargs, PPO settings, normalization and budget.

    python scripts/export_zoo.py        # writes configs/rl_zoo3/ppo.yml

rl_zoo3 keys its entries by env id.  ``Tendon2RResidual-v1`` is a second id of the plain env,
so its entry adds our wrapper with the zoo's ``env_wrapper``; ``Tendon2RResidual-v2`` has PD
inside, so its entry is the residual entry's PPO settings on the id as registered (its own
residual units and scale, no wrapper).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from tendon2r_gym.presets import PPO_CONFIG
from tendon2r_gym.training.hyperparams import Hyperparams
from tendon2r_gym.validation import invalid

#: Zoo env id -> our entry.
ENTRIES = {
    "Tendon2R-v1": "default_scratch",
    "Tendon2RResidual-v1": "default",
    "Tendon2R-v2": "default_scratch",
    "Tendon2RResidual-v2": "default",
}
WRAPPER = "tendon2r_gym.policies.residual.ResidualPDWrapper"

HEADER = """\
# GENERATED from tendon2r_gym/data/ppo.yaml by `python scripts/export_zoo.py`; edit that file
# instead (tests/test_zoo.py checks that this one is up to date).
#   python -m rl_zoo3.train --algo ppo --env Tendon2R-v2 --gym-packages tendon2r_gym \\
#       --conf-file configs/rl_zoo3/ppo.yml
#   python -m rl_zoo3.train --algo ppo --env Tendon2RResidual-v2 --gym-packages tendon2r_gym \\
#       --conf-file configs/rl_zoo3/ppo.yml
# Tendon2RResidual-v2 has PD inside (no env_wrapper); Tendon2RResidual-v1 is the plain env
# under a second id, with our wrapper added.
# The zoo runs SB3's DummyVecEnv with the same n_envs x n_steps as our native vector env.
"""


def zoo_entry(hp: Hyperparams, pd_inside: bool = False) -> dict[str, Any]:
    """Returns one rl_zoo3 entry with the hyperparameters of ``hp`` (``pd_inside``: for an id
    whose entry point wraps PD already, so no wrapper is added)."""
    entry: dict[str, Any] = {
        "env_kwargs": hp.env_kwargs,
        "n_envs": hp.n_envs,
        "n_timesteps": float(hp.total_timesteps),
        "policy": "MlpPolicy",
        **hp.ppo,
        # the zoo's VecNormalize, with PPO's discount as ours
        "normalize": {**hp.normalize, "gamma": hp.gamma},
        "policy_kwargs": hp.policy_kwargs,
    }
    if hp.frame_stride > 1:
        raise invalid("frame_stride", hp.frame_stride, "1 in an rl_zoo3 entry (no stride there)")
    if hp.frame_stack > 1:
        entry["frame_stack"] = hp.frame_stack
    if hp.residual_scale > 0 and not pd_inside:
        kwargs = {"residual_scale": hp.residual_scale}
        if hp.residual_filter_tau > 0:
            kwargs["residual_filter_tau"] = hp.residual_filter_tau
        entry["env_wrapper"] = [{WRAPPER: kwargs}]
    return entry


def pd_inside(env_id: str) -> bool:
    """Whether ``env_id``'s entry point wraps PD (a residual id from v2 on)."""
    from tendon2r_gym import SECOND_ID_RESIDUAL

    name, _, version = env_id.rpartition("-")
    return name == "Tendon2RResidual" and version not in SECOND_ID_RESIDUAL


def zoo_file(path: str | Path = PPO_CONFIG) -> str:
    """Returns the text of the rl_zoo3 hyperparameter file."""
    table = {
        env_id: zoo_entry(Hyperparams.from_entry(name, path), pd_inside(env_id))
        for env_id, name in ENTRIES.items()
    }
    return HEADER + yaml.safe_dump(table, sort_keys=False)

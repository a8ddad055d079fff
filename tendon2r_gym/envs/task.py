"""Import shim: tendon2r_gym.envs.formulas under its old path, with `Formulas` under its old
name ``Task`` (research code written before the rename imports them so).  New code imports
tendon2r_gym.envs.formulas; this module goes once nothing imports it."""

from tendon2r_gym.envs.formulas import (
    DIVERGED_PAST_LIMIT,
    DIVERGED_SPEED,
    DIVERGENCE_WARNING_IDS,
    DIVERGENCE_WARNINGS,
    LINKS,
    N_ARM_PARAMS,
    RAD_PER_DEG,
    RATE_TO_ACTION,
    RESET_INFO_KEYS,
    STEP_INFO_KEYS,
    Formulas,
    arm_params,
    reference_params,
    signed_log,
    to_action,
)

Task = Formulas

__all__ = [
    "DIVERGED_PAST_LIMIT",
    "DIVERGED_SPEED",
    "DIVERGENCE_WARNINGS",
    "DIVERGENCE_WARNING_IDS",
    "LINKS",
    "N_ARM_PARAMS",
    "RAD_PER_DEG",
    "RATE_TO_ACTION",
    "RESET_INFO_KEYS",
    "STEP_INFO_KEYS",
    "Formulas",
    "Task",
    "arm_params",
    "reference_params",
    "signed_log",
    "to_action",
]

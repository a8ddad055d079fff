"""PPO training: typed hyperparameters (hyperparams), SB3 callbacks (callbacks) and the run
owner (manager).  The SB3 adapter of the native vector env is
tendon2r_gym.training.vector_env_sb3.  One seed's training as a job (jobs) runs in this
process, on local worker processes or on a Ray cluster (executors)."""

from typing import Any

__all__ = ["Experiment", "Hyperparams", "fine_tune", "recorded_hyperparams", "train_run"]


def __getattr__(name: str) -> Any:
    """Imports the torch side (manager) on first use, so that the hyperparameters' module
    (torch-free) imports in a core install; triton's LLVM is loaded before torch's
    (tendon2r_gym.llvm: a render before training)."""
    if name == "Hyperparams":
        from tendon2r_gym.training.hyperparams import Hyperparams

        return Hyperparams
    if name in __all__:
        from tendon2r_gym.llvm import load_triton

        load_triton()
        from tendon2r_gym.training import manager

        return getattr(manager, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

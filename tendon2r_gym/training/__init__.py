"""PPO training: typed hyperparameters (hyperparams), SB3 callbacks (callbacks) and the run
owner (manager).  The SB3 adapter of the native vector env is tendon2r_gym.vector_env_sb3."""

# Before torch: triton's LLVM and Mesa's (a render before training) clash (tendon2r_gym.llvm).
from tendon2r_gym.llvm import load_triton

load_triton()


from tendon2r_gym.training.hyperparams import Hyperparams  # noqa: E402
from tendon2r_gym.training.manager import (  # noqa: E402
    Experiment,
    fine_tune,
    recorded_hyperparams,
    train_run,
)

__all__ = ["Experiment", "Hyperparams", "fine_tune", "recorded_hyperparams", "train_run"]

"""PPO training: typed hyperparameters (hyperparams), SB3 callbacks (callbacks) and the run
owner (manager).  The SB3 adapter of the native vector env is tendon2r_gym.vector_env_sb3."""

from tendon2r_gym.training.hyperparams import Hyperparams
from tendon2r_gym.training.manager import Experiment, fine_tune, recorded_hyperparams, train_run

__all__ = ["Experiment", "Hyperparams", "fine_tune", "recorded_hyperparams", "train_run"]

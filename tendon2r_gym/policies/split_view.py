"""Import shim: the shipped ``generalist_real`` bundle's model file pickled this module path for
its policy class, which lives in :mod:`tendon2r_gym.training.split_view` (a model is trained
there; SB3's own ``PPO.load`` of that file imports the class by this name)."""

from tendon2r_gym.training.split_view import MaskedFlatten, SplitViewPolicy

__all__ = ["MaskedFlatten", "SplitViewPolicy"]

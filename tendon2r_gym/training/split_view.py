"""Import shim: the shipped ``real_arm`` bundle's model file pickled this module path for its
policy classes, which live in :mod:`tendon2r_gym.policies.split_view`."""

from tendon2r_gym.policies.split_view import MaskedFlatten, SplitViewPolicy

__all__ = ["MaskedFlatten", "SplitViewPolicy"]

"""An SB3 actor-critic whose critic sees parts of the observation that its actor does not.

``hide_from_actor: [arm]`` gives the critic privileged information that the deployed actor
never needs (asymmetric actor-critic: the critic sees the drawn arm, the actor must cope with
any arm).  The hidden entries are zero for the actor (after VecNormalize, a constant zero
carries no information), so both networks keep the observation's shape and SB3 saves and loads
the policy like MlpPolicy.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.preprocessing import get_flattened_obs_dim
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor


class MaskedFlatten(BaseFeaturesExtractor):
    """Flattens the observation and multiplies it by a fixed 0/1 mask."""

    def __init__(self, observation_space: gym.Space, keep: list[float]) -> None:
        super().__init__(observation_space, get_flattened_obs_dim(observation_space))
        self.register_buffer("keep", th.as_tensor(keep, dtype=th.float32))

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return th.flatten(observations, start_dim=1) * self.keep


class SplitViewPolicy(ActorCriticPolicy):
    """ActorCriticPolicy with separate feature extractors: the actor's keeps ``actor_keep``
    (0/1 per observation entry), the critic's every entry.  ``critic_keep`` (default: all
    ones) is the critic's mask as the model files of earlier versions record it."""

    def __init__(
        self,
        *args: Any,
        actor_keep: list[float],
        critic_keep: list[float] | None = None,
        **kwargs: Any,
    ) -> None:
        self.actor_keep = list(actor_keep)
        self.critic_keep = list(critic_keep or [1.0] * len(self.actor_keep))
        self._next_keep = [self.actor_keep, self.critic_keep]  # SB3 builds the actor's first
        kwargs.update(share_features_extractor=False, features_extractor_class=MaskedFlatten)
        super().__init__(*args, **kwargs)

    def make_features_extractor(self) -> BaseFeaturesExtractor:
        keep = self._next_keep.pop(0)
        return MaskedFlatten(self.observation_space, keep)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(actor_keep=self.actor_keep, critic_keep=self.critic_keep)
        for key in ("share_features_extractor", "features_extractor_class"):
            data.pop(key, None)
        return data

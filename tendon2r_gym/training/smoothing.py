"""PPO with a smooth policy: CAPS's regularization of the mean action (Mysore et al., "Regularizing
Action Policies for Smooth Control with Reinforcement Learning", ICRA 2021).

A reward penalty on the action's rate reaches the policy only through noisy returns; CAPS adds
two terms to PPO's loss that act on the network itself:

- **temporal** ``||mu(s_t) - mu(s_t+1)||``: consecutive states of a rollout (within an episode)
  give close mean actions;
- **spatial** ``||mu(s) - mu(s + sigma * n)||``, ``n ~ N(0, I)``: close states give close mean
  actions: it lowers the policy's gain on its inputs, a gain through which even a noiseless
  closed loop can chatter at the control rate.

``mu`` is the deterministic action (the Gaussian's mean) and the states are the observations the
policy sees, after VecNormalize (unit spread), so ``sigma`` is in standard deviations.  Before
each of PPO's minibatch steps (a torch optimizer step pre-hook), the terms' gradient on
``samples`` random states of the rollout, clipped to PPO's ``max_grad_norm`` on its own, is
added to PPO's: one joint step, as CAPS, with SB3's ``PPO.train`` unchanged.  With both weights 0
(the default) the algorithm is SB3's PPO.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from stable_baselines3 import PPO

from tendon2r_gym.training.hyperparams import Smoothing


class SmoothPPO(PPO):
    """SB3's PPO whose every minibatch step also descends CAPS's smoothness terms
    (``smoothing``).  Its zips load with ``PPO.load``: the settings are a training choice, kept
    in the run's config.yaml, not in the model."""

    def __init__(self, *args: Any, smoothing: Smoothing | None = None, **kwargs: Any) -> None:
        self.smoothing = smoothing or Smoothing()
        super().__init__(*args, **kwargs)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "smoothing"]

    def train(self) -> None:
        if not self.smoothing.active:
            return super().train()
        # The rollout in time order (n_steps, n_envs, ...), before PPO's train flattens it:
        # each state and the next within its episode.
        buffer = self.rollout_buffer
        obs = th.as_tensor(np.asarray(buffer.observations), device=self.device)
        pairs = np.flatnonzero(np.asarray(buffer.episode_starts)[1:].reshape(-1) == 0)
        now = obs[:-1].reshape(-1, *obs.shape[2:])[pairs]
        after = obs[1:].reshape(-1, *obs.shape[2:])[pairs]
        terms: dict[str, list[float]] = {"temporal": [], "spatial": []}

        def add_gradient(*_: Any) -> None:
            if len(now):
                self._add_smoothing_gradient(now, after, terms)

        handle = self.policy.optimizer.register_step_pre_hook(add_gradient)
        try:
            super().train()
        finally:
            handle.remove()
        for key, values in terms.items():
            if values:
                self.logger.record(f"train/smoothness_{key}", float(np.mean(values)))
        return None

    def _mean_action(self, obs: th.Tensor) -> th.Tensor:
        return self.policy.get_distribution(obs).mode()

    def _add_smoothing_gradient(
        self, now: th.Tensor, after: th.Tensor, terms: dict[str, list[float]]
    ) -> None:
        """Adds the gradient of CAPS's terms on ``smoothing.samples`` random states of the
        rollout (and each one's next state) to the policy's, clipped to ``max_grad_norm`` on
        its own."""
        s = self.smoothing
        i = th.randint(len(now), (min(s.samples, len(now)),), device=self.device)
        x = now[i]
        mu = self._mean_action(x)
        loss = th.zeros((), device=self.device)
        for key, weight, other in (
            ("temporal", s.temporal, lambda: after[i]),
            ("spatial", s.spatial, lambda: x + s.sigma * th.randn_like(x)),
        ):
            if weight > 0:
                term = th.linalg.vector_norm(mu - self._mean_action(other()), dim=1).mean()
                terms[key].append(term.item())
                loss = loss + weight * term
        params = [p for p in self.policy.parameters() if p.requires_grad]
        grads = th.autograd.grad(loss, params, allow_unused=True)
        pairs = [(p, g) for p, g in zip(params, grads, strict=True) if g is not None]
        norm = th.nn.utils.get_total_norm([g for _, g in pairs])  # as clip_grad_norm_ does
        factor = min(1.0, self.max_grad_norm / (float(norm) + 1e-6))
        for p, g in pairs:
            p.grad = g * factor if p.grad is None else p.grad + g * factor

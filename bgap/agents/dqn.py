"""DQN as in the paper: SB3's DQN with a choice of loss, prioritized replay and the authors'
exponential epsilon decay.

Only the gradient step is rewritten (SB3 hard-codes the Huber loss and knows no importance
weights); everything else is SB3's. The whole update is in :meth:`DQN.train`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch as th
import torch.nn.functional as F
from stable_baselines3 import DQN as SB3DQN

from bgap.agents.per import PrioritizedReplayBuffer, PrioritizedSamples


def exponential_epsilon(model: Any) -> None:
    """The authors' schedule, where ``model.exploration_decay_steps`` is set (replacing the
    linear one that SB3's ``_on_step`` has just applied): epsilon = final + (initial -
    final) exp(-t / decay_steps), t the environment steps."""
    if model.exploration_decay_steps:
        decay = math.exp(-model.num_timesteps / model.exploration_decay_steps)
        model.exploration_rate = (
            model.exploration_final_eps
            + (model.exploration_initial_eps - model.exploration_final_eps) * decay
        )
        model.logger.record("rollout/exploration_rate", model.exploration_rate)


def anneal_beta(model: Any) -> bool:
    """Move a prioritized buffer's exponent beta towards 1 over ``model.per_beta_steps``;
    whether the model's buffer is prioritized."""
    buffer = model.replay_buffer
    if not isinstance(buffer, PrioritizedReplayBuffer):
        return False
    frac = min(1.0, model.num_timesteps / max(1, model.per_beta_steps))
    buffer.beta = buffer.beta0 + frac * (1.0 - buffer.beta0)
    return True


class DQN(SB3DQN):
    """:param loss: ``"mse"`` (the paper) or ``"huber"`` (SB3's default)
    :param exploration_decay_steps: if set, epsilon = final + (initial - final) *
        exp(-t / decay_steps) with t the environment steps (the authors' rl-agents schedule);
        otherwise SB3's linear schedule over ``exploration_fraction``
    :param per_beta_steps: steps over which the PER exponent beta anneals to 1
    """

    def __init__(
        self,
        *args: Any,
        loss: str = "mse",
        exploration_decay_steps: float | None = None,
        per_beta_steps: int = 100_000,
        **kwargs: Any,
    ) -> None:
        if loss not in ("mse", "huber"):
            raise ValueError(f"loss={loss!r}: use 'mse' or 'huber'")
        self.loss = loss
        self.exploration_decay_steps = exploration_decay_steps
        self.per_beta_steps = per_beta_steps
        super().__init__(*args, **kwargs)

    def _on_step(self) -> None:
        super()._on_step()
        exponential_epsilon(self)

    def td_loss(
        self, current: th.Tensor, target: th.Tensor, weights: th.Tensor | None = None
    ) -> th.Tensor:
        """Mean (importance-weighted) MSE or Huber loss between Q(s, a) and its TD target."""
        if self.loss == "mse":
            per_sample = F.mse_loss(current, target, reduction="none")
        else:
            per_sample = F.smooth_l1_loss(current, target, reduction="none")
        if weights is not None:
            per_sample = per_sample * weights
        return per_sample.mean()

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        buffer = self.replay_buffer
        prioritized = anneal_beta(self)
        losses = []
        for _ in range(gradient_steps):
            data = buffer.sample(batch_size, env=self._vec_normalize_env)
            discounts = data.discounts if data.discounts is not None else self.gamma
            with th.no_grad():
                next_q = self.q_net_target(data.next_observations).max(dim=1)[0].reshape(-1, 1)
                target = data.rewards + (1 - data.dones) * discounts * next_q
            current = th.gather(self.q_net(data.observations), dim=1, index=data.actions.long())
            weights = data.weights if isinstance(data, PrioritizedSamples) else None
            loss = self.td_loss(current, target, weights)
            losses.append(loss.item())
            self.policy.optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
            if prioritized:
                td = (current - target).detach().cpu().numpy()
                buffer.update_priorities(data.indices, td)
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", float(np.mean(losses)))

"""QR-DQN (Dabney et al., 2018) as bgap trains it: sb3-contrib's QRDQN with bgap's
prioritized replay and the authors' exponential epsilon decay, so that it differs from
:class:`bgap.agents.dqn.DQN` only in learning each action's return distribution (its
quantiles) instead of its mean.

Only the gradient step is rewritten, as for DQN: sb3-contrib's loss reduces the quantile
Huber loss to one number, which leaves no room for importance weights. The loss per sample
sums over the current quantiles and averages over the target ones (sb3-contrib's
``sum_over_quantiles=True``, whose mean over the batch it equals); a transition's new
priority is the TD error of the implied Q-values, |mean target - mean current quantile|, on
DQN's scale. Kept from DQN (ours): prioritized replay, Adam with torch's default epsilon,
gradient clipping, the greedy target action by the mean of the target quantiles.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from sb3_contrib import QRDQN as ContribQRDQN

from bgap.agents.dqn import anneal_beta, exponential_epsilon
from bgap.agents.per import PrioritizedSamples


def quantile_huber_per_sample(current: th.Tensor, target: th.Tensor, kappa: float = 1.0):
    """The quantile Huber loss of each sample: ``current`` (B, N) and ``target`` (B, N')
    quantiles -> (B,), summed over the current quantiles and averaged over the target ones."""
    n = current.shape[-1]
    tau = (th.arange(n, device=current.device, dtype=th.float32) + 0.5) / n
    delta = target.unsqueeze(-2) - current.unsqueeze(-1)  # (B, N, N')
    huber = th.where(delta.abs() > kappa, kappa * (delta.abs() - 0.5 * kappa), 0.5 * delta**2)
    rho = (tau.view(1, -1, 1) - (delta.detach() < 0).float()).abs() * huber / kappa
    return rho.sum(dim=-2).mean(dim=-1)


class QRDQN(ContribQRDQN):
    """:param exploration_decay_steps: as :class:`bgap.agents.dqn.DQN`'s
    :param per_beta_steps: steps over which the PER exponent beta anneals to 1
    """

    def __init__(
        self,
        *args: Any,
        exploration_decay_steps: float | None = None,
        per_beta_steps: int = 100_000,
        **kwargs: Any,
    ) -> None:
        self.exploration_decay_steps = exploration_decay_steps
        self.per_beta_steps = per_beta_steps
        super().__init__(*args, **kwargs)

    def _on_step(self) -> None:
        super()._on_step()
        exponential_epsilon(self)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        prioritized = anneal_beta(self)
        n, losses = self.n_quantiles, []
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            discounts = data.discounts if data.discounts is not None else self.gamma
            with th.no_grad():
                next_q = self.quantile_net_target(data.next_observations)  # (B, N, A)
                best = next_q.mean(dim=1, keepdim=True).argmax(dim=2, keepdim=True)
                next_q = next_q.gather(2, best.expand(batch_size, n, 1)).squeeze(2)
                target = data.rewards + (1 - data.dones) * discounts * next_q  # (B, N)
            current = self.quantile_net(data.observations)
            index = data.actions[..., None].long().expand(batch_size, n, 1)
            current = th.gather(current, dim=2, index=index).squeeze(2)  # (B, N)
            per_sample = quantile_huber_per_sample(current, target)
            if isinstance(data, PrioritizedSamples):  # weights (B, 1): flattened, not (B, B)
                per_sample = per_sample * data.weights.view(-1)
            loss = per_sample.mean()
            losses.append(loss.item())
            self.policy.optimizer.zero_grad()
            loss.backward()
            if self.max_grad_norm is not None:
                th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
            if prioritized:
                td = (target.mean(dim=1) - current.mean(dim=1)).detach().cpu().numpy()
                self.replay_buffer.update_priorities(data.indices, td)
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", float(np.mean(losses)))

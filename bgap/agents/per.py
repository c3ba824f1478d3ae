"""Prioritized experience replay (Schaul et al., 2016) for Stable-Baselines3's DQN.

SB3 ships no prioritized buffer. Proportional prioritisation: transition i is sampled with
probability P(i) = p_i^alpha / sum_k p_k^alpha, p_i = |TD error_i| + eps, new transitions
entering with the largest priority seen so far. Importance-sampling weights
w_i = (N P(i))^-beta / max_k w_k (the max over the whole buffer, as in the paper) correct
the bias; beta is annealed from ``beta0`` to 1 by the agent.

Sampling draws from the normalised priority vector directly (O(N) per batch): the paper's
buffer holds 15,000 transitions, where that costs tens of microseconds, so a sum tree would
add code without adding speed.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer


class PrioritizedSamples(NamedTuple):
    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    rewards: th.Tensor
    discounts: th.Tensor | None
    weights: th.Tensor
    """Importance-sampling weights, shape (batch, 1)."""
    indices: np.ndarray
    """Flat buffer indices (position * n_envs + env), for :meth:`update_priorities`."""


class PrioritizedReplayBuffer(ReplayBuffer):
    """A drop-in ``replay_buffer_class`` for SB3's DQN (with :class:`bgap.agents.dqn.DQN`)."""

    def __init__(
        self,
        *args: Any,
        alpha: float = 0.6,
        beta0: float = 0.4,
        eps: float = 1e-6,
        **kwargs: Any,
    ) -> None:
        super().__init__(*args, **kwargs)
        if self.optimize_memory_usage:
            raise ValueError("PrioritizedReplayBuffer does not support optimize_memory_usage")
        self.alpha, self.beta0, self.beta, self.eps = alpha, beta0, beta0, eps
        self.priorities = np.zeros((self.buffer_size, self.n_envs), dtype=np.float64)
        self.max_priority = 1.0

    def add(self, *args: Any, **kwargs: Any) -> None:
        self.priorities[self.pos] = self.max_priority**self.alpha
        super().add(*args, **kwargs)

    def probabilities(self) -> np.ndarray:
        """P(i) over the filled part of the buffer, flat (position * n_envs + env)."""
        filled = self.buffer_size if self.full else self.pos
        p = self.priorities[:filled].ravel()
        return p / p.sum()

    def sample(self, batch_size: int, env: Any = None) -> PrioritizedSamples:
        probs = self.probabilities()
        # SB3 seeds numpy's global stream (set_random_seed); its own buffer samples from it too.
        flat = np.random.choice(len(probs), size=batch_size, p=probs)  # noqa: NPY002
        batch_inds, env_inds = np.divmod(flat, self.n_envs)
        n = len(probs)
        weights = (n * probs[flat]) ** (-self.beta)
        weights /= (n * probs.min()) ** (-self.beta)
        data = (
            self._normalize_obs(self.observations[batch_inds, env_inds, :], env),
            self.actions[batch_inds, env_inds, :],
            self._normalize_obs(self.next_observations[batch_inds, env_inds, :], env),
            (self.dones[batch_inds, env_inds] * (1 - self.timeouts[batch_inds, env_inds])).reshape(
                -1, 1
            ),
            self._normalize_reward(self.rewards[batch_inds, env_inds].reshape(-1, 1), env),
        )
        tensors = tuple(map(self.to_torch, data))
        w = self.to_torch(weights.astype(np.float32).reshape(-1, 1))
        return PrioritizedSamples(*tensors, None, w, flat)

    def update_priorities(self, indices: np.ndarray, td_errors: np.ndarray) -> None:
        """p_i = |delta_i| + eps, stored as p_i^alpha."""
        p = np.abs(np.asarray(td_errors, dtype=np.float64)).ravel() + self.eps
        batch_inds, env_inds = np.divmod(np.asarray(indices), self.n_envs)
        self.priorities[batch_inds, env_inds] = p**self.alpha
        self.max_priority = max(self.max_priority, float(p.max()))

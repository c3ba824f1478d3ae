"""Prioritized experience replay (Schaul et al., 2016) for Stable-Baselines3's DQN.

SB3 ships no prioritized buffer. Proportional prioritisation: transition i is sampled with
probability P(i) = p_i^alpha / sum_k p_k^alpha, p_i = |TD error_i| + eps, new transitions
entering with the largest priority seen so far. Importance-sampling weights
w_i = (N P(i))^-beta / max_k w_k (the max over the whole buffer, as in the paper) correct
the bias; beta is annealed from ``beta0`` to 1 by the agent.

:class:`PrioritizedReplayBuffer` (one training, SB3's DQN) draws from the normalised priority
vector directly (O(N) per batch): at the paper's 15,000 transitions that costs tens of
microseconds. :class:`SumTrees` serves the batched learner, where K members' cumulative sums
cost O(K N) per update (~2 ms at K = 20): K sum trees (and min trees, for the weights'
normaliser) in stacked arrays, sampled and updated in O(K log N) numpy operations.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numba as nb
import numpy as np
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer

from bgap.common.errors import check_memory

SLOT_BYTES = 8 + 3 * 4 + 8 + 2 * 8
"""A replay slot's bytes besides its two observations: the action (int64), the reward, done
and timeout flags (float32), the priority (float64) and its sum- and min-tree entries."""


def check_replay_memory(buffer_size: int, obs_dim: int, members: int = 1) -> None:
    """Refuse a replay buffer of ``buffer_size`` transitions of ``obs_dim`` float32 features
    (``members`` of them) that this machine cannot hold, before it is allocated. SB3's own
    check only warns, and numpy's lazily zeroed arrays let the training start, to be killed
    without a message once the buffer fills."""
    nbytes = members * buffer_size * (2 * 4 * obs_dim + SLOT_BYTES)
    fix = "a smaller agent.buffer_size" + (
        f", or fewer members than {members}" if members > 1 else ""
    )
    check_memory(nbytes, "agent.buffer_size", buffer_size, fix)


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


# The trees' kernels: numba loops, since numpy's fancy indexing per level cost as much as the
# cumulative sum they replace (bench learn measures both).
_jit = nb.njit(cache=True, nogil=True)


@_jit
def _set(tree_sum, tree_min, members, leaves, values, capacity):  # pragma: no cover (numba)
    for i in range(leaves.shape[0]):
        k = members[i]
        for j in range(leaves.shape[1]):
            node = leaves[i, j] + capacity
            v = values[i, j]
            tree_sum[k, node] = v
            tree_min[k, node] = v if v > 0 else np.inf
            node //= 2
            while node >= 1:
                a, b = 2 * node, 2 * node + 1
                tree_sum[k, node] = tree_sum[k, a] + tree_sum[k, b]
                tree_min[k, node] = min(tree_min[k, a], tree_min[k, b])
                node //= 2


@_jit
def _find(tree_sum, members, u, capacity, out):  # pragma: no cover (numba)
    for i in range(u.shape[0]):
        k = members[i]
        for j in range(u.shape[1]):
            value = u[i, j] * tree_sum[k, 1]
            node = 1
            while node < capacity:
                left, right = tree_sum[k, 2 * node], tree_sum[k, 2 * node + 1]
                if value >= left and right > 0:
                    value -= left
                    node = 2 * node + 1
                else:
                    node = 2 * node
            out[i, j] = node - capacity


class SumTrees:
    """K sum trees and K min trees over ``n`` leaves each, in two (K, 2 * capacity) arrays.

    Node 1 is the root, node i's children are 2i and 2i + 1, leaf j is node capacity + j
    (capacity: the power of two >= n). Every ancestor of a written leaf is recomputed from its
    children, never updated by differences, so sums do not drift over millions of updates.
    Written here because no maintained library offers trees stacked across trainings (SB3 has
    no prioritized replay; the sum trees of other libraries are one buffer each in Python).
    """

    def __init__(self, k: int, n: int) -> None:
        self.k, self.n = k, n
        self.capacity = 1 << max(int(np.ceil(np.log2(max(n, 1)))), 0)
        self.sum = np.zeros((k, 2 * self.capacity))
        self.min = np.full((k, 2 * self.capacity), np.inf)

    def set(self, members: np.ndarray, leaves: np.ndarray, values: np.ndarray) -> None:
        """Leaf ``leaves[i, j]`` of member ``members[i]`` takes ``values[i, j]`` (zero: empty);
        of repeated leaves, the last value stays (numpy's fancy assignment)."""
        leaves = np.asarray(leaves, dtype=np.int64)
        values = np.broadcast_to(np.asarray(values, dtype=np.float64), leaves.shape)
        _set(
            self.sum,
            self.min,
            np.asarray(members, dtype=np.int64),
            leaves,
            np.ascontiguousarray(values),
            self.capacity,
        )

    def rebuild(self, member: int, values: np.ndarray) -> None:
        """Member ``member``'s leaves from a flat array of ``n`` values (a resumed replay)."""
        leaves = np.zeros(self.capacity)
        leaves[: len(values)] = values
        self.sum[member, self.capacity :] = leaves
        self.min[member, self.capacity :] = np.where(leaves > 0, leaves, np.inf)
        level = self.capacity // 2
        while level >= 1:
            children = slice(2 * level, 4 * level)
            self.sum[member, level : 2 * level] = self.sum[member, children].reshape(-1, 2).sum(1)
            self.min[member, level : 2 * level] = self.min[member, children].reshape(-1, 2).min(1)
            level //= 2

    def total(self, members: np.ndarray) -> np.ndarray:
        return self.sum[members, 1]

    def smallest(self, members: np.ndarray) -> np.ndarray:
        return self.min[members, 1]

    def find(self, members: np.ndarray, u: np.ndarray) -> np.ndarray:
        """For u in [0, 1) of shape (len(members), B): the leaf j whose prefix sums satisfy
        sum(<j) <= u * total < sum(<=j), the inverse of the cumulative distribution (what
        ``searchsorted(cumsum, u * total, side="right")`` finds, up to rounding). Never an
        empty leaf: a descent goes right only into a subtree holding priority."""
        u = np.ascontiguousarray(u, dtype=np.float64)
        out = np.empty(u.shape, dtype=np.int64)
        _find(self.sum, np.asarray(members, dtype=np.int64), u, self.capacity, out)
        return out

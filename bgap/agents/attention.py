"""Ego attention (Leurent & Mercat, 2019): a features extractor that reads the observed
vehicles as a set, for every SB3 algorithm (``agent.extractor=attention``).

bgap's observation holds the ego in row 0 and the other observed vehicles, relative to the
ego and sorted by distance, in rows 1 to V - 1; absent rows are zero with presence 0 (column
0) and come last. The ego row, embedded by its own MLP, is the query; every row (the ego's
too, so that an empty road leaves one key) embedded by a shared MLP gives keys and values;
absent rows are masked. The output averages the attended vector with the ego's embedding,
as highway-env's own example (scripts/sb3_highway_ppo_transformer.py). So the features do
not depend on the order of the other vehicles, nor on anything in the absent rows. Written
here because neither SB3 nor highway-env ships it as a package.
"""

from __future__ import annotations

import gymnasium as gym
import torch as th
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

PRESENCE = 0
"""Column of the presence feature in bgap's observation (``features[0]``)."""


def _mlp(inputs: int, width: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(inputs, width), nn.ReLU(), nn.Linear(width, width), nn.ReLU())


class EgoAttention(BaseFeaturesExtractor):
    """Features of a (V, F) observation: ``embed_dim`` numbers from ``heads``-head attention
    of the ego over the observed vehicles."""

    def __init__(self, observation_space: gym.spaces.Box, embed_dim: int = 64, heads: int = 2):
        super().__init__(observation_space, features_dim=embed_dim)
        features = observation_space.shape[-1]
        self.ego_embed, self.embed = _mlp(features, embed_dim), _mlp(features, embed_dim)
        self.attention = nn.MultiheadAttention(embed_dim, heads, bias=False, batch_first=True)

    def forward(self, obs: th.Tensor) -> th.Tensor:
        ego = self.ego_embed(obs[:, :1])  # (B, 1, E)
        rows = th.cat([ego, self.embed(obs[:, 1:])], dim=1)  # (B, V, E)
        absent = obs[..., PRESENCE] < 0.5
        absent[:, 0] = False  # the ego is always there
        attended, _ = self.attention(ego, rows, rows, key_padding_mask=absent, need_weights=False)
        return (attended.squeeze(1) + ego.squeeze(1)) / 2

"""Navigation agents: SB3 DQN with the paper's loss and prioritized replay.

``DQN`` and ``PrioritizedReplayBuffer`` are imported on first use (PEP 562): the schema in
:mod:`bgap.agents.config`, which every command's config imports, then does not load torch and
Stable-Baselines3 (about 2.5 s) into commands that train nothing."""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bgap.agents.dqn import DQN
    from bgap.agents.per import PrioritizedReplayBuffer

__all__ = ["DQN", "PrioritizedReplayBuffer"]
_HOMES = {"DQN": "bgap.agents.dqn", "PrioritizedReplayBuffer": "bgap.agents.per"}


def __getattr__(name: str):
    if name in _HOMES:
        return getattr(import_module(_HOMES[name]), name)
    raise AttributeError(f"module 'bgap.agents' has no attribute {name!r}")

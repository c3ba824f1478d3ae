"""Navigation agents: SB3 DQN with the paper's loss and prioritized replay."""

from bgap.agents.dqn import DQN
from bgap.agents.per import PrioritizedReplayBuffer

__all__ = ["DQN", "PrioritizedReplayBuffer"]

"""The ``agent`` config group's schema: DQN hyperparameters."""

from __future__ import annotations

from dataclasses import dataclass, field

from bgap.common.errors import check


@dataclass
class AgentConfig:
    """DQN hyperparameters (config group ``agent``). Defaults: the paper and the authors'
    rl-agents configuration (FACTS.md)."""

    name: str = "dqn"
    net_arch: list[int] = field(default_factory=lambda: [256, 256])
    learning_rate: float = 5e-4
    loss: str = "mse"
    """``mse`` (the paper) or ``huber`` (SB3's default)."""
    gamma: float = 0.8
    batch_size: int = 32
    buffer_size: int = 15_000
    target_update_interval: int = 50
    """Environment steps between target-network copies (one update per step: = updates)."""
    train_freq: int = 1
    gradient_steps: int = 1
    learning_starts: int = 200
    exploration_initial: float = 1.0
    exploration_final: float = 0.05
    exploration_decay_steps: float = 6000.0
    """Time constant [env steps] of epsilon = final + (initial - final) exp(-t / decay)."""
    max_grad_norm: float = 10.0
    replay: str = "per"
    """``per`` (prioritized, the paper) or ``uniform`` (SB3's buffer, the authors' code)."""
    converged: bool = True
    """``false`` in a preset that a sweep wrote before it finished its trials: commands
    refuse it unless ``agent.converged=true`` says it is used knowingly."""
    per_alpha: float = 0.6
    per_beta0: float = 0.4

    def __post_init__(self) -> None:
        check(self.loss in ("mse", "huber"), "agent.loss", self.loss, "use mse or huber")
        check(self.replay in ("per", "uniform"), "agent.replay", self.replay, "use per or uniform")
        check(0 < self.gamma <= 1, "agent.gamma", self.gamma, "must lie in (0, 1]")
        check(self.learning_rate > 0, "agent.learning_rate", self.learning_rate, "must be > 0")
        check(
            0 <= self.exploration_final <= self.exploration_initial <= 1,
            "agent.exploration_final",
            self.exploration_final,
            "need 0 <= exploration_final <= exploration_initial <= 1",
        )
        check(
            self.batch_size >= 1 and self.buffer_size >= self.batch_size,
            "agent.buffer_size",
            self.buffer_size,
            "must be >= agent.batch_size >= 1",
        )

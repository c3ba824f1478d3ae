"""The ``agent`` config group's schema: the learning algorithm and its hyperparameters."""

from __future__ import annotations

from dataclasses import dataclass, field

from bgap.common.errors import check

ALGOS = ("dqn", "qrdqn", "ppo")
"""Learning algorithms: bgap's DQN (SB3's, with the paper's loss, schedules and prioritized
replay), QR-DQN (sb3-contrib's, with the same replay and schedules) and SB3's PPO."""
EXTRACTORS = ("flatten", "attention")
"""What the networks read: the flattened observation, or ego attention over its rows."""
OBSERVATION_OPTIONS = {"closing": 1, "ttc": 1, "rule": 5}
"""Columns a learner may add to the paper's observation (:mod:`bgap.agents.observation`),
with how many each adds, in the order they are appended."""


@dataclass
class AgentConfig:
    """The algorithm and its hyperparameters (config group ``agent``: one preset per
    algorithm and recipe). Defaults: DQN as in the paper and the authors' rl-agents
    configuration (FACTS.md)."""

    name: str = "dqn"
    algo: str = "dqn"
    """``dqn``, ``qrdqn`` or ``ppo`` (:data:`ALGOS`); the presets ``agent=qrdqn`` and
    ``agent=ppo`` set it with hyperparameters of their own."""
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
    extractor: str = "flatten"
    """What the networks read: ``flatten`` (the observation as one vector, the paper's MLP)
    or ``attention`` (ego attention over the observed vehicles, :mod:`bgap.agents.attention`;
    ``net_arch`` then follows it)."""
    attention_dim: int = 64
    """``extractor=attention``: width of the embeddings and of the features."""
    attention_heads: int = 2
    """``extractor=attention``: attention heads (must divide ``attention_dim``)."""
    n_quantiles: int = 25
    """QR-DQN: quantiles of each action's return distribution."""
    n_steps: int = 128
    """PPO: steps per environment between updates (a rollout of n_steps x environments)."""
    n_epochs: int = 10
    """PPO: passes over each rollout."""
    gae_lambda: float = 0.95
    """PPO: the advantage estimate's lambda."""
    clip_range: float = 0.2
    """PPO: the policy ratio's clip."""
    ent_coef: float = 0.0
    """PPO: weight of the entropy bonus."""
    vf_coef: float = 0.5
    """PPO: weight of the value loss."""
    observation: list[str] = field(default_factory=list)
    """Columns added to the paper's observation (:data:`OBSERVATION_OPTIONS`; [] the paper's):
    ``closing`` speed and ``ttc`` (time to collision) per vehicle, ``rule`` the rule-based
    ego's suggestion; presets ``observation=paper|ttc|rule|ttc_rule``."""

    def __post_init__(self) -> None:
        check(self.algo in ALGOS, "agent.algo", self.algo, f"use one of {', '.join(ALGOS)}")
        check(self.loss in ("mse", "huber"), "agent.loss", self.loss, "use mse or huber")
        check(
            all(width >= 1 for width in self.net_arch),
            "agent.net_arch",
            self.net_arch,
            "every layer needs a width >= 1 ([] for no hidden layer)",
        )
        check(
            self.extractor in EXTRACTORS,
            "agent.extractor",
            self.extractor,
            f"use one of {', '.join(EXTRACTORS)}",
        )
        check(
            self.attention_heads >= 1 and self.attention_dim % self.attention_heads == 0,
            "agent.attention_heads",
            self.attention_heads,
            f"must be >= 1 and divide agent.attention_dim={self.attention_dim}",
        )
        check(self.n_quantiles >= 1, "agent.n_quantiles", self.n_quantiles, "must be >= 1")
        check(self.n_steps >= 2, "agent.n_steps", self.n_steps, "must be >= 2")
        check(self.n_epochs >= 1, "agent.n_epochs", self.n_epochs, "must be >= 1")
        check(0 <= self.gae_lambda <= 1, "agent.gae_lambda", self.gae_lambda, "must lie in [0, 1]")
        check(self.clip_range > 0, "agent.clip_range", self.clip_range, "must be > 0")
        check(self.ent_coef >= 0, "agent.ent_coef", self.ent_coef, "must be >= 0")
        check(self.vf_coef >= 0, "agent.vf_coef", self.vf_coef, "must be >= 0")
        self.observation = observation_options(self.observation)
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


def observation_options(options: list[str], key: str = "agent.observation") -> list[str]:
    """``options`` in :data:`OBSERVATION_OPTIONS`' order (one learner, one name), or a
    ConfigError naming the unknown or repeated one."""
    options = list(options)
    for option in options:
        check(
            option in OBSERVATION_OPTIONS,
            key,
            option,
            f"is not an observation option; use some of {list(OBSERVATION_OPTIONS)} (or "
            "the presets observation=paper|ttc|rule|ttc_rule)",
        )
    check(len(set(options)) == len(options), key, options, "names an option twice")
    return [option for option in OBSERVATION_OPTIONS if option in options]

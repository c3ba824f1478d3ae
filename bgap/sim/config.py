"""The schema every simulating command shares: the environment it builds and the backend.

``env``, ``behavior`` and ``reward`` are the traffic's own schemas (:mod:`bgap.traffic`);
:data:`SCHEMAS` registers them with this one for the commands whose configs compose them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from bgap.common.errors import check
from bgap.common.vocab import BACKENDS
from bgap.traffic.behaviors import BehaviorConfig
from bgap.traffic.replay import TrafficConfig, load_replay
from bgap.traffic.scenario import EnvConfig, RewardConfig, check_config, env_config


@dataclass
class BaseConfig:
    """What every bgap entry point shares: the environment it builds."""

    env: EnvConfig = field(default_factory=EnvConfig)
    behavior: BehaviorConfig = field(default_factory=BehaviorConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    mix: float = 0.5
    """Fraction of aggressive background vehicles; exactly round(mix * n) are aggressive."""
    radius: float = 180.0
    """Ego perception radius [m]: vehicles farther away are absent from the observation."""
    seed: int = 0
    backend: str = "highway"
    """Simulator: ``highway`` (highway-env, the reference) or ``vector`` (bgap.sim, the same
    model batched and compiled, ~1000x faster on dense traffic)."""
    traffic: TrafficConfig = field(default_factory=TrafficConfig)
    """Where the background traffic comes from: bgap's driver classes (``simulated``) or a
    recorded table (``traffic=replay traffic.table=PATH``, :mod:`bgap.traffic.replay`)."""

    def __post_init__(self) -> None:
        self.mix += 0.0  # -0.0 is 0.0: one folder name, one result
        self.radius += 0.0
        check(self.backend in BACKENDS, "backend", self.backend, "use highway or vector")
        check(self.seed >= 0, "seed", self.seed, "must be >= 0 (numpy seeds are non-negative)")
        check(
            self.behavior.converged,
            "behavior",
            self.behavior.name,
            "is a calibration that ended outside its tolerance (converged: false in the "
            "preset); continue the calibration, or use it knowingly with behavior.converged=true",
        )
        check(
            self.reward.converged,
            "reward",
            self.reward.name,
            "is from a sweep stopped before its trials were done (converged: false in the "
            "preset); rerun the sweep to finish it, or use it knowingly with "
            "reward.converged=true",
        )
        check_config(env_config(self))  # the one validator both simulators run

    def check_inputs(self) -> None:
        """The checks that read files, run by a command before it starts
        (:func:`bgap.common.config.load`), not by every config built: a replayed table no
        episode can come from fails here, in one line."""
        t = self.traffic
        frequency = self.env.simulation_frequency
        if t.source == "replay":
            load_replay(t.table, frequency, t.min_duration, t.scenes)
        elif t.source == "mixture":  # every table the mixture replays, on its training side
            for table in t.mixture.tables if t.mixture.sources.get("replay", 0) > 0 else []:
                load_replay(table, frequency, t.min_duration, "train")


SCHEMAS = (
    ("env", "base_env", EnvConfig),
    ("behavior", "base_behavior", BehaviorConfig),
    ("reward", "base_reward", RewardConfig),
    ("traffic", "base_traffic", TrafficConfig),
)
"""Hydra ConfigStore entries (group, name, schema) of the environment's config groups."""

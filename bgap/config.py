"""Typed configuration: the schema of every Hydra config group, and the bridge to highway-env.

YAML files under ``conf/`` hold values; the dataclasses here are their schema, registered in
Hydra's ConfigStore. A wrong type or an unknown key fails when Hydra composes the config;
ranges (``mix`` in [0, 1], ``radius`` > 0, ...) are checked in ``__post_init__``, which runs
when :func:`validate` turns the composed config into objects, first thing in every entry
point, before any work starts.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf

CONF_DIR = str(Path(__file__).resolve().parent.parent / "conf")


class ConfigError(ValueError):
    """A configuration value is out of range; the message names the key and the fix."""


def _check(ok: bool, key: str, value: Any, rule: str) -> None:
    if not ok:
        raise ConfigError(f"{key}={value!r} is invalid: {rule}")


@dataclass
class DriverParams:
    """IDM and MOBIL parameters of one driver class. ``None`` keeps highway-env's default.

    A class whose parameters are all ``None`` is highway-env's stock ``IDMVehicle``, unchanged.
    """

    time_gap: Optional[float] = None
    """IDM desired time gap T [s] (highway-env TIME_WANTED, 1.5)."""
    min_distance: Optional[float] = None
    """IDM minimum bumper-to-bumper gap s0 [m]; highway-env measures centre to centre, so its
    DISTANCE_WANTED is s0 + vehicle length (default 5 + 5)."""
    acc: Optional[float] = None
    """IDM maximum comfortable acceleration a [m/s^2] (COMFORT_ACC_MAX, 3)."""
    dec: Optional[float] = None
    """IDM comfortable deceleration b [m/s^2], positive (-COMFORT_ACC_MIN, 5)."""
    delta: Optional[float] = None
    """IDM acceleration exponent; ``None`` draws it in [3.5, 4.5] as highway-env does."""
    v0: Optional[float] = None
    """IDM desired speed [m/s]; ``None`` keeps highway-env's (the initial speed, <= 30)."""
    v0_spread: float = 0.0
    """Relative uniform spread of v0 per vehicle: v0 * U(1 - s, 1 + s)."""
    politeness: Optional[float] = None
    """MOBIL politeness p in [0, 1] (POLITENESS, 0)."""
    min_acc_gain: Optional[float] = None
    """MOBIL minimum acceleration gain [m/s^2] (LANE_CHANGE_MIN_ACC_GAIN, 0.2)."""
    b_safe: Optional[float] = None
    """MOBIL safe braking limit imposed on the new follower [m/s^2] (2)."""
    acc_max: Optional[float] = None
    """Physical acceleration/braking limit [m/s^2] (ACC_MAX, 6)."""

    def __post_init__(self) -> None:
        for name in ("time_gap", "min_distance", "acc", "dec", "v0", "acc_max", "delta"):
            v = getattr(self, name)
            _check(v is None or v > 0, f"behavior.*.{name}", v, "must be positive or null")
        for name in ("min_acc_gain", "b_safe"):
            v = getattr(self, name)
            _check(v is None or v >= 0, f"behavior.*.{name}", v, "must be >= 0 or null")
        p = self.politeness
        _check(p is None or 0 <= p <= 1, "behavior.*.politeness", p, "must lie in [0, 1]")
        s = self.v0_spread
        _check(0 <= s < 1, "behavior.*.v0_spread", s, "must lie in [0, 1)")

    @property
    def is_stock(self) -> bool:
        return all(v is None for k, v in asdict(self).items() if k != "v0_spread")


@dataclass
class BehaviorConfig:
    """Parameters of the two driver classes (config group ``behavior``)."""

    name: str = "paper"
    conservative: DriverParams = field(default_factory=DriverParams)
    aggressive: DriverParams = field(default_factory=DriverParams)


@dataclass
class EnvConfig:
    """Road, traffic density and timing (config group ``env``: ``sparse`` or ``dense``)."""

    name: str = "sparse"
    vehicles_count: int = 5
    """Background vehicles n."""
    observed_vehicles: int = 5
    """Rows V of the observation, the ego's row included (highway-env's convention)."""
    lanes_count: int = 4
    duration: float = 60.0
    """Episode length [s]."""
    policy_frequency: int = 1
    simulation_frequency: int = 15
    vehicles_density: float = 1.0
    ego_speeds: list[float] = field(default_factory=lambda: [10.0, 15.0, 20.0, 25.0, 30.0])
    """Target speeds [m/s] the ego's FASTER/SLOWER meta-actions step through."""

    def __post_init__(self) -> None:
        _check(self.vehicles_count >= 0, "env.vehicles_count", self.vehicles_count, "must be >= 0")
        _check(
            self.observed_vehicles >= 1,
            "env.observed_vehicles",
            self.observed_vehicles,
            "must be >= 1 (the ego's row)",
        )
        _check(self.lanes_count >= 1, "env.lanes_count", self.lanes_count, "must be >= 1")
        _check(self.duration > 0, "env.duration", self.duration, "must be positive")
        _check(self.policy_frequency >= 1, "env.policy_frequency", self.policy_frequency, ">= 1")
        _check(
            self.simulation_frequency % self.policy_frequency == 0,
            "env.simulation_frequency",
            self.simulation_frequency,
            "must be a multiple of env.policy_frequency",
        )
        _check(self.vehicles_density > 0, "env.vehicles_density", self.vehicles_density, "> 0")
        _check(
            len(self.ego_speeds) >= 1 and min(self.ego_speeds) >= 0,
            "env.ego_speeds",
            self.ego_speeds,
            "needs at least one non-negative speed",
        )


@dataclass
class RewardConfig:
    """Weights of the reward terms R = r_C + r_LC + r_RL + r_HS (config group ``reward``)."""

    name: str = "authors"
    collision: float = -1.0
    lane_change: float = 0.0
    right_lane: float = 0.1
    high_speed: float = 0.4
    speed_range: list[float] = field(default_factory=lambda: [20.0, 30.0])
    """Forward speeds [m/s] mapped linearly to r_HS in [0, 1]."""
    normalize: bool = True
    """Map the summed reward to [0, 1] using the most negative and most positive weights."""

    def __post_init__(self) -> None:
        lo, hi = self.speed_range
        _check(
            len(self.speed_range) == 2 and lo < hi,
            "reward.speed_range",
            self.speed_range,
            "must be [low, high] with low < high",
        )


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

    def __post_init__(self) -> None:
        _check(
            isinstance(self.mix, (int, float)) and 0.0 <= self.mix <= 1.0,
            "mix",
            self.mix,
            "must lie in [0, 1], the fraction of aggressive vehicles (e.g. mix=0.6)",
        )
        _check(
            math.isfinite(self.radius) and self.radius > 0,
            "radius",
            self.radius,
            "must be a positive distance in metres (e.g. radius=90)",
        )


@dataclass
class SimulateConfig(BaseConfig):
    """``python -m bgap.simulate``: record a behaviour-rich trajectory dataset."""

    episodes: int = 20
    out: str = "outputs/simulate"
    """Output folder: trajectories.parquet, config.yaml, command.txt (and the GIF)."""
    policy: str = "idle"
    """Ego policy while recording: ``idle`` or ``random``."""
    render: bool = False
    """Also render the first episode to ``episode0.gif`` (ego green, aggressive red,
    conservative blue)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        _check(self.episodes >= 1, "episodes", self.episodes, "must be >= 1")
        _check(self.policy in ("idle", "random"), "policy", self.policy, "use idle or random")


@dataclass
class StyleWeights:
    """One number per aggressive style."""

    overtaking: float = 1.0
    overspeeding: float = 1.0
    weaving: float = 1.0


@dataclass
class CMetricConfig:
    """CMetric parameters (config group ``cmetric``); README "CMetric" says why each default."""

    name: str = "default"
    mu: float = 30.0
    """Traffic-graph radius [m]: an edge joins vehicles closer than this."""
    window: float = 3.0
    """Length of the sliding windows the centrality polynomials are fitted on [s]."""
    stride: float = 1.0
    """Step between window starts [s]."""
    degree: int = 2
    """Degree of the centrality polynomials (the paper: 2)."""
    regularization: float = 1e-6
    """Ridge weight lambda of the least-squares fits, per sample, on normalised time."""
    epsilon: float = 0.5
    """Radius [s] of the ball in which a critical point's sharpness is measured (weaving)."""
    sharpness_min: float = 1e-4
    """Critical points with epsilon-sharpness at or below this are flat, not weaving."""
    weights: StyleWeights = field(
        default_factory=lambda: StyleWeights(overtaking=0.1, overspeeding=1.0, weaving=0.1)
    )
    """Weight of each style's likelihood in the aggressiveness score."""
    scales: StyleWeights = field(
        default_factory=lambda: StyleWeights(overtaking=0.0013, overspeeding=0.165, weaving=0.22)
    )
    """Each style's likelihood is divided by its scale before weighting (units: SLE units)."""

    def __post_init__(self) -> None:
        for key in ("mu", "window", "stride", "epsilon"):
            v = getattr(self, key)
            _check(v > 0, f"cmetric.{key}", v, "must be positive")
        _check(self.degree >= 1, "cmetric.degree", self.degree, "must be >= 1")
        _check(self.regularization >= 0, "cmetric.regularization", self.regularization, ">= 0")
        _check(self.sharpness_min >= 0, "cmetric.sharpness_min", self.sharpness_min, ">= 0")
        for style in ("overtaking", "overspeeding", "weaving"):
            w, s = getattr(self.weights, style), getattr(self.scales, style)
            _check(w >= 0, f"cmetric.weights.{style}", w, "must be >= 0")
            _check(s > 0, f"cmetric.scales.{style}", s, "must be positive")


@dataclass
class CMetricAppConfig:
    """``python -m bgap.cmetric TRAJECTORIES [overrides]``."""

    cmetric: CMetricConfig = field(default_factory=CMetricConfig)
    fps: float = 15.0
    """Frame rate used when the table has frames but no times."""
    out: Optional[str] = None
    """Scores file (.csv or .parquet); default: next to the input, ``<stem>_cmetric.csv``."""
    plot_vehicles: list[int] = field(default_factory=list)
    """Vehicle ids to plot (first episode); default: the two highest and two lowest scores."""


def register_configs() -> None:
    """Register the schemas; YAML files name them in their defaults list."""
    cs = ConfigStore.instance()
    cs.store(name="base_simulate", node=SimulateConfig)
    cs.store(group="env", name="base_env", node=EnvConfig)
    cs.store(group="behavior", name="base_behavior", node=BehaviorConfig)
    cs.store(group="reward", name="base_reward", node=RewardConfig)
    cs.store(group="cmetric", name="base_cmetric", node=CMetricConfig)
    cs.store(name="base_cmetric_app", node=CMetricAppConfig)


def validate(cfg: DictConfig) -> Any:
    """Instantiate the composed config as dataclasses, running every range check.

    Raises :class:`ConfigError` naming the offending key.
    """
    return OmegaConf.to_object(cfg)


def compose(config_name: str = "simulate", overrides: list[str] | None = None) -> DictConfig:
    """Compose a config from ``conf/`` with command-line style overrides, outside any Hydra app
    (tests, Optuna trials). Unknown keys and wrong types raise here."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    register_configs()
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=list(overrides or []))


def load(cfg: DictConfig) -> Any:
    """:func:`validate` for command-line entry points: a bad value ends the program with a
    one-line message instead of a traceback."""
    try:
        return validate(cfg)
    except ConfigError as err:
        raise SystemExit(f"bgap: configuration error: {err}") from None


def env_config(cfg: BaseConfig | DictConfig) -> dict[str, Any]:
    """Translate a bgap config into highway-env's config dictionary for our environment."""
    if isinstance(cfg, DictConfig):
        cfg = validate(cfg)
    e, r = cfg.env, cfg.reward
    return {
        "observation": {
            "type": "Kinematics",
            "vehicles_count": e.observed_vehicles,
            "features": ["presence", "x", "y", "vx", "vy"],
            "absolute": False,
            "normalize": True,
            "clip": True,
            "see_behind": True,
            "order": "sorted",
        },
        "action": {"type": "DiscreteMetaAction", "target_speeds": list(e.ego_speeds)},
        "lanes_count": e.lanes_count,
        "vehicles_count": e.vehicles_count,
        "vehicles_density": e.vehicles_density,
        "duration": e.duration,
        "policy_frequency": e.policy_frequency,
        "simulation_frequency": e.simulation_frequency,
        "collision_reward": r.collision,
        "lane_change_reward": r.lane_change,
        "right_lane_reward": r.right_lane,
        "high_speed_reward": r.high_speed,
        "reward_speed_range": list(r.speed_range),
        "normalize_reward": r.normalize,
        "mix": cfg.mix,
        "perception_radius": cfg.radius,
        "behavior": {
            "name": cfg.behavior.name,
            "conservative": asdict(cfg.behavior.conservative),
            "aggressive": asdict(cfg.behavior.aggressive),
        },
    }

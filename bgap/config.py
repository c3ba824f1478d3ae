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

    name: str = "highway"
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
    backend: str = "highway"
    """Simulator: ``highway`` (highway-env, the reference) or ``vector`` (bgap.sim, the same
    model batched and compiled, ~1000x faster on dense traffic)."""

    def __post_init__(self) -> None:
        _check(self.backend in BACKENDS, "backend", self.backend, "use highway or vector")
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
    per_alpha: float = 0.6
    per_beta0: float = 0.4

    def __post_init__(self) -> None:
        _check(self.loss in ("mse", "huber"), "agent.loss", self.loss, "use mse or huber")
        _check(self.replay in ("per", "uniform"), "agent.replay", self.replay, "use per or uniform")
        _check(0 < self.gamma <= 1, "agent.gamma", self.gamma, "must lie in (0, 1]")
        _check(self.learning_rate > 0, "agent.learning_rate", self.learning_rate, "must be > 0")
        _check(
            0 <= self.exploration_final <= self.exploration_initial <= 1,
            "agent.exploration_final",
            self.exploration_final,
            "need 0 <= exploration_final <= exploration_initial <= 1",
        )
        _check(
            self.batch_size >= 1 and self.buffer_size >= self.batch_size,
            "agent.buffer_size",
            self.buffer_size,
            "must be >= agent.batch_size >= 1",
        )


@dataclass
class ProfileConfig:
    """Compute budget (config group ``profile``: ``quick`` or ``paper``)."""

    name: str = "quick"
    train_steps: int = 30_000
    """Environment steps of training (the cap when ``train_episodes`` is set)."""
    train_episodes: Optional[int] = None
    """Stop after this many training episodes (the paper: 3000)."""
    n_envs: int = 2
    """Parallel training environments (subprocesses when > 1)."""
    exploration_decay_steps: Optional[float] = None
    """Overrides ``agent.exploration_decay_steps`` (short budgets need a shorter decay)."""
    eval_every_episodes: int = 0
    """Periodic greedy evaluation during training every this many episodes; 0: off."""
    eval_during_training: int = 20
    """Episodes of each periodic evaluation (the paper: 20 every 50)."""
    eval_episodes: int = 100
    """Episodes per grid cell of the final evaluation."""
    checkpoint_every: int = 1000
    """Steps between checkpoints (model and replay buffer)."""

    def __post_init__(self) -> None:
        _check(self.train_steps >= 1, "profile.train_steps", self.train_steps, "must be >= 1")
        _check(
            self.train_episodes is None or self.train_episodes >= 1,
            "profile.train_episodes",
            self.train_episodes,
            "must be >= 1 or null",
        )
        _check(self.n_envs >= 1, "profile.n_envs", self.n_envs, "must be >= 1")
        _check(self.eval_episodes >= 1, "profile.eval_episodes", self.eval_episodes, ">= 1")
        _check(
            self.checkpoint_every >= 1, "profile.checkpoint_every", self.checkpoint_every, ">= 1"
        )


@dataclass
class GridConfig:
    """Evaluation grid (config group ``grid``). An empty list means the run's own value."""

    name: str = "single"
    mixes: list[float] = field(default_factory=list)
    densities: list[str] = field(default_factory=list)
    """Names of ``env`` presets (``sparse``, ``dense``)."""
    radii: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        for m in self.mixes:
            _check(0 <= m <= 1, "grid.mixes", self.mixes, "every mix must lie in [0, 1]")
        for r in self.radii:
            _check(r > 0, "grid.radii", self.radii, "every radius must be positive")


POLICIES = ("behavior_rich", "default")
BACKENDS = ("highway", "vector")
PAPER_MIXES = (0.0, 0.2, 0.4, 0.5, 0.6, 0.8, 1.0)
BASELINES = ("idle", "random", "left")


@dataclass
class ExperimentConfig(BaseConfig):
    """Training, evaluation and the main job (``bgap.train``, ``bgap.evaluate``, ``bgap.run``)."""

    agent: AgentConfig = field(default_factory=AgentConfig)
    profile: ProfileConfig = field(default_factory=ProfileConfig)
    grid: GridConfig = field(default_factory=GridConfig)
    backend: str = "vector"
    """Training and evaluation run on the vectorised backend by default (the same traffic,
    step for step, ~1000x faster on dense); ``backend=highway`` runs highway-env itself."""
    policy: str = "behavior_rich"
    """``behavior_rich`` trains in the enriched traffic; ``default`` in stock traffic."""
    mix_sampling: str = "fixed"
    """Training mix: ``fixed`` (= ``mix``), ``uniform`` in [0, 1] or ``paper`` (one of the
    paper's seven mixes) drawn anew each episode."""
    root: str = "outputs"
    """Every run folder and result lives under this output root."""
    run_dir: Optional[str] = None
    """Training run folder; default ``<root>/runs/<name derived from the config>``."""
    resume: bool = False
    """Continue an interrupted training run from its last checkpoint."""
    models: list[str] = field(default_factory=list)
    """``bgap.evaluate``: run folders (or model.zip files) to evaluate."""
    baselines: list[str] = field(default_factory=lambda: ["idle", "random"])
    """Scripted policies evaluated beside the models: idle, random, left."""
    eval_seed: int = 100_000
    """Evaluation episode k of every cell uses seed eval_seed + k, for every policy."""
    workers: int = 2
    """Evaluation worker processes."""
    out: Optional[str] = None
    """``bgap.evaluate`` / ``bgap.run`` results folder; default under ``<root>/results``."""

    def __post_init__(self) -> None:
        super().__post_init__()
        _check(self.policy in POLICIES, "policy", self.policy, f"use one of {POLICIES}")
        _check(
            self.mix_sampling in ("fixed", "uniform", "paper"),
            "mix_sampling",
            self.mix_sampling,
            "use fixed, uniform or paper",
        )
        for b in self.baselines:
            _check(b in BASELINES, "baselines", self.baselines, f"each one of {BASELINES}")
        _check(self.workers >= 1, "workers", self.workers, "must be >= 1")


@dataclass
class ParamBounds:
    """Search interval [low, high] per driver parameter (DriverParams units); null: the
    parameter is not searched and keeps the preset's value."""

    time_gap: Optional[list[float]] = field(default_factory=lambda: [0.5, 2.5])
    min_distance: Optional[list[float]] = field(default_factory=lambda: [1.0, 6.0])
    acc: Optional[list[float]] = field(default_factory=lambda: [1.0, 6.0])
    dec: Optional[list[float]] = field(default_factory=lambda: [2.0, 9.0])
    delta: Optional[list[float]] = None
    v0: Optional[list[float]] = field(default_factory=lambda: [20.0, 45.0])
    politeness: Optional[list[float]] = field(default_factory=lambda: [0.0, 1.0])
    min_acc_gain: Optional[list[float]] = field(default_factory=lambda: [0.0, 0.5])
    b_safe: Optional[list[float]] = field(default_factory=lambda: [1.0, 9.0])

    def __post_init__(self) -> None:
        for key, b in asdict(self).items():
            if b is None:
                continue
            _check(
                len(b) == 2 and b[0] < b[1],
                f"calibrate.bounds.{key}",
                list(b),
                "must be [low, high] with low < high",
            )
            _check(b[0] >= 0, f"calibrate.bounds.{key}", list(b), "must be >= 0")

    def searched(self) -> dict[str, tuple[float, float]]:
        return {k: (float(b[0]), float(b[1])) for k, b in asdict(self).items() if b is not None}


@dataclass
class ClassTargets:
    """Target mean CMetric score per class."""

    aggressive: float = 0.77
    conservative: float = 0.31

    def __post_init__(self) -> None:
        for key, t in asdict(self).items():
            _check(0 < t < 1, f"calibrate.targets.{key}", t, "CMetric scores lie in (0, 1)")


@dataclass
class StartParams:
    """Per class, the first trial's parameters; null values take the behaviour preset's."""

    conservative: DriverParams = field(default_factory=DriverParams)
    aggressive: DriverParams = field(default_factory=DriverParams)


@dataclass
class CalibrationConfig:
    """Behaviour calibration (config group ``calibrate``); README "Calibration" says why."""

    name: str = "default"
    classes: list[str] = field(default_factory=lambda: ["aggressive", "conservative"])
    """Driver classes to calibrate, one Optuna study each."""
    trials: int = 100
    """Completed trials per class and round (counted across workers and reruns)."""
    rounds: int = 3
    """Rounds of calibrating the classes in turn, each against the other's latest best."""
    targets: ClassTargets = field(default_factory=ClassTargets)
    tolerance: float = 0.02
    """A class is calibrated when |mean score - target| is below this."""
    bounds: ParamBounds = field(default_factory=ParamBounds)
    start: StartParams = field(default_factory=StartParams)
    density: str = "dense"
    """``env`` preset of the scenes each trial simulates."""
    scene_mix: float = 0.5
    """Aggressive fraction of the scenes (both classes must be present)."""
    episodes: int = 4
    duration: float = 30.0
    """Length of each scene [s]."""
    scene_seed: int = 0
    """Scene k of every trial uses seed scene_seed + k: trials differ only in parameters."""
    max_crashed: float = 0.05
    """Trials whose scenes end with more than this fraction of vehicles crashed are penalised."""
    min_speed: float = 8.0
    """... and those whose class drives slower than this [m/s] (stalled traffic)."""
    min_auc: float = 0.75
    """... and those where CMetric separates the two classes worse than this ROC AUC."""
    sampler_seed: int = 0
    storage: Optional[str] = None
    """Optuna storage URL: sqlite:///..., postgresql://..., or journal:PATH (a journal file
    for parallel workers). Default: SQLite under ``<root>/calibration/``."""
    study: str = "bgap-calibration"
    """Study name prefix; the class and the scene settings are appended."""
    preset: str = "conf/behavior/calibrated.yaml"
    """Where the calibrated behaviour preset is written (``behavior=calibrated``)."""
    out: str = "results/calibration"

    def __post_init__(self) -> None:
        from bgap.behaviors import CLASSES

        for c in self.classes:
            _check(c in CLASSES, "calibrate.classes", self.classes, f"use {list(CLASSES)}")
        _check(
            bool(self.bounds.searched()),
            "calibrate.bounds",
            "all null",
            "give [low, high] for at least one parameter",
        )
        _check(self.trials >= 1, "calibrate.trials", self.trials, "must be >= 1")
        _check(self.rounds >= 1, "calibrate.rounds", self.rounds, "must be >= 1")
        _check(self.episodes >= 1, "calibrate.episodes", self.episodes, "must be >= 1")
        _check(0 < self.scene_mix < 1, "calibrate.scene_mix", self.scene_mix, "must lie in (0, 1)")
        _check(self.tolerance > 0, "calibrate.tolerance", self.tolerance, "must be positive")


@dataclass
class CalibrateAppConfig(BaseConfig):
    """``python -m bgap.calibrate``: Optuna searches driver parameters for CMetric targets."""

    calibrate: CalibrationConfig = field(default_factory=CalibrationConfig)
    cmetric: CMetricConfig = field(default_factory=CMetricConfig)
    backend: str = "vector"
    root: str = "outputs"


@dataclass
class SweepConfig(ExperimentConfig):
    """``python -m bgap.sweep``: the experiment every trial starts from, plus the search."""

    sweep: str = "reward"
    """Search space ``sweeps/<sweep>.yaml`` (``reward`` or ``dqn``)."""
    mode: str = "multi"
    """``multi``: minimise collisions and maximise speed (Pareto front); ``single``: the
    scalarisation collision % - speed_weight * speed, with pruning."""
    trials: int = 20
    """Finished trials wanted in the study, counted across workers and reruns."""
    speed_weight: float = 2.0
    """Collision percentage points one m/s of average speed is worth (single mode, and the
    choice of the written preset on a Pareto front)."""
    prune_every: int = 0
    """Single mode: steps between intermediate evaluations (0: a quarter of the budget)."""
    sweep_eval_episodes: int = 30
    """Greedy evaluation episodes per trial (fixed seeds, the same for every trial)."""
    storage: Optional[str] = None
    """Optuna URL (sqlite:///..., postgresql://..., journal:PATH); default SQLite under root."""
    study: Optional[str] = None
    """Study name; default ``<sweep>-<mode>-<env>``."""
    write_preset: bool = True
    preset: Optional[str] = None
    """Where the chosen preset goes; default ``conf/<group>/tuned.yaml``."""
    overrides: list[str] = field(default_factory=list)
    """Extra overrides every trial composes with (e.g. ["profile.train_steps=5000"])."""

    def __post_init__(self) -> None:
        super().__post_init__()
        _check(self.mode in ("multi", "single"), "mode", self.mode, "use multi or single")


def register_configs() -> None:
    """Register the schemas; YAML files name them in their defaults list."""
    cs = ConfigStore.instance()
    cs.store(name="base_simulate", node=SimulateConfig)
    cs.store(group="env", name="base_env", node=EnvConfig)
    cs.store(group="behavior", name="base_behavior", node=BehaviorConfig)
    cs.store(group="reward", name="base_reward", node=RewardConfig)
    cs.store(group="cmetric", name="base_cmetric", node=CMetricConfig)
    cs.store(name="base_cmetric_app", node=CMetricAppConfig)
    cs.store(name="base_experiment", node=ExperimentConfig)
    cs.store(group="agent", name="base_agent", node=AgentConfig)
    cs.store(group="profile", name="base_profile", node=ProfileConfig)
    cs.store(group="grid", name="base_grid", node=GridConfig)
    cs.store(group="calibrate", name="base_calibrate", node=CalibrationConfig)
    cs.store(name="base_calibrate_app", node=CalibrateAppConfig)
    cs.store(name="base_sweep", node=SweepConfig)


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
    from hydra.core.global_hydra import GlobalHydra

    register_configs()
    if GlobalHydra.instance().is_initialized():  # inside a Hydra app (its search path: conf/)
        return hydra_compose(config_name=config_name, overrides=list(overrides or []))
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=list(overrides or []))


def load(cfg: DictConfig) -> Any:
    """:func:`validate` for command-line entry points: a bad value ends the program with a
    one-line message instead of a traceback."""
    try:
        return validate(cfg)
    except ConfigError as err:
        raise SystemExit(f"bgap: configuration error: {err}") from None


def env_preset(name: str) -> EnvConfig:
    """The ``env`` group's preset ``name`` (``conf/env/<name>.yaml``) as an EnvConfig."""
    path = Path(CONF_DIR) / "env" / f"{name}.yaml"
    if not path.exists():
        choices = sorted(p.stem for p in path.parent.glob("*.yaml"))
        raise ConfigError(f"density {name!r} has no preset conf/env/{name}.yaml; use {choices}")
    return load_preset(EnvConfig, path)


def load_preset(schema: type, path: str | Path) -> Any:
    """A config-group preset file as a validated ``schema`` object, without Hydra's search
    path (its ``defaults`` list, naming the schema, is ignored)."""
    values = OmegaConf.load(path)
    values.pop("defaults", None)
    return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(schema), values))


def write_preset(node: Any, group: str, path: str | Path, note: str) -> Path:
    """Write dataclass ``node`` as a preset of config group ``group`` (``group=<stem>`` then
    selects it when ``path`` is ``conf/<group>/<stem>.yaml``), headed by the comment ``note``.
    Null values are left out: the groups written so (behavior, reward, agent) default every
    optional field to null."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    body = OmegaConf.to_yaml(OmegaConf.structured(node))
    body = "\n".join(line for line in body.splitlines() if not line.endswith(": null"))
    path.write_text(f"# {note}\ndefaults:\n  - base_{group}\n{body}\n")
    return path


def env_config(cfg: BaseConfig | DictConfig) -> dict[str, Any]:
    """Translate a bgap config into highway-env's config dictionary for our environment."""
    if isinstance(cfg, DictConfig):
        cfg = validate(cfg)
    from bgap.envs.highway import OBSERVATION

    e, r = cfg.env, cfg.reward
    return {
        "observation": {**OBSERVATION, "vehicles_count": e.observed_vehicles},
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

"""Command configuration: the schema of every command, and the Hydra plumbing.

YAML files under ``bgap/conf`` (package data) hold values; dataclasses are their schema,
registered in Hydra's ConfigStore by :func:`register_configs` when a command starts (never
at import). The schemas of the concerns live with them: ``env`` and ``reward`` in
:mod:`bgap.scenario`, ``behavior`` in :mod:`bgap.behaviors`, ``cmetric`` in
:mod:`bgap.cmetric.params`, ``agent`` in :mod:`bgap.agents.config`; this module holds the
commands' own schemas, which compose them. A wrong type or an unknown key fails when Hydra
composes the config; ranges (``mix`` in [0, 1], ``radius`` > 0, ...) are checked in
``__post_init__``, which runs when :func:`validate` turns the composed config into objects,
first thing in every entry point, before any work starts.
"""

from __future__ import annotations

import functools
import sys
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Optional

import hydra
from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf

from bgap.agents.config import AgentConfig
from bgap.behaviors import BehaviorConfig, DriverParams
from bgap.cmetric.params import CMetricConfig
from bgap.cmetric.search.params import CMetricSearchConfig
from bgap.datasets.sumo import SumoConfig
from bgap.errors import check
from bgap.presets import CONF_DIR
from bgap.scenario import EnvConfig, RewardConfig, check_config, env_config
from bgap.vocab import (
    BACKENDS,
    BASELINES,
    CHECKPOINTS,
    CLASSES,
    LEARNERS,
    MIX_SAMPLING,
    POLICIES,
    SPEED_FLOOR,
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


@dataclass
class SimulateConfig(BaseConfig):
    """``python -m bgap.simulate``: record a behaviour-rich trajectory dataset."""

    episodes: int = 20
    out: str = "outputs/simulate"
    """Output folder: trajectories.parquet, config.yaml, command.txt (and the GIF)."""
    policy: str = "idle"
    """Ego policy while recording: a baseline (``idle``, ``random``, ``left``) or a trained
    model (``model.zip`` or its run folder)."""
    render: bool = False
    """Also render the first episode to ``episode0.gif`` (ego green, aggressive red,
    conservative blue; ``backend=highway``)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        check(self.episodes >= 1, "episodes", self.episodes, "must be >= 1")
        check(
            self.policy in BASELINES or Path(self.policy).exists(),
            "policy",
            self.policy,
            f"use one of {BASELINES} or the path of a trained model (model.zip or its run folder)",
        )
        check(
            not self.render or self.backend == "highway",
            "render",
            self.render,
            "drawing needs backend=highway (the vector backend draws nothing)",
        )


@dataclass
class DatasetsConfig:
    """``python -m bgap.datasets SOURCE [PATH] [overrides]``: traffic from outside bgap."""

    source: str = "sumo"
    """Where the trajectories come from: ``sumo`` (recorded by :mod:`bgap.datasets.sumo`),
    ``highd`` or ``ngsim`` (the files at ``path`` converted: :mod:`bgap.datasets.highd`,
    :mod:`bgap.datasets.ngsim`)."""
    path: Optional[str] = None
    """``highd``: a recording's ``XX_tracks.csv`` or a folder of them; ``ngsim``: a
    trajectory file (``.csv`` or the original ``.txt``)."""
    sumo: SumoConfig = field(default_factory=SumoConfig)
    episodes: int = 10
    seed: int = 0
    """Episode ``k`` runs with seed ``seed + k``."""
    out: Optional[str] = None
    """Output folder; default ``outputs/datasets/<source>``."""

    def __post_init__(self) -> None:
        sources = ("sumo", "highd", "ngsim")
        check(self.source in sources, "source", self.source, f"use one of {sources}")
        check(
            self.source == "sumo" or self.path is not None,
            "path",
            self.path,
            f"give the {self.source} file or folder: python -m bgap.datasets {self.source} PATH",
        )
        check(self.episodes >= 1, "episodes", self.episodes, "must be >= 1")
        check(self.seed >= 0, "seed", self.seed, "must be >= 0")


@dataclass
class CMetricAppConfig:
    """``python -m bgap.cmetric input=TRAJECTORIES [overrides]``."""

    input: Optional[str] = None
    """The trajectory table to score (.parquet or .csv; schema: :mod:`bgap.cmetric.io`)."""
    cmetric: CMetricConfig = field(default_factory=CMetricConfig)
    fps: float = 15.0
    """Frame rate used when the table has frames but no times."""
    out: Optional[str] = None
    """A folder (``<folder>/<stem>_cmetric.csv`` and side files; a new folder ends with /)
    or a scores file (.csv or .parquet); default ``outputs/cmetric/<stem>_<preset>/``."""
    plot_vehicles: list[int] = field(default_factory=list)
    """Vehicle ids to plot (first episode); default: the two highest and two lowest scores."""

    def __post_init__(self) -> None:
        check(self.fps > 0, "fps", self.fps, "must be a positive frame rate [Hz] (e.g. fps=15)")


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
        check(self.train_steps >= 1, "profile.train_steps", self.train_steps, "must be >= 1")
        check(
            self.train_episodes is None or self.train_episodes >= 1,
            "profile.train_episodes",
            self.train_episodes,
            "must be >= 1 or null",
        )
        check(self.n_envs >= 1, "profile.n_envs", self.n_envs, "must be >= 1")
        check(self.eval_episodes >= 1, "profile.eval_episodes", self.eval_episodes, ">= 1")
        check(self.checkpoint_every >= 1, "profile.checkpoint_every", self.checkpoint_every, ">= 1")


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
            check(0 <= m <= 1, "grid.mixes", self.mixes, "every mix must lie in [0, 1]")
        for r in self.radii:
            check(r > 0, "grid.radii", self.radii, "every radius must be positive")


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
    """Training run folder; default ``<root>/runs/<name derived from the config>``. With
    ``seeds=[...]`` or ``policies=[...]`` (the batched learner), the folder holding one run
    folder per training, ``<density>-<policy>-s<seed>``."""
    resume: bool = False
    """Continue an interrupted training run from its last checkpoint."""
    models: list[str] = field(default_factory=list)
    """``bgap.evaluate``: run folders (or model.zip files) to evaluate."""
    baselines: list[str] = field(default_factory=lambda: ["idle", "random", "rule"])
    """Scripted policies evaluated beside the models: idle, random, left, rule (IDM + MOBIL)."""
    eval_seed: int = 100_000
    """Test episodes: episode k of every cell uses seed eval_seed + k, for every policy."""
    seeds: list[int] = field(default_factory=list)
    """``bgap.run``: training seeds, each trained and evaluated, with intervals across them
    (training seeds are the independent units); empty: ``[seed]``."""
    val_seed: int = 50_000
    """Validation episodes (training's periodic evaluations, sweeps' scores) use seed
    val_seed + k: choices are made on these, never on the test episodes (ours)."""
    workers: int = 2
    """Evaluation worker processes."""
    learner: str = "sb3"
    """``sb3``: Stable-Baselines3's DQN, one training per process (the reference);
    ``batched``: every training of the command in one batched learner
    (:mod:`bgap.agents.batched`; ``bgap.train seeds=[0,1,2]``), on CUDA when torch sees a
    GPU."""
    threads: int = 0
    """torch threads of the batched learner; 0: one per core. (The SB3 learner uses 1.)"""
    policies: list[str] = field(default_factory=list)
    """``bgap.train``: train these policy families (each with every seed); empty:
    ``[policy]``."""
    out: Optional[str] = None
    """``bgap.evaluate`` / ``bgap.run`` results folder; default under ``<root>/results``."""
    checkpoint: str = "best"
    """Which parameters of a training are evaluated: ``best``, the checkpoint its periodic
    validations chose (``best_model.zip``: the highest mean validation return, as SB3's
    ``EvalCallback``; ours, the paper keeps none), or ``last``, the final parameters
    (``model.zip``). A run without validations has only the last."""

    def __post_init__(self) -> None:
        super().__post_init__()
        check(self.policy in POLICIES, "policy", self.policy, f"use one of {POLICIES}")
        check(
            self.agent.converged,
            "agent",
            self.agent.name,
            "is from a sweep stopped before its trials were done (converged: false in the "
            "preset); rerun the sweep to finish it, or use it knowingly with "
            "agent.converged=true",
        )
        check(
            self.checkpoint in CHECKPOINTS,
            "checkpoint",
            self.checkpoint,
            f"use one of {CHECKPOINTS}",
        )
        check(
            self.mix_sampling in MIX_SAMPLING,
            "mix_sampling",
            self.mix_sampling,
            f"use one of {MIX_SAMPLING}",
        )
        for b in self.baselines:
            check(b in BASELINES, "baselines", self.baselines, f"each one of {BASELINES}")
        check(self.workers >= 1, "workers", self.workers, "must be >= 1")
        check(self.learner in LEARNERS, "learner", self.learner, f"use one of {LEARNERS}")
        check(self.threads >= 0, "threads", self.threads, "must be >= 0 (0: one per core)")
        for p in self.policies:
            check(p in POLICIES, "policies", self.policies, f"each one of {POLICIES}")
        check(
            all(s >= 0 for s in self.seeds) and len(set(self.seeds)) == len(self.seeds),
            "seeds",
            self.seeds,
            "must be distinct non-negative training seeds, e.g. seeds=[0,1,2]",
        )
        check(
            self.val_seed + 10_000 <= self.eval_seed or self.eval_seed + 10_000 <= self.val_seed,
            "val_seed",
            self.val_seed,
            f"must be at least 10000 away from eval_seed={self.eval_seed} (validation and test "
            "episodes never share seeds)",
        )


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
            check(
                len(b) == 2 and b[0] < b[1],
                f"calibrate.bounds.{key}",
                list(b),
                "must be [low, high] with low < high",
            )
            check(b[0] >= 0, f"calibrate.bounds.{key}", list(b), "must be >= 0")

    def searched(self) -> dict[str, tuple[float, float]]:
        return {k: (float(b[0]), float(b[1])) for k, b in asdict(self).items() if b is not None}


@dataclass
class ClassTargets:
    """Target mean CMetric score per class."""

    aggressive: float = 0.77
    conservative: float = 0.31

    def __post_init__(self) -> None:
        for key, t in asdict(self).items():
            check(0 < t < 1, f"calibrate.targets.{key}", t, "CMetric scores lie in (0, 1)")


@dataclass
class StatisticWeights:
    """Weights of the statistics that calibration to data compares (:mod:`bgap.kinematics`;
    each distance is scaled by the target's spread first, so equal weights weigh equally)."""

    score: float = 1.0
    speed: float = 1.0
    headway: float = 1.0
    acceleration: float = 1.0
    lane_changes: float = 1.0

    def __post_init__(self) -> None:
        values = asdict(self)
        check(
            min(values.values()) >= 0 and max(values.values()) > 0,
            "calibrate.weights",
            values,
            "weights must be >= 0, at least one > 0",
        )


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
    preset: Optional[str] = None
    """Where the calibrated behaviour preset is written; default
    ``<root>/presets/behavior/user_calibrated.yaml`` (``behavior=user_calibrated``). The
    pipeline writes the packaged ``behavior/calibrated.yaml``."""
    out: Optional[str] = None
    """Report folder; default ``<root>/calibration``."""
    target: Optional[str] = None
    """A labelled trajectory table (any file CMetric reads, with ``label`` and ``lane``):
    fit both classes at once to its statistics instead of ``targets``
    (:mod:`bgap.calibrate_data`)."""
    aggressive_prefix: str = "agg"
    """Target labels starting with this (case-insensitive) are aggressive, others
    conservative (``ego`` is left out)."""
    target_fps: float = 15.0
    """Frames per second of a target table without a ``time`` column."""
    min_vehicles: int = 10
    """Vehicles of each class the target must hold."""
    scene_from_data: bool = True
    """Simulate the target's lane count and aggressive share (else the ``density`` preset's
    lanes and ``scene_mix``)."""
    weights: StatisticWeights = field(default_factory=StatisticWeights)
    warmup: float = 0.0
    """Calibration to data: seconds simulated before each scene's measured ``duration``
    (traffic recorded at a steady state has no start-up accelerations)."""
    sensitivity_points: int = 5
    """Calibration to data: values per parameter in the one-at-a-time sensitivity sweep
    around the best trial (0: no sensitivity report)."""
    noise_repeats: int = 3
    """... and other scene sets the best parameters rerun on to measure the objective's
    noise."""
    reference_penalty: float = 0.0
    """Calibration to data: this times the weighted mean, over the statistics, of how much
    farther a trial's traffic lies from the target than Table I's traffic on the same scenes
    (scaled distance; 0 where it is closer) is added to the objective, so that the search
    does not buy a lower mean by giving up statistics Table I already matched (0: the plain
    weighted mean)."""

    def __post_init__(self) -> None:
        check(self.target_fps > 0, "calibrate.target_fps", self.target_fps, "must be > 0")
        check(self.min_vehicles >= 2, "calibrate.min_vehicles", self.min_vehicles, ">= 2")
        check(
            self.sensitivity_points == 0 or self.sensitivity_points >= 2,
            "calibrate.sensitivity_points",
            self.sensitivity_points,
            "0 (no report) or >= 2",
        )
        check(self.noise_repeats >= 1, "calibrate.noise_repeats", self.noise_repeats, ">= 1")
        check(self.warmup >= 0, "calibrate.warmup", self.warmup, "must be >= 0 s")
        check(
            self.reference_penalty >= 0,
            "calibrate.reference_penalty",
            self.reference_penalty,
            "must be >= 0 (0: no penalty)",
        )
        for c in self.classes:
            check(c in CLASSES, "calibrate.classes", self.classes, f"use {list(CLASSES)}")
        check(
            bool(self.bounds.searched()),
            "calibrate.bounds",
            "all null",
            "give [low, high] for at least one parameter",
        )
        check(self.trials >= 1, "calibrate.trials", self.trials, "must be >= 1")
        check(self.rounds >= 1, "calibrate.rounds", self.rounds, "must be >= 1")
        check(self.episodes >= 1, "calibrate.episodes", self.episodes, "must be >= 1")
        check(0 < self.scene_mix < 1, "calibrate.scene_mix", self.scene_mix, "must lie in (0, 1)")
        check(self.tolerance > 0, "calibrate.tolerance", self.tolerance, "must be positive")


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
    scalarisation collision % - speed_weight * speed, with pruning; ``constrained``:
    minimise collisions among policies at least ``speed_floor`` x idle's speed, with pruning."""
    trials: int = 20
    """Finished trials wanted in the study, counted across workers and reruns."""
    speed_weight: float = 2.0
    """Collision percentage points one m/s of average speed is worth (single mode, and the
    choice of the written preset on a Pareto front)."""
    speed_floor: float = SPEED_FLOOR
    """Constrained mode: the fraction of idle's mean speed (same validation episodes) a
    policy must reach to count as feasible."""
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
    """Where the chosen preset goes; default ``<root>/presets/<group>/user_tuned.yaml``
    (then ``reward=user_tuned``)."""
    overrides: list[str] = field(default_factory=list)
    """Extra overrides every trial composes with (e.g. ["profile.train_steps=5000"])."""

    def __post_init__(self) -> None:
        super().__post_init__()
        modes = ("multi", "single", "constrained")
        check(self.mode in modes, "mode", self.mode, f"use one of {modes}")
        check(0 < self.speed_floor <= 2, "speed_floor", self.speed_floor, "a fraction in (0, 2]")


@dataclass
class RecipeConfig(SweepConfig):
    """``python -m bgap.recipe``: the recipe sweep, then its best trials rerun on more seeds."""

    sweep: str = "recipe"
    mode: str = "constrained"
    candidates: int = 4
    """Best sweep trials (by the constrained objective) rerun with ``check_seeds``."""
    check_seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    """Training seeds of each candidate's rerun."""
    check_episodes: int = 100
    """Validation episodes per candidate and seed (the same for the idle and rule egos)."""
    preset_dir: Optional[str] = None
    """Where the chosen ``reward/<preset_name>.yaml`` and ``agent/<preset_name>.yaml`` go;
    default ``<root>/presets`` (the pipeline's stage: ``bgap/conf``)."""
    preset_name: str = "user_recipe"
    """Name of the written presets (``reward=user_recipe agent=user_recipe``); the pipeline's
    stage writes the packaged ``recipe``, which a user's preset must not shadow."""
    stock_check: bool = False
    """Also train each candidate's default policy (highway-env's stock traffic) with every
    check seed, and rank the candidates whose default policy misses the stock rule (fewer
    than ``stock_max_collision_pct`` collisions at ``speed_floor`` x idle's speed, on stock
    validation episodes) after those that meet it: the recipe is shared by both policies."""
    stock_max_collision_pct: float = 50.0
    """The stock rule's collision bound (issue 20: under half of the episodes)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        check(self.mode != "multi", "mode", self.mode, "a recipe needs one objective")
        check(
            0 < self.stock_max_collision_pct <= 100,
            "stock_max_collision_pct",
            self.stock_max_collision_pct,
            "a percentage in (0, 100]",
        )
        check(self.candidates >= 1, "candidates", self.candidates, "must be >= 1")
        check(len(self.check_seeds) >= 2, "check_seeds", self.check_seeds, ">= 2 seeds")
        check(self.check_episodes >= 10, "check_episodes", self.check_episodes, ">= 10")


def register_configs() -> None:
    """Register the schemas; YAML files name them in their defaults list. Idempotent."""
    # The presets folder on the search path (bgap.presets) need not exist yet.
    warnings.filterwarnings(
        "ignore", message=r"provider=hydra\.searchpath in main, path=.* is not available"
    )
    _store_schemas()


@functools.cache
def _store_schemas() -> None:
    """Once per process: Hydra's ConfigStore is a process-wide singleton, and storing the 16
    schemas again (each converted to an OmegaConf node) was half the time of every
    :func:`compose`."""
    cs = ConfigStore.instance()
    cs.store(name="base_simulate", node=SimulateConfig)
    cs.store(group="env", name="base_env", node=EnvConfig)
    cs.store(group="behavior", name="base_behavior", node=BehaviorConfig)
    cs.store(group="reward", name="base_reward", node=RewardConfig)
    cs.store(group="cmetric", name="base_cmetric", node=CMetricConfig)
    cs.store(name="base_cmetric_app", node=CMetricAppConfig)
    cs.store(name="base_cmetric_search", node=CMetricSearchConfig)
    cs.store(name="base_datasets", node=DatasetsConfig)
    cs.store(name="base_experiment", node=ExperimentConfig)
    cs.store(group="agent", name="base_agent", node=AgentConfig)
    cs.store(group="profile", name="base_profile", node=ProfileConfig)
    cs.store(group="grid", name="base_grid", node=GridConfig)
    cs.store(group="calibrate", name="base_calibrate", node=CalibrationConfig)
    cs.store(name="base_calibrate_app", node=CalibrateAppConfig)
    cs.store(name="base_sweep", node=SweepConfig)
    cs.store(name="base_recipe", node=RecipeConfig)


def validate(cfg: DictConfig) -> Any:
    """Instantiate the composed config as dataclasses, running every range check.

    Raises :class:`ConfigError` naming the offending key.
    """
    return OmegaConf.to_object(cfg)


def compose(config_name: str = "simulate", overrides: list[str] | None = None) -> DictConfig:
    """Compose a config from the packaged ``conf/`` with command-line style overrides,
    outside any Hydra app (tests, Optuna trials). Unknown keys and wrong types raise here."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    register_configs()
    if GlobalHydra.instance().is_initialized():  # inside a Hydra app (its search path: conf/)
        return hydra_compose(config_name=config_name, overrides=list(overrides or []))
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=list(overrides or []))


def load(cfg: DictConfig) -> Any:
    """:func:`validate` for command-line entry points; a bad value raises
    :class:`ConfigError`, which :func:`app` reports in one line."""
    return validate(cfg)


def app(
    config_name: str, prog: str, on_interrupt: str = "nothing was saved; rerun the command"
) -> Callable[[Callable[[DictConfig], Any]], Callable[[], Any]]:
    """``@app("train", "bgap.train")``: a command's ``main(dcfg)`` as a command-line program
    over the packaged config ``<config_name>.yaml``, with the schemas registered first (not
    as an import side effect).

    Plain ``key=value`` overrides are composed here, so that every known mistake ends in one
    line and exit status 2 (:mod:`bgap.cli`); options (``--help``, ``--cfg job``, ``-m`` for
    multirun) and ``hydra.*`` overrides go to Hydra's own command line.
    """
    from bgap.cli import run

    def decorator(task: Callable[[DictConfig], Any]) -> Callable[[], Any]:
        @functools.wraps(task)
        def reported(dcfg: DictConfig) -> Any:  # Hydra's own reporting would print a trace
            return run(prog, lambda: task(dcfg), on_interrupt)

        hydra_task = hydra.main(version_base="1.3", config_path=CONF_DIR, config_name=config_name)(
            reported
        )

        @functools.wraps(task)
        def main() -> Any:
            register_configs()
            args = sys.argv[1:]
            if any(a.startswith(("-", "hydra.", "hydra/", "+hydra", "~hydra")) for a in args):
                return hydra_task()
            return run(prog, lambda: task(compose(config_name, args)), on_interrupt)

        return main

    return decorator

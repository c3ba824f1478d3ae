"""Schema of ``bgap.calibrate``: the search (bounds, targets, scenes) of both calibration
modes, to CMetric scores and to observed data."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Optional

from omegaconf import DictConfig

from bgap.cmetric.config import SCHEMAS as CMETRIC_SCHEMAS
from bgap.cmetric.params import CMetricConfig
from bgap.common import config as plumbing
from bgap.common.errors import check
from bgap.common.vocab import CLASSES
from bgap.sim.config import SCHEMAS as SIM_SCHEMAS
from bgap.sim.config import BaseConfig
from bgap.traffic.behaviors import DriverParams


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
    """Weights of the statistics that calibration to data compares
    (:mod:`bgap.calibration.kinematics`; each distance is scaled by the target's spread
    first, so equal weights weigh equally)."""

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
    (:mod:`bgap.calibration.data`)."""
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


SCHEMAS = (
    *SIM_SCHEMAS,
    *CMETRIC_SCHEMAS,
    ("calibrate", "base_calibrate", CalibrationConfig),
    (None, "base_calibrate_app", CalibrateAppConfig),
)
"""Hydra ConfigStore entries of ``calibrate.yaml``."""


def compose(config_name: str, overrides: list[str] | None = None) -> DictConfig:
    """The packaged ``<config_name>.yaml`` of these commands with command-line style
    overrides, outside a Hydra app (scripts, tests)."""
    return plumbing.compose(config_name, overrides, SCHEMAS)

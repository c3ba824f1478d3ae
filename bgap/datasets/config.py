"""Schemas of the dataset commands: ``bgap.simulate`` (bgap's own recorded traffic) and
``bgap.datasets`` (SUMO, highD, NGSIM)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from omegaconf import DictConfig

from bgap.common import config as plumbing
from bgap.common.errors import check
from bgap.common.vocab import BASELINES
from bgap.datasets.sumo import SumoConfig
from bgap.sim.config import SCHEMAS as SIM_SCHEMAS
from bgap.sim.config import BaseConfig

ZOO = "zoo:"
"""A zoo name's prefix (:data:`bgap.agents.zoo.PREFIX`; not imported: the dataset commands'
schemas stay clear of the agents)."""


@dataclass
class SimulateConfig(BaseConfig):
    """``python -m bgap.simulate``: record a behaviour-rich trajectory dataset."""

    episodes: int = 20
    out: str = "outputs/simulate"
    """Output folder: trajectories.parquet, config.yaml, command.txt (and the GIF)."""
    policy: str = "idle"
    """Ego policy while recording: a baseline (``idle``, ``random``, ``left``), a trained
    model (``model.zip`` or its run folder) or a zoo name (``zoo:main/sparse/default/s0``)."""
    zoo_override: bool = False
    """Play a zoo policy under other observation settings than it was trained with."""
    render: bool = False
    """Also render the first episode to ``episode0.gif`` (ego green, aggressive red,
    conservative blue; ``backend=highway``)."""

    def __post_init__(self) -> None:
        # before the base checks, which read the table: the setting is refused either way
        check(
            self.traffic.source != "replay",
            "traffic",
            self.traffic.name,
            "simulate records bgap's own traffic, and a replayed table is its own recording; "
            "play a policy in it with bgap.evaluate traffic=replay",
        )
        super().__post_init__()
        check(self.episodes >= 1, "episodes", self.episodes, "must be >= 1")
        check(
            self.policy in BASELINES or self.policy.startswith(ZOO) or Path(self.policy).exists(),
            "policy",
            self.policy,
            f"use one of {BASELINES}, the path of a trained model (model.zip or its run folder) "
            "or a zoo name (zoo:<arm>/<density>/<family>/s<seed>)",
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


SCHEMAS = (
    *SIM_SCHEMAS,
    (None, "base_simulate", SimulateConfig),
    (None, "base_datasets", DatasetsConfig),
)
"""Hydra ConfigStore entries of ``simulate.yaml`` and ``datasets.yaml``."""


def compose(config_name: str, overrides: list[str] | None = None) -> DictConfig:
    """The packaged ``<config_name>.yaml`` of these commands with command-line style
    overrides, outside a Hydra app (scripts, tests)."""
    return plumbing.compose(config_name, overrides, SCHEMAS)

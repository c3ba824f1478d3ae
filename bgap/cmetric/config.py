"""Schemas of the CMetric commands (``bgap.cmetric``, ``bgap.cmetric.search``,
``bgap.cmetric.boundary``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from omegaconf import DictConfig

from bgap.cmetric.params import CMetricConfig
from bgap.cmetric.search.params import CMetricSearchConfig
from bgap.common import config as plumbing
from bgap.common.errors import check


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
class BoundaryConfig:
    """``python -m bgap.cmetric.boundary tables=[...]``: the class boundary on labelled
    tables."""

    tables: list[str] = field(default_factory=list)
    """Labelled trajectory tables, or folders holding ``trajectories.parquet`` files (the
    pipeline: its ``cmetric_data``)."""
    cmetric_preset: str = "tuned"
    """The CMetric preset the tables are scored with (``bgap/conf/cmetric``, or the pipeline's
    ``tuned`` in ``results/presets/cmetric``; a field of its own name, since ``cmetric=``
    picks that config group in the other commands)."""
    out: str = "outputs/cmetric_boundary"
    """The report folder."""
    preset: Optional[str] = None
    """Where the boundary preset goes; default ``<out>/<cmetric_preset>.yaml``."""

    def __post_init__(self) -> None:
        check(
            bool(self.tables),
            "tables",
            self.tables,
            "give labelled tables, e.g. tables=[outputs/pipeline/cmetric_data]",
        )


SCHEMAS = (
    ("cmetric", "base_cmetric", CMetricConfig),
    (None, "base_cmetric_boundary", BoundaryConfig),
    (None, "base_cmetric_app", CMetricAppConfig),
    (None, "base_cmetric_search", CMetricSearchConfig),
)
"""Hydra ConfigStore entries of ``cmetric_app.yaml``, ``cmetric_boundary.yaml`` and
``cmetric_search.yaml``."""


def compose(config_name: str, overrides: list[str] | None = None) -> DictConfig:
    """The packaged ``<config_name>.yaml`` of these commands with command-line style
    overrides, outside a Hydra app (scripts, tests)."""
    return plumbing.compose(config_name, overrides, SCHEMAS)

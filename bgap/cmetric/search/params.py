"""The search's settings: plain dataclasses (the ``cmetric_search`` config's schema)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from bgap.cmetric.params import CMetricConfig
from bgap.common.errors import check


@dataclass
class SearchDataset:
    """One labelled trajectory table of the search."""

    path: str = "???"
    name: str = ""
    """Shown in the report; default: the file's stem (plus the crop)."""
    radius: Optional[float] = None
    """Keep only vehicles within this distance [m] of the ego (``is_ego`` rows) per frame."""
    split: bool = True
    """False: the whole table is validation data (it never tunes the parameters)."""


@dataclass
class CMetricSearchConfig:
    """``python -m bgap.cmetric.search datasets=[...]``: see the module docstring."""

    datasets: list[SearchDataset] = field(default_factory=list)
    """Tables given one by one."""
    data_dir: Optional[str] = None
    """Also every ``<data_dir>/<name>/trajectories.parquet`` (``bgap.simulate``'s output) and
    ``<data_dir>/*.parquet``, split into search and validation parts, each at every radius."""
    validation_dir: Optional[str] = None
    """Also every table found there as in ``data_dir``, validation only (never tunes)."""
    radii: list[Optional[float]] = field(default_factory=lambda: [None])
    """Crops applied to the tables found in the two folders (null: the whole road)."""
    crops_tune: bool = True
    """False: the crops (a radius that is not null) of ``data_dir``'s tables only validate;
    the whole-road tables alone tune. A crop of a few dozen vehicles has an AUC standard
    error of ~0.08 and, as the worst part, decided CMetric's whole parameter search."""
    cmetric: CMetricConfig = field(default_factory=CMetricConfig)
    """The starting preset: trial 0 evaluates it, and settings not searched keep its values."""
    trials: int = 60
    seed: int = 0
    """Seed of the TPE sampler."""
    z: float = 0.0
    """Each search part counts with its AUC less ``z`` standard errors (0: the AUC itself;
    1: a one-sigma lower bound, which keeps the smallest parts from deciding by noise)."""
    known_truths: bool = True
    """Refuse settings that break the hand-built scenes' truths (:mod:`bgap.cmetric.truths`:
    a weaver, an overspeeder and a cruiser): such a trial scores its objective less 1, so
    it can never be chosen while any setting keeps them."""
    max_flagged: float = 0.10
    """Largest share of a dataset's vehicles that may be flagged without a penalty."""
    fps: float = 15.0
    """Frame rate of tables that have frames but no times."""
    out: str = "outputs/cmetric_search"
    """Study, report, figures and (by default) the preset."""
    storage: Optional[str] = None
    """Optuna storage URL; default ``sqlite:///<out>/optuna.db``."""
    study: Optional[str] = None
    """Study name; default ``cmetric-<hash of the tables' contents and the settings>``, so a
    rerun on other data starts a new study instead of mixing trials."""
    preset: Optional[str] = None
    """Where the tuned preset goes; default ``<out>/presets/cmetric/user_tuned.yaml``
    (the pipeline's stage: ``results/presets/cmetric/tuned.yaml``)."""

    def __post_init__(self) -> None:
        for key in ("data_dir", "validation_dir"):
            folder = getattr(self, key)
            check(folder is None or Path(folder).is_dir(), key, folder, "no such folder")
        for r in self.radii:
            check(r is None or r > 0, "radii", self.radii, "each radius > 0 m, or null")
        found = self._found(self.data_dir, True) + self._found(self.validation_dir, False)
        self.datasets = [*self.datasets, *(d for d in found if d not in self.datasets)]
        check(len(self.datasets) >= 1, "datasets", self.datasets, "give at least one table")
        check(any(d.split for d in self.datasets), "datasets", "split", "one must tune")
        check(self.trials >= 1, "trials", self.trials, "must be >= 1")
        check(self.z >= 0, "z", self.z, "must be >= 0 standard errors")
        check(0 <= self.max_flagged < 1, "max_flagged", self.max_flagged, "must be in [0, 1)")
        for d in self.datasets:
            check(Path(d.path).is_file(), "datasets.path", d.path, "no such file")
            check(d.radius is None or d.radius > 0, "datasets.radius", d.radius, "must be > 0")

    def _found(self, folder: Optional[str], split: bool) -> list[SearchDataset]:
        """The tables of ``folder``, each at every radius (sorted, so names are stable)."""
        if folder is None:
            return []
        root = Path(folder)
        tables = {p.parent.name: p for p in sorted(root.glob("*/trajectories.parquet"))}
        tables |= {p.stem: p for p in sorted(root.glob("*.parquet"))}
        check(len(tables) > 0, "data folder", folder, "holds no .parquet trajectory table")
        return [
            SearchDataset(
                str(path), name + (f"@{r:g}m" if r else ""), r, split and (not r or self.crops_tune)
            )
            for name, path in sorted(tables.items())
            for r in self.radii
        ]

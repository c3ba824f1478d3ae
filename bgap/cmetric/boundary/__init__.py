"""A class boundary on CMetric's aggressiveness, fixed once on bgap's own labelled tables.

    python -m bgap.cmetric.boundary tables=[outputs/pipeline/cmetric_data] cmetric_preset=tuned \
        out=results/cmetric/boundary preset=results/presets/cmetric/boundary/tuned.yaml

The boundary is the aggressiveness above which a vehicle reads aggressive: the threshold
that maximises Youden's J (true minus false positive rate: balanced accuracy, whatever the
share of aggressive drivers) on the tables' even episodes, pooled, the part CMetric's search
tunes on; its balanced accuracy is reported on the odd episodes too. A table without labels
is then read with it (a replayed table's aggressive share), never with its own
median, which would make every table half aggressive. Vehicles without evidence (no score)
are left out of both. Writes ``boundary.json``, ``scores.png`` (each class's scores and the
boundary), ``command.txt`` and the preset (:class:`ClassBoundary`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from bgap.cmetric.io import load_trajectories
from bgap.cmetric.params import CMetricConfig
from bgap.cmetric.score import score_trajectories
from bgap.common.errors import ConfigError
from bgap.common.presets import shipped
from bgap.common.vocab import AGGRESSIVE, CONSERVATIVE

BOUNDARY_DIR = "cmetric/boundary"
"""Where the pipeline's boundaries live:
``results/presets/cmetric/boundary/<cmetric preset>.yaml``."""


@dataclass
class ClassBoundary:
    """The aggressiveness above which a vehicle scored at the CMetric preset ``cmetric``
    reads aggressive, and how well it separates bgap's labelled classes."""

    name: str = "tuned"
    cmetric: str = "tuned"
    """The CMetric preset (``cmetric/<name>.yaml``, packaged or the pipeline's) the scores
    come from."""
    boundary: float = 0.0
    balanced_accuracy: float = float("nan")
    """On the odd (validation) episodes; the tuning episodes' is in ``boundary.json``."""
    tables: list[str] = field(default_factory=list)


def youden_threshold(scores: np.ndarray, positive: np.ndarray) -> float:
    """The threshold t maximising TPR - FPR of "score > t" (the first of tied maxima), set
    midway between the two distinct scores it falls between."""
    values = np.unique(scores)
    if len(values) < 2:
        raise ConfigError("a class boundary needs scores that differ between vehicles")
    cuts = (values[:-1] + values[1:]) / 2
    pos, neg = scores[positive], scores[~positive]
    tpr = (pos[:, None] > cuts).mean(axis=0)
    fpr = (neg[:, None] > cuts).mean(axis=0)
    return float(cuts[int(np.argmax(tpr - fpr))])


def balanced_accuracy(scores: np.ndarray, positive: np.ndarray, boundary: float) -> float:
    said = scores > boundary
    return float((said[positive].mean() + (~said[~positive]).mean()) / 2)


def labelled_scores(tables: list[Path], cfg: CMetricConfig) -> pd.DataFrame:
    """Every labelled (aggressive or conservative) vehicle with a score: table, episode,
    aggressiveness, whether it is aggressive."""
    parts = []
    for path in tables:
        vehicles = score_trajectories(path, cfg).vehicles
        if "label" not in vehicles:
            raise ConfigError(f"{path}: no label column; a boundary is fixed on labelled tables")
        kept = vehicles[vehicles.label.isin([AGGRESSIVE, CONSERVATIVE])]
        kept = kept.dropna(subset=["aggressiveness"])
        parts.append(kept.assign(table=str(path), positive=kept.label == AGGRESSIVE))
    return pd.concat(parts, ignore_index=True)


def fit(tables: list[Path], cmetric: str) -> tuple[ClassBoundary, dict, pd.DataFrame]:
    """The boundary of the CMetric preset ``cmetric`` on ``tables`` (even episodes), its
    report (the balanced accuracy of both parts and each part's size) and the scored
    vehicles (:func:`labelled_scores`)."""
    cfg = _cmetric(cmetric)
    scored = labelled_scores(tables, cfg)
    even = scored.episode.astype(int) % 2 == 0
    tune, check = scored[even], scored[~even]
    for part, rows in (("even", tune), ("odd", check)):
        if rows.positive.all() or not rows.positive.any():
            raise ConfigError(f"the {part} episodes need both aggressive and conservative cars")
    x, y = tune.aggressiveness.to_numpy(), tune.positive.to_numpy()
    boundary = youden_threshold(x, y)
    validation = balanced_accuracy(
        check.aggressiveness.to_numpy(), check.positive.to_numpy(), boundary
    )
    result = ClassBoundary(
        name=cmetric,
        cmetric=cmetric,
        boundary=boundary,
        balanced_accuracy=validation,
        tables=[str(t) for t in tables],
    )
    report = asdict(result) | {
        "tuning_balanced_accuracy": balanced_accuracy(x, y, boundary),
        "tuning_vehicles": len(tune),
        "validation_vehicles": len(check),
        "aggressive_share_tuning": float(y.mean()),
    }
    return result, report, scored


def share(table: str | Path | pd.DataFrame, boundary: ClassBoundary) -> float:
    """The share of a table's scored vehicles (each track once; an ``is_ego`` vehicle left
    out) whose aggressiveness lies above ``boundary``."""
    cfg = shipped(
        CMetricConfig, "cmetric", boundary.cmetric, f"no CMetric preset {boundary.cmetric!r}"
    )
    rows = load_trajectories(table, extra=("is_ego",))
    vehicles = score_trajectories(rows, cfg).vehicles.dropna(subset=["aggressiveness"])
    keys = ["episode", "vehicle_id"]
    if "is_ego" in rows:  # a recording's ego (a bgap or SUMO table) is not its traffic
        egos = rows[rows.is_ego.astype(bool)][keys].drop_duplicates()
        vehicles = vehicles.merge(egos, on=keys, how="left", indicator=True)
        vehicles = vehicles[vehicles.pop("_merge") == "left_only"]
    if "label" in vehicles:
        vehicles = vehicles[vehicles.label.astype(str) != "ego"]
    if vehicles.empty:
        raise ConfigError(f"{table}: CMetric scores none of its vehicles (no evidence)")
    return float((vehicles.aggressiveness > boundary.boundary).mean())


def _cmetric(name: str) -> CMetricConfig:
    """The shipped CMetric preset ``name``."""
    return shipped(CMetricConfig, "cmetric", name, f"no CMetric preset {name!r}")


def packaged(cmetric: str = "tuned") -> ClassBoundary:
    """The boundary the pipeline fixed for the CMetric preset ``cmetric``."""
    missing = (
        f"no class boundary for cmetric={cmetric}; the pipeline's cmetric_boundary stage "
        "fixes it (dvc repro cmetric_boundary)"
    )
    return shipped(ClassBoundary, BOUNDARY_DIR, cmetric, missing)

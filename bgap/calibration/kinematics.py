"""Kinematic statistics of any trajectory table, per driver class, and how far two tables'
statistics lie apart: what calibration to observed traffic compares, and what a
user can check on their own data.

The statistics, each a sample per class (documented choices are ours unless a source is
named):

- ``speed`` [m/s]: every vehicle-frame's speed;
- ``headway`` [s]: time headway to the leader, every vehicle-frame that follows one: the
  centre-to-centre distance to the nearest vehicle ahead in the same lane over the
  follower's speed. Centre to centre because trajectory tables carry no vehicle lengths;
  frames with headways above ``max_headway`` (10 s: free driving, not following) or speeds
  below 1 m/s are left out;
- ``acceleration`` [m/s^2]: longitudinal, central differences of ``vx`` per vehicle;
- ``lane_changes`` [per vehicle-minute]: one value per vehicle observed at least
  ``min_minutes``: its changes of ``lane`` over the minutes it was observed.

A table is read as :func:`bgap.cmetric.io.load_trajectories` reads it (so any file CMetric
scores); it needs ``label`` and ``lane`` columns. Labels map to bgap's two classes by
:func:`driver_class`. :func:`scene` estimates the simulated scene a table implies, and
:func:`compare` the distances between two tables' statistics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from bgap.cmetric.io import TrajectoryError, load_trajectories
from bgap.common.vocab import AGGRESSIVE, CONSERVATIVE, EGO

STATISTICS = ("speed", "headway", "acceleration", "lane_changes")
"""The statistics :func:`class_samples` returns, in this order."""
ALL_STATISTICS = ("score", *STATISTICS)
"""What calibration to data compares, per class: the CMetric score and the kinematic
statistics."""


def driver_class(labels: pd.Series, aggressive_prefix: str = "agg") -> pd.Series:
    """bgap's class of each label: ``aggressive`` where it starts with ``aggressive_prefix``
    (case-insensitive), ``ego`` for ``ego``, ``conservative`` for every other label."""
    text = labels.astype(str).str.lower()
    out = np.where(text.str.startswith(aggressive_prefix.lower()), AGGRESSIVE, CONSERVATIVE)
    return pd.Series(np.where(text == EGO, EGO, out), index=labels.index)


def _prepared(source, fps: float, aggressive_prefix: str) -> pd.DataFrame:
    table = load_trajectories(source, fps=fps, extra=("lane",))
    for column, what in (("label", "its class"), ("lane", "its lane index")):
        if column not in table:
            raise TrajectoryError(f"the table has no {column!r} column: give each row {what}")
    table["cls"] = driver_class(table.label, aggressive_prefix)
    return table


def class_samples(
    source,
    fps: float = 15.0,
    aggressive_prefix: str = "agg",
    max_headway: float = 10.0,
    min_minutes: float = 1 / 6,
) -> dict[str, dict[str, np.ndarray]]:
    """``{class: {statistic: sample}}`` for the classes present (the ego left out)."""
    table = _prepared(source, fps, aggressive_prefix)
    table = table.sort_values(["episode", "vehicle_id", "frame"], ignore_index=True)
    speed = np.hypot(table.vx.to_numpy(), table.vy.to_numpy())
    table["speed_"] = speed
    # longitudinal acceleration: central differences of vx over time, per vehicle
    accel = np.full(len(table), np.nan)
    for rows in table.groupby(["episode", "vehicle_id"]).indices.values():
        if len(rows) > 2:
            accel[rows] = np.gradient(table.vx.to_numpy()[rows], table.time.to_numpy()[rows])
    table["acceleration"] = accel
    table["headway"] = _headways(table, max_headway)
    # lane changes per vehicle-minute, vehicles observed at least min_minutes
    # rows are sorted; ids of any type (a SUMO table's "dense_mix50", "v27") compare equal
    same = table.episode.eq(table.episode.shift()) & table.vehicle_id.eq(table.vehicle_id.shift())
    table["changed"] = same & (table.lane.diff() != 0)
    per_vehicle = table.groupby(["episode", "vehicle_id"])
    changes = per_vehicle.changed.sum()
    minutes = (per_vehicle.time.max() - per_vehicle.time.min()) / 60.0
    cls = per_vehicle.cls.first()
    kept = minutes >= min_minutes
    rate = (changes[kept] / minutes[kept]).rename("lane_changes")
    out: dict[str, dict[str, np.ndarray]] = {}
    for name in (AGGRESSIVE, CONSERVATIVE):
        rows = table[table.cls == name]
        if rows.empty:
            continue
        out[name] = {
            "speed": rows.speed_.to_numpy(),
            "headway": rows.headway.dropna().to_numpy(),
            "acceleration": rows.acceleration.dropna().to_numpy(),
            "lane_changes": rate[cls[kept] == name].to_numpy(dtype=float),
        }
    return out


def _headways(table: pd.DataFrame, max_headway: float) -> np.ndarray:
    """Time headway to the nearest vehicle ahead in the same lane, per row (NaN where there
    is none, it is above ``max_headway``, or the follower is slower than 1 m/s)."""
    order = table.sort_values(["episode", "frame", "lane", "x"]).index.to_numpy()
    t = table.loc[order]
    same = (
        (t.episode.to_numpy()[1:] == t.episode.to_numpy()[:-1])
        & (t.frame.to_numpy()[1:] == t.frame.to_numpy()[:-1])
        & (t.lane.to_numpy()[1:] == t.lane.to_numpy()[:-1])
    )
    gap = np.full(len(t), np.nan)
    gap[:-1] = np.where(same, t.x.to_numpy()[1:] - t.x.to_numpy()[:-1], np.nan)
    speed = t.speed_.to_numpy()
    with np.errstate(divide="ignore", invalid="ignore"):
        headway = np.where(speed >= 1.0, gap / speed, np.nan)
    headway[headway > max_headway] = np.nan
    out = np.full(len(table), np.nan)
    out[order] = headway
    return out


@dataclass
class Scene:
    """The simulated scene a table implies."""

    lanes: int
    """Distinct lane indices seen."""
    vehicles_per_km_lane: float
    """Mean over frames of the vehicles within the stretch the frame covers (its 5th to 95th
    percentile of x), per km and lane."""
    speed_limit: float
    """The 85th percentile of the conservative class's speeds, rounded to 1 m/s: the
    traffic engineers' rule for setting a limit from observed speeds (ours to use it so)."""
    aggressive_share: float
    """Aggressive vehicles among all but the ego."""


def scene(source, fps: float = 15.0, aggressive_prefix: str = "agg") -> Scene:
    """:class:`Scene` of a table (labels and lanes as :func:`class_samples` reads them)."""
    table = _prepared(source, fps, aggressive_prefix)
    others = table[table.cls != EGO]
    lanes = int(others.lane.nunique())
    per_frame = others.groupby(["episode", "frame"]).x
    lo, hi = per_frame.quantile(0.05), per_frame.quantile(0.95)
    within = others.join(lo.rename("lo"), on=["episode", "frame"]).join(
        hi.rename("hi"), on=["episode", "frame"]
    )
    inside = within[(within.x >= within.lo) & (within.x <= within.hi)]
    count = inside.groupby(["episode", "frame"]).size()
    length_km = (hi - lo).reindex(count.index) / 1000.0
    usable = length_km > 0
    density = float((count[usable] / length_km[usable]).mean() / max(lanes, 1))
    calm = others[others.cls == CONSERVATIVE]
    pool = calm if len(calm) else others
    speeds = np.hypot(pool.vx, pool.vy)
    vehicles = others.drop_duplicates(["episode", "vehicle_id"])
    return Scene(
        lanes=lanes,
        vehicles_per_km_lane=density,
        speed_limit=float(np.round(np.quantile(speeds, 0.85))),
        aggressive_share=float((vehicles.cls == AGGRESSIVE).mean()),
    )


def compare(
    observed: dict[str, dict[str, np.ndarray]],
    simulated: dict[str, dict[str, np.ndarray]],
    weights: dict[str, float] | None = None,
) -> pd.DataFrame:
    """Per class and statistic (:data:`STATISTICS`, then any other sample ``observed``
    holds, such as CMetric scores): the observed and simulated means, the Wasserstein-1 distance
    between the two samples and that distance over the observed sample's standard
    deviation (``scaled``: comparable across statistics), and its ``weight`` (default 1).
    A statistic without values on either side gets NaN distances."""
    # Imported here: scipy.stats takes ~0.3 s to import; only this statistic needs it.
    from scipy.stats import wasserstein_distance

    weights = weights or {}
    rows = []
    for cls, stats in observed.items():
        for name in [*STATISTICS, *(k for k in stats if k not in STATISTICS)]:
            a = stats.get(name, np.empty(0))
            b = simulated.get(cls, {}).get(name, np.empty(0))
            distance = wasserstein_distance(a, b) if len(a) and len(b) else np.nan
            spread = float(np.std(a)) if len(a) > 1 else np.nan
            rows.append(
                {
                    "class": cls,
                    "statistic": name,
                    "observed_mean": float(np.mean(a)) if len(a) else np.nan,
                    "simulated_mean": float(np.mean(b)) if len(b) else np.nan,
                    "observed_n": len(a),
                    "simulated_n": len(b),
                    "distance": distance,
                    "scaled": distance / spread if spread and spread > 0 else np.nan,
                    "weight": float(weights.get(name, 1.0)),
                }
            )
    return pd.DataFrame(rows)


def total_distance(table: pd.DataFrame) -> float:
    """The weighted mean of the scaled distances of :func:`compare` (NaN rows left out)."""
    kept = table.dropna(subset=["scaled"])
    return float(np.average(kept.scaled, weights=kept.weight)) if len(kept) else np.nan

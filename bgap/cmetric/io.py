"""Reading and validating trajectory tables for CMetric: the one trajectory reader
(:func:`bgap.common.tables.load_trajectories`, schema there) and what CMetric needs beyond
it (:func:`check_scoreable`). The Parquet written by :mod:`bgap.sim.recorder` is read as is.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

# the one trajectory reader, re-exported where CMetric's users find it
from bgap.common.errors import TrajectoryError  # noqa: F401
from bgap.common.tables import (  # noqa: F401
    ALIASES,
    finite_difference_velocity,
    load_trajectories,
    read_table,
)


def check_scoreable(df: pd.DataFrame) -> None:
    """A loaded table CMetric can score: some scene with two frames and two vehicles
    (centralities of a traffic graph, fitted over time)."""
    frames = df.groupby("episode").frame.nunique()
    if frames.max() < 2:
        raise TrajectoryError(
            f"every scene has a single frame ({frames.size} scene(s)); CMetric fits "
            "centralities over time and needs a few seconds of frames per vehicle"
        )
    vehicles = df.groupby("episode").vehicle_id.nunique()
    if vehicles.max() < 2:
        raise TrajectoryError(
            "every scene has a single vehicle; CMetric scores a vehicle against its "
            "neighbours in the traffic graph and needs at least two vehicles in a scene"
        )


SPEED_RANGE = (0.3, 80.0)
"""[m/s] Road traffic's typical speed (the median over the moving rows): outside it, the
coordinates are not in metres or the clock not in seconds (km: 1,000 x too slow; pixels or
millimetres: far too fast)."""


def check_scale(df: pd.DataFrame) -> None:
    """Refuse a table whose coordinates or clock are not metres and seconds."""
    speed = np.hypot(df["vx"].to_numpy(), df["vy"].to_numpy())
    moving = speed[speed > 1e-6]
    if len(moving) < 10:
        return
    median = float(np.median(moving))
    low, high = SPEED_RANGE
    if not low <= median <= high:
        raise TrajectoryError(
            f"the vehicles' median speed is {median:.3g} m/s, outside road traffic's "
            f"{low:g}-{high:g} m/s: give x and y in metres and time in seconds (feet: x 0.3048)"
        )


def check_duration(df: pd.DataFrame, window: float) -> None:
    """Refuse a table none of whose scenes lasts one CMetric window: no window would be
    fitted, and every vehicle would go unscored."""
    spans = df.groupby("episode").time.agg(lambda t: float(t.max() - t.min()))
    if float(spans.max()) < window:
        raise TrajectoryError(
            f"the longest scene lasts {spans.max():.3g} s, shorter than CMetric's window "
            f"({window:g} s): give a longer recording or a shorter cmetric.window"
        )

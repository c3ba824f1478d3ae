"""Reading and validating trajectory tables for CMetric: the one trajectory reader
(:func:`bgap.common.tables.load_trajectories`, schema there) and what CMetric needs beyond
it (:func:`check_scoreable`). The Parquet written by :mod:`bgap.sim.recorder` is read as is.
"""

from __future__ import annotations

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

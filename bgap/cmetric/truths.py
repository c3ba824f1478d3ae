"""Hand-built scenes whose driving styles are known: the truths any CMetric setting must keep.

The tests hold the shipped presets to them, and the parameter search
(:mod:`bgap.cmetric.search`) refuses settings that break them: simulated traffic alone lets
a search drop a style that does not separate its classes (weaving, in bgap's and SUMO's
traffic) although a weaving car is aggressive by the paper's definition.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from bgap.cmetric.params import CMetricConfig
from bgap.cmetric.score import score_trajectories

WEAVER, OVERSPEEDER, CRUISER = 1, 2, 3
"""Vehicle ids of the three cars of :func:`known_truth_scene` that carry a truth."""


def known_truth_scene() -> pd.DataFrame:
    """15 Hz, 30 s: a platoon of 12 cars at 20 m/s, a weaver inside it zig-zagging across
    the lanes, an overspeeder at 35 m/s passing it in a free lane, a cruiser in one lane."""
    fps, seconds = 15, 30
    rows = []
    for f in range(fps * seconds):
        t = f / fps
        for k in range(12):  # platoon in lanes 0, 1, 3, 15 m apart
            rows.append((f, 100 + k, 20 * t + 15.0 * (k // 3), 4.0 * [0, 1, 3][k % 3], 20.0, 0))
        weave_y = 6.0 + 6.0 * np.sin(2 * np.pi * t / 5.0)  # lanes 0..3 every 5 s
        weave_vy = 6.0 * 2 * np.pi / 5.0 * np.cos(2 * np.pi * t / 5.0)
        rows.append((f, WEAVER, 20 * t + 25.0, weave_y, 20.0, weave_vy))
        rows.append((f, OVERSPEEDER, 35 * t - 150.0, 8.0, 35.0, 0.0))
        rows.append((f, CRUISER, 20 * t + 40.0, 4.0, 20.0, 0.0))
    df = pd.DataFrame(rows, columns=["frame", "vehicle_id", "x", "y", "vx", "vy"])
    df["time"] = df.frame / fps
    return df


def broken_truths(cfg: CMetricConfig) -> list[str]:
    """The truths of :func:`known_truth_scene` that ``cfg`` breaks (empty: all hold): each
    style ranks its own car first, and the weaver and the overspeeder are both scored more
    aggressive than the cruiser."""
    scores = score_trajectories(known_truth_scene(), cfg).vehicles.set_index("vehicle_id")
    cars = scores.loc[[WEAVER, OVERSPEEDER, CRUISER]]
    checks = {
        "weaving ranks the weaver first": cars.weaving_sle.idxmax() == WEAVER,
        "overspeeding ranks the overspeeder first": cars.overspeeding_sle.idxmax() == OVERSPEEDER,
        "overtaking ranks the cruiser last": cars.overtaking_sle.idxmin() == CRUISER,
        "the cruiser is the least aggressive": cars.aggressiveness.idxmin() == CRUISER,
    }
    return [name for name, ok in checks.items() if not ok]

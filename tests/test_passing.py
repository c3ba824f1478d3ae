"""Overtakes counted per policy step (bgap.sim.passing) on hand-built positions: a pass,
being passed, a vehicle that stays ahead, and one that leaves the road."""

from __future__ import annotations

import numpy as np

from bgap.sim.core import PARK_X
from bgap.sim.passing import overtakes


def test_only_the_vehicles_the_ego_passes_count():
    """Env 0: the ego (0 -> 30 m) passes a car at 10 -> 25 m and one at 20 -> 28 m, is
    passed by one at -5 -> 40 m, and stays behind one at 50 -> 65 m: 2. Env 1: a car ahead
    leaves the road (parked far behind) and one ahead is passed: 1. Env 2: a car level with
    the ego (not ahead) is left behind: 0."""
    before = np.array([
        [0.0, 10.0, 20.0, -5.0, 50.0],
        [0.0, 30.0, 5.0, PARK_X, PARK_X - 50],
        [0.0, 0.0, -20.0, -30.0, -40.0],
    ])  # fmt: skip
    after = np.array([
        [30.0, 25.0, 28.0, 40.0, 65.0],
        [30.0, PARK_X, 25.0, PARK_X, PARK_X - 50],
        [30.0, 20.0, 0.0, -10.0, -20.0],
    ])  # fmt: skip
    assert overtakes(before, after).tolist() == [2, 1, 0]
    # time reversed: the car that passed the ego is the one passed, the passed ones pass it
    assert overtakes(after, before).tolist() == [1, 0, 0]

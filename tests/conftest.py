"""Shared fixtures: small, seeded environments and recordings."""

from __future__ import annotations

import numpy as np
import pytest

from bgap.config import SimulateConfig, compose, validate


def make_cfg(*overrides: str) -> SimulateConfig:
    """A validated config composed from conf/ exactly as the command line would."""
    return validate(compose("simulate", list(overrides)))


@pytest.fixture(scope="session")
def sparse_mixed_recording():
    """20 seeded 60 s sparse episodes, paper behaviours, half aggressive, idle ego."""
    from bgap.simulate import simulate

    cfg = make_cfg("env=sparse", "mix=0.5", "behavior=paper", "seed=100")
    return simulate(cfg, episodes=20, progress=False)


def lane_changes(table) -> np.ndarray:
    """Per-vehicle lane changes, counted from the recorded lane column."""
    ordered = table.sort_values(["episode", "vehicle_id", "frame"])
    same = (ordered.episode.diff() == 0) & (ordered.vehicle_id.diff() == 0)
    changed = same & (ordered.lane.diff() != 0)
    return changed.groupby([ordered.episode, ordered.vehicle_id]).sum()

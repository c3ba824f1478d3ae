"""Trajectory tables: every simulation frame of every vehicle, one row per vehicle and frame.

Both simulators report their frames in one array layout (:mod:`bgap.sim.simulators`, recorded
by :func:`bgap.sim.rollout.rollout` with ``record=True``); this module turns them into the table
CMetric reads. The schema:

==============  ========  ====================================================
column          type      meaning
==============  ========  ====================================================
episode         int32     episode index within the recording
frame           int32     simulation frame within the episode (0 = reset)
time            float64   frame / simulation_frequency [s]
vehicle_id      int32     0 is the ego; 1..n background vehicles (stable)
label           string    ``ego``, ``aggressive`` or ``conservative``
is_ego          bool
x, y            float64   position of the vehicle centre [m]
vx, vy          float64   velocity [m/s]
speed           float64   |v| [m/s]
lane            int16     lane index, 0 = leftmost
crashed         bool
==============  ========  ====================================================
"""

from __future__ import annotations

import numpy as np
import pandas as pd

RECORD_FIELDS = ("x", "y", "vx", "vy", "speed", "lane", "crashed")
"""The fields of a recorded frame, in the simulators' array layout (last axis)."""


def initial_states(f: np.ndarray, g: np.ndarray, num_envs: int, n: int) -> np.ndarray:
    """The current frame of every env of the vector backend (its float and int states ``f``,
    ``g`` of ``n`` background vehicles) in the recording layout: (B, 1, n + 1, 7)."""
    from bgap.sim import core  # the kernels only where frames are recorded: tables load without

    out = np.zeros((num_envs, 1, n + 1, len(RECORD_FIELDS)))
    for b in range(num_envs):
        core.record(f, g, b, n + 1, out, 0)
    return out


COLUMNS = [
    "episode",
    "frame",
    "time",
    "vehicle_id",
    "label",
    "is_ego",
    "x",
    "y",
    "vx",
    "vy",
    "speed",
    "lane",
    "crashed",
]
REQUIRED = ["episode", "frame", "time", "vehicle_id", "label", "x", "y", "vx", "vy"]


def table_from_states(
    states: np.ndarray, labels: list[str], episode: int, dt: float
) -> pd.DataFrame:
    """The schema's table from one episode's frames ``states`` (frames, vehicles, 7: x, y,
    vx, vy, speed, lane, crashed; the vectorised backend's layout), vehicle 0 the ego."""
    t, n = states.shape[:2]
    frame = np.repeat(np.arange(t, dtype=np.int32), n)
    vid = np.tile(np.arange(n, dtype=np.int32), t)
    labels_ = np.tile(np.asarray(labels, dtype=object), t)
    return _table(
        np.full(t * n, episode), frame, frame * dt, vid, labels_, states.reshape(t * n, -1)
    )


def _table(episode, frame, time, vehicle_id, labels, states) -> pd.DataFrame:
    """The schema from one value per row; ``states`` holds x, y, vx, vy, speed, lane, crashed."""
    return pd.DataFrame(
        {
            "episode": episode.astype(np.int32),
            "frame": frame.astype(np.int32),
            "time": time,
            "vehicle_id": vehicle_id.astype(np.int32),
            "label": labels.astype(str),
            "is_ego": vehicle_id == 0,
            "x": states[:, 0],
            "y": states[:, 1],
            "vx": states[:, 2],
            "vy": states[:, 3],
            "speed": states[:, 4],
            "lane": states[:, 5].astype(np.int16),
            "crashed": states[:, 6].astype(bool),
        }
    )

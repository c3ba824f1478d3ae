"""Trajectory recording: every simulation frame of every vehicle, as a tidy table.

The schema (one row per vehicle and frame) is what CMetric reads and what both simulator
backends write:

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

from pathlib import Path

import numpy as np
import pandas as pd

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


class TrajectoryRecorder:
    """Listens to a :class:`~bgap.envs.highway.BehaviorHighwayEnv` and keeps every frame.

    Attach before ``reset`` so frame 0 is captured::

        rec = TrajectoryRecorder(env)
        env.reset(seed=0); ...
        rec.to_frame().to_parquet("trajectories.parquet")
    """

    def __init__(self, env) -> None:
        self.env = env.unwrapped
        self.env.frame_listeners.append(self)
        self._rows: list[np.ndarray] = []
        self._labels: list[list[str]] = []
        self._last_episode = None
        self._episodes_seen = 0

    def __call__(self, env) -> None:
        # Episodes are numbered per recording, not by the env's lifetime counter.
        if env.episode != self._last_episode:
            self._last_episode = env.episode
            self._episodes_seen += 1
        episode = self._episodes_seen - 1
        vehicles = env.road.vehicles
        dt = 1.0 / env.config["simulation_frequency"]
        block = np.empty((len(vehicles), 11))
        for i, v in enumerate(vehicles):
            vel = v.velocity
            block[i] = (
                episode,
                env.frame,
                env.frame * dt,
                v.bgap_id,
                v.position[0],
                v.position[1],
                vel[0],
                vel[1],
                v.speed,
                v.lane_index[2],
                v.crashed,
            )
        self._rows.append(block)
        self._labels.append([v.bgap_label for v in vehicles])

    def detach(self) -> None:
        if self in self.env.frame_listeners:
            self.env.frame_listeners.remove(self)

    def to_frame(self) -> pd.DataFrame:
        """The recorded trajectories in the documented schema."""
        if not self._rows:
            return pd.DataFrame({c: [] for c in COLUMNS})
        data = np.concatenate(self._rows)
        labels = np.concatenate([np.asarray(lab, dtype=object) for lab in self._labels])
        return _table(data[:, 0], data[:, 1], data[:, 2], data[:, 3], labels, data[:, 4:])

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self.to_frame().to_parquet(path, index=False)
        return path


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

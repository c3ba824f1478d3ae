"""highD (Krajewski et al., 2018) recordings as bgap's trajectory table.

The format, as the dataset's documentation ("highD format", ``data/`` of each release)
defines it; one recording is three CSV files with a common prefix ``XX_``:

- ``XX_tracks.csv``, one row per vehicle and frame: ``frame`` (from 1; ours from 0), ``id``, ``x``,
  ``y`` (the **upper-left corner** of the bounding box, image coordinates in metres: y
  points down), ``width`` (length along the road), ``height`` (width across it),
  ``xVelocity``, ``yVelocity`` [m/s], ``laneId`` (lane areas numbered across both
  carriageways), and more (accelerations, headways, neighbour ids) that bgap does not need;
- ``XX_tracksMeta.csv``, one row per vehicle: ``id``, ``class`` (``Car``/``Truck``),
  ``drivingDirection`` (1: towards smaller x, the upper carriageway; 2: towards larger x);
- ``XX_recordingMeta.csv``: ``id``, ``frameRate`` (25), ``speedLimit`` (-1 where none).

Conversion (ours): positions become box centres; each carriageway is its own scene
(``episode = 2 x recording index + direction - 1``: graphs never join opposite
directions), turned so that traffic moves towards +x with its left at smaller y, bgap's
(highway-env's) frame: direction 2 keeps image coordinates, direction 1 is rotated by 180
degrees. Lanes are numbered 0 from the left within each carriageway. ``label`` is the
vehicle class in lower case (``car``, ``truck``): highD carries no driving-style labels.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from bgap.cmetric.io import TrajectoryError
from bgap.common.tables import read_csv
from bgap.sim.recorder import COLUMNS

TRACK_COLUMNS = ("frame", "id", "x", "y", "width", "height", "xVelocity", "yVelocity", "laneId")
META_COLUMNS = ("id", "class", "drivingDirection")


def recordings(path: str | Path) -> list[Path]:
    """The ``XX_tracks.csv`` files that ``path`` names: itself, or every one in a folder."""
    path = Path(path)
    if path.is_dir():
        found = sorted(path.glob("*_tracks.csv"))
        if not found:
            raise TrajectoryError(f"{path}: no highD recording (*_tracks.csv) in this folder")
        return found
    if not path.exists():
        raise TrajectoryError(f"{path}: no such file")
    if not path.name.endswith("_tracks.csv"):
        raise TrajectoryError(f"{path}: not a highD tracks file; give XX_tracks.csv or its folder")
    return [path]


def _read(path: Path, columns: tuple[str, ...]) -> pd.DataFrame:
    if not path.exists():
        raise TrajectoryError(f"{path}: no such file (a highD recording has three files)")
    table = read_csv(path)
    missing = [c for c in columns if c not in table]
    if missing:
        raise TrajectoryError(f"{path}: missing highD column(s) {missing}")
    return table


def read_recording(tracks_path: Path, index: int) -> pd.DataFrame:
    """One recording (its three files) as two scenes, one per carriageway."""

    prefix = tracks_path.name[: -len("tracks.csv")]
    tracks = _read(tracks_path, TRACK_COLUMNS)
    meta = _read(tracks_path.with_name(f"{prefix}tracksMeta.csv"), META_COLUMNS)
    recording = _read(tracks_path.with_name(f"{prefix}recordingMeta.csv"), ("frameRate",))
    fps = float(recording.frameRate.iloc[0])
    table = tracks.merge(meta[list(META_COLUMNS)], on="id", how="left", validate="many_to_one")
    if table.drivingDirection.isna().any():
        ids = sorted(table.id[table.drivingDirection.isna()].unique())[:5]
        raise TrajectoryError(f"{tracks_path}: vehicles {ids} are not in {prefix}tracksMeta.csv")
    first = int(table.frame.min())  # 1 in highD's files
    x = table.x + table.width / 2
    y = table.y + table.height / 2
    sign = np.where(table.drivingDirection == 1, -1.0, 1.0)  # direction 1: turned by 180 deg
    out = pd.DataFrame(
        {
            "episode": (2 * index + table.drivingDirection - 1).astype(np.int32),
            "frame": (table.frame - first).astype(np.int32),
            "time": (table.frame - first) / fps,
            "vehicle_id": table.id.astype(np.int32),
            "label": table["class"].astype(str).str.lower(),  # a numeric class code too
            "is_ego": False,
            "x": sign * x,
            "y": sign * y,
            "vx": sign * table.xVelocity,
            "vy": sign * table.yVelocity,
        }
    )
    out["speed"] = np.hypot(out.vx, out.vy)
    # lanes from the left of each carriageway: its lane areas ordered by (turned) y
    lane_y = out.y.groupby([out.episode, table.laneId]).mean().reset_index(name="lane_y")
    lane_y["lane"] = lane_y.groupby("episode").lane_y.rank(method="dense").astype(np.int16) - 1
    lanes = lane_y.set_index(["episode", "laneId"]).lane
    out["lane"] = lanes.reindex(pd.MultiIndex.from_arrays([out.episode, table.laneId])).values
    out["crashed"] = False
    return out[COLUMNS]


def read(path: str | Path) -> pd.DataFrame:
    """Every recording ``path`` names (a tracks file or a folder of them), in order."""
    parts = [read_recording(p, k) for k, p in enumerate(recordings(path))]
    return pd.concat(parts, ignore_index=True).sort_values(["episode", "vehicle_id", "frame"])

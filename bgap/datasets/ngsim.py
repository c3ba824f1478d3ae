"""NGSIM vehicle trajectories (US-101, I-80; FHWA, 2005-2006) as bgap's trajectory table.

The format, as the NGSIM "Vehicle Trajectories and Supporting Data" documentation defines
it: one CSV row per vehicle and frame (10 frames per second), lengths in **feet**.
bgap reads ``Vehicle_ID``, ``Frame_ID``, ``Local_X`` (lateral position of the front centre
from the left edge of the section), ``Local_Y`` (longitudinal position of the front centre,
in the direction of travel), ``v_Class`` (1 motorcycle, 2 automobile, 3 truck) and
``Lane_ID`` (1 = the leftmost lane; on US-101 6 is the auxiliary lane, 7 and 8 the ramps),
and ``Location`` where the file has it (the combined file of data.transportation.gov:
``us-101``, ``i-80``, ...). The text files of the original release (no header, the same
first 18 columns in this order) are read too.

Conversion (ours): metres; ``x`` = Local_Y, ``y`` = Local_X (the direction of travel is
+x and the left is smaller y, bgap's frame); ``vx``, ``vy`` by central differences of the
positions per vehicle (``v_Vel`` is known to be noisy and has no lateral part); ``lane`` =
Lane_ID - 1; one scene per location (``episode``); rows repeated in the files (same vehicle
and frame) are kept once. ``label`` is the vehicle class (``motorcycle``, ``car``,
``truck``): NGSIM carries no driving-style labels.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from bgap.cmetric.io import TrajectoryError, finite_difference_velocity
from bgap.common.tables import read_csv
from bgap.sim.recorder import COLUMNS

FEET = 0.3048
FPS = 10.0
NAMES = (
    "Vehicle_ID",
    "Frame_ID",
    "Total_Frames",
    "Global_Time",
    "Local_X",
    "Local_Y",
    "Global_X",
    "Global_Y",
    "v_Length",
    "v_Width",
    "v_Class",
    "v_Vel",
    "v_Acc",
    "Lane_ID",
    "Preceding",
    "Following",
    "Space_Headway",
    "Time_Headway",
)
"""The original release's columns, in order (its ``.txt`` files have no header)."""
CLASSES = {1: "motorcycle", 2: "car", 3: "truck"}


def read(path: str | Path) -> pd.DataFrame:
    """An NGSIM trajectory file (``.csv`` with a header, or the original ``.txt``)."""

    path = Path(path)
    if not path.is_file():
        raise TrajectoryError(f"{path}: no such file; give an NGSIM trajectory .csv or .txt")
    if path.suffix.lower() == ".txt":
        table = read_csv(path, sep=r"\s+", header=None)
        table = table.iloc[:, : len(NAMES)].set_axis(NAMES, axis=1)
    else:
        table = read_csv(path, low_memory=False)
    needed = ["Vehicle_ID", "Frame_ID", "Local_X", "Local_Y", "v_Class", "Lane_ID"]
    missing = [c for c in needed if c not in table]
    if missing:
        raise TrajectoryError(f"{path}: missing NGSIM column(s) {missing}")
    if "Location" not in table:
        table["Location"] = path.stem
    table = table.drop_duplicates(["Location", "Vehicle_ID", "Frame_ID"])
    locations = {name: k for k, name in enumerate(sorted(table.Location.astype(str).unique()))}
    table = table.sort_values(["Location", "Vehicle_ID", "Frame_ID"], ignore_index=True)
    first = table.groupby("Location").Frame_ID.transform("min")
    out = pd.DataFrame(
        {
            "episode": table.Location.astype(str).map(locations).astype(np.int32),
            "frame": (table.Frame_ID - first).astype(np.int32),
            "time": (table.Frame_ID - first) / FPS,
            "vehicle_id": table.Vehicle_ID.astype(np.int32),
            "label": table.v_Class.map(CLASSES).fillna("other"),
            "is_ego": False,
            "x": table.Local_Y * FEET,
            "y": table.Local_X * FEET,
        }
    )
    out["vx"], out["vy"] = finite_difference_velocity(out)  # rows sorted per vehicle in time
    out["speed"] = np.hypot(out.vx, out.vy)
    out["lane"] = (table.Lane_ID - 1).astype(np.int16)
    out["crashed"] = False
    return out[COLUMNS]

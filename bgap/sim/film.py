"""Pictures of recorded traffic: one image per simulation frame of a trajectory table.

Both simulators record the same table (:mod:`bgap.sim.recorder`), replayed traffic
included, so one drawing serves every backend and traffic source; highway-env's own renderer
(pygame) draws only its own backend. The view follows the ego along the road, seen from
above: lanes in grey with white markings, vehicles as boxes along the road (ego green,
aggressive red, conservative blue, any other traffic grey; a crashed vehicle is drawn in
yellow). Headings are not drawn (a lane change turns a car by a few degrees at most).

Why written here: the picture is a handful of filled rectangles; a plotting library would
take longer per frame than the simulation itself.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from bgap.traffic.road import LANE_WIDTH, VEHICLE_LENGTH, VEHICLE_WIDTH

WIDTH = 960
"""[px] Picture width; heights and widths are multiples of 16 (H.264's macroblock)."""
SCALE = 6.0
"""[px/m] 160 m of road across the picture."""
BEHIND = 0.3
"""Share of the picture behind the ego."""
MARGIN = 24
"""[px] Verge above and below the road."""
COLOURS = {
    "ego": (40, 180, 60),
    "aggressive": (210, 50, 50),
    "conservative": (50, 90, 210),
}
OTHER = (150, 150, 150)
CRASHED = (240, 200, 0)
ROAD, VERGE, MARKING = (90, 90, 90), (70, 120, 60), (235, 235, 235)


def height(lanes: int) -> int:
    """[px] Picture height for a road of ``lanes`` lanes (a multiple of 16)."""
    raw = lanes * LANE_WIDTH * SCALE + 2 * MARGIN
    return int(np.ceil(raw / 16) * 16)


def _background(lanes: int, x0: float) -> np.ndarray:
    h = height(lanes)
    image = np.empty((h, WIDTH, 3), dtype=np.uint8)
    image[:] = VERGE
    top = (h - int(round(lanes * LANE_WIDTH * SCALE))) // 2
    bottom = top + int(round(lanes * LANE_WIDTH * SCALE))
    image[top:bottom] = ROAD
    image[top : top + 2] = MARKING
    image[bottom - 2 : bottom] = MARKING
    # dashed lane markings, 3 m dashes every 9 m, fixed to the road (they move past the ego)
    xs = np.arange(WIDTH)
    metres = x0 + xs / SCALE
    dashes = (metres % 9.0) < 3.0
    for k in range(1, lanes):
        y = top + int(round(k * LANE_WIDTH * SCALE))
        image[y - 1 : y + 1, dashes] = MARKING
    return image


def frames(table: pd.DataFrame, lanes: int) -> list[np.ndarray]:
    """One RGB picture per frame of one episode's trajectory ``table`` (the recorder's
    schema; ``y`` is 0 at the centre of the leftmost lane, growing to the right)."""
    table = table.sort_values(["frame", "vehicle_id"], kind="stable")
    h = height(lanes)
    top = (h - int(round(lanes * LANE_WIDTH * SCALE))) // 2
    half_l, half_w = VEHICLE_LENGTH * SCALE / 2, VEHICLE_WIDTH * SCALE / 2
    is_ego = table.is_ego.to_numpy()
    x, y = table.x.to_numpy(), table.y.to_numpy()
    crashed = table.crashed.to_numpy()
    colours = np.array([COLOURS.get(label, OTHER) for label in table.label], dtype=np.uint8)
    colours[crashed] = CRASHED
    starts = np.flatnonzero(np.r_[True, np.diff(table.frame.to_numpy()) != 0])
    images = []
    for a, b in zip(starts, np.r_[starts[1:], len(table)], strict=True):
        ego = np.flatnonzero(is_ego[a:b])
        x_ego = x[a + ego[0]] if len(ego) else x[a:b].mean()
        x0 = x_ego - BEHIND * WIDTH / SCALE
        image = _background(lanes, x0)
        px = np.rint((x[a:b] - x0) * SCALE)
        py = np.rint(top + (y[a:b] + LANE_WIDTH / 2) * SCALE)
        x1 = np.clip(px - half_l, 0, WIDTH).astype(int)
        x2 = np.clip(px + half_l, 0, WIDTH).astype(int)
        y1 = np.clip(py - half_w, 0, h).astype(int)
        y2 = np.clip(py + half_w, 0, h).astype(int)
        for i in np.argsort(is_ego[a:b], kind="stable"):  # the ego drawn last, on top
            image[y1[i] : y2[i], x1[i] : x2[i]] = colours[a + i]
        images.append(image)
    return images

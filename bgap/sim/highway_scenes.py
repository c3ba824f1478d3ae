"""A highway-env scene loaded into the vectorised backend: :func:`scene_from_highway` puts a
``BehaviorHighwayEnv``'s road into :class:`bgap.sim.vector.VectorHighway`'s kernel layout, so
that the two backends can be compared from identical starts."""

from __future__ import annotations

from typing import Any

import numpy as np
from highway_env.vehicle.behavior import IDMVehicle

from bgap.sim import core
from bgap.sim.core import (
    ACC,
    AGGRESSIVE,
    CONSERVATIVE,
    CRASHED,
    EGO,
    HEADING,
    LABEL,
    LANE,
    N_FLOAT,
    N_INT,
    N_PARAM,
    SPEED,
    SPEED_INDEX,
    STEER,
    TARGET_LANE,
    TARGET_SPEED,
    TIMER,
    X,
    Y,
)
from bgap.sim.highway_params import IDM_DEFAULTS, driver_params
from bgap.sim.vector import Scene
from bgap.traffic.behaviors import BehaviorVehicle

_CLASS_CODES = {"conservative": CONSERVATIVE, "aggressive": AGGRESSIVE}


def scene_from_highway(env: Any) -> Scene:
    """The current scene of a highway-env ``BehaviorHighwayEnv`` in the kernel layout."""
    env = env.unwrapped
    vehicles = env.road.vehicles
    ego = env.vehicle
    if vehicles[0] is not ego:
        raise ValueError("the ego must be the first vehicle of the road")
    n = len(vehicles)
    f, g, p = np.zeros((n, N_FLOAT)), np.zeros((n, N_INT), dtype=np.int64), np.zeros((n, N_PARAM))
    p[:] = IDM_DEFAULTS
    for i, v in enumerate(vehicles):
        f[i, X], f[i, Y] = v.position
        f[i, HEADING], f[i, SPEED] = v.heading, v.speed
        f[i, TARGET_SPEED] = v.target_speed
        f[i, STEER], f[i, ACC] = v.action["steering"], v.action["acceleration"]
        if v.impact is not None:
            f[i, core.IMPACT_X], f[i, core.IMPACT_Y] = v.impact
            g[i, core.HAS_IMPACT] = 1
        g[i, LANE], g[i, TARGET_LANE] = v.lane_index[2], v.target_lane_index[2]
        g[i, CRASHED] = int(v.crashed)
        p[i, core.P_VMAX] = v.MAX_SPEED
        if v is ego:
            g[i, LABEL] = EGO
            g[i, SPEED_INDEX] = getattr(v, "speed_index", 0)
            continue
        if not isinstance(v, IDMVehicle):
            raise ValueError(f"vehicle {i} is a {type(v).__name__}, not an IDM driver")
        g[i, LABEL] = _CLASS_CODES[getattr(v, "bgap_label", "conservative")]
        f[i, TIMER] = v.timer
        p[i] = driver_params(v)
        p[i, core.P_OWN] = float(isinstance(v, BehaviorVehicle))
    return Scene(f, g, p, steps=int(round(env.time * env.config["policy_frequency"])))

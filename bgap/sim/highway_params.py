"""highway-env's side of the vectorised backend: the highway-env options it supports
(:func:`check_supported`), the IDM/MOBIL attributes of highway-env's vehicles as rows of
the kernels' parameter columns (:mod:`bgap.sim.core`), and bgap's driver classes as the
class table the compiled scene draw reads (:func:`class_table`)."""

from __future__ import annotations

from typing import Any

import numpy as np
from highway_env.vehicle.behavior import IDMVehicle

from bgap.sim import core
from bgap.sim.core import AGGRESSIVE, CONSERVATIVE, N_PARAM
from bgap.traffic.behaviors import DRIVER_ATTRIBUTES, BehaviorVehicle, is_stock

# Parameter column of each IDMVehicle attribute, in highway-env's units except P_B, which
# holds the braking magnitude -COMFORT_ACC_MIN.
PARAM_COLUMNS = {
    "TIME_WANTED": core.P_T,
    "DISTANCE_WANTED": core.P_D0,
    "COMFORT_ACC_MAX": core.P_A,
    "COMFORT_ACC_MIN": core.P_B,
    "DELTA": core.P_DELTA,
    "POLITENESS": core.P_POLITENESS,
    "LANE_CHANGE_MIN_ACC_GAIN": core.P_GAIN,
    "LANE_CHANGE_MAX_BRAKING_IMPOSED": core.P_BSAFE,
    "ACC_MAX": core.P_AMAX,
    "MAX_SPEED": core.P_VMAX,
}


def column_value(attr: str, value: float) -> float:
    """A highway-env attribute's value as its parameter column holds it."""
    return -value if attr == "COMFORT_ACC_MIN" else value


def driver_params(vehicle: Any) -> np.ndarray:
    """The IDM/MOBIL attributes of a highway-env vehicle (or vehicle class) as a parameter
    row; P_OWN is left 0."""
    row = np.zeros(N_PARAM)
    for attr, col in PARAM_COLUMNS.items():
        row[col] = column_value(attr, float(getattr(vehicle, attr)))
    return row


# highway-env's IDMVehicle defaults (DISTANCE_WANTED = 5 m + LENGTH, DELTA 4, MAX_SPEED 40).
IDM_DEFAULTS = driver_params(IDMVehicle)


def check_supported(config: dict[str, Any]) -> None:
    """Fail clearly on highway-env options the vectorised model does not implement."""
    obs = config["observation"]
    expected = {
        "type": "Kinematics",
        "absolute": False,
        "normalize": True,
        "clip": True,
        "see_behind": True,
        "order": "sorted",
    }
    for key, value in expected.items():
        if obs.get(key, value) != value:
            raise ValueError(
                f"backend=vector supports observation.{key}={value!r} only (got {obs[key]!r}); "
                "use backend=highway for other observations"
            )
    if list(obs.get("features", [])) != ["presence", "x", "y", "vx", "vy"]:
        raise ValueError("backend=vector observes features presence, x, y, vx, vy only")
    if config["action"]["type"] != "DiscreteMetaAction":
        raise ValueError("backend=vector supports the DiscreteMetaAction ego only")
    if config.get("controlled_vehicles", 1) != 1:
        raise ValueError("backend=vector supports one controlled vehicle")
    sim, pol = int(config["simulation_frequency"]), int(config["policy_frequency"])
    if sim % pol:
        raise ValueError("simulation_frequency must be a multiple of policy_frequency")


def class_table(behavior: dict[str, Any]) -> np.ndarray:
    """:func:`bgap.sim.core.spawn`'s ``classes`` for the environment config's ``behavior``:
    the ego's row (highway-env's IDM defaults), then each class's code, v0, v0 spread and
    parameter row."""
    table = np.zeros((3, 3 + N_PARAM))
    table[0, 3:] = IDM_DEFAULTS
    for c, (code, name) in enumerate(((CONSERVATIVE, "conservative"), (AGGRESSIVE, "aggressive"))):
        params = behavior[name]
        row = IDM_DEFAULTS.copy()
        row[core.P_DELTA] = np.nan  # drawn per vehicle unless the class sets it
        for key, (attr, convert) in DRIVER_ATTRIBUTES.items():
            if params.get(key) is not None:
                row[PARAM_COLUMNS[attr]] = column_value(attr, float(convert(params[key])))
        if not is_stock(params):
            row[core.P_OWN] = 1.0
            row[core.P_VMAX] = BehaviorVehicle.MAX_SPEED
        v0 = params.get("v0")
        spread = float(params.get("v0_spread") or 0.0)
        table[c + 1, :3] = (code, np.nan if v0 is None else float(v0), spread)
        table[c + 1, 3:] = row
    return table

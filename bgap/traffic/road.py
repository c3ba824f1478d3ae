"""The road, the vehicles and the ego's meta-actions as highway-env (the reference simulator)
defines them: read from its classes, not restated, so the vectorised backend's kernels and
the environment cannot disagree on them."""

from __future__ import annotations

import inspect

from highway_env.envs.common.action import DiscreteMetaAction
from highway_env.road.lane import StraightLane
from highway_env.road.road import RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle
from highway_env.vehicle.kinematics import Vehicle

# ---------------------------------------------------------------- ego actions
ACTIONS = {name: index for index, name in DiscreteMetaAction.ACTIONS_ALL.items()}
LANE_LEFT, IDLE, LANE_RIGHT = ACTIONS["LANE_LEFT"], ACTIONS["IDLE"], ACTIONS["LANE_RIGHT"]
FASTER, SLOWER = ACTIONS["FASTER"], ACTIONS["SLOWER"]
N_ACTIONS = len(ACTIONS)

# ---------------------------------------------------------------- road and vehicles
LANE_WIDTH = float(StraightLane.DEFAULT_WIDTH)
VEHICLE_LENGTH, VEHICLE_WIDTH = float(Vehicle.LENGTH), float(Vehicle.WIDTH)
EGO_MAX_SPEED, MIN_SPEED = float(Vehicle.MAX_SPEED), float(Vehicle.MIN_SPEED)
_ROAD = inspect.signature(RoadNetwork.straight_road_network).parameters
SPEED_LIMIT = float(_ROAD["speed_limit"].default)
"""Speed limit of highway-env's straight road [m/s] (the lane speed limit of highway-v0)."""
ROAD_LENGTH = float(_ROAD["length"].default)
TAU_ACC, TAU_HEADING = ControlledVehicle.TAU_ACC, ControlledVehicle.TAU_HEADING
TAU_LATERAL = ControlledVehicle.TAU_LATERAL
MAX_STEERING = ControlledVehicle.MAX_STEERING_ANGLE
LANE_CHANGE_DELAY = IDMVehicle.LANE_CHANGE_DELAY

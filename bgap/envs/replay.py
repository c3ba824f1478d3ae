"""Replayed traffic on highway-env's road: the reference replay.

A :class:`ReplayVehicle` is a recorded vehicle on highway-env's road: frame by frame it takes
its recorded state (:class:`bgap.traffic.replay.RecordedScene`) until, in ``reactive`` mode, it
switches to IDM behind the ego for good. :class:`ReplayScene` puts a window's vehicles on the
road, adds those that enter the section and removes those that leave, after every frame.
Collisions between two vehicles still following their logs are the recording's business and
are not checked.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from highway_env.road.road import Road
from highway_env.vehicle.kinematics import Vehicle

from bgap.common.vocab import CLASSES, COLORS, CONSERVATIVE
from bgap.traffic.behaviors import BehaviorVehicle, set_driver_params
from bgap.traffic.replay import RecordedScene, Window


class ReplayVehicle(BehaviorVehicle):
    """Recorded vehicle ``v`` of ``scene``, placed at frame ``frame`` of the recording."""

    def __init__(
        self, road: Road, scene: RecordedScene, v: int, frame: int, reactive: bool
    ) -> None:
        x, y, vx, vy = scene.state[frame, v]
        super().__init__(road, [x, y], math.atan2(vy, vx), math.hypot(vx, vy))
        self.scene, self.v, self.frame, self.reactive = scene, v, frame, reactive
        self.switched = False  # on IDM from now on (reactive mode)
        self.gone = False  # left the recorded section
        self.enable_lane_change = False  # MOBIL is never used in a replay
        self.own_v0 = False  # its class sets a desired speed (ReplayScene)

    @property
    def following_log(self) -> bool:
        return not self.switched

    def act(self, action: Any = None) -> None:
        if not self.switched and self.reactive and self._behind_reactor():
            self.switched = True
            self.target_lane_index = self.lane_index
            if not self.own_v0:  # highway-env's desired speed: the speed it has
                self.target_speed = self.speed
        if self.switched:
            super().act()

    def _behind_reactor(self) -> bool:
        """Its leader in its lane is the ego or a switched vehicle, closer than its IDM
        desired gap."""
        leader, _ = self.road.neighbour_vehicles(self, self.lane_index)
        if leader is None or not (not isinstance(leader, ReplayVehicle) or leader.switched):
            return False
        return self.lane_distance_to(leader) < self.desired_gap(self, leader)

    def step(self, dt: float) -> None:
        if self.switched:
            super().step(dt)
            return
        self.frame += 1
        if self.frame >= len(self.scene.state) or not self.scene.present[self.frame, self.v]:
            self.gone = True
            return
        x, y, vx, vy = self.scene.state[self.frame, self.v]
        self.position = np.array([x, y], dtype=float)
        self.heading, self.speed = math.atan2(vy, vx), math.hypot(vx, vy)
        self.impact = None  # the log does not yield
        self.on_state_update()

    def handle_collisions(self, other: Any, dt: float = 0) -> None:
        if self.following_log and isinstance(other, ReplayVehicle) and other.following_log:
            return  # two recorded vehicles: whatever the recording shows
        super().handle_collisions(other, dt)


class ReplayScene:
    """The window's recorded vehicles on ``road`` (the ego excluded), kept in step with the
    recording frame by frame (:meth:`after_frame`)."""

    def __init__(
        self,
        road: Road,
        window: Window,
        behavior: dict[str, Any],
        reactive: bool,
        rng: np.random.Generator,
    ) -> None:
        self.road, self.window, self.reactive = road, window, reactive
        self.behavior, self.rng = behavior, rng
        self.frame = window.start
        self.added: set[int] = set()
        self._add_entering()

    def ego_state(self) -> tuple[list[float], float, float]:
        """Position, heading and speed of the replaced vehicle at the window's start."""
        x, y, vx, vy = self.window.scene.state[self.window.start, self.window.ego]
        return [float(x), float(y)], math.atan2(vy, vx), math.hypot(vx, vy)

    def _add_entering(self) -> None:
        scene = self.window.scene
        for v in np.flatnonzero(scene.present[self.frame]):
            if v == self.window.ego or v in self.added:
                continue
            self.added.add(int(v))
            vehicle = ReplayVehicle(self.road, scene, int(v), self.frame, self.reactive)
            label = scene.labels[v]
            cls = label if label in CLASSES else CONSERVATIVE
            set_driver_params(vehicle, self.behavior[cls], self.rng)
            vehicle.own_v0 = self.behavior[cls].get("v0") is not None
            vehicle.bgap_label = cls
            vehicle.bgap_id = recorded_id(scene, int(v))
            vehicle.color = COLORS[cls]
            self.road.vehicles.append(vehicle)

    def after_frame(self) -> None:
        """One recorded frame later: vehicles that left the section go, entering ones come."""
        self.frame += 1
        self.road.vehicles = [
            v for v in self.road.vehicles if not (isinstance(v, ReplayVehicle) and v.gone)
        ]
        if self.frame < len(self.window.scene.state):
            self._add_entering()


def recorded_id(scene: Any, v: int) -> int:
    """The id a replayed vehicle carries in bgap's records: its table's integer id, or its
    index in the scene where the table names vehicles by strings (a SUMO table's "v27")."""
    value = scene.ids[v]
    return int(value) if isinstance(value, (int, np.integer)) else v


def log_contact(vehicles: list[Vehicle]) -> bool:
    """Whether the ego (first) crashed into or was hit by a vehicle still following its log
    (which could not react): the recorded vehicles that crashed this frame."""
    ego = vehicles[0]
    if not ego.crashed:
        return False
    return any(isinstance(v, ReplayVehicle) and v.following_log and v.crashed for v in vehicles[1:])

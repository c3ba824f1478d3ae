"""The behaviour-rich highway: highway-env's ``highway-v0`` with two driver classes.

Built on ``highway_env.envs.HighwayEnv`` (not a copy): we override vehicle creation (an
exact number of aggressive drivers), the perception radius, the reward (a real lane-change
term) and ``info``, and add a per-frame hook used by the trajectory recorder.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from gymnasium import spaces
from highway_env import utils
from highway_env.envs.highway_env import HighwayEnv
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.kinematics import Vehicle

from bgap.common.errors import check_memory
from bgap.common.vocab import AGGRESSIVE, COLORS, CONSERVATIVE, EGO
from bgap.envs.replay import ReplayScene, log_contact, recorded_id
from bgap.traffic.behaviors import count_aggressive, create_driver, episode_mix, mix_stream
from bgap.traffic.replay import load_replay
from bgap.traffic.road import SPEED_LIMIT
from bgap.traffic.scenario import (
    REWARD_TERMS,
    check_config,
    contact_dx,
    default_config,
    merged_config,
)

FrameListener = Callable[["BehaviorHighwayEnv"], None]

VEHICLE_BYTES = 3_200
"""Memory of one highway-env vehicle with its driver (tracemalloc over a reset: 3.1 kB per
vehicle at 50 and at 400 vehicles)."""


class _HookedRoad(Road):
    """A highway-env ``Road`` that tells the environment after every simulation frame."""

    def __init__(self, *args: Any, on_step: Callable[[], None], **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._on_step = on_step

    def step(self, dt: float) -> None:
        super().step(dt)
        self._on_step()


class BehaviorHighwayEnv(HighwayEnv):
    """highway-v0 enriched with aggressive and conservative drivers.

    Config keys beyond highway-v0's: ``mix`` (fraction of aggressive background vehicles),
    ``mix_sampling`` (``fixed``, or a new mix per episode: ``uniform``, ``paper``),
    ``perception_radius`` [m], ``behavior`` (parameters per class, see
    :class:`bgap.traffic.behaviors.DriverParams`), and a ``lane_change_reward`` that is really paid.
    Defaults and checks: :mod:`bgap.traffic.scenario`, shared with the vectorised backend.
    """

    @classmethod
    def default_config(cls) -> dict:
        return default_config()

    def __init__(self, config: dict | None = None, render_mode: str | None = None) -> None:
        self.frame_listeners: list[FrameListener] = []
        self.frame = 0
        self.episode = -1
        self._mix_rng = mix_stream(0)
        super().__init__(config, render_mode)

    # ---------------------------------------------------------------- configuration
    def configure(self, config: dict | None) -> None:
        # nested dicts merged all the way down, unknown keys refused (bgap.traffic.scenario)
        self.config = merged_config(self.config, config)
        check_config(self.config)
        # highway-env reads the perception distance from this class constant at observe time.
        self.PERCEPTION_DISTANCE = float(self.config["perception_radius"])
        self.replay, self.replay_scene = None, None
        traffic = self.config.get("traffic") or {}
        if traffic.get("source") == "replay":  # the road takes the table's lanes
            self.replay = load_replay(
                traffic["table"],
                self.config["simulation_frequency"],
                traffic["min_duration"],
                traffic.get("scenes", "all"),
            )
            self.config["lanes_count"] = self.replay.lanes
        else:  # checked once: the count holds for every episode
            n = int(self.config["vehicles_count"])
            check_memory(n * VEHICLE_BYTES, "vehicles_count", n, "fewer vehicles")

    def define_spaces(self) -> None:
        super().define_spaces()
        # Observations are normalised and clipped, so say so (highway-env declares +-inf).
        space = self.observation_space
        self.observation_space = spaces.Box(-1.0, 1.0, shape=space.shape, dtype=space.dtype)

    # ---------------------------------------------------------------- scene creation
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:  # the mix draws have their own stream (bgap.behaviors.mix_stream)
            self._mix_rng = mix_stream(seed)
        return super().reset(seed=seed, options=options)

    def _reset(self) -> None:
        self.episode += 1
        self.frame = 0
        super()._reset()
        self._target_lane_before = self.vehicle.target_lane_index
        self._lane_change = False
        self._notify()

    def _create_road(self) -> None:
        self.road = _HookedRoad(
            network=RoadNetwork.straight_road_network(
                self.config["lanes_count"], speed_limit=SPEED_LIMIT
            ),
            np_random=self.np_random,
            record_history=self.config["show_trajectories"],
            on_step=self._after_frame,
        )

    def _create_vehicles(self) -> None:
        """highway-v0's spawning, with exactly round(mix * n) aggressive drivers at random;
        or a replay's window (:mod:`bgap.envs.replay`)."""
        if self.replay is not None:
            self._create_replay()
            return
        n = int(self.config["vehicles_count"])
        self.mix = episode_mix(self.config, self._mix_rng)
        n_aggressive = count_aggressive(self.mix, n)
        labels = np.array([AGGRESSIVE] * n_aggressive + [CONSERVATIVE] * (n - n_aggressive))
        labels = self.np_random.permutation(labels)

        ego = Vehicle.create_random(
            self.road,
            speed=25.0,
            lane_id=self.config["initial_lane_id"],
            spacing=self.config["ego_spacing"],
        )
        ego = self.action_type.vehicle_class(self.road, ego.position, ego.heading, ego.speed)
        ego.bgap_label, ego.bgap_id, ego.color = EGO, 0, COLORS[EGO]
        self.controlled_vehicles = [ego]
        self.road.vehicles.append(ego)
        spacing = 1 / self.config["vehicles_density"]
        behavior = self.config["behavior"]
        for i, label in enumerate(labels, start=1):
            vehicle = create_driver(self.road, str(label), behavior[label], spacing, self.np_random)
            vehicle.bgap_id = i
            self.road.vehicles.append(vehicle)

    def _create_replay(self) -> None:
        """The ego in place of a recorded vehicle, the window's other vehicles replayed."""
        traffic = self.config["traffic"]
        per_step = int(self.config["simulation_frequency"] // self.config["policy_frequency"])
        longest = int(round(self.config["duration"] * self.config["simulation_frequency"]))
        window = self.replay.window(
            self.np_random, longest, traffic["vehicle"], traffic["start"], traffic["scene"]
        )
        self.replay_steps = window.frames // per_step  # policy steps the window holds
        scene = ReplayScene(
            self.road,
            window,
            self.config["behavior"],
            traffic["mode"] == "reactive",
            self.np_random,
        )
        position, heading, speed = scene.ego_state()
        ego = self.action_type.vehicle_class(self.road, position, heading, speed)
        ego.bgap_label, ego.color = EGO, COLORS[EGO]
        ego.bgap_id = recorded_id(window.scene, window.ego)
        self.controlled_vehicles = [ego]
        self.road.vehicles.insert(0, ego)
        self.replay_scene = scene
        labels = [getattr(v, "bgap_label", None) for v in self.road.vehicles[1:]]
        self.mix = float(np.mean([label == AGGRESSIVE for label in labels])) if labels else 0.0

    def _is_truncated(self) -> bool:
        if self.replay is not None and self.steps >= self.replay_steps * int(
            self.config["simulation_frequency"] // self.config["policy_frequency"]
        ):
            return True  # the replaced vehicle's window ends
        return super()._is_truncated()

    # ---------------------------------------------------------------- stepping
    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        self._target_lane_before = self.vehicle.target_lane_index
        self._x_before = {id(v): float(v.position[0]) for v in self.road.vehicles}
        return super().step(action)

    def overtakes(self) -> int:
        """Vehicles the ego passed in the last step: ahead of it (centre to centre) before
        the step, behind it after; vehicles that entered or left the road in it not counted
        (:func:`bgap.sim.passing.overtakes`, the vector backend's count)."""
        before = getattr(self, "_x_before", {})
        ego = self.vehicle
        if id(ego) not in before:
            return 0
        x0, x1 = before[id(ego)], float(ego.position[0])
        return sum(
            1
            for v in self.road.vehicles
            if v is not ego and id(v) in before and before[id(v)] > x0 and v.position[0] < x1
        )

    def _after_frame(self) -> None:
        self.frame += 1
        if self.replay_scene is not None:
            self.replay_scene.after_frame()
        self._notify()

    def _notify(self) -> None:
        for listener in self.frame_listeners:
            listener(self)

    # ---------------------------------------------------------------- reward and info
    def lane_changed(self) -> bool:
        """Whether the last action started a real lane change.

        The meta-action moves the ego's target lane only when the neighbouring lane exists
        and is reachable, so LANE_LEFT in the leftmost lane is not a lane change.
        """
        return self.vehicle.target_lane_index != self._target_lane_before

    def _rewards(self, action: Any) -> dict[str, float]:
        rewards = super()._rewards(action)
        rewards["lane_change_reward"] = float(self.lane_changed())
        return rewards

    def _reward(self, action: Any) -> float:
        """Weighted sum of the four terms. highway-env leaves the lane-change term out of its
        normalisation range; ours maps [sum of negative, sum of positive weights] to [0, 1]."""
        rewards = self._rewards(action)
        weights = {name: float(self.config[name]) for name in REWARD_TERMS}
        reward = sum(weights[name] * rewards[name] for name in REWARD_TERMS)
        if self.config["normalize_reward"]:
            low = sum(min(w, 0.0) for w in weights.values())
            high = sum(max(w, 0.0) for w in weights.values())
            if high > low:
                reward = utils.lmap(reward, [low, high], [0, 1])
        return float(reward * rewards["on_road_reward"])

    def observed_vehicles(self) -> list[Vehicle]:
        """Background vehicles strictly within the perception radius of the ego."""
        ego = self.vehicle
        return [
            v
            for v in self.road.vehicles
            if v is not ego and np.linalg.norm(v.position - ego.position) < self.PERCEPTION_DISTANCE
        ]

    def _info(self, obs: np.ndarray, action: Any | None = None) -> dict:
        info = super()._info(obs, action)
        others = [v for v in self.road.vehicles if v is not self.vehicle]
        seen = self.observed_vehicles()
        info.update(
            {
                "ego_speed": float(self.vehicle.speed),
                "crashed": bool(self.vehicle.crashed),
                "lane_change": self.lane_changed(),
                "lane": int(self.vehicle.lane_index[2]),
                "contact_dx": contact_dx(*_positions(self.road.vehicles)),
                "aggressive_fraction": _fraction_aggressive(others),
                "aggressive_fraction_observed": _fraction_aggressive(seen),
                "observed_count": len(seen),
                "overtakes": self.overtakes(),
            }
        )
        if self.replay is not None:  # the ego's crash partner could not react (log mode)
            info["log_contact"] = log_contact(self.road.vehicles)
        return info


def _fraction_aggressive(vehicles: list[Vehicle]) -> float:
    if not vehicles:
        return 0.0
    return sum(getattr(v, "bgap_label", None) == AGGRESSIVE for v in vehicles) / len(vehicles)


def _positions(vehicles: list[Vehicle]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, y and crashed of ``vehicles`` (the ego first, as in ``road.vehicles``)."""
    state = np.array([(*v.position, v.crashed) for v in vehicles], dtype=float)
    return state[:, 0], state[:, 1], state[:, 2] > 0

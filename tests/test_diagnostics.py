"""How an episode ended (bgap.rollout.EpisodeStats), on hand-built scenes in both simulators.

Each scene is built in highway-env (ego and one IDM driver placed by hand), copied into the
vector backend, and stepped in both with the same ego actions; the crash must happen in both
and be classified as the kind the scene was built to produce.
"""

from __future__ import annotations

import numpy as np
import pytest

from bgap.envs import make_env
from bgap.sim.highway_scenes import scene_from_highway
from bgap.sim.rollout import EpisodeStats
from bgap.sim.vector import VectorHighway
from bgap.traffic.road import IDLE, LANE_LEFT, LANE_WIDTH
from bgap.traffic.scenario import contact_dx, env_config
from tests.conftest import make_cfg


def _place(road, vehicle, x: float, lane: int, speed: float, target_speed: float) -> None:
    """Put ``vehicle`` at ``x`` on the centre of ``lane``, driving straight at ``speed``."""
    index = ("0", "1", lane)
    vehicle.position = np.array([x, lane * LANE_WIDTH])
    vehicle.heading, vehicle.speed = 0.0, speed
    vehicle.lane_index = vehicle.target_lane_index = index
    vehicle.lane = road.network.get_lane(index)
    vehicle.target_speed = target_speed
    if hasattr(vehicle, "timer"):
        vehicle.timer = -1e3  # no MOBIL decision (lane change) during the test


def _scene(ego: tuple, *others: tuple):
    """highway-env with the ego and IDM drivers at (x, lane, speed, target speed) each."""
    cfg = make_cfg("env=sparse", f"env.vehicles_count={len(others)}", "mix=0.0")
    env = make_env(cfg)
    env.reset(seed=0)
    road = env.unwrapped.road
    ego_vehicle, *drivers = road.vehicles
    _place(road, ego_vehicle, *ego)
    ego_vehicle.speed_index = ego_vehicle.speed_to_index(ego[3])
    for driver, other in zip(drivers, others, strict=True):
        _place(road, driver, *other)
    venv = VectorHighway(env_config(cfg), 1)
    venv.reset(seed=0)
    venv.load_scene(0, scene_from_highway(env))
    return env, venv


def _play(env, venv, actions: list[int]) -> tuple[str, str]:
    """The ending each backend reports after ``actions`` (stopping at a crash)."""
    endings = []
    for backend in ("highway", "vector"):
        stats = EpisodeStats(1)
        for action in actions:
            if backend == "highway":
                _, reward, done, _, info = env.step(action)
                info = {k: np.array([v]) for k, v in info.items() if k != "rewards"}
            else:
                _, reward, done, _, info = venv.step(np.array([action]))
                done = done[0]
            stats.add(np.array([0]), np.atleast_1d(reward), info)
            if done:
                break
        assert stats.crashed[0], f"{backend}: the scene was built to crash"
        endings.append(stats.ending(0))
    return endings[0], endings[1]


def test_the_ego_running_into_a_slow_vehicle_ahead_is_a_rear_end():
    env, venv = _scene((100.0, 1, 25.0, 25.0), (118.0, 1, 8.0, 8.0))
    assert _play(env, venv, [IDLE] * 5) == ("rear_end", "rear_end")


def test_a_fast_vehicle_running_into_the_ego_from_behind_is_rear_ended():
    # 40 m/s, 12 m behind a 20 m/s ego: IDM's braking is capped at 6 m/s^2, too little.
    env, venv = _scene((100.0, 1, 20.0, 20.0), (88.0, 1, 40.0, 40.0))
    assert _play(env, venv, [IDLE] * 5) == ("rear_ended", "rear_ended")


def test_moving_into_a_vehicle_alongside_is_a_lane_change_crash():
    env, venv = _scene((100.0, 1, 25.0, 25.0), (101.0, 0, 25.0, 25.0))
    assert _play(env, venv, [LANE_LEFT] + [IDLE] * 4) == ("lane_change", "lane_change")


def test_a_crash_long_after_a_lane_change_is_not_blamed_on_it():
    """Changing lane, then driving 5 s into a slow vehicle ahead: a rear end, not a lane
    change (the 2 s window)."""
    env, venv = _scene((100.0, 1, 25.0, 25.0), (210.0, 0, 5.0, 5.0))
    assert _play(env, venv, [LANE_LEFT] + [IDLE] * 9) == ("rear_end", "rear_end")


def test_an_episode_without_crash_is_a_timeout():
    stats = EpisodeStats(2)
    info = {
        "ego_speed": np.array([25.0, 25.0]),
        "lane_change": np.array([False, True]),
        "crashed": np.array([False, False]),
        "contact_dx": np.array([0.0, 0.0]),
    }
    stats.add(np.array([0, 1]), np.zeros(2), info)
    assert [stats.ending(0), stats.ending(1)] == ["timeout", "timeout"]


@pytest.mark.parametrize(
    "x,crashed,expected",
    [
        ([0.0, 6.0, -30.0], [True, True, False], 6.0),  # the crashed one, not the nearest
        ([0.0, 80.0, -5.0], [True, True, True], -5.0),  # nearest of two crashed
        ([0.0, 5.0], [False, True], 0.0),  # the ego has not crashed
    ],
)
def test_contact_offset_is_the_nearest_crashed_vehicle(x, crashed, expected):
    x = np.array(x)
    got = contact_dx(x, np.zeros_like(x), np.array(crashed))
    assert got == pytest.approx(expected)

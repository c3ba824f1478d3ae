"""Driver classes behave as their parameters say, and stock traffic is highway-env's."""

from __future__ import annotations

import gymnasium as gym
import highway_env  # noqa: F401  (registers highway-v0)
import numpy as np
import pytest

from bgap.envs import make_env
from bgap.traffic.behaviors import BehaviorVehicle
from tests.conftest import lane_changes, make_cfg


def test_paper_parameters_reach_the_vehicles():
    env = make_env(make_cfg("env=dense", "mix=0.5", "behavior=paper"))
    env.reset(seed=0)
    for v in env.unwrapped.road.vehicles[1:]:
        assert isinstance(v, BehaviorVehicle)
        if v.bgap_label == "aggressive":
            assert (v.TIME_WANTED, v.DISTANCE_WANTED, v.COMFORT_ACC_MAX, v.COMFORT_ACC_MIN) == (
                1.2,
                2.5 + 5.0,
                6.0,
                -9.0,
            )
            assert (
                v.POLITENESS,
                v.LANE_CHANGE_MIN_ACC_GAIN,
                v.LANE_CHANGE_MAX_BRAKING_IMPOSED,
            ) == (0.0, 0.0, 9.0)
            assert v.target_speed == 40.0
        else:
            assert (v.TIME_WANTED, v.DISTANCE_WANTED, v.COMFORT_ACC_MAX, v.COMFORT_ACC_MIN) == (
                1.5,
                10.0,
                3.0,
                -6.0,
            )
            assert 22.5 <= v.target_speed <= 27.5
        assert 3.5 <= v.DELTA <= 4.5


def test_aggressive_faster_and_change_lanes_more(sparse_mixed_recording):
    table = sparse_mixed_recording
    others = table[~table.is_ego]
    speed = others.groupby("label").speed.mean()
    assert speed["aggressive"] > 30.0, "aggressive drivers must overspeed past the 30 m/s limit"
    assert speed["aggressive"] > speed["conservative"] + 5.0
    changes = lane_changes(others)
    labels = others.groupby(["episode", "vehicle_id"]).label.first()
    per_vehicle = changes.groupby(labels).mean()
    assert per_vehicle["aggressive"] > per_vehicle["conservative"]


def _traffic_stats(env, episodes: int, seed0: int):
    """Per-episode mean speed and lane changes per vehicle of the background traffic."""
    speeds, changes = [], []
    for k in range(episodes):
        env.reset(seed=seed0 + k)
        u = env.unwrapped
        others = [v for v in u.road.vehicles if v is not u.vehicle]
        lanes = np.array([v.lane_index[2] for v in others])
        ep_speed, ep_changes, done = [], 0, False
        while not done:
            _, _, term, trunc, _ = env.step(1)
            done = term or trunc
            now = np.array([v.lane_index[2] for v in others])
            ep_changes += int((now != lanes).sum())
            lanes = now
            ep_speed.append(np.mean([v.speed for v in others]))
        speeds.append(np.mean(ep_speed))
        changes.append(ep_changes / len(others))
    return np.array(speeds), np.array(changes)


def _within_noise(a: np.ndarray, b: np.ndarray, k: float = 3.0) -> bool:
    se = np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
    return abs(a.mean() - b.mean()) <= k * se + 1e-9


@pytest.mark.slow  # the default suite's time budget
def test_stock_traffic_matches_highway_v0():
    settings = {
        "lanes_count": 4,
        "vehicles_count": 5,
        "duration": 30,
        "policy_frequency": 1,
        "simulation_frequency": 15,
        "action": {"type": "DiscreteMetaAction", "target_speeds": [10, 15, 20, 25, 30]},
    }
    ref = gym.make("highway-v0", config=settings)
    ours = make_env(make_cfg("env=sparse", "behavior=stock", "mix=0.5", "env.duration=30"))
    # 10 episodes each: the test's 3-standard-error band is then about 1 m/s on the speed
    ref_speed, ref_changes = _traffic_stats(ref, 10, 1000)
    our_speed, our_changes = _traffic_stats(ours, 10, 5000)
    assert _within_noise(ref_speed, our_speed), (ref_speed.mean(), our_speed.mean())
    assert _within_noise(ref_changes, our_changes), (ref_changes.mean(), our_changes.mean())
    # and the stock preset is not the paper's traffic
    paper = make_env(make_cfg("env=sparse", "behavior=paper", "mix=0.5", "env.duration=30"))
    paper_speed, _ = _traffic_stats(paper, 3, 5000)
    assert paper_speed.mean() > our_speed.mean() + 3.0


@pytest.mark.parametrize("mix", [0.0, 1.0])
def test_pure_classes(mix):
    env = make_env(make_cfg("env=sparse", f"mix={mix}", "env.duration=20"))
    env.reset(seed=2)
    for _ in range(20):
        env.step(1)
    speeds = [v.speed for v in env.unwrapped.road.vehicles[1:]]
    if mix == 1.0:
        assert np.mean(speeds) > 30.0
    else:
        assert np.max(speeds) <= 27.5 + 0.5

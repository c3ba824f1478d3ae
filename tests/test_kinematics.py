"""Kinematic statistics of trajectory tables (bgap.kinematics): a scene built by hand with
every statistic known, highway-env's own leader search, and closed-form distances."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from bgap.calibration.kinematics import class_samples, compare, driver_class, scene, total_distance
from bgap.cmetric.io import TrajectoryError

FPS = 5.0
T = np.arange(61) / FPS  # 12 s


def _scene() -> pd.DataFrame:
    """Lane 1: a leader at 25 m/s 40 m ahead of a follower at 20 m/s (headway (40 + 5t) / 20).
    An aggressive car accelerating at 1 m/s^2 from 20 m/s changes from lane 0 to lane 2
    once, at t = 6 s. An ego sits in lane 3."""
    rows = []
    for vid, label, x, vx, lane in (
        (1, "conservative", 100 + 25 * T, np.full_like(T, 25.0), np.ones_like(T)),
        (2, "Cautious", 60 + 20 * T, np.full_like(T, 20.0), np.ones_like(T)),
        (3, "AGGRESSIVE-1", 20 * T + 0.5 * T**2, 20 + T, np.where(T < 6, 0, 2)),
        (0, "ego", 50 + 22 * T, np.full_like(T, 22.0), np.full_like(T, 3)),
    ):
        rows.append(
            pd.DataFrame(dict(episode=0, frame=np.arange(len(T)), time=T, vehicle_id=vid,
                              label=label, x=x, y=4.0 * lane, vx=vx, vy=0.0, lane=lane))
        )  # fmt: skip
    return pd.concat(rows, ignore_index=True)


def test_labels_map_to_bgaps_two_classes():
    labels = pd.Series(["aggressive", "Agg-2", "ego", "cautious", "normal", "AGGR"])
    assert driver_class(labels).tolist() == [
        "aggressive", "aggressive", "ego", "conservative", "conservative", "aggressive"
    ]  # fmt: skip
    assert driver_class(labels, "norm").tolist()[4] == "aggressive"


def test_every_statistic_of_a_hand_built_scene():
    stats = class_samples(_scene(), fps=FPS)
    calm, agg = stats["conservative"], stats["aggressive"]
    assert sorted(calm) == ["acceleration", "headway", "lane_changes", "speed"]
    assert np.sort(calm["speed"]).tolist() == [20.0] * 61 + [25.0] * 61  # the ego left out
    assert calm["headway"] == pytest.approx((40 + 5 * T) / 20)  # the leader follows nobody
    assert len(agg["headway"]) == 0  # alone in each lane
    assert agg["acceleration"] == pytest.approx(np.ones(61))
    assert calm["acceleration"] == pytest.approx(np.zeros(122))
    assert agg["lane_changes"] == pytest.approx([1 / 0.2])  # one change in 12 s
    assert calm["lane_changes"] == pytest.approx([0.0, 0.0])
    short = class_samples(_scene()[lambda t: t.time <= 6.0], fps=FPS)
    assert len(short["aggressive"]["lane_changes"]) == 0  # 6 s < min_minutes (10 s)


def test_headways_agree_with_highway_envs_leader_search():
    from bgap.envs import make_env
    from tests.conftest import make_cfg

    env = make_env(make_cfg("env=dense", "mix=0.5"))
    env.reset(seed=3)  # vehicles spawn centred in their lanes: lane index = lane occupied
    road = env.unwrapped.road
    vehicles = road.vehicles
    table = pd.DataFrame(
        dict(episode=0, frame=0, time=0.0, vehicle_id=range(len(vehicles)),
             label=["conservative"] * len(vehicles), x=[v.position[0] for v in vehicles],
             y=[v.position[1] for v in vehicles], vx=[v.velocity[0] for v in vehicles],
             vy=[v.velocity[1] for v in vehicles], lane=[v.lane_index[2] for v in vehicles])
    )  # fmt: skip
    ours = class_samples(table, max_headway=np.inf)["conservative"]["headway"]
    theirs = []
    for v in vehicles:
        front, _ = road.neighbour_vehicles(v)
        if front is not None:
            theirs.append((front.position[0] - v.position[0]) / v.speed)
    assert len(theirs) > 20
    assert np.sort(ours) == pytest.approx(np.sort(theirs))


def test_scene_estimates_lanes_density_limit_and_shares():
    s = scene(_scene(), fps=FPS)
    assert s.lanes == 3 and s.speed_limit == 25.0
    assert s.aggressive_share == pytest.approx(1 / 3)
    # 101 vehicles 10 m apart in one lane: 100 per km (the 5-95% stretch: 91 in 900 m)
    ring = pd.DataFrame(
        dict(episode=0, frame=0, vehicle_id=range(101), label="conservative",
             x=np.arange(101) * 10.0, y=0.0, vx=25.0, vy=0.0, lane=0)
    )  # fmt: skip
    assert scene(ring).vehicles_per_km_lane == pytest.approx(91 / 0.9)


def test_distances_have_their_closed_forms():
    rng = np.random.default_rng(0)
    a = rng.normal(25, 2, 500)
    observed = {"conservative": {"speed": a, "headway": a / 10}}
    same = compare(observed, observed)
    assert (same.dropna(subset=["distance"]).distance == 0).all()
    shifted = compare(observed, {"conservative": {"speed": a + 1.5, "headway": a / 10}})
    speed = shifted.set_index("statistic").loc["speed"]
    assert speed.distance == pytest.approx(1.5)  # W1 of a shift is the shift
    assert speed.scaled == pytest.approx(1.5 / np.std(a))
    # statistics missing on a side are NaN and left out of the total
    assert shifted.set_index("statistic").loc["lane_changes"].isna().distance
    assert total_distance(shifted) == pytest.approx(1.5 / np.std(a) / 2)
    weighted = shifted.assign(weight=np.where(shifted.statistic == "speed", 3.0, 1.0))
    assert total_distance(weighted) == pytest.approx(1.5 / np.std(a) * 3 / 4)


def test_tables_without_labels_or_lanes_are_refused():
    table = _scene()
    with pytest.raises(TrajectoryError, match="no 'label' column"):
        class_samples(table.drop(columns="label"), fps=FPS)
    with pytest.raises(TrajectoryError, match="no 'lane' column"):
        scene(table.drop(columns="lane"), fps=FPS)

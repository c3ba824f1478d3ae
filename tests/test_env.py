"""The behaviour-rich environment: spaces, mix, perception radius, reward terms, determinism."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
from gymnasium.utils.env_checker import check_env
from highway_env.vehicle.kinematics import Vehicle

from bgap.datasets.simulate import simulate
from bgap.envs import make_env
from tests.conftest import make_cfg

LANE_LEFT, IDLE, LANE_RIGHT = 0, 1, 2


@pytest.mark.parametrize("density,rows", [("sparse", 5), ("dense", 40)])
def test_gymnasium_checker_and_observation_shape(density, rows):
    env = make_env(make_cfg(f"env={density}"))
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=3)
    assert obs.shape == (rows, 5)
    assert env.action_space.n == 5
    for _ in range(3):
        obs, *_ = env.step(env.action_space.sample())
        assert obs.shape == (rows, 5)
        assert np.all(np.abs(obs) <= 1.0)
        assert set(np.unique(obs[:, 0])) <= {0.0, 1.0}
        assert obs[0, 0] == 1.0  # the ego is always present


# Hand-counted round-half-up of mix * n.
EXPECTED_AGGRESSIVE = {
    ("sparse", 0.0): 0,
    ("sparse", 0.2): 1,
    ("sparse", 0.5): 3,
    ("sparse", 1.0): 5,
    ("dense", 0.0): 0,
    ("dense", 0.2): 8,
    ("dense", 0.5): 20,
    ("dense", 1.0): 40,
}


@pytest.mark.parametrize("density,mix", list(EXPECTED_AGGRESSIVE))
def test_exact_aggressive_count(density, mix):
    env = make_env(make_cfg(f"env={density}", f"mix={mix}"))
    n = 5 if density == "sparse" else 40
    for seed in range(3):
        _, info = env.reset(seed=seed)
        others = [v for v in env.unwrapped.road.vehicles if v is not env.unwrapped.vehicle]
        labels = [v.bgap_label for v in others]
        assert len(others) == n
        assert labels.count("aggressive") == EXPECTED_AGGRESSIVE[(density, mix)]
        assert labels.count("conservative") == n - EXPECTED_AGGRESSIVE[(density, mix)]
        _, _, _, _, info = env.step(IDLE)
        assert info["aggressive_fraction"] == pytest.approx(EXPECTED_AGGRESSIVE[(density, mix)] / n)


def test_aggressive_vehicles_are_placed_at_random():
    env = make_env(make_cfg("env=dense", "mix=0.5"))
    orders = set()
    for seed in range(4):
        env.reset(seed=seed)
        orders.add(tuple(v.bgap_label for v in env.unwrapped.road.vehicles[1:]))
    assert len(orders) == 4


def _present_vs_within(radius: float, seeds=range(2), steps=5):
    env = make_env(make_cfg("env=dense", f"radius={radius}"))
    present = []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        for _ in range(steps):
            u = env.unwrapped
            ego = u.vehicle
            dist = [
                np.linalg.norm(v.position - ego.position) for v in u.road.vehicles if v is not ego
            ]
            within = sum(d < radius for d in dist)
            # Every present row but the ego's is a vehicle within the radius, and every
            # vehicle within the radius is present (V = 40 rows hold all of them).
            assert int(obs[1:, 0].sum()) == min(within, obs.shape[0] - 1)
            present.append(obs[1:, 0].sum())
            obs, _, term, trunc, info = env.step(env.action_space.sample())
            assert info["observed_count"] == sum(
                np.linalg.norm(v.position - u.vehicle.position) < radius
                for v in u.road.vehicles
                if v is not u.vehicle
            )
            if term or trunc:
                break
    return float(np.mean(present))


def test_perception_radius_limits_presence():
    near, far = _present_vs_within(30.0), _present_vs_within(180.0)
    assert near < far
    assert far > 5 and near < 5


def test_radius_observation_rows_lie_within_radius():
    # Positions are normalised by highway-env's x range [-200, 200] m: undo it and check.
    env = make_env(make_cfg("env=sparse", "radius=30"))
    obs, _ = env.reset(seed=1)
    for _ in range(10):
        rel = obs[1:][obs[1:, 0] == 1]
        dx = rel[:, 1] * 200.0
        dy = rel[:, 2] * 12.0  # y range is +-4 m * number of side lanes (3)
        assert np.all(np.hypot(dx, dy) < 30.0 + 1e-6)
        obs, *_ = env.step(IDLE)


# ----------------------------------------------------------------- reward terms
def scripted_env(reward: str, ego_lane: int, ego_speed: float, obstacles=()):
    """Our environment with the scene replaced: the ego at x = 100 m in ``ego_lane`` and
    motionless obstacles at (lane, x)."""
    env = make_env(make_cfg("env=sparse", f"reward={reward}"))
    env.reset(seed=0)
    u = env.unwrapped
    road = u.road

    def lane(i):
        return road.network.get_lane(("0", "1", i))

    ego = u.action_type.vehicle_class(road, lane(ego_lane).position(100.0, 0), 0.0, ego_speed)
    ego.bgap_label, ego.bgap_id = "ego", 0
    road.vehicles = [ego]
    u.controlled_vehicles = [ego]
    for k, (lane_id, x) in enumerate(obstacles, start=1):
        v = Vehicle(road, lane(lane_id).position(x, 0), 0.0, 0.0)
        v.bgap_label, v.bgap_id = "conservative", k
        road.vehicles.append(v)
    return env


# (reward preset, ego lane, speed, action, obstacles, expected reward, expected terms)
# authors: collision -10, lane change 0.5, right lane 0.2 * lane / 3, high speed clip((v-20)/10).
CASES = {
    "crash": (
        "authors",
        1,
        15.0,
        IDLE,
        [(1, 110.0)],
        -10.0 + 0.2 / 3,
        {"collision_reward": 1.0, "lane_change_reward": 0.0},
    ),
    "lane_change_left": (
        "authors",
        1,
        15.0,
        LANE_LEFT,
        [],
        0.5,
        {"lane_change_reward": 1.0, "right_lane_reward": 0.0},
    ),
    "lane_change_right": (
        "authors",
        1,
        15.0,
        LANE_RIGHT,
        [],
        0.5 + 0.2 * 2 / 3,
        {"lane_change_reward": 1.0},
    ),
    "no_lane_left_of_leftmost": (
        "authors",
        0,
        15.0,
        LANE_LEFT,
        [],
        0.0,
        {"lane_change_reward": 0.0},
    ),
    "rightmost_lane": ("authors", 3, 15.0, IDLE, [], 0.2, {"right_lane_reward": 1.0}),
    "top_speed": ("authors", 0, 30.0, IDLE, [], 1.0, {"high_speed_reward": 1.0}),
    # highway weights (-1, lc 0, rl 0.1, hs 0.4) normalised over [-1, 0.5].
    "normalised_top_speed_rightmost": ("highway", 3, 30.0, IDLE, [], 1.0, {}),
    "normalised_idle_slow_left": ("highway", 0, 15.0, IDLE, [], 1 / 1.5, {}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_reward_terms_hand_computed(case):
    reward_name, lane, speed, action, obstacles, expected, terms = CASES[case]
    env = scripted_env(reward_name, lane, speed, obstacles)
    _, reward, terminated, _, info = env.step(action)
    assert reward == pytest.approx(expected, abs=1e-6)
    for name, value in terms.items():
        assert info["rewards"][name] == pytest.approx(value)
    assert info["lane_change"] == bool(info["rewards"]["lane_change_reward"])
    assert terminated == (case == "crash") == info["crashed"]


def test_lane_change_weight_is_used_in_normalised_reward():
    env = scripted_env("highway", 1, 15.0)
    env.unwrapped.config["lane_change_reward"] = 0.5
    _, reward, *_ = env.step(LANE_LEFT)
    # raw 0.5 (lane change) mapped from [-1, 0.4 + 0.1 + 0.5] to [0, 1]
    assert reward == pytest.approx((0.5 + 1.0) / 2.0)


# ----------------------------------------------------------------- determinism and config
def test_same_seed_same_trajectories_bit_for_bit():
    cfg = make_cfg("env=sparse", "mix=0.6", "policy=random", "seed=7", "env.duration=8")
    a = simulate(cfg, episodes=2, progress=False)
    b = simulate(cfg, episodes=2, progress=False)
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    c = simulate(
        make_cfg("env=sparse", "mix=0.6", "policy=random", "seed=8", "env.duration=8"),
        episodes=2,
        progress=False,
    )
    assert not np.array_equal(a[["x", "y"]].to_numpy()[:200], c[["x", "y"]].to_numpy()[:200])


def test_env_rejects_bad_values_directly():
    with pytest.raises(ValueError, match="mix"):
        gym.make("bgap/BehaviorHighway-v0", config={"mix": 1.2})
    with pytest.raises(ValueError, match="perception_radius"):
        gym.make("bgap/BehaviorHighway-v0", config={"perception_radius": 0})

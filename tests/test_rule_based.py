"""The rule-based ego (IDM + MOBIL over meta-actions) on observations highway-env computes."""

from __future__ import annotations

import numpy as np
import pytest

from bgap.agents.policies import rollout
from bgap.agents.rule_based import DEFAULT, RuleBasedEgo, RuleParams, TunedRule, idm
from bgap.traffic.road import FASTER, IDLE, LANE_LEFT, LANE_RIGHT, SLOWER
from bgap.traffic.scenario import env_config
from tests.conftest import make_cfg
from tests.test_diagnostics import _scene


def _action(ego: tuple, *others: tuple) -> int:
    env, _ = _scene(ego, *others)
    obs = env.unwrapped.observation_type.observe()
    return int(RuleBasedEgo()(obs[None])[0])


def test_idm_matches_highway_envs_own_acceleration():
    from highway_env.vehicle.behavior import IDMVehicle

    env, _ = _scene((100.0, 1, 24.0, 24.0), (140.0, 1, 18.0, 18.0))
    ego, lead = env.unwrapped.road.vehicles
    follower = IDMVehicle(env.unwrapped.road, ego.position, speed=24.0, target_speed=30.0)
    expected = follower.acceleration(follower, lead)
    got = idm(np.array(24.0), 30.0, np.array(40.0), np.array(18.0))
    assert float(got) == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize(
    "ego,other,expected",
    [
        ((100.0, 1, 20.0, 20.0), (400.0, 1, 20.0, 20.0), FASTER),  # free road, below 30 m/s
        ((100.0, 3, 30.0, 30.0), (400.0, 3, 30.0, 30.0), IDLE),  # at top speed, far behind
        ((100.0, 1, 25.0, 25.0), (140.0, 1, 15.0, 15.0), LANE_LEFT),  # free lane 0 to overtake
        ((100.0, 0, 25.0, 25.0), (140.0, 0, 15.0, 15.0), LANE_RIGHT),  # lane 0: overtake right
    ],
)
def test_meta_action_per_situation(ego, other, expected):
    assert _action(ego, other) == expected


def test_brakes_behind_a_slow_vehicle_when_the_side_lane_is_taken():
    slow_ahead, alongside = (125.0, 3, 10.0, 10.0), (102.0, 2, 25.0, 25.0)
    assert _action((100.0, 3, 25.0, 25.0), slow_ahead, alongside) == SLOWER
    assert _action((100.0, 3, 25.0, 25.0), slow_ahead) == LANE_LEFT  # free: overtake


def test_no_lane_change_in_front_of_a_fast_follower():
    """A slow leader ahead, and a 40 m/s driver 15 m behind in the left lane: MOBIL's safety
    criterion forbids moving in front of it; with lane 2 free the ego goes right instead."""
    assert _action((100.0, 1, 25.0, 25.0), (85.0, 0, 40.0, 40.0)) != LANE_LEFT


def test_rule_based_ego_avoids_the_crashes_idle_has_in_dense_conservative_traffic():
    """Idle never brakes and runs into slower conservative drivers; IDM keeps its gap."""
    config = env_config(make_cfg("env=dense", "mix=0.0"))
    seeds = range(50_000, 50_040)
    idle = rollout(config, "idle", seeds).episodes
    rule = rollout(config, "rule", seeds).episodes
    assert idle.crashed.mean() > 0.2  # idle's known weakness in this traffic ...
    assert rule.crashed.mean() < idle.crashed.mean() / 4  # ... which the rule-based ego avoids
    assert rule.avg_speed.mean() > 0.9 * idle.avg_speed.mean()  # not by crawling


@pytest.mark.parametrize("politeness", [0.0, 1.0])
def test_mobil_with_politeness_decides_as_highway_envs_mobil(politeness):
    """A leader 60 m ahead at 22 m/s; the right lane free but for a follower 50 m back at
    27 m/s. Alone, the ego gains by moving right; counting the follower's loss (politeness
    1) it stays. highway-env's ``IDMVehicle.mobil`` with the same parameters decides."""
    from highway_env.vehicle.behavior import IDMVehicle

    params = RuleParams(politeness=politeness, lane_change_max_braking_imposed=4.0)
    env, _ = _scene((100.0, 0, 25.0, 25.0), (160.0, 0, 22.0, 30.0), (50.0, 1, 27.0, 30.0))
    road = env.unwrapped.road
    obs = env.unwrapped.observation_type.observe()
    ours = int(RuleBasedEgo(params=params)(obs[None])[0])
    ego = road.vehicles[0]
    reference = IDMVehicle(road, ego.position, speed=25.0, target_speed=30.0)
    reference.POLITENESS = politeness
    reference.LANE_CHANGE_MAX_BRAKING_IMPOSED = 4.0
    road.vehicles[0] = reference
    assert (ours == LANE_RIGHT) == reference.mobil(("0", "1", 1))
    assert (ours == LANE_RIGHT) == (politeness == 0.0)  # the case tells the two apart


def test_idm_only_keeps_its_lane_and_defaults_keep_the_rule():
    """IDM only never asks for a lane change where the rule overtakes, and the rule with
    the default parameters spelled out decides as the default rule."""
    env, _ = _scene((100.0, 3, 25.0, 25.0), (125.0, 3, 10.0, 10.0))
    obs = env.unwrapped.observation_type.observe()[None]
    assert int(RuleBasedEgo()(obs)[0]) == LANE_LEFT
    assert int(RuleBasedEgo(lane_changes=False)(obs)[0]) == SLOWER
    spelled = RuleParams(**{k: getattr(DEFAULT, k) for k in DEFAULT.__dataclass_fields__})
    assert int(RuleBasedEgo(params=spelled)(obs)[0]) == LANE_LEFT


def test_tuned_reads_the_preset_of_the_traffic_and_refuses_a_missing_one(tmp_path, monkeypatch):
    """rule_tuned plays the preset whose observed vehicles match the environment's (the
    stock preset in stock traffic), and names the stage to run where none does."""
    from bgap.agents import rule_based as module
    from bgap.common import presets
    from bgap.common.errors import ConfigError
    from bgap.common.presets import write_preset

    def path(group: str, name: str):
        return tmp_path / group / f"{name}.yaml"

    monkeypatch.setattr(presets, "SHIPPED", (str(tmp_path),))
    preset = TunedRule(time_wanted=2.5, situation="dense", observed_vehicles=40)
    write_preset(preset, "rule", path("rule", "dense"), "test preset", "test")
    dense = {"observation": {"vehicles_count": 40}, "behavior": {"name": "paper"}}
    assert module.tuned(dense).time_wanted == 2.5
    with pytest.raises(ConfigError, match="5 observed vehicles"):
        module.tuned({"observation": {"vehicles_count": 5}, "behavior": {"name": "paper"}})
    with pytest.raises(ConfigError, match="stock traffic"):
        module.tuned({**dense, "behavior": {"name": "stock"}})

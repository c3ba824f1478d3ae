"""The hybrid's rule-based fallback (bgap.agents.hybrid) on hand-built observation frames:
it takes the rule's action exactly where a vehicle's time to collision, computed by hand,
is under the threshold."""

from __future__ import annotations

import numpy as np
import pytest

from bgap.agents.hybrid import Hybrid
from bgap.agents.rule_based import V_RANGE, X_RANGE, rule_based
from bgap.common.errors import ConfigError
from bgap.traffic.road import FASTER, LANE_WIDTH, VEHICLE_LENGTH

LANES = 4
Y_RANGE = LANE_WIDTH * LANES


def frame(others: list[tuple[float, float, float]], speed: float = 30.0) -> np.ndarray:
    """One observation (5 rows): the ego in lane 1 at ``speed``, then each other vehicle at
    (dx, dy, dvx) from it [m, m, m/s], the remaining rows absent."""
    obs = np.zeros((5, 5))
    obs[0] = [1.0, 0.0, LANE_WIDTH / Y_RANGE, speed / V_RANGE, 0.0]
    for k, (dx, dy, dvx) in enumerate(others, start=1):
        obs[k] = [1.0, dx / X_RANGE, dy / Y_RANGE, dvx / V_RANGE, 0.0]
    return obs


def test_the_fallback_takes_the_rules_action_exactly_under_the_threshold():
    """Times to collision by hand, (|dx| - length) / closing speed, threshold 2 s:
    a leader 20 m ahead 10 m/s slower: (20 - 5) / 10 = 1.5 s (fallback); 50 m ahead:
    4.5 s (learned); a slower car 10 m ahead one lane over: no course (learned); a follower
    12 m behind 10 m/s faster: 0.7 s (fallback); nobody around (learned)."""
    assert VEHICLE_LENGTH == 5.0
    obs = np.stack([
        frame([(20.0, 0.0, -10.0)]),
        frame([(50.0, 0.0, -10.0)]),
        frame([(10.0, LANE_WIDTH, -10.0)]),
        frame([(-12.0, 0.0, 10.0)]),
        frame([]),
    ])  # fmt: skip
    config = {"lanes_count": LANES}
    hybrid = Hybrid(lambda o, rngs: np.full(len(o), FASTER), config, threshold=2.0)
    actions = hybrid(obs, [np.random.default_rng(0)] * len(obs))
    near = [True, False, False, True, False]
    np.testing.assert_array_equal(hybrid.near_collision(obs), near)
    rule = rule_based(config)(obs[near])
    assert not (rule == FASTER).any()  # the fallback's rows tell the two apart
    np.testing.assert_array_equal(actions[near], rule)
    np.testing.assert_array_equal(actions[~np.array(near)], FASTER)
    assert (hybrid.decisions, hybrid.fallbacks) == (5, 2)
    assert hybrid.share == pytest.approx(0.4)
    assert Hybrid(lambda o, r: np.full(len(o), FASTER), config, threshold=1.0).near_collision(
        obs
    ).tolist() == [False, False, False, True, False]  # 1.5 s is not under 1 s; 0.7 s is


def test_a_threshold_outside_the_horizon_is_refused():
    with pytest.raises(ConfigError, match="threshold=12.0 is invalid"):
        Hybrid(lambda o, r: o, {}, threshold=12.0)


def test_a_hybrid_spec_plays_its_policy_with_the_fallback_wherever_a_policy_plays():
    """``hybrid:SPEC`` and ``hybrid-1:SPEC`` wrap SPEC's policy (here the scripted ``idle``)
    at the default 2 s and at 1 s; on the frames above they fall back exactly where the
    thresholds say; a bad threshold is one line."""
    from bgap.agents.policies import as_policy, hybrid_spec

    assert hybrid_spec("hybrid:zoo:main/dense/behavior_rich/s0") == (
        2.0,
        "zoo:main/dense/behavior_rich/s0",
    )
    assert hybrid_spec("hybrid-2.5:ppo:run/model.zip") == (2.5, "ppo:run/model.zip")
    assert hybrid_spec("ppo:run/model.zip") is None
    config = {"lanes_count": LANES}
    obs = np.stack([frame([(20.0, 0.0, -10.0)]), frame([(-12.0, 0.0, 10.0)]), frame([])])
    for spec, near in (
        ("hybrid:idle", [True, True, False]),
        ("hybrid-1:idle", [False, True, False]),
    ):
        policy, rows = as_policy(spec, config)
        assert isinstance(policy, Hybrid) and rows is None
        np.testing.assert_array_equal(policy.near_collision(obs), near)
    with pytest.raises(ConfigError, match="hybrid-<seconds>:SPEC"):
        as_policy("hybrid-soon:idle", config)


def test_an_evaluation_plays_a_hybrid_and_counts_overtakes():
    """``bgap.evaluate`` with ``hybrid:idle`` beside ``idle`` on the same seeded episodes
    and ``grid.overtakes=true``: the hybrid's rows carry its fallback's share, every row an
    ``overtakes`` count; where the fallback never acted, the hybrid's episodes are idle's."""
    from bgap.common.config import validate
    from bgap.experiments.config import compose
    from bgap.experiments.evaluate import evaluate

    cfg = validate(compose("evaluate", ["env=dense", "profile=tiny", "grid.overtakes=true"]))
    rows = evaluate(cfg, {"idle": "idle", "h": "hybrid:idle"}, episodes=6, progress=False)
    assert {"overtakes", "fallback_share"} <= set(rows.columns)
    hybrid, idle = rows[rows.policy == "h"], rows[rows.policy == "idle"]
    share = hybrid.fallback_share.iloc[0]
    assert 0.0 <= share <= 1.0 and idle.fallback_share.isna().all()
    if share == 0.0:
        assert hybrid.steps.tolist() == idle.steps.tolist()
    assert (rows.overtakes >= 0).all()

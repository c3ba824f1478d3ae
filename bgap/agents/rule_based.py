"""A rule-based ego: highway-env's IDM and MOBIL logic mapped onto the five meta-actions.

    from bgap.agents.policies import rollout
    rollout(config, "rule", seeds)          # the baseline ``rule`` of every evaluation

A reference a learned policy should approach: it keeps a safe gap with the Intelligent Driver
Model and changes lane by MOBIL's incentive and safety criteria, with highway-env's own
parameters (``IDMVehicle``'s class attributes). It reads only what the learned policies read,
the normalised kinematics observation (presence, x, y, vx, vy; the ego's row absolute, the
others relative), so it runs unchanged on both simulators and at any density.

Why written here: highway-env's ``IDMVehicle`` drives a vehicle directly (continuous
acceleration, its own lane-change timer) and cannot be played as a policy over meta-actions,
which is what every bgap policy is; the mapping (ours) is: SLOWER when IDM asks for more than
``brake`` m/s^2 of deceleration, FASTER when it allows more than ``accelerate`` m/s^2 of
acceleration, a lane change when MOBIL accepts one (politeness 0, highway-env's gain and
safety thresholds), IDLE otherwise.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from highway_env.vehicle.behavior import IDMVehicle

from bgap.common.vocab import EGO_MAX_SPEED, FASTER, IDLE, LANE_LEFT, LANE_RIGHT, LANE_WIDTH, SLOWER

# highway-env's normalisation of the Kinematics observation (KinematicObservation.normalize_obs)
X_RANGE, V_RANGE = 5.0 * EGO_MAX_SPEED, 2.0 * EGO_MAX_SPEED


def idm(speed: np.ndarray, target: Any, gap: np.ndarray, lead_speed: np.ndarray) -> np.ndarray:
    """IDMVehicle.acceleration with highway-env's parameters: ``gap`` centre to centre [m]
    (inf: free road)."""
    a, b = IDMVehicle.COMFORT_ACC_MAX, -IDMVehicle.COMFORT_ACC_MIN
    free = a * (1.0 - np.power(np.maximum(speed, 0.0) / target, IDMVehicle.DELTA))
    wanted = (
        IDMVehicle.DISTANCE_WANTED
        + speed * IDMVehicle.TIME_WANTED
        + speed * (speed - lead_speed) / (2.0 * np.sqrt(a * b))
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        interaction = np.where(np.isfinite(gap), a * (wanted / np.maximum(gap, 1e-2)) ** 2, 0.0)
    return free - interaction


class RuleBasedEgo:
    """IDM + MOBIL over meta-actions, for a batch of observations (module docstring).

    Args:
        lanes: lanes of the road (the observation's y range is ``LANE_WIDTH * lanes``).
        target_speed: the IDM's desired speed [m/s] (the ego's top target speed).
        brake, accelerate: IDM acceleration thresholds [m/s^2] of SLOWER and FASTER.
    """

    def __init__(
        self,
        lanes: int = 4,
        target_speed: float = 30.0,
        brake: float = 1.0,
        accelerate: float = 0.5,
    ) -> None:
        self.y_range = LANE_WIDTH * lanes
        self.lanes, self.target = lanes, target_speed
        self.brake, self.accelerate = brake, accelerate

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=float)
        y0 = obs[:, 0, 2] * self.y_range
        v0 = obs[:, 0, 3] * V_RANGE
        lane0 = np.rint(y0 / LANE_WIDTH).astype(int)
        present = obs[:, 1:, 0] > 0.5
        dx = obs[:, 1:, 1] * X_RANGE
        lane = np.rint((y0[:, None] + obs[:, 1:, 2] * self.y_range) / LANE_WIDTH).astype(int)
        speed = v0[:, None] + obs[:, 1:, 3] * V_RANGE

        def neighbours(target_lane: np.ndarray) -> tuple[np.ndarray, ...]:
            """Gap and speed of the leader and of the follower in ``target_lane``."""
            inside = present & (lane == target_lane[:, None])
            ahead = np.where(inside & (dx > 0), dx, np.inf)
            behind = np.where(inside & (dx <= 0), -dx, np.inf)
            i, j = ahead.argmin(axis=1), behind.argmin(axis=1)
            rows = np.arange(len(obs))
            return ahead[rows, i], speed[rows, i], behind[rows, j], speed[rows, j]

        gap, lead, _, _ = neighbours(lane0)
        current = idm(v0, self.target, gap, lead)
        actions = np.full(len(obs), IDLE)
        actions[current > self.accelerate] = FASTER
        actions[current < -self.brake] = SLOWER
        # MOBIL (politeness 0): the best side lane whose gain beats the threshold, if the new
        # follower would not brake harder than b_safe and no vehicle is alongside.
        settled = np.abs(y0 - lane0 * LANE_WIDTH) < 0.5  # not in the middle of a change
        best = np.full(len(obs), IDMVehicle.LANE_CHANGE_MIN_ACC_GAIN)
        for action, side in ((LANE_LEFT, -1), (LANE_RIGHT, 1)):
            target = lane0 + side
            gap_new, lead_new, back, follower = neighbours(target)
            gain = idm(v0, self.target, gap_new, lead_new) - current
            # the follower's desired speed is unknown: at least its speed (no free-road braking)
            imposed = np.where(
                np.isfinite(back), idm(follower, np.maximum(follower, self.target), back, v0), 0.0
            )
            safe = (imposed >= -IDMVehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED) & (
                np.minimum(gap_new, back) > 1.5 * IDMVehicle.LENGTH
            )
            ok = settled & (target >= 0) & (target < self.lanes) & safe & (gain > best)
            actions[ok], best[ok] = action, gain[ok]
        return actions

    def __repr__(self) -> str:
        return f"RuleBasedEgo(lanes={self.lanes}, target_speed={self.target})"


def rule_based(config: dict[str, Any] | None = None) -> RuleBasedEgo:
    """The rule-based ego for an environment ``config`` (its lanes and top ego speed)."""
    config = config or {}
    speeds = config.get("action", {}).get("target_speeds", [30.0])
    return RuleBasedEgo(lanes=int(config.get("lanes_count", 4)), target_speed=float(max(speeds)))

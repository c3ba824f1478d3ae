"""A rule-based ego: highway-env's IDM and MOBIL logic mapped onto the five meta-actions.

    from bgap.agents.policies import rollout
    rollout(config, "rule", seeds)          # the baseline ``rule`` of every evaluation
    rollout(config, "rule_tuned", seeds)    # its tuned parameters (python -m bgap.tune_rule)
    rollout(config, "idm", seeds)           # IDM only: it never changes lane

A reference a learned policy should approach: it keeps a safe gap with the Intelligent Driver
Model and changes lane by MOBIL's incentive and safety criteria. ``rule`` runs highway-env's
own parameters (``IDMVehicle``'s class attributes, :data:`DEFAULT`); ``rule_tuned`` the ones
``bgap.tune_rule`` chose on validation episodes for the traffic at hand (:func:`tuned`). It
reads only what the learned policies read, the normalised kinematics observation (presence,
x, y, vx, vy; the ego's row absolute, the others relative), so it runs unchanged on both
simulators and at any density.

Why written here: highway-env's ``IDMVehicle`` drives a vehicle directly (continuous
acceleration, its own lane-change timer) and cannot be played as a policy over meta-actions,
which is what every bgap policy is; the mapping (ours) is: SLOWER when IDM asks for more than
``brake`` m/s^2 of deceleration, FASTER when it allows more than ``accelerate`` m/s^2 of
acceleration, a lane change when MOBIL accepts one (``IDMVehicle.mobil``: the new follower
must not brake harder than ``b_safe``, the own gain plus ``politeness`` x the followers'
must beat the threshold), IDLE otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from highway_env.vehicle.behavior import IDMVehicle

from bgap.common.errors import ConfigError
from bgap.common.presets import PIPELINE_DIR, shipped
from bgap.traffic.road import EGO_MAX_SPEED, FASTER, IDLE, LANE_LEFT, LANE_RIGHT, LANE_WIDTH, SLOWER

# highway-env's normalisation of the Kinematics observation (KinematicObservation.normalize_obs)
X_RANGE, V_RANGE = 5.0 * EGO_MAX_SPEED, 2.0 * EGO_MAX_SPEED


@dataclass(frozen=True)
class RuleParams:
    """IDM's and MOBIL's parameters (highway-env's ``IDMVehicle`` names, its values the
    defaults): the six ``bgap.tune_rule`` searches, and the fixed ones."""

    time_wanted: float = IDMVehicle.TIME_WANTED
    """IDM's desired time gap [s]."""
    comfort_acc_max: float = IDMVehicle.COMFORT_ACC_MAX
    """IDM's maximum acceleration a [m/s^2]."""
    comfort_acc_min: float = IDMVehicle.COMFORT_ACC_MIN
    """IDM's comfortable deceleration, negative (-b) [m/s^2]."""
    politeness: float = IDMVehicle.POLITENESS
    """MOBIL's weight of the followers' accelerations in the incentive."""
    lane_change_min_acc_gain: float = IDMVehicle.LANE_CHANGE_MIN_ACC_GAIN
    """MOBIL's threshold [m/s^2]: the incentive a lane change must beat."""
    lane_change_max_braking_imposed: float = IDMVehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED
    """MOBIL's safe braking b_safe [m/s^2] the new follower may be made to brake."""
    distance_wanted: float = IDMVehicle.DISTANCE_WANTED
    """IDM's jam distance, centre to centre [m] (not searched)."""
    delta: float = IDMVehicle.DELTA
    """IDM's velocity exponent (not searched)."""


DEFAULT = RuleParams()
"""highway-env's parameters: the baseline ``rule`` and the tuning's trial 0."""


def idm(
    speed: np.ndarray,
    target: Any,
    gap: np.ndarray,
    lead_speed: np.ndarray,
    params: RuleParams = DEFAULT,
) -> np.ndarray:
    """IDMVehicle.acceleration (highway-env's parameters unless ``params``): ``gap`` centre
    to centre [m] (inf: free road)."""
    a, b = params.comfort_acc_max, -params.comfort_acc_min
    free = a * (1.0 - np.power(np.maximum(speed, 0.0) / target, params.delta))
    wanted = (
        params.distance_wanted
        + speed * params.time_wanted
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
        params: IDM's and MOBIL's parameters (default: highway-env's).
        lane_changes: False keeps the lane (IDM only, the baseline ``idm``).
    """

    def __init__(
        self,
        lanes: int = 4,
        target_speed: float = 30.0,
        brake: float = 1.0,
        accelerate: float = 0.5,
        params: RuleParams = DEFAULT,
        lane_changes: bool = True,
    ) -> None:
        self.y_range = LANE_WIDTH * lanes
        self.lanes, self.target = lanes, target_speed
        self.brake, self.accelerate = brake, accelerate
        self.params, self.lane_changes = params, lane_changes

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=float)
        p = self.params
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

        def follows(
            behind: np.ndarray, follower: np.ndarray, gap: np.ndarray, lead: np.ndarray
        ) -> np.ndarray:
            """The IDM acceleration of a follower ``behind`` m back (inf: none, 0) with
            ``gap`` to its leader: its desired speed is unknown, so at least its speed (no
            free-road braking)."""
            return np.where(
                np.isfinite(behind),
                idm(follower, np.maximum(follower, self.target), gap, lead, p),
                0.0,
            )

        gap, lead, back0, follower0 = neighbours(lane0)
        current = idm(v0, self.target, gap, lead, p)
        actions = np.full(len(obs), IDLE)
        actions[current > self.accelerate] = FASTER
        actions[current < -self.brake] = SLOWER
        if not self.lane_changes:
            return actions
        # MOBIL: the best side lane whose incentive beats the threshold, if the new follower
        # would not brake harder than b_safe and no vehicle is alongside.
        settled = np.abs(y0 - lane0 * LANE_WIDTH) < 0.5  # not in the middle of a change
        best = np.full(len(obs), p.lane_change_min_acc_gain)
        for action, side in ((LANE_LEFT, -1), (LANE_RIGHT, 1)):
            target = lane0 + side
            gap_new, lead_new, back, follower = neighbours(target)
            gain = idm(v0, self.target, gap_new, lead_new, p) - current
            imposed = follows(back, follower, back, v0)
            if p.politeness:  # the followers' gains: the new one behind the ego, the old one
                # behind the ego's leader (highway-env's IDMVehicle.mobil)
                others = (
                    imposed
                    - follows(back, follower, back + gap_new, lead_new)
                    + follows(back0, follower0, back0 + gap, lead)
                    - follows(back0, follower0, back0, v0)
                )
                gain = gain + p.politeness * others
            safe = (imposed >= -p.lane_change_max_braking_imposed) & (
                np.minimum(gap_new, back) > 1.5 * IDMVehicle.LENGTH
            )
            ok = settled & (target >= 0) & (target < self.lanes) & safe & (gain > best)
            actions[ok], best[ok] = action, gain[ok]
        return actions

    def __repr__(self) -> str:
        kind = "" if self.lane_changes else ", lane_changes=False"
        return f"RuleBasedEgo(lanes={self.lanes}, target_speed={self.target}{kind}, {self.params})"


SITUATIONS = ("sparse", "dense", "stock")
"""The tuned rule's presets (the pipeline's ``results/presets/rule/<situation>.yaml``): one
per density of bgap's traffic, one for highway-env's stock traffic (both densities)."""


@dataclass(frozen=True)
class TunedRule(RuleParams):
    """A tuned preset: the parameters and the traffic they were tuned in."""

    situation: str = ""
    """sparse, dense or stock (:data:`SITUATIONS`)."""
    observed_vehicles: int = 0
    """The observation's rows in that density (0: any, the stock preset)."""


def tuned(config: dict[str, Any]) -> RuleParams:
    """The tuned parameters for the traffic of environment ``config``: the stock preset in
    highway-env's stock traffic, otherwise the preset of the density its observation rows
    match (replayed tables included)."""
    stock = config.get("behavior", {}).get("name") == "stock"
    rows = int(config.get("observation", {}).get("vehicles_count", 0))
    for situation in ("stock",) if stock else ("sparse", "dense"):
        preset = shipped(TunedRule, "rule", situation)
        if preset is None:
            continue
        if stock or preset.observed_vehicles == rows:
            return RuleParams(**{f.name: getattr(preset, f.name) for f in fields(RuleParams)})
    traffic = "stock traffic" if stock else f"{rows} observed vehicles"
    raise ConfigError(
        f"rule_tuned has no tuned preset for {traffic} in {Path(PIPELINE_DIR) / 'rule'}; tune "
        "one with dvc repro tune_rule, or leave rule_tuned out of baselines"
    )


def rule_based(
    config: dict[str, Any] | None = None, params: RuleParams = DEFAULT, lane_changes: bool = True
) -> RuleBasedEgo:
    """The rule-based ego for an environment ``config`` (its lanes and top ego speed)."""
    config = config or {}
    speeds = config.get("action", {}).get("target_speeds", [30.0])
    return RuleBasedEgo(
        lanes=int(config.get("lanes_count", 4)),
        target_speed=float(max(speeds)),
        params=params,
        lane_changes=lane_changes,
    )

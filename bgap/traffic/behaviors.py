"""Driver behaviours: highway-env IDM/MOBIL vehicles with per-vehicle, per-class parameters.

highway-env keeps IDM and MOBIL parameters as class attributes of ``IDMVehicle`` and
evaluates every IDM prediction with the *deciding* vehicle's parameters. For a mix of
driver classes we need each vehicle's own parameters, so :class:`BehaviorVehicle` stores
them as instance attributes and evaluates a vehicle's IDM acceleration with that vehicle's
parameters when it is an IDM driver (falling back to highway-env's rule for the ego, which
is not). It also drops highway-env's clipping of the IDM target speed to the lane speed
limit (added upstream in 2023), without which the paper's aggressive drivers (v0 = 40 m/s)
could never overspeed on a 30 m/s highway.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any, Optional

import numpy as np
from highway_env import utils
from highway_env.road.road import Road
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.kinematics import Vehicle

from bgap.common.errors import check
from bgap.common.presets import shipped
from bgap.common.vocab import COLORS, PAPER_MIXES


@dataclass
class DriverParams:
    """IDM and MOBIL parameters of one driver class. ``None`` keeps highway-env's default.

    A class whose parameters are all ``None`` is highway-env's stock ``IDMVehicle``, unchanged.
    """

    time_gap: Optional[float] = None
    """IDM desired time gap T [s] (highway-env TIME_WANTED, 1.5)."""
    min_distance: Optional[float] = None
    """IDM minimum bumper-to-bumper gap s0 [m]; highway-env measures centre to centre, so its
    DISTANCE_WANTED is s0 + vehicle length (default 5 + 5)."""
    acc: Optional[float] = None
    """IDM maximum comfortable acceleration a [m/s^2] (COMFORT_ACC_MAX, 3)."""
    dec: Optional[float] = None
    """IDM comfortable deceleration b [m/s^2], positive (-COMFORT_ACC_MIN, 5)."""
    delta: Optional[float] = None
    """IDM acceleration exponent; ``None`` draws it in [3.5, 4.5] as highway-env does."""
    v0: Optional[float] = None
    """IDM desired speed [m/s]; ``None`` keeps highway-env's (the initial speed, <= 30)."""
    v0_spread: float = 0.0
    """Relative uniform spread of v0 per vehicle: v0 * U(1 - s, 1 + s)."""
    politeness: Optional[float] = None
    """MOBIL politeness p in [0, 1] (POLITENESS, 0)."""
    min_acc_gain: Optional[float] = None
    """MOBIL minimum acceleration gain [m/s^2] (LANE_CHANGE_MIN_ACC_GAIN, 0.2)."""
    b_safe: Optional[float] = None
    """MOBIL safe braking limit imposed on the new follower [m/s^2] (2)."""
    acc_max: Optional[float] = None
    """Physical acceleration/braking limit [m/s^2] (ACC_MAX, 6)."""

    def __post_init__(self) -> None:
        for name in ("time_gap", "min_distance", "acc", "dec", "v0", "acc_max", "delta"):
            v = getattr(self, name)
            check(v is None or v > 0, f"behavior.*.{name}", v, "must be positive or null")
        for name in ("min_acc_gain", "b_safe"):
            v = getattr(self, name)
            check(v is None or v >= 0, f"behavior.*.{name}", v, "must be >= 0 or null")
        p = self.politeness
        check(p is None or 0 <= p <= 1, "behavior.*.politeness", p, "must lie in [0, 1]")
        s = self.v0_spread
        check(0 <= s < 1, "behavior.*.v0_spread", s, "must lie in [0, 1)")

    @property
    def is_stock(self) -> bool:
        return is_stock(asdict(self))


@dataclass
class BehaviorConfig:
    """Parameters of the two driver classes (config group ``behavior``)."""

    name: str = "paper"
    conservative: DriverParams = field(default_factory=DriverParams)
    aggressive: DriverParams = field(default_factory=DriverParams)
    converged: bool = True
    """False in a calibrated preset whose search ended outside its tolerance: commands refuse
    it unless ``behavior.converged=true`` says it is used knowingly."""


def env_behavior(behavior: BehaviorConfig) -> dict[str, Any]:
    """``behavior`` as an environment config's ``behavior`` entry (both backends read it)."""
    return {
        "name": behavior.name,
        "conservative": asdict(behavior.conservative),
        "aggressive": asdict(behavior.aggressive),
    }


def paper_behavior() -> BehaviorConfig:
    """Table I of the paper, from its one home: the packaged preset ``behavior/paper.yaml``
    (read once per version of the file: every environment built takes these defaults)."""
    return shipped(BehaviorConfig, "behavior", "paper", "behavior/paper.yaml is missing")


# Field of DriverParams -> IDMVehicle attribute, with the conversion from paper units (also
# the vectorised backend's mapping, bgap.sim.vector).
DRIVER_ATTRIBUTES = {
    "time_gap": ("TIME_WANTED", lambda v: v),
    "min_distance": ("DISTANCE_WANTED", lambda v: v + Vehicle.LENGTH),  # bumper -> centre gap
    "acc": ("COMFORT_ACC_MAX", lambda v: v),
    "dec": ("COMFORT_ACC_MIN", lambda v: -v),
    "delta": ("DELTA", lambda v: v),
    "politeness": ("POLITENESS", lambda v: v),
    "min_acc_gain": ("LANE_CHANGE_MIN_ACC_GAIN", lambda v: v),
    "b_safe": ("LANE_CHANGE_MAX_BRAKING_IMPOSED", lambda v: v),
    "acc_max": ("ACC_MAX", lambda v: v),
}


def is_stock(params: Mapping[str, Any]) -> bool:
    """True when a class leaves every parameter to highway-env (the stock IDM)."""
    return all(params.get(k) is None for k in (*DRIVER_ATTRIBUTES, "v0"))


class BehaviorVehicle(IDMVehicle):
    """An IDM/MOBIL driver whose parameters are its own, not its class's."""

    # Allow v0 = 40 m/s to be approached without the kinematic model's 40 m/s cap biting.
    MAX_SPEED = 50.0

    def acceleration(
        self,
        ego_vehicle: Vehicle,
        front_vehicle: Vehicle | None = None,
        rear_vehicle: Vehicle | None = None,
    ) -> float:
        """IDM acceleration of ``ego_vehicle`` with *its own* parameters when it is an IDM
        driver; its desired speed is not clipped to the speed limit if it is one of ours."""
        if not ego_vehicle or not isinstance(ego_vehicle, Vehicle):
            return 0.0
        driver = ego_vehicle if isinstance(ego_vehicle, IDMVehicle) else self
        target = getattr(ego_vehicle, "target_speed", 0)
        if not isinstance(ego_vehicle, BehaviorVehicle) and ego_vehicle.lane is not None:
            if ego_vehicle.lane.speed_limit is not None:  # highway-env's rule for the others
                target = np.clip(target, 0, ego_vehicle.lane.speed_limit)
        acc = driver.COMFORT_ACC_MAX * (
            1 - np.power(max(ego_vehicle.speed, 0) / abs(utils.not_zero(target)), driver.DELTA)
        )
        if front_vehicle:
            d = ego_vehicle.lane_distance_to(front_vehicle)
            gap = driver.desired_gap(ego_vehicle, front_vehicle)
            acc -= driver.COMFORT_ACC_MAX * np.power(gap / utils.not_zero(d), 2)
        return float(acc)


def create_driver(
    road: Road, label: str, params: Mapping[str, Any], spacing: float, rng: np.random.Generator
) -> IDMVehicle:
    """Spawn one background vehicle of class ``label`` behind the last one, as highway-env does.

    A stock class gives an unmodified ``IDMVehicle`` (highway-v0's traffic); otherwise a
    :class:`BehaviorVehicle` with the given parameters, unset ones keeping highway-env's values.
    """
    stock = is_stock(params)
    vehicle = (IDMVehicle if stock else BehaviorVehicle).create_random(road, spacing=spacing)
    set_driver_params(vehicle, params, rng)
    vehicle.bgap_label = label
    vehicle.color = COLORS[label]
    return vehicle


def set_driver_params(
    vehicle: IDMVehicle, params: Mapping[str, Any], rng: np.random.Generator
) -> None:
    """Give ``vehicle`` a class's parameters (unset ones: highway-env's; no ``delta``: its
    draw in [3.5, 4.5]; ``v0``: the desired speed, spread per vehicle)."""
    if params.get("delta") is None:
        vehicle.randomize_behavior()  # highway-env's DELTA draw in [3.5, 4.5]
    for key, (attr, convert) in DRIVER_ATTRIBUTES.items():
        if params.get(key) is not None:
            setattr(vehicle, attr, float(convert(params[key])))
    if params.get("v0") is not None:
        spread = float(params.get("v0_spread") or 0.0)
        vehicle.target_speed = float(params["v0"]) * rng.uniform(1 - spread, 1 + spread)


def count_aggressive(mix: float, n: int) -> int:
    """round(mix * n), halves rounded up (Python's round() would round 2.5 to 2)."""
    return int(np.floor(mix * n + 0.5))


def episode_mix(config: Mapping[str, Any], rng: np.random.Generator) -> float:
    """The aggressive fraction of the next episode of an environment with ``config``: its
    ``mix``, or a draw from ``rng`` (the env's :func:`mix_stream`) when ``mix_sampling`` is
    ``uniform`` or ``paper``. The one place both backends decide an episode's mix."""
    mode = config.get("mix_sampling", "fixed")
    return float(config["mix"]) if mode == "fixed" else sample_mix(rng, mode)


def mix_stream(seed: int) -> np.random.Generator:
    """The random stream of the per-episode mix draws of an env seeded ``seed``: its own, so
    that the traffic's draws are the same with and without mix sampling."""
    return np.random.default_rng(seed + 7919)


def sample_mix(rng: np.random.Generator, mode: str) -> float:
    """One training mix: ``uniform`` in [0, 1] or ``paper`` (one of the paper's mixes)."""
    return float(rng.uniform(0, 1) if mode == "uniform" else rng.choice(PAPER_MIXES))

"""The scenario every simulator runs: road, traffic, reward, and their one validator.

Both backends (highway-env's :class:`~bgap.envs.highway.BehaviorHighwayEnv` and the
vectorised :class:`~bgap.sim.vector.VectorHighway`) take the same highway-env style config
dictionary. This module owns it: the typed schemas of the ``env`` and ``reward`` config
groups, the translation of a bgap config into that dictionary (:func:`env_config`), its
defaults (:func:`default_config`: highway-env's ``highway-v0`` defaults overlaid with bgap's
schema defaults and Table I's drivers) and the checks both backends run on it
(:func:`check_config`).
"""

from __future__ import annotations

import copy
import difflib
import functools
import inspect
import math
from dataclasses import asdict, dataclass, field
from importlib import import_module
from typing import Any, Protocol

import numpy as np
from highway_env.envs.highway_env import HighwayEnv

from bgap.common.errors import ConfigError, check
from bgap.common.presets import shipped
from bgap.common.vocab import CLASSES, MIX_SAMPLING
from bgap.traffic.behaviors import BehaviorConfig, env_behavior, paper_behavior
from bgap.traffic.replay import TrafficConfig


@dataclass
class EnvConfig:
    """Road, traffic density and timing (config group ``env``: ``sparse`` or ``dense``)."""

    name: str = "sparse"
    vehicles_count: int = 5
    """Background vehicles n."""
    observed_vehicles: int = 5
    """Rows V of the observation, the ego's row included (highway-env's convention)."""
    lanes_count: int = 4
    duration: float = 60.0
    """Episode length [s]."""
    policy_frequency: int = 1
    simulation_frequency: int = 15
    vehicles_density: float = 1.0
    ego_speeds: list[float] = field(default_factory=lambda: [10.0, 15.0, 20.0, 25.0, 30.0])
    """Target speeds [m/s] the ego's FASTER/SLOWER meta-actions step through."""

    def __post_init__(self) -> None:
        check(self.vehicles_count >= 0, "env.vehicles_count", self.vehicles_count, "must be >= 0")
        check(
            self.observed_vehicles >= 1,
            "env.observed_vehicles",
            self.observed_vehicles,
            "must be >= 1 (the ego's row)",
        )
        check(self.lanes_count >= 1, "env.lanes_count", self.lanes_count, "must be >= 1")
        speeds = self.ego_speeds
        increasing = all(a < b for a, b in zip(speeds, speeds[1:], strict=False))
        check(
            len(speeds) >= 1 and speeds[0] > 0 and increasing,
            "env.ego_speeds",
            speeds,
            "must be positive target speeds in increasing order",
        )
        check(self.duration > 0, "env.duration", self.duration, "must be positive")
        check(self.policy_frequency >= 1, "env.policy_frequency", self.policy_frequency, ">= 1")
        check(
            self.simulation_frequency % self.policy_frequency == 0,
            "env.simulation_frequency",
            self.simulation_frequency,
            "must be a multiple of env.policy_frequency",
        )
        check(self.vehicles_density > 0, "env.vehicles_density", self.vehicles_density, "> 0")
        check(
            len(self.ego_speeds) >= 1 and min(self.ego_speeds) >= 0,
            "env.ego_speeds",
            self.ego_speeds,
            "needs at least one non-negative speed",
        )


@dataclass
class RewardConfig:
    """Weights of the reward terms R = r_C + r_LC + r_RL + r_HS (config group ``reward``)."""

    name: str = "highway"
    collision: float = -1.0
    lane_change: float = 0.0
    right_lane: float = 0.1
    high_speed: float = 0.4
    speed_range: list[float] = field(default_factory=lambda: [20.0, 30.0])
    """Forward speeds [m/s] mapped linearly to r_HS in [0, 1]."""
    normalize: bool = True
    """Map the summed reward to [0, 1] using the most negative and most positive weights."""
    converged: bool = True
    """``false`` in a preset that a sweep wrote before it finished its trials: commands
    refuse it unless ``reward.converged=true`` says it is used knowingly."""

    def __post_init__(self) -> None:
        check(
            len(self.speed_range) == 2 and self.speed_range[0] < self.speed_range[1],
            "reward.speed_range",
            self.speed_range,
            "must be [low, high] with low < high",
        )


class Scenario(Protocol):
    """What :func:`env_config` reads: any bgap command config has these fields."""

    env: EnvConfig
    reward: RewardConfig
    behavior: BehaviorConfig
    mix: float
    radius: float
    traffic: TrafficConfig


# The paper's observation: presence, x, y, vx, vy of V vehicles (the ego's row first),
# relative to the ego, normalised; vehicles behind are seen too.
OBSERVATION: dict[str, Any] = {
    "type": "Kinematics",
    "features": ["presence", "x", "y", "vx", "vy"],
    "absolute": False,
    "normalize": True,
    "clip": True,
    "see_behind": True,
    "order": "sorted",
}

REWARD_TERMS = {
    "collision_reward": "collision",
    "lane_change_reward": "lane_change",
    "right_lane_reward": "right_lane",
    "high_speed_reward": "high_speed",
}
"""highway-env's name of each reward term -> its weight in :class:`RewardConfig`."""


def env_config(cfg: Scenario, mix_sampling: str = "fixed") -> dict[str, Any]:
    """Translate a bgap config into the environment's config dictionary (both backends).

    ``mix_sampling``: ``fixed`` keeps ``cfg.mix``; ``uniform`` or ``paper`` draw a new mix at
    every reset (training across mixes)."""
    e, r = cfg.env, cfg.reward
    traffic = getattr(cfg, "traffic", None)
    replay = {"traffic": traffic.as_config()} if traffic and traffic.source != "simulated" else {}
    return {
        "observation": {**OBSERVATION, "vehicles_count": e.observed_vehicles},
        "action": {"type": "DiscreteMetaAction", "target_speeds": list(e.ego_speeds)},
        "lanes_count": e.lanes_count,
        "vehicles_count": e.vehicles_count,
        "vehicles_density": e.vehicles_density,
        "duration": e.duration,
        "policy_frequency": e.policy_frequency,
        "simulation_frequency": e.simulation_frequency,
        **{key: getattr(r, weight) for key, weight in REWARD_TERMS.items()},
        "reward_speed_range": list(r.speed_range),
        "normalize_reward": r.normalize,
        "mix": cfg.mix,
        "mix_sampling": mix_sampling,
        "perception_radius": cfg.radius,
        "behavior": env_behavior(cfg.behavior),
        **replay,
    }


FAST_SIMULATION_FREQUENCY = 10
"""The opt-in fast mode (ours): ``env.simulation_frequency=10`` instead of
highway-env's 15 Hz, a third fewer frames per policy step on either backend. Its traffic
differs from highway-env's frame by frame, but on the parity study's episodes (dense, mixes
0, 0.5 and 1, the vector backend against the highway-env rows of ``results/parity``) every
collision, speed and lane-change rate stays within its interval; 5 Hz does not
(``tests/test_sim.py::test_the_fast_mode_passes_the_parity_study_and_5_hz_does_not``)."""


def fast_mode(config: dict[str, Any]) -> dict[str, Any]:
    """``config`` (an environment config dictionary) in the fast mode: the same scenario
    simulated at :data:`FAST_SIMULATION_FREQUENCY`."""
    return {**config, "simulation_frequency": FAST_SIMULATION_FREQUENCY}


def contact_dx(x: np.ndarray, y: np.ndarray, crashed: np.ndarray) -> float:
    """``info["contact_dx"]`` of both backends: after a step that ended in the ego's crash,
    the longitudinal offset [m] (other minus ego) of the crashed vehicle nearest the ego,
    i.e. the one it touched (> 0: ahead, < 0: behind); 0 when the ego has not crashed (not
    NaN: infos must compare equal, gymnasium's determinism check). Arrays over the road's
    vehicles, the ego first."""
    if not crashed[0] or not np.any(crashed[1:]):
        return 0.0
    distance = np.hypot(x[1:] - x[0], y[1:] - y[0])
    distance[~np.asarray(crashed[1:], dtype=bool)] = np.inf
    return float(x[1 + int(np.argmin(distance))] - x[0])


@dataclass
class _Defaults:
    env: EnvConfig = field(default_factory=EnvConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    behavior: BehaviorConfig = field(default_factory=paper_behavior)
    mix: float = 0.5
    radius: float = 180.0


def default_config() -> dict[str, Any]:
    """highway-env's ``highway-v0`` defaults overlaid with bgap's: the schema defaults above
    (sparse traffic, highway-env's reward weights) and Table I's drivers at mix 0.5."""
    return {**HighwayEnv.default_config(), **env_config(_Defaults())}


def full_config(config: dict[str, Any]) -> dict[str, Any]:
    """:func:`default_config` updated with ``config`` (:func:`merged_config`), checked with
    :func:`check_config`."""
    full = merged_config(default_config(), config)
    check_config(full)
    return full


OPTIONAL_KEYS = ("traffic",)
"""Keys a config may add to the defaults: replayed traffic (:func:`env_config`)."""


def merged_config(base: dict[str, Any], config: dict[str, Any] | None) -> dict[str, Any]:
    """``base`` updated with ``config``, nested dicts merged all the way down (a user's
    ``{"observation": {"vehicles_count": 40}}`` keeps the observation's type and features;
    highway-env's own update would drop them). A nested dict of another ``type`` replaces
    the default's. A key neither highway-env nor bgap knows is refused, naming the nearest
    known key, and so is a partial ``behavior`` (both classes, every parameter)."""
    config = dict(config or {})
    unknown = sorted(set(config) - set(base) - set(OPTIONAL_KEYS))
    if unknown:
        close = difflib.get_close_matches(unknown[0], list(base), n=1)
        hint = f"did you mean {close[0]!r}?" if close else "see the environment page's keys"
        raise ConfigError(f"{unknown[0]!r} is not a setting of the environment ({hint})")
    if isinstance(config.get("behavior"), dict):
        _check_behavior(config["behavior"])
    merged = copy.deepcopy(base)
    for key, value in config.items():
        merged[key] = _merge(merged.get(key), value)
    for key in NESTED_TYPES:
        if isinstance(config.get(key), dict) and isinstance(merged.get(key), dict):
            _check_nested(key, config[key], merged[key].get("type"))
    return merged


NESTED_TYPES = {
    "observation": (
        "highway_env.envs.common.observation",
        {
            "Kinematics": "KinematicObservation",
            "OccupancyGrid": "OccupancyGridObservation",
            "KinematicsGoal": "KinematicsGoalObservation",
            "TimeToCollision": "TimeToCollisionObservation",
            "GrayscaleObservation": "GrayscaleObservation",
            "AttributesObservation": "AttributesObservation",
            "MultiAgentObservation": "MultiAgentObservation",
            "TupleObservation": "TupleObservation",
            "LidarObservation": "LidarObservation",
            "ExitObservation": "ExitObservation",
        },
    ),
    "action": (
        "highway_env.envs.common.action",
        {
            "ContinuousAction": "ContinuousAction",
            "DiscreteAction": "DiscreteAction",
            "DiscreteMetaAction": "DiscreteMetaAction",
            "MultiAgentAction": "MultiAgentAction",
        },
    ),
}
"""The nested settings whose keys are their type's: highway-env's factories
(``observation_factory``, ``action_factory``) map each ``type`` to a class that takes its
settings as keyword arguments and silently drops any it does not know."""


def _check_nested(key: str, given: dict[str, Any], kind: Any) -> None:
    """Refuse a key of ``given`` (the ``observation`` or ``action`` dict a user passed) that
    its type's class does not take: ``{"observation": {"vehicle_count": 40}}`` would
    otherwise observe the default 5 vehicles without a word."""
    module, classes = NESTED_TYPES[key]
    check(kind in classes, f"{key}.type", kind, f"use one of {sorted(classes)}")
    known = {"type", *_parameters(getattr(import_module(module), classes[kind]))}
    unknown = sorted(set(given) - known)
    if unknown:
        close = difflib.get_close_matches(unknown[0], sorted(known), n=1)
        hint = f"did you mean {close[0]!r}?" if close else f"its keys: {sorted(known)}"
        raise ConfigError(f"{key}.{unknown[0]} is not a setting of the {kind} {key} ({hint})")


@functools.cache
def _parameters(cls: type) -> frozenset[str]:
    """The keyword parameters of ``cls``'s constructor and of the constructors it calls
    (inspected once per class and process)."""
    names = set()
    for klass in cls.__mro__:
        if klass.__module__.startswith("highway_env") and "__init__" in vars(klass):
            for name, p in inspect.signature(klass.__init__).parameters.items():
                if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY):
                    names.add(name)
    return frozenset(names - {"self", "env"})


def _merge(base: Any, value: Any) -> Any:
    if not isinstance(base, dict) or not isinstance(value, dict):
        return copy.deepcopy(value)
    if "type" in value and value["type"] != base.get("type"):
        return copy.deepcopy(value)  # another observation or action type: its own keys
    out = dict(base)
    for key, item in value.items():
        out[key] = _merge(base.get(key), item)
    return out


def _check_behavior(behavior: dict[str, Any]) -> None:
    """A ``behavior`` dict names both classes with every parameter (one left out would
    silently keep another preset's values)."""
    fields = set(asdict(paper_behavior().conservative))
    for cls in CLASSES:
        given = behavior.get(cls)
        check(
            isinstance(given, dict),
            "behavior",
            sorted(behavior),
            f"is partial: give both classes {list(CLASSES)}, each with {sorted(fields)}",
        )
        missing = sorted(fields - set(given))
        check(not missing, f"behavior.{cls}", sorted(given), f"is partial: it lacks {missing}")


def check_config(config: dict[str, Any]) -> None:
    """The checks both backends run on their config dictionary; :class:`ConfigError` names
    the key. (Composed bgap configs are checked earlier by their schemas; this guards the
    dictionaries users pass to ``gym.make`` or ``VectorHighway`` directly.)"""
    mix, radius = config["mix"], config["perception_radius"]
    check(
        _number(mix) and 0.0 <= float(mix) <= 1.0,
        "mix",
        mix,
        "must lie in [0, 1], the fraction of aggressive vehicles (e.g. mix=0.6)",
    )
    check(
        _number(radius) and radius > 0,
        "radius",
        radius,
        "must be a positive perception distance in metres (e.g. radius=90; the "
        "environment's key: perception_radius)",
    )
    sampling = config.get("mix_sampling", "fixed")
    check(sampling in MIX_SAMPLING, "mix_sampling", sampling, f"use one of {MIX_SAMPLING}")
    unknown = set(config["behavior"]) - {"name", *CLASSES}
    check(not unknown, "behavior", sorted(unknown), f"unknown classes; use {list(CLASSES)}")
    n = config["vehicles_count"]
    check(_whole(n) and n >= 0, "vehicles_count", n, "must be an integer >= 0")
    observation = config.get("observation") or {}
    if observation.get("type") == "Kinematics":
        rows, order = observation.get("vehicles_count", 5), observation.get("order", "sorted")
        check(
            _whole(rows) and rows >= 1,
            "observation.vehicles_count",
            rows,
            "must be an integer >= 1 (the ego's row, then the vehicles it observes)",
        )
        check(
            order in ("sorted", "shuffled"),
            "observation.order",
            order,
            "use 'sorted' (nearest first) or 'shuffled'",
        )
    lanes = config.get("lanes_count", 1)
    check(_whole(lanes) and lanes >= 1, "lanes_count", lanes, "must be an integer >= 1")
    duration = config.get("duration", 1.0)
    check(
        _number(duration) and duration > 0,
        "duration",
        duration,
        "must be a positive number of seconds",
    )
    speeds = (config.get("action") or {}).get("target_speeds", [1.0])
    check(
        isinstance(speeds, (list, tuple, np.ndarray))
        and len(speeds) >= 1
        and all(_number(v) and v > 0 for v in speeds),
        "action.target_speeds",
        speeds,
        "must be one or more positive speeds [m/s] (env.ego_speeds)",
    )
    sim, pol = config["simulation_frequency"], config["policy_frequency"]
    for key, hz in (("simulation_frequency", sim), ("policy_frequency", pol)):
        check(_whole(hz) and hz >= 1, key, hz, "must be a whole number of steps a second >= 1")
    check(
        sim % pol == 0,
        "simulation_frequency",
        sim,
        f"must be a multiple of policy_frequency ({pol})",
    )
    traffic = config.get("traffic")
    if traffic:  # replayed traffic (bgap.traffic.replay): the schema's checks
        TrafficConfig(**{k: v for k, v in traffic.items() if k != "name"})


def _number(value: Any) -> bool:
    """A finite int or float (not a bool, a string or None)."""
    return (
        isinstance(value, (int, float, np.integer, np.floating))
        and not isinstance(value, bool)
        and math.isfinite(value)
    )


def _whole(value: Any) -> bool:
    """An int (not a bool; a float such as 5.0 would reach array shapes and ranges)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def env_preset(name: str) -> EnvConfig:
    """The ``env`` group's packaged preset ``name`` (``env/<name>.yaml``) as an EnvConfig."""
    return shipped(EnvConfig, "env", name, f"density {name!r} has no preset env/{name}.yaml")

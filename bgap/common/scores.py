"""The score bgap's choices rank by: a collision measure among policies fast enough.

One definition for every choice made on validation episodes: a constrained sweep's trials,
the tuned rule-based ego's parameters and a training's checkpoint under the ``per_km`` rule.
It sits on the ground floor because the training monitor (agents) and the analysis both
read it, with the one definition of an episode's distance and of collisions per 100 km.
"""

from __future__ import annotations

from typing import Any

from bgap.common.vocab import SPEED_FLOOR

PER_KM = 100_000.0
"""Metres in the unit of exposure-normalised safety: collisions per 100 km."""


def episode_distance(episodes: Any, policy_frequency: float) -> Any:
    """Each episode's metres driven, from a rollout's table (``avg_speed``, ``steps``): its
    mean speed (one sample per policy step) x its duration (steps / policy frequency)."""
    return episodes.avg_speed * episodes.steps / policy_frequency


def collisions_per_100km(crashed: Any, distance: Any) -> float:
    """Collisions per 100 km over episodes (``distance`` in m): an episode ends at its first
    crash, so the crashes count events over the distance driven."""
    return float(crashed.sum() / distance.sum() * PER_KM)


def constrained_score(
    collisions: float, speed: float, idle_speed: float, floor: float = SPEED_FLOOR
) -> float:
    """Lower is better: the collisions (% of episodes, or per 100 km) of a policy whose mean
    speed reaches ``floor`` x idle's on the same episodes, at most 100; below that, 100 + the
    shortfall in % of the floor, so any policy fast enough ranks above any that is not. (Per
    100 km has no ceiling of its own: a rate of 100 or more, a collision every kilometre,
    scores 100, and the faster of two such ranks first where the caller breaks ties.)"""
    need = floor * idle_speed
    return min(collisions, 100.0) if speed >= need else 100.0 + 100.0 * (need - speed) / need

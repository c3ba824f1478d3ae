"""The score bgap's choices rank by: a collision measure among policies fast enough.

One definition for every choice made on validation episodes: a constrained sweep's trials,
the tuned rule-based ego's parameters and a training's checkpoint under the ``per_km`` rule.
It sits on the ground floor because the training monitor (agents) and the analysis both
read it.
"""

from __future__ import annotations

from bgap.common.vocab import SPEED_FLOOR

PER_KM = 100_000.0
"""Metres in the unit of exposure-normalised safety: collisions per 100 km."""


def constrained_score(
    collisions: float, speed: float, idle_speed: float, floor: float = SPEED_FLOOR
) -> float:
    """Lower is better: the collisions (% of episodes, or per 100 km) of a policy whose mean
    speed reaches ``floor`` x idle's on the same episodes; below that, 100 + the shortfall in %
    of the floor, so any policy fast enough ranks above any that is not."""
    need = floor * idle_speed
    return collisions if speed >= need else 100.0 + 100.0 * (need - speed) / need

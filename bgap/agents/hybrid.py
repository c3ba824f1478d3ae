"""A learned policy with a rule-based safety fallback: the generalisation study's hybrid.

    hybrid = Hybrid(learned, config, threshold=2.0)   # learned: any Policy
    actions = hybrid(obs, rngs)                        # the rule's where a collision is near
    hybrid.share                                       # the fallback's share of decisions

Each decision is the learned policy's meta-action, except where some observed vehicle is on
a collision course with the ego (it overlaps the ego's lane laterally and closes in, ahead
or behind) with a time to collision under ``threshold`` seconds: there the rule-based ego's
action (:mod:`bgap.agents.rule_based`) is taken. The time to collision is the observation
option ``ttc``'s (:mod:`bgap.agents.observation`: the bumper-to-bumper gap over the closing
speed), so the fallback sees what a learner with that option sees. The fallback acts when
the policy plays, not while it learns (``docs/notes/2026-12-07-generalisation-plan.md``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bgap.agents.observation import TTC_HORIZON, ObservationFeatures
from bgap.agents.rule_based import RuleBasedEgo, rule_based
from bgap.common.errors import check

DEFAULT_THRESHOLD = 2.0
"""The fallback's time-to-collision threshold [s] unless a hybrid's spec names one."""


class Hybrid:
    """``learned``'s actions with the rule-based ego's where the time to collision is under
    ``threshold`` [s], in an environment of ``config`` (its lanes and speeds); counts its
    decisions and fallbacks."""

    def __init__(
        self,
        learned: Any,
        config: dict[str, Any] | None = None,
        threshold: float = DEFAULT_THRESHOLD,
        rule: RuleBasedEgo | None = None,
    ) -> None:
        check(
            0.0 < threshold < TTC_HORIZON,
            "threshold",
            threshold,
            f"must lie in (0, {TTC_HORIZON:g}) s, the time-to-collision column's horizon",
        )
        self.learned, self.threshold = learned, threshold
        self.rule = rule if rule is not None else rule_based(config)
        self.ttc = ObservationFeatures(["ttc"], config)
        self.decisions = self.fallbacks = 0

    def near_collision(self, obs: np.ndarray) -> np.ndarray:
        """Per observation of the batch ``obs`` (B, V, 5): whether an observed vehicle's time
        to collision with the ego is under the threshold."""
        ttc = self.ttc(obs)[:, :, -1] * TTC_HORIZON
        others = np.asarray(obs)[:, :, 0] > 0.5
        others[:, 0] = False  # the ego's own row
        return (others & (ttc < self.threshold)).any(axis=1)

    def __call__(self, obs: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray:
        obs = np.asarray(obs)
        actions = np.array(self.learned(obs, rngs), copy=True)
        near = self.near_collision(obs)
        if near.any():
            actions[near] = self.rule(obs[near])
        self.decisions += len(obs)
        self.fallbacks += int(near.sum())
        return actions

    @property
    def share(self) -> float:
        """The fallback's share of the decisions made so far (NaN before the first)."""
        return self.fallbacks / self.decisions if self.decisions else float("nan")

"""CMetric's parameters: a plain dataclass, usable without Hydra or any other part of bgap.

The ``cmetric`` config group's YAML files hold values for it; ``bgap.cmetric``'s functions
take it directly (``score_trajectories(table, CMetricConfig(mu=60))``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from bgap.common.errors import check

DEGREE_RULES = ("new_slower", "net_passes")
EVIDENCE = ("all", "neighbours")
AGGREGATES = ("mean", "max", "quantile")


@dataclass
class StyleWeights:
    """One number per aggressive style."""

    overtaking: float = 1.0
    overspeeding: float = 1.0
    weaving: float = 1.0


@dataclass
class CMetricConfig:
    """CMetric parameters (config group ``cmetric``); README "CMetric" says why each default."""

    name: str = "default"
    mu: float = 30.0
    """Traffic-graph radius [m]: an edge joins vehicles closer than this."""
    mu_spacing: Optional[float] = None
    """When set, each scene's radius is this many times its typical spacing (the median
    distance from a vehicle to its nearest neighbour, :func:`bgap.cmetric.score.spacing`)
    instead of ``mu``: one setting for dense and sparse traffic alike."""
    window: float = 3.0
    """Length of the sliding windows the centrality polynomials are fitted on [s]."""
    stride: float = 1.0
    """Step between window starts [s]."""
    degree: int = 2
    """Degree of the centrality polynomials (the paper: 2)."""
    regularization: float = 1e-6
    """Ridge weight lambda of the least-squares fits, per sample, on normalised time."""
    epsilon: float = 0.5
    """Radius [s] of the ball in which a critical point's sharpness is measured (weaving)."""
    sharpness_min: float = 1e-4
    """Critical points with epsilon-sharpness at or below this are flat, not weaving."""
    weights: StyleWeights = field(
        default_factory=lambda: StyleWeights(overtaking=0.1, overspeeding=1.0, weaving=0.1)
    )
    """Weight of each style's likelihood in the aggressiveness score."""
    scales: StyleWeights = field(
        default_factory=lambda: StyleWeights(overtaking=0.0013, overspeeding=0.165, weaving=0.22)
    )
    """Each style's likelihood is divided by its scale before weighting (units: SLE units)."""
    degree_rule: str = "new_slower"
    """``new_slower``: the paper's cumulative count of new, no-faster neighbours;
    ``net_passes``: +1 per vehicle left behind, -1 per vehicle that leaves this one behind
    (signed; see :mod:`bgap.cmetric.centrality`)."""
    evidence: str = "all"
    """``all``: every window counts (the paper); ``neighbours``: windows in which the
    vehicle never had a neighbour within ``mu`` are missing evidence, not calm driving, and
    a vehicle without any other window is flagged (``flagged``) and gets no score (NaN)."""
    aggregate: str = "mean"
    """How window scores make a vehicle's: ``mean``, ``max`` or ``quantile`` (``q``)."""
    q: float = 0.9
    """The quantile of window scores when ``aggregate=quantile``."""

    def __post_init__(self) -> None:
        for key in ("mu", "window", "stride", "epsilon"):
            v = getattr(self, key)
            check(v > 0, f"cmetric.{key}", v, "must be positive")
        check(self.degree >= 1, "cmetric.degree", self.degree, "must be >= 1")
        check(self.regularization >= 0, "cmetric.regularization", self.regularization, ">= 0")
        check(self.sharpness_min >= 0, "cmetric.sharpness_min", self.sharpness_min, ">= 0")
        for key, allowed in (
            ("degree_rule", DEGREE_RULES),
            ("evidence", EVIDENCE),
            ("aggregate", AGGREGATES),
        ):
            v = getattr(self, key)
            check(v in allowed, f"cmetric.{key}", v, f"use one of {', '.join(allowed)}")
        check(0 < self.q <= 1, "cmetric.q", self.q, "must be in (0, 1]")
        check(
            self.mu_spacing is None or self.mu_spacing > 0,
            "cmetric.mu_spacing",
            self.mu_spacing,
            "must be > 0 (times the median nearest-neighbour distance) or null",
        )
        for style in ("overtaking", "overspeeding", "weaving"):
            w, s = getattr(self.weights, style), getattr(self.scales, style)
            check(w >= 0, f"cmetric.weights.{style}", w, "must be >= 0")
            check(s > 0, f"cmetric.scales.{style}", s, "must be positive")

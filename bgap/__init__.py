"""bgap: behaviour-rich traffic simulation, CMetric and behaviour-aware navigation (B-GAP)."""

import bgap.envs  # noqa: F401  (registers bgap/BehaviorHighway-v0)

__version__ = "0.1.0"

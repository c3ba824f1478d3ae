"""bgap: behaviour-rich traffic simulation, CMetric and behaviour-aware navigation (B-GAP).

Importing ``bgap`` loads nothing else, so ``bgap.cmetric`` stays light; ``import bgap.envs``
registers the gymnasium environment ``bgap/BehaviorHighway-v0``.
"""

__version__ = "0.1.0"

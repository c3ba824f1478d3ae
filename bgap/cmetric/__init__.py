"""CMetric: driving-style likelihoods and intensities from centralities of traffic graphs.

    from bgap.cmetric import score_trajectories
    result = score_trajectories("trajectories.parquet")
    result.vehicles  # one row per vehicle: mean SLE/SIE per style and the aggressiveness score

Pipeline (paper appendix): traffic graph per frame -> closeness and degree centrality
(:mod:`~bgap.cmetric.centrality`) -> polynomial fits over sliding windows
(:mod:`~bgap.cmetric.poly`) -> SLE / SIE per style and one score (:mod:`~bgap.cmetric.styles`).
CMetric knows no simulator: it reads any trajectory table (:mod:`~bgap.cmetric.io`).
"""

from bgap.cmetric.io import TrajectoryError, load_trajectories
from bgap.cmetric.score import CMetricResult, score_trajectories

__all__ = ["CMetricResult", "TrajectoryError", "load_trajectories", "score_trajectories"]

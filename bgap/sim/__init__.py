"""The simulators and what plays in them: the seam over both backends (highway-env and
bgap's compiled vector backend), the one rollout loop, and the trajectory recorder."""

"""What the ego's driving does to the traffic around it, counted per policy step: the
vehicles it overtakes (the generalisation study reports overtakes beside lane changes, as
the paper's navigation passes slower vehicles).

    passed = overtakes(x_before, x_after)   # per env, this step's overtakes

Positions come in the vector backend's layout (``f[:, :, X]``: environments x vehicles,
the ego first). A vehicle is overtaken when its centre was ahead of the ego's before the
step and behind it after; one that overtakes the ego is not counted, nor is a vehicle
parked off the road (absent, :data:`bgap.sim.core.PARK_X`) before or after, which
would otherwise jump from ahead to far behind when it leaves.
"""

from __future__ import annotations

import numpy as np

from bgap.sim.core import PARK_X

PRESENT_X = PARK_X / 2
"""Positions beyond this are on the road; parked vehicles wait at PARK_X and behind."""


def overtakes(x_before: np.ndarray, x_after: np.ndarray) -> np.ndarray:
    """Per environment, the vehicles the ego passed between two policy steps (``x``: its
    vehicles' positions [m], ego first, shape (environments, vehicles))."""
    x0, x1 = np.asarray(x_before, dtype=float), np.asarray(x_after, dtype=float)
    ahead = x0[:, 1:] > x0[:, :1]
    behind = x1[:, 1:] < x1[:, :1]
    present = (x0[:, 1:] > PRESENT_X) & (x1[:, 1:] > PRESENT_X)
    return (ahead & behind & present).sum(axis=1)

"""Confidence intervals, in one place for evaluation, figures and the parity study.

Rates get Wilson score intervals (never of zero width, also at 0 or n events); means get
Student t intervals.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import t as student_t

Z95 = 1.959964
"""Standard normal quantile of a two-sided 95% interval."""


def wilson_interval(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """95% Wilson score interval of a rate of ``k`` events in ``n`` trials (NaN for n = 0).

    Clipped to [0, 1] so that rounding never puts a bound on the wrong side of k / n (at
    k = n the upper bound is exactly 1, not 0.9999999999999999)."""
    if n == 0:
        return math.nan, math.nan
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    lo, hi = centre - half, centre + half
    return (0.0 if k == 0 else max(0.0, min(lo, p))), (1.0 if k == n else min(1.0, max(hi, p)))


def t_interval(x: np.ndarray) -> tuple[float, float]:
    """95% Student t interval of the mean of ``x`` (NaN below two values)."""
    x = np.asarray(x, dtype=float)
    if len(x) < 2:
        return math.nan, math.nan
    half = student_t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / math.sqrt(len(x))
    return x.mean() - half, x.mean() + half


def mean_interval(x: np.ndarray) -> tuple[float, float]:
    """:func:`t_interval`, except that a single value is returned as its own (degenerate)
    interval, for plotting one training seed or one episode."""
    x = np.asarray(x, dtype=float)
    if len(x) < 2:
        return float(np.mean(x)), float(np.mean(x))
    return t_interval(x)

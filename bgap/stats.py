"""Confidence intervals, in one place for evaluation, figures and the parity study.

Rates get Wilson score intervals (never of zero width, also at 0 or n events); means get
Student t intervals; differences between policies whose independent units are training
seeds get a two-level bootstrap (:func:`seed_bootstrap_diff`); a table of claims gets Holm's
correction (:func:`holm`). The rule that judges a policy against the idle ego is here too
(:func:`constrained_score`, :func:`beats_idle`), so sweeps, checkpoint selection and the
results' flags apply one definition.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import t as student_t

from bgap.vocab import SPEED_FLOOR

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


def seed_bootstrap_diff(
    a_events: np.ndarray,
    a_episodes: np.ndarray,
    b_events: np.ndarray,
    b_episodes: np.ndarray,
    rng: np.random.Generator,
    draws: int = 2000,
) -> tuple[float, float, float, float]:
    """Difference of two arms' mean event rates (a - b) when training seeds are the
    independent units: ``a_events[i]`` events in ``a_episodes[i]`` episodes for training seed
    i of arm a (likewise b; the arms' seeds are unrelated, so nothing is paired).

    Two-level bootstrap: each draw resamples each arm's seeds with replacement, then each
    drawn seed's episodes (binomially, at that seed's observed rate), and averages the
    seeds' rates. Returns the observed difference, the 95% percentile interval and a
    two-sided bootstrap p-value (twice the smaller tail beyond 0). Coverage is checked by
    simulation in ``tests/test_stats.py`` (10 seeds x 100 episodes per arm)."""

    def arm(events: np.ndarray, episodes: np.ndarray) -> np.ndarray:
        events, episodes = np.asarray(events), np.asarray(episodes)
        pick = rng.integers(len(events), size=(draws, len(events)))
        n = episodes[pick]
        return (rng.binomial(n, events[pick] / n) / n).mean(axis=1)

    observed = float(
        np.mean(np.asarray(a_events) / a_episodes) - np.mean(np.asarray(b_events) / b_episodes)
    )
    d = arm(a_events, a_episodes) - arm(b_events, b_episodes)
    lo, hi = np.percentile(d, [2.5, 97.5])
    p = min(1.0, 2 * min(float(np.mean(d <= 0)), float(np.mean(d >= 0))))
    return observed, float(lo), float(hi), p


def holm(pvalues: np.ndarray) -> np.ndarray:
    """Holm's step-down adjusted p-values (family-wise error control over a table of
    claims): the k-th smallest of m p-values is multiplied by m - k + 1, then made
    non-decreasing in that order and capped at 1."""
    p = np.asarray(pvalues, dtype=float)
    order = np.argsort(p)
    scaled = p[order] * (len(p) - np.arange(len(p)))
    adjusted = np.empty_like(p)
    adjusted[order] = np.minimum(1.0, np.maximum.accumulate(scaled))
    return adjusted


def constrained_score(
    collision_pct: float, speed: float, idle_speed: float, floor: float = SPEED_FLOOR
) -> float:
    """Lower is better: the collision % of a policy whose mean speed reaches ``floor`` x idle's
    on the same episodes; below that, 100 + the shortfall in % of the floor, so any policy fast
    enough ranks above any that is not. Used by the constrained sweeps, the recipe's choice
    and the selection of a training's best checkpoint."""
    need = floor * idle_speed
    return collision_pct if speed >= need else 100.0 + 100.0 * (need - speed) / need


def beats_idle(
    collision_pct: float,
    speed: float,
    idle_collision_pct: float,
    idle_speed: float,
    floor: float = SPEED_FLOOR,
) -> bool:
    """Fewer collisions than idle at a mean speed of at least ``floor`` x idle's (the same
    episodes): a trained policy that does not is flagged, never silently compared."""
    return collision_pct < idle_collision_pct and speed >= floor * idle_speed

"""Intervals for a crossed study, and the simulation that checks their coverage.

In the study every training seed of an arm plays the same episodes (the same episode seeds
per cell): outcomes ``y[s, e]`` form a crossed design, seeds x episodes. The mean over
seeds and episodes then varies with the seeds drawn *and* with the episodes drawn, and the
second part is shared by every seed, so it does not shrink as seeds are added. An interval
that resamples each seed's episodes on its own (the two-level bootstrap of
:func:`bgap.analysis.stats.seed_bootstrap`) sees only the first part.

:func:`crossed_interval` is the two-way random-effects interval (seed, episode and
residual variance components from the ANOVA mean squares, Student t with Satterthwaite's
degrees of freedom); :func:`crossed_difference_interval` is the same for two arms that play
the same episodes. Both are closed forms: scipy and statsmodels offer one-way intervals
and mixed models fitted by likelihood, not this moment estimator of a crossed design's
mean, and a closed form lets the coverage simulation run thousands of studies in seconds.

How often each covers the truth in simulated studies of this design:
:mod:`bgap.analysis.coverage`.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtri, stdtr, stdtrit

from bgap.analysis.stats import wilson_interval

LEVEL = 0.95


def _t(df: float, level: float) -> float:
    return float(stdtrit(df, 0.5 + level / 2))


def _components(y: np.ndarray) -> tuple[float, float, float, float, float, float]:
    """Mean squares of seeds, episodes and residual of ``y[s, e]`` and their degrees of
    freedom (two-way ANOVA without replication)."""
    s, e = y.shape
    grand = y.mean()
    rows, cols = y.mean(axis=1), y.mean(axis=0)
    ms_s = e * np.sum((rows - grand) ** 2) / max(s - 1, 1)
    ms_e = s * np.sum((cols - grand) ** 2) / max(e - 1, 1)
    resid = y - rows[:, None] - cols[None, :] + grand
    df_r = max((s - 1) * (e - 1), 1)
    ms_r = np.sum(resid**2) / df_r
    return ms_s, s - 1, ms_e, e - 1, ms_r, df_r


def satterthwaite(terms: list[tuple[float, float]]) -> float:
    """Degrees of freedom of a sum of mean squares ``sum(c * ms)`` given as ``(c * ms,
    df)`` pairs (negative coefficients included)."""
    num = sum(v for v, _ in terms) ** 2
    den = sum(v**2 / d for v, d in terms if d > 0)
    return float(num / den) if den > 0 else float("inf")


def crossed_variance(y: np.ndarray) -> tuple[float, float]:
    """Variance of the grand mean of a crossed seeds x episodes table and its degrees of
    freedom: Var = s2_seed / S + s2_episode / E + s2_residual / (S E), estimated without
    bias by (MS_seed + MS_episode - MS_residual) / (S E). A negative estimate (a component
    estimated below zero) is floored at the larger of the two one-way terms; the
    degrees of freedom are Satterthwaite's."""
    y = np.asarray(y, dtype=float)
    s, e = y.shape
    ms_s, df_s, ms_e, df_e, ms_r, df_r = _components(y)
    var = (ms_s + ms_e - ms_r) / (s * e)
    df = satterthwaite([(ms_s, df_s), (ms_e, df_e), (-ms_r, df_r)])
    floor = max(ms_s, ms_e) / (s * e)
    if var < floor:  # a truncated estimate: read it at the df of its own term
        var, df = floor, float(df_s if ms_s >= ms_e else df_e)
    return float(var), max(float(df), 1.0)


def crossed_interval(y: np.ndarray, level: float = LEVEL) -> tuple[float, float, float]:
    """Mean of ``y[s, e]`` (seed s, shared episode e) and its two-way random-effects
    interval at ``level``."""
    y = np.asarray(y, dtype=float)
    var, df = crossed_variance(y)
    half = _t(df, level) * np.sqrt(var)
    mean = float(y.mean())
    return mean, mean - half, mean + half


def crossed_difference_variance(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Variance and degrees of freedom of the difference of the means of two arms whose
    seeds are unrelated trainings but play the same episodes (``a[s, e]`` and ``b[t, e]``,
    columns aligned).

    The episode component is shared: what varies with the episodes drawn is each episode's
    difference of the two arms' seed means, so its term is read from those differences;
    each arm's seed term comes from its own seeds x episodes table."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"the arms play different episodes: {a.shape[1]} vs {b.shape[1]}")
    (sa, e), sb = a.shape, b.shape[0]
    if min(sa, sb) < 2:
        return float("nan"), float("nan")
    ms_sa, df_sa, _, _, ms_ra, df_ra = _components(a)
    ms_sb, df_sb, _, _, ms_rb, df_rb = _components(b)
    d = a.mean(axis=0) - b.mean(axis=0)
    ms_d = float(np.var(d, ddof=1)) if e > 1 else 0.0  # E[.] = s2_ed + s2_ra/sa + s2_rb/sb
    # Var(diff) = s2_sa/sa + s2_sb/sb + (s2_ed + s2_ra/sa + s2_rb/sb)/e, with
    # s2_s = (MS_s - MS_r)/e: every term from the mean squares, MS_r cancelling
    terms = [
        (ms_sa / (sa * e), df_sa),
        (ms_sb / (sb * e), df_sb),
        (ms_d / e, e - 1),
        (-ms_ra / (sa * e), df_ra),
        (-ms_rb / (sb * e), df_rb),
    ]
    var = sum(v for v, _ in terms)
    df = satterthwaite(terms)
    # each of Welch's variance of the seed means and the episode term alone is a lower
    # bound in expectation: an estimate below both is floored at the larger
    welch = (ms_sa / sa + ms_sb / sb) / e
    floor = max(welch, ms_d / e)
    if var < floor:
        var, df = floor, float(min(df_sa, df_sb))
    return float(var), max(float(df), 1.0)


def paired_difference_variance(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Variance and degrees of freedom of the difference of the means of the same models
    (rows: training seeds, aligned) in two conditions, each condition's episodes shared by
    every seed (``a[s, e]``, ``b[s, f]``): the paired seeds' differences carry the seed
    term, each condition's own episodes add theirs, Var = var(d_s)/S + s2_ea/E_a + s2_eb/E_b."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape[0] != b.shape[0]:
        raise ValueError(f"paired conditions need the same seeds: {a.shape[0]} vs {b.shape[0]}")
    s = a.shape[0]
    if s < 2:
        return float("nan"), float("nan")
    d = a.mean(axis=1) - b.mean(axis=1)
    terms = [(float(np.var(d, ddof=1)) / s, s - 1)]
    for y in (a, b):
        _, _, ms_e, df_e, ms_r, df_r = _components(y)
        terms += [(ms_e / (s * y.shape[1]), df_e), (-ms_r / (s * y.shape[1]), df_r)]
    var, df = sum(v for v, _ in terms), satterthwaite(terms)
    if var < terms[0][0]:  # the paired seeds' term alone is a lower bound in expectation
        var, df = terms[0][0], float(s - 1)
    return float(var), max(float(df), 1.0)


def t_test(
    estimate: float, var: float, df: float, null: float = 0.0, level: float = LEVEL
) -> tuple[float, float, float]:
    """Student t interval at ``level`` of an estimate of variance ``var`` on ``df`` degrees
    of freedom, and the two-sided p-value of ``null`` (analytic: no Monte Carlo error at
    Holm's levels). A zero variance gives a point and p = 1 at the null, 0 elsewhere;
    an unknown one (fewer than two seeds) gives NaN."""
    if not np.isfinite(var):
        return float("nan"), float("nan"), float("nan")
    if var <= 0:
        return estimate, estimate, 1.0 if estimate == null else 0.0
    se = float(np.sqrt(var))
    half = _t(df, level) * se
    p = float(2 * stdtr(df, -abs(estimate - null) / se))
    return estimate - half, estimate + half, p


def crossed_difference_interval(
    a: np.ndarray, b: np.ndarray, level: float = LEVEL
) -> tuple[float, float, float]:
    """Difference of two arms' means on the same episodes and its interval
    (:func:`crossed_difference_variance`)."""
    diff = float(np.mean(a) - np.mean(b))
    lo, hi, _ = t_test(diff, *crossed_difference_variance(a, b), level=level)
    return diff, lo, hi


def rate_test(
    y: np.ndarray, null: float, level: float = LEVEL
) -> tuple[float, float, float, float]:
    """A rate (0/1 ``y[s, e]``) against a fixed number: :func:`rate_interval` at ``level``
    and the p-value of ``null``, the smallest alpha whose interval at 1 - alpha excludes
    it (bisection: the interval widens with its level), so that p and interval agree."""
    mean, lo, hi = rate_interval(y, level)
    inside = lambda alpha: (lambda r: r[1] <= null <= r[2])(rate_interval(y, 1 - alpha))  # noqa: E731
    if inside(1 - 1e-9):
        return mean, lo, hi, 1.0
    a, b = 1e-12, 1 - 1e-9  # excluded at b, assumed excluded below 1e-12 too
    if inside(a):
        for _ in range(50):
            m = (a + b) / 2
            a, b = (m, b) if inside(m) else (a, m)
    return mean, lo, hi, float(b)


def log_rate_interval(y: np.ndarray, level: float = LEVEL) -> tuple[float, float, float]:
    """Mean rate of 0/1 ``y[s, e]`` with an interval that allows for skewed seed rates:
    the modified Cox interval of a lognormal mean (Armstrong 1992) on the seeds' rates,
    ``exp(m + s2/2 +- t * sqrt(s2/S + s2^2 / (2 (S - 1))))`` for the seeds' log rates of
    mean m and variance s2, each rate read as (events + 1/2) / (episodes + 1) so that a
    seed without events has a log. Written here: no kept library offers it for rates."""
    y = np.asarray(y, dtype=float)
    s, e = y.shape
    x = np.log((y.sum(axis=1) + 0.5) / (e + 1))
    m, s2 = x.mean(), x.var(ddof=1)
    centre = m + s2 / 2
    half = _t(s - 1, level) * np.sqrt(s2 / s + s2**2 / (2 * (s - 1)))
    # a rate is at most 1 (and exp would overflow at the tiny alphas of Holm's steps)
    return (
        float(y.mean()),
        float(np.exp(min(centre - half, 0.0))),
        float(np.exp(min(centre + half, 0.0))),
    )


def rate_interval(y: np.ndarray, level: float = LEVEL) -> tuple[float, float, float]:
    """The interval the study prints for a rate over seeds x shared episodes.

    Its lower end is :func:`crossed_interval`'s, its upper end the higher of that and
    :func:`log_rate_interval`'s (a rate whose seeds are skewed is underestimated when the
    few high seeds are missed, so only the upper end needs the log scale), and both ends
    reach at least as far as the Wilson interval of all episodes pooled (a rate cannot be
    known better than its episodes allow: all-zero tables have no spread to read). No single
    method covers in every setting of :func:`bgap.analysis.coverage.coverage_table`; this
    one does at 3, 5 and 10 seeds."""
    mean, lo, hi = crossed_interval(y, level)
    _, _, hi_log = log_rate_interval(y, level)
    y = np.asarray(y, dtype=float)
    w_lo, w_hi = wilson_interval(int(round(y.sum())), y.size, z=float(ndtri(0.5 + level / 2)))
    return mean, max(0.0, min(lo, w_lo)), max(hi, hi_log, w_hi)

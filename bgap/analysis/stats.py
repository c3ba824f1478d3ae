"""Confidence intervals, in one place for evaluation, figures and the parity study.

Rates get Wilson score intervals (never of zero width, also at 0 or n events); rates per
distance driven (collisions per 100 km) exact Poisson intervals; means get Student t
intervals; differences between policies whose independent units are training
seeds get a two-level bootstrap (:func:`seed_bootstrap`); a table of claims gets Holm's
correction (:func:`holm`). The rule that judges a policy against the idle ego is here too
(:func:`beats_idle`; the score choices rank by: :mod:`bgap.common.scores`), so the sweeps,
bgap.run's flags and the results page apply one definition.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np

# scipy.special's quantiles, not scipy.stats' distributions (chi2.ppf and t.ppf evaluate
# these same functions): importing scipy.stats cost every command 1 s.
from scipy.special import gammaincinv, stdtrit

from bgap.common.scores import PER_KM
from bgap.common.vocab import SPEED_FLOOR

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


def poisson_interval(k: int, exposure: float, level: float = 0.95) -> tuple[float, float]:
    """Exact (Garwood) interval of an event rate per unit of ``exposure`` from ``k`` events:
    chi-square quantiles of 2k and 2k + 2 degrees of freedom, halved. Never of zero width: 0
    events in E units reads [0, 3.69 / E]. NaN without exposure."""
    if exposure <= 0:
        return float("nan"), float("nan")
    tail = (1 - level) / 2
    lo = 0.0 if k == 0 else gammaincinv(k, tail)  # chi2.ppf(tail, 2k) / 2
    hi = gammaincinv(k + 1, 1 - tail)  # chi2.ppf(1 - tail, 2k + 2) / 2
    return float(lo / exposure), float(hi / exposure)


def per_100km(crashes: np.ndarray, distance: np.ndarray) -> tuple[float, float, float]:
    """Collisions per 100 km of ego travel over episodes (``distance`` in m), with the exact
    Poisson interval: an episode ends at its first crash, so crashes count events over the
    distance driven."""
    k, exposure = int(np.sum(crashes)), float(np.sum(distance)) / PER_KM
    lo, hi = poisson_interval(k, exposure)
    return (k / exposure if exposure > 0 else float("nan")), lo, hi


def seed_per_100km_interval(
    crashes: Sequence[np.ndarray],
    distance: Sequence[np.ndarray],
    rng: np.random.Generator,
    draws: int = 4000,
) -> tuple[float, float, float]:
    """Collisions per 100 km averaged over training seeds (each seed's crashes over its own
    distance), and its 95% interval: a two-level bootstrap (seeds, then each seed's
    episodes, crash and distance together), widened where needed to the pooled episodes'
    Poisson interval, so never of zero width (as :func:`seed_rate_interval`)."""
    pairs = [
        (np.asarray(c, dtype=float), np.asarray(d, dtype=float) / PER_KM)
        for c, d in zip(crashes, distance, strict=True)
    ]
    rates = [c.sum() / d.sum() for c, d in pairs]
    pick = rng.integers(len(pairs), size=(draws, len(pairs)))
    dist = np.empty(pick.shape)
    for s, (c, d) in enumerate(pairs):
        slots = pick == s
        if slots.any():
            idx = rng.integers(len(c), size=(int(slots.sum()), len(c)))
            dist[slots] = c[idx].sum(axis=1) / d[idx].sum(axis=1)
    lo, hi, _ = bootstrap_test(dist.mean(axis=1), observed=float(np.mean(rates)))
    _, p_lo, p_hi = per_100km(
        np.concatenate([c for c, _ in pairs]), np.concatenate([d for _, d in pairs]) * PER_KM
    )
    return float(np.mean(rates)), min(lo, p_lo), max(hi, p_hi)


def t_interval(x: np.ndarray) -> tuple[float, float]:
    """95% Student t interval of the mean of ``x`` (NaN below two values)."""
    x = np.asarray(x, dtype=float)
    if len(x) < 2:
        return math.nan, math.nan
    half = stdtrit(len(x) - 1, 0.975) * x.std(ddof=1) / math.sqrt(len(x))
    return x.mean() - half, x.mean() + half


def spread_interval(x: np.ndarray, counts: bool = False) -> tuple[float, float]:
    """95% interval of the mean of ``x`` that never has zero width: :func:`t_interval`, except
    for a sample without spread (every value equal, where the t interval collapses): counts
    (lane changes per episode) get the exact Poisson interval of their total
    (:func:`poisson_interval`: all zeros over n episodes read [0, 3.69 / n]), other measures
    their value +- the precision they are stored in (single precision). NaN below two
    values."""
    x = np.asarray(x, dtype=float)
    if len(x) < 2:
        return math.nan, math.nan
    if np.ptp(x) > 0:
        return t_interval(x)
    if counts:
        return poisson_interval(int(round(x.sum())), len(x))
    half = float(np.spacing(np.float32(abs(x[0]))))
    return x[0] - half, x[0] + half


def mean_interval(x: np.ndarray, counts: bool = False) -> tuple[float, float]:
    """:func:`spread_interval`, except that a single value is returned as its own
    (degenerate) interval, for plotting one training seed or one episode."""
    x = np.asarray(x, dtype=float)
    if len(x) < 2:
        return float(np.mean(x)), float(np.mean(x))
    return spread_interval(x, counts)


def seed_bootstrap(
    a: Sequence[np.ndarray],
    b: Sequence[np.ndarray] | None = None,
    *,
    rng: np.random.Generator,
    draws: int = 20_000,
    paired: bool = False,
    differences: Literal["events", "values"] | None = None,
) -> tuple[float, np.ndarray]:
    """Two-level bootstrap of a mean over training seeds, the independent units.

    ``a[i]`` holds training seed i's episode values (0/1 crashes, speeds, ...); the statistic
    is the mean over seeds of each seed's mean, or with ``b`` the difference of two such
    means (a - b). Each draw resamples the seeds with replacement, then each drawn seed's
    episodes with replacement (independently per slot: a seed drawn twice gets two
    resamples). A seed's 0/1 values (crashes) are drawn as its rate from the Jeffreys
    posterior instead (:func:`_resampled_means`), so no interval has zero width.

    ``paired``: ``a[i]`` and ``b[i]`` come from the same trained model (one policy in two
    traffic conditions), so each draw picks the same seeds for both; their episodes are
    resampled independently (different conditions share no episodes). Unrelated trainings
    (two policy families) are never paired.

    ``differences``: where two conditions play identical scenes (the same episode seeds and
    traffic, e.g. two perception radii), ``a`` alone holds each seed's per-scene differences
    instead. ``"events"``: differences of 0/1 events (-1, 0 or +1), a drawn seed's shares of
    scenes with an event only at the first setting, at both or neither, and only at the second
    drawn from their Dirichlet posterior (Jeffreys prior, 1/2 each), the paired analogue of
    the Beta posterior of a rate: a seed whose scenes all end alike still varies,
    symmetrically about 0, so no interval has zero width. ``"values"``: other differences,
    resampled as values (never read as a rate's events: all-zero differences are no rate of
    0 events, whose draws would all lie above 0 and make a difference of exactly 0
    significant).

    Returns the observed statistic and its ``draws`` bootstrap replicates."""
    a = [np.asarray(x, dtype=float) for x in a]
    pick_a = rng.integers(len(a), size=(draws, len(a)))
    observed = float(np.mean([x.mean() for x in a]))
    if differences is not None:
        if b is not None:
            raise ValueError("differences are one sample: pass them as `a` alone")
        if differences == "events":
            return observed, _dirichlet_means(a, pick_a, rng)
        return observed, _resampled_means(a, pick_a, rng, events=False)
    dist = _resampled_means(a, pick_a, rng)
    if b is not None:
        b = [np.asarray(x, dtype=float) for x in b]
        if paired and len(b) != len(a):
            raise ValueError(f"paired arms need the same seeds: {len(a)} vs {len(b)}")
        pick_b = pick_a if paired else rng.integers(len(b), size=(draws, len(b)))
        observed -= float(np.mean([x.mean() for x in b]))
        dist = dist - _resampled_means(b, pick_b, rng)
    return observed, dist


def _dirichlet_means(groups: list[np.ndarray], pick: np.ndarray, rng) -> np.ndarray:
    """Per draw, the mean over the picked seeds of each one's share of +1 minus its share of
    -1 differences, the shares drawn from their Dirichlet posterior (``differences="events"``)."""
    if any(not np.isin(x, (-1.0, 0.0, 1.0)).all() for x in groups):
        raise ValueError("differences of events are -1, 0 or +1")
    means = np.empty(pick.shape)
    for s, x in enumerate(groups):
        slots = pick == s
        if slots.any():
            counts = np.array([(x > 0).sum(), (x == 0).sum(), (x < 0).sum()])
            shares = rng.dirichlet(counts + 0.5, size=int(slots.sum()))
            means[slots] = shares[:, 0] - shares[:, 2]
    return means.mean(axis=1)


def _resampled_means(
    groups: list[np.ndarray], pick: np.ndarray, rng, events: bool = True
) -> np.ndarray:
    """Per draw, the mean over the picked seeds of each one's resampled episode mean; with
    ``events``, a seed of 0/1 values is drawn as a rate instead."""
    means = np.empty(pick.shape)
    for s, x in enumerate(groups):
        slots = pick == s
        k, n = int(slots.sum()), len(x)
        if k == 0:
            continue
        if events and np.isin(x, (0.0, 1.0)).all():
            # the seed's rate from its Jeffreys posterior Beta(e + 1/2, n - e + 1/2): the
            # spread of a binomial resample, but a seed with 0 (or n) events still varies (a
            # resample of 0/100 is always 0, which would make intervals of zero width)
            e = x.sum()
            means[slots] = rng.beta(e + 0.5, n - e + 0.5, size=k)
        else:  # chunks keep the (k, n) index array small
            out = np.empty(k)
            step = max(1, 2_000_000 // n)
            for i in range(0, k, step):
                m = min(step, k - i)
                out[i : i + m] = x[rng.integers(n, size=(m, n))].mean(axis=1)
            means[slots] = out
    return means.mean(axis=1)


def bootstrap_test(
    dist: np.ndarray, level: float = 0.95, null: float = 0.0, observed: float | None = None
) -> tuple[float, float, float]:
    """Percentile interval at ``level`` of bootstrap replicates and the two-sided p-value of
    ``null`` (twice the smaller share of replicates on either side of it): the interval at
    level 1 - alpha excludes ``null`` exactly when p < alpha (up to ties at ``null``).
    With ``observed``, the interval is widened to contain it (a rate of 0 events, whose
    posterior draws all lie above 0)."""
    tail = 100 * (1 - level) / 2
    lo, hi = np.percentile(dist, [tail, 100 - tail])
    if observed is not None:
        lo, hi = min(lo, observed), max(hi, observed)
    p = min(1.0, 2 * min(float(np.mean(dist <= null)), float(np.mean(dist >= null))))
    return float(lo), float(hi), p


def seed_bootstrap_diff(
    a_events: np.ndarray,
    a_episodes: np.ndarray,
    b_events: np.ndarray,
    b_episodes: np.ndarray,
    rng: np.random.Generator,
    draws: int = 2000,
) -> tuple[float, float, float, float]:
    """:func:`seed_bootstrap` of two unrelated arms' event rates from counts:
    ``a_events[i]`` events in ``a_episodes[i]`` episodes for training seed i of arm a.
    Returns the observed difference a - b, the 95% percentile interval and the two-sided
    p-value. Coverage is checked by simulation in ``tests/test_stats.py`` (10 seeds x 100
    episodes per arm)."""

    def episodes(events, n) -> list[np.ndarray]:
        return [
            np.r_[np.ones(int(k)), np.zeros(int(m) - int(k))]
            for k, m in zip(events, n, strict=True)
        ]

    observed, dist = seed_bootstrap(
        episodes(a_events, a_episodes), episodes(b_events, b_episodes), rng=rng, draws=draws
    )
    return (observed, *bootstrap_test(dist, observed=observed))


def seed_rate_interval(
    groups: Sequence[np.ndarray], rng: np.random.Generator, draws: int = 4000
) -> tuple[float, float]:
    """95% interval of a rate averaged over training seeds (``groups[i]``: seed i's 0/1
    episodes): the two-level bootstrap's percentile interval, widened where needed to the
    Wilson interval of all the episodes pooled, so that it is never of zero width (0 crashes
    in 300 episodes reads [0, 0.013], not [0, 0]) and never narrower than the episodes alone
    allow."""
    observed, dist = seed_bootstrap(groups, rng=rng, draws=draws)
    lo, hi, _ = bootstrap_test(dist, observed=observed)
    pooled = np.concatenate([np.asarray(g, dtype=float) for g in groups])
    w_lo, w_hi = wilson_interval(int(pooled.sum()), len(pooled))
    return min(lo, w_lo), max(hi, w_hi)


RULE_FLOOR = 0.95
"""The speed a learned policy must keep, as a share of the rule-based ego's, to count as
beating it (the rule-based ego as yardstick)."""


def versus_rule(per100: float, speed: float, rule_per100: float, rule_speed: float) -> str:
    """A policy read against the rule-based ego on the same episodes, by point estimates:
    ``beats`` it with fewer collisions per 100 km at a mean speed of at least
    :data:`RULE_FLOOR` x its speed; is ``beaten`` by it with no fewer collisions per 100 km
    and no higher speed; else it trades one for the other: ``safer, slower`` (fewer
    collisions per 100 km, under the floor's speed) or ``faster, less safe`` (a higher
    speed, no fewer collisions per 100 km)."""
    if per100 < rule_per100:
        return "beats" if speed >= RULE_FLOOR * rule_speed else "safer, slower"
    return "beaten" if speed <= rule_speed else "faster, less safe"


STOCK_MARGIN = 1.0
"""Percentage points of episodes a default policy may crash in beyond the rule-based ego's,
in stock traffic, and still meet the stock rule."""

SHORT_PENALTY = 1000.0
"""What the recipe objectives add to a speed shortfall: above any collision excess, so a
policy that keeps the pace ranks above any that does not."""


def speed_shortfall(speed: float, rule_speed: float, floor: float = RULE_FLOOR) -> float:
    """How far ``speed`` falls below ``floor`` x the rule-based ego's speed, in % of that
    floor (0 at or above it): the one speed rule of the recipe objective and of its trials'
    pruning."""
    need = floor * rule_speed
    return max(0.0, 100.0 * (need - speed) / need) if need > 0 else 0.0


def keeps_up(
    collision_pct: float,
    speed: float,
    rule_collision_pct: float,
    rule_speed: float,
    floor: float = RULE_FLOOR,
    margin: float = STOCK_MARGIN,
) -> bool:
    """The stock rule: a default policy crashes in at most ``margin`` points more
    episodes than the rule-based ego, at a mean speed of at least ``floor`` x its (the same
    episodes)."""
    return collision_pct <= rule_collision_pct + margin and speed >= floor * rule_speed


def rule_objective(
    rich: dict[str, float],
    rich_rule: dict[str, float],
    stock: dict[str, float],
    stock_rule: dict[str, float],
    floor: float = RULE_FLOOR,
    margin: float = STOCK_MARGIN,
) -> float:
    """The recipe objective (lower is better), scoring both policies of a recipe
    against the rule-based ego on the same validation episodes. Each argument holds
    ``collision_pct``, ``per_100km`` and ``avg_speed``: the behaviour-rich policy in its
    traffic, the rule-based ego there, the default policy in stock traffic, the rule-based
    ego there.

    A policy below ``floor`` x the rule-based ego's speed makes the value 1000 + the sum of
    both policies' shortfalls in % of their floors, so a recipe whose two policies keep the
    pace ranks above any that does not. Otherwise it is the worse of the two excesses: the
    behaviour-rich policy's collisions per 100 km minus the rule-based ego's, and the default
    policy's collision % minus the rule-based ego's minus ``margin``. Below 0: both of issue
    32's rules are met (the first strictly)."""
    short = sum(
        speed_shortfall(policy["avg_speed"], rule["avg_speed"], floor)
        for policy, rule in ((rich, rich_rule), (stock, stock_rule))
    )
    if short > 0:
        return SHORT_PENALTY + short
    return max(
        rule_excess("behavior_rich", rich, rich_rule),
        rule_excess("default", stock, stock_rule, margin),
    )


def policy_score(
    policy: str,
    mine: dict[str, float],
    rule: dict[str, float],
    floor: float = RULE_FLOOR,
    margin: float = STOCK_MARGIN,
) -> float:
    """One policy's half of :func:`rule_objective` (lower is better): below ``floor`` x the
    rule-based ego's speed, 1000 + the shortfall in % of that floor; else its
    :func:`rule_excess`."""
    short = speed_shortfall(mine["avg_speed"], rule["avg_speed"], floor)
    return SHORT_PENALTY + short if short > 0 else rule_excess(policy, mine, rule, margin)


def rule_excess(
    policy: str, mine: dict[str, float], rule: dict[str, float], margin: float = STOCK_MARGIN
) -> float:
    """One policy's term of :func:`rule_objective` (below 0: its rule is met):
    behaviour-rich, its collisions per 100 km minus the rule-based ego's; ``default`` (in
    stock traffic), its collision % minus the rule-based ego's minus ``margin``."""
    if policy == "default":
        return mine["collision_pct"] - rule["collision_pct"] - margin
    return mine["per_100km"] - rule["per_100km"]


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

"""The simulation that checks the study's intervals: studies of its design (training seeds
x the episodes they share) with a known true crash rate, and how often each interval method's
nominal 95% interval covers it.

:func:`coverage` compares one arm's rate intervals (:data:`METHODS`: the two-level bootstrap
the study printed before, Student t over seed means, the crossed interval, the log-scale
one, and the one printed now); :func:`difference_coverage`, :func:`paired_coverage` and
:func:`scene_coverage` the differences of two arms, of the same models in two conditions,
and of the same models on the same scenes. Each reports the median width as a multiple of
an oracle's that knows the true variance of the estimate. ``tools/interval_coverage.py``
prints the tables of docs/intervals.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bgap.analysis.intervals import (
    LEVEL,
    crossed_difference_interval,
    crossed_interval,
    log_rate_interval,
    paired_difference_variance,
    rate_interval,
    satterthwaite,
    t_test,
)
from bgap.analysis.stats import seed_bootstrap_diff, seed_rate_interval, t_interval
from bgap.analysis.yardsticks import compare


def _seed_t(y: np.ndarray, level: float = LEVEL) -> tuple[float, float, float]:
    """Student t over the seeds' means (95%): seeds as the units, shared episodes ignored."""
    lo, hi = t_interval(y.mean(axis=1))
    return float(y.mean()), float(lo), float(hi)


def _two_level(y: np.ndarray, level: float = LEVEL, rng=None) -> tuple[float, float, float]:
    """The two-level bootstrap the study printed (seeds, then each seed's own episodes)."""
    lo, hi = seed_rate_interval(list(y), rng=rng, draws=2000)
    return float(y.mean()), lo, hi


METHODS: dict[str, Callable] = {
    "two-level bootstrap": _two_level,
    "seed t": _seed_t,
    "crossed t": crossed_interval,
    "log-scale (Cox)": log_rate_interval,
    "printed": rate_interval,
}
"""Interval methods of one arm's mean that :func:`coverage` compares."""


@dataclass(frozen=True)
class Design:
    """A simulated study: ``seeds`` training seeds each playing the same ``episodes``
    episodes, seed crash rates around ``rate`` (``spread``: "normal" with coefficient of
    variation ``cv``, or "lognormal" with log-sd ``sigma_log``), and episodes whose
    difficulty multiplies every seed's rate by a shared Gamma factor of mean 1 and
    coefficient of variation ``episode_cv``."""

    seeds: int
    rate: float
    spread: str = "normal"
    cv: float = 0.3
    sigma_log: float = 1.2
    episodes: int = 100
    episode_cv: float = 0.7

    def seed_rates(self, rng: np.random.Generator, n: int) -> np.ndarray:
        if self.spread == "lognormal":
            z = rng.standard_normal(n)
            return self.rate * np.exp(self.sigma_log * z - self.sigma_log**2 / 2)
        return np.clip(self.rate * (1 + self.cv * rng.standard_normal(n)), 0.0, None)

    def episode_factors(self, rng: np.random.Generator, n: int) -> np.ndarray:
        k = 1 / self.episode_cv**2
        return rng.gamma(k, 1 / k, size=n)

    @staticmethod
    def play(rng: np.random.Generator, rates: np.ndarray, factors: np.ndarray) -> np.ndarray:
        """0/1 crashes of seeds of these ``rates`` in episodes of these difficulty
        ``factors``."""
        p = np.minimum(rates[:, None] * factors[None, :], 1.0)
        return (rng.random(p.shape) < p).astype(float)

    def draw(self, rng: np.random.Generator) -> np.ndarray:
        rates = self.seed_rates(rng, self.seeds)
        return self.play(rng, rates, self.episode_factors(rng, self.episodes))

    def truth(self, draws: int = 2_000_000) -> float:
        """The population mean crash rate (a seed and an episode drawn at random); equal to
        ``rate`` unless rates are clipped at 1, so it is computed, derandomised."""
        rng = np.random.default_rng(12345)
        p = self.seed_rates(rng, draws) * self.episode_factors(rng, draws)
        return float(np.minimum(p, 1.0).mean())


def _summary(estimates: list[float], truth: float, bounds: list) -> dict[str, float]:
    """Coverage of ``truth`` by ``bounds`` (lo, hi per study) and their median width as a
    multiple of the oracle's: the true standard deviation of the estimates, times 1.96."""
    oracle = 2 * 1.959964 * float(np.sqrt(np.mean((np.asarray(estimates) - truth) ** 2)))
    bb = np.asarray(bounds, dtype=float)
    return {
        "coverage": float(((bb[:, 0] <= truth) & (truth <= bb[:, 1])).mean()),
        "width": float(np.median(bb[:, 1] - bb[:, 0])) / oracle,
    }


def _rows(
    settings: dict[str, tuple[dict, dict]],
    fn: Callable,
    episodes: tuple[int, int],
    studies: int,
    seeds: tuple[int, ...],
    seed: int,
) -> list[dict]:
    """``fn(a, b, studies, seed)`` for every two-arm setting at each seed count, one row per
    setting, seed count and method."""
    rows = []
    for name, (ka, kb) in settings.items():
        for s in seeds:
            a, b = Design(s, episodes=episodes[0], **ka), Design(s, episodes=episodes[1], **kb)
            result = fn(a, b, studies, seed)
            rows += [{"setting": name, "seeds": s, "method": m, **v} for m, v in result.items()]
    return rows


def coverage(
    design: Design,
    studies: int = 1000,
    seed: int = 0,
    methods: dict[str, Callable] | None = None,
) -> dict[str, dict[str, float]]:
    """Share of ``studies`` simulated studies of ``design`` whose nominal 95% interval
    covers the true mean, per method, with each method's median width as a multiple of
    the oracle's (the true standard deviation of the mean over these studies, times the
    normal quantile). Derandomised: the same ``seed`` gives the same table."""
    methods = METHODS if methods is None else methods
    rng = np.random.default_rng(seed)
    truth = design.truth()
    tables = [design.draw(rng) for _ in range(studies)]
    means = [t.mean() for t in tables]
    out: dict[str, dict[str, float]] = {}
    for name, method in methods.items():
        kwargs = {"rng": np.random.default_rng(seed + 1)} if method is _two_level else {}
        out[name] = _summary(means, truth, [method(t, **kwargs)[1:] for t in tables])
    return out


def difference_coverage(
    a: Design, b: Design, studies: int = 1000, seed: int = 0
) -> dict[str, dict[str, float]]:
    """:func:`coverage` of the difference between two arms (unrelated trainings) that play
    the same episodes: each study draws one set of episode factors for both arms."""
    rng = np.random.default_rng(seed)
    boot = np.random.default_rng(seed + 1)
    truth = a.truth() - b.truth()
    diffs = []
    bounds: dict[str, list] = {"two-level bootstrap": [], "seed t (Welch)": [], "printed": []}
    for _ in range(studies):
        f = a.episode_factors(rng, a.episodes)
        ya, yb = (d.play(rng, d.seed_rates(rng, d.seeds), f) for d in (a, b))
        diffs.append(ya.mean() - yb.mean())
        bounds["printed"].append(crossed_difference_interval(ya, yb)[1:])
        bounds["seed t (Welch)"].append(_welch(ya.mean(axis=1), yb.mean(axis=1)))
        n_a, n_b = np.full(a.seeds, a.episodes), np.full(b.seeds, b.episodes)
        result = seed_bootstrap_diff(ya.sum(axis=1), n_a, yb.sum(axis=1), n_b, boot, draws=1000)
        bounds["two-level bootstrap"].append(result[1:3])
    return {name: _summary(diffs, truth, bb) for name, bb in bounds.items()}


def paired_coverage(
    a: Design, b: Design, studies: int = 1000, seed: int = 0
) -> dict[str, dict[str, float]]:
    """:func:`coverage` of the difference between the same models in two conditions: each
    seed's rate in ``b`` is its rate in ``a`` times ``b.rate / a.rate`` (one model), each
    condition has its own episodes, shared by every seed."""
    rng = np.random.default_rng(seed)
    truth = a.truth() - b.truth()
    diffs, bounds = [], []
    for _ in range(studies):
        pa = a.seed_rates(rng, a.seeds)
        ya = a.play(rng, pa, a.episode_factors(rng, a.episodes))
        yb = b.play(rng, pa * b.rate / a.rate, b.episode_factors(rng, b.episodes))
        d = ya.mean() - yb.mean()
        diffs.append(d)
        bounds.append(t_test(d, *paired_difference_variance(ya, yb))[:2])
    return {"printed": _summary(diffs, truth, bounds)}


def _welch(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Welch's interval of the difference of two seed means (its degrees of freedom are
    Satterthwaite's for the two variance terms)."""
    vx, vy = x.var(ddof=1) / len(x), y.var(ddof=1) / len(y)
    df = satterthwaite([(vx, len(x) - 1), (vy, len(y) - 1)])
    return t_test(float(x.mean() - y.mean()), vx + vy, max(df, 1.0))[:2]


SETTINGS: dict[str, dict] = {
    "rate 0.5%": {"rate": 0.005},
    "rate 5%": {"rate": 0.05},
    "rate 30%": {"rate": 0.3},
    "rare, lognormal seeds": {"rate": 0.005, "spread": "lognormal"},
    "alike seeds, hard episodes": {"rate": 0.05, "cv": 0.05, "episode_cv": 1.5},
}
"""The simulated settings of the coverage table: seed rates spread normally (coefficient of
variation 0.3) at three rates, rare rates spread lognormally (log-sd 1.2, a few seeds far
above the rest), and seeds that all drive alike in episodes of very unequal difficulty
(where the shared episodes, not the seeds, make the uncertainty)."""


def coverage_table(
    studies: int = 1000, seeds: tuple[int, ...] = (3, 5, 10), episodes: int = 100, seed: int = 0
) -> list[dict]:
    """:func:`coverage` of every method in every :data:`SETTINGS` at each seed count, one
    row per setting, seed count and method."""
    rows = []
    for name, kwargs in SETTINGS.items():
        for s in seeds:
            result = coverage(Design(s, episodes=episodes, **kwargs), studies, seed)
            rows += [{"setting": name, "seeds": s, "method": m, **v} for m, v in result.items()]
    return rows


DIFFERENCES: dict[str, tuple[dict, dict]] = {
    "5% vs 3%": ({"rate": 0.05}, {"rate": 0.03}),
    "30% vs 20%": ({"rate": 0.3}, {"rate": 0.2}),
    "rare, lognormal seeds, equal": (
        {"rate": 0.005, "spread": "lognormal"},
        {"rate": 0.005, "spread": "lognormal"},
    ),
    "alike seeds, hard episodes": (
        {"rate": 0.05, "cv": 0.05, "episode_cv": 1.5},
        {"rate": 0.04, "cv": 0.05, "episode_cv": 1.5},
    ),
}
"""The simulated differences between two arms of the coverage table."""


def difference_table(
    studies: int = 1000, seeds: tuple[int, ...] = (3, 5, 10), episodes: int = 700, seed: int = 0
) -> list[dict]:
    """:func:`difference_coverage` in every :data:`DIFFERENCES` at each seed count."""
    return _rows(DIFFERENCES, difference_coverage, (episodes, episodes), studies, seeds, seed)


PAIRED: dict[str, tuple[dict, dict]] = {
    "5% vs 3%": ({"rate": 0.05}, {"rate": 0.03}),
    "30% vs 20%": ({"rate": 0.3}, {"rate": 0.2}),
    "0.5% vs 1%": ({"rate": 0.005}, {"rate": 0.01}),
    "5% vs 3%, lognormal seeds": (
        {"rate": 0.05, "spread": "lognormal"},
        {"rate": 0.03, "spread": "lognormal"},
    ),
}
"""The simulated differences of the same models in two conditions (300 and 600 episodes)."""


def paired_table(studies: int = 1000, seeds: tuple[int, ...] = (3, 5, 10), seed: int = 0) -> list:
    """:func:`paired_coverage` in every :data:`PAIRED` setting at each seed count."""
    return _rows(PAIRED, paired_coverage, (300, 600), studies, seeds, seed)


def scene_coverage(
    a: Design, b: Design, studies: int = 1000, seed: int = 0
) -> dict[str, dict[str, float]]:
    """:func:`coverage` of the difference between the same models in two settings that play
    the same scenes (two perception radii): each seed's rate in ``b`` is its rate in ``a``
    times ``b.rate / a.rate``, and one uniform draw per seed and scene decides both
    outcomes (a scene that is hard in one setting is hard in the other). The interval is
    the crossed one of the per-scene differences."""
    rng = np.random.default_rng(seed)
    truth = a.truth() - b.truth()
    diffs, bounds = [], []
    for _ in range(studies):
        pa = np.minimum(a.seed_rates(rng, a.seeds)[:, None] * a.episode_factors(rng, a.episodes), 1)
        u = rng.random(pa.shape)
        d = (u < pa).astype(float) - (u < np.minimum(pa * b.rate / a.rate, 1)).astype(float)
        diffs.append(d.mean())
        bounds.append(crossed_interval(d)[1:])
    return {"printed": _summary(diffs, truth, bounds)}


def scene_table(studies: int = 1000, seeds: tuple[int, ...] = (3, 5, 10), seed: int = 0) -> list:
    """:func:`scene_coverage` in every :data:`PAIRED` setting (700 shared scenes)."""
    return _rows(PAIRED, scene_coverage, (700, 700), studies, seeds, seed)


def yardstick_coverage(
    design: Design, ratio: float = 1.5, studies: int = 1000, seed: int = 0
) -> dict[str, dict[str, float]]:
    """:func:`coverage` of a learned arm's collisions per 100 km less a yardstick's, the
    interval :mod:`bgap.analysis.yardsticks` prints: the yardstick is one driver of crash
    rate ``ratio`` x the design's, playing the arm's episodes (their difficulty shared); an
    episode drives 1 km, or half of it where it ends in a crash; one cell."""
    rng = np.random.default_rng(seed)
    yard_rate = design.rate * ratio
    # the truth: each seed's crashes over its kilometres, over a population of episodes
    truth_rng = np.random.default_rng(12345)
    f = design.episode_factors(truth_rng, 20_000)

    def per_100km(rates: np.ndarray) -> np.ndarray:
        p = np.minimum(rates[:, None] * f[None, :], 1.0)
        return p.mean(axis=1) / (1.0 - 0.5 * p).mean(axis=1) * 100.0

    seeds_truth = np.concatenate([per_100km(design.seed_rates(truth_rng, 500)) for _ in range(20)])
    truth = float(seeds_truth.mean() - per_100km(np.array([yard_rate]))[0])

    def sides(y: np.ndarray) -> tuple:
        """Crashes, kilometres' metres and speeds of a crash table."""
        return y, 1000.0 * (1 - 0.5 * y), np.full(y.shape, 25.0)

    mixes = np.zeros(design.episodes)
    diffs, bounds = [], []
    for _ in range(studies):
        factors = design.episode_factors(rng, design.episodes)
        ya = design.play(rng, design.seed_rates(rng, design.seeds), factors)
        yb = design.play(rng, np.array([yard_rate]), factors)
        result = compare(sides(ya), sides(yb), mixes)
        diffs.append(result["diff"])
        bounds.append((result["diff_lo"], result["diff_hi"]))
    return {"printed": _summary(diffs, truth, bounds)}


def yardstick_table(
    studies: int = 1000, seeds: tuple[int, ...] = (3, 5, 10), seed: int = 0
) -> list[dict]:
    """:func:`yardstick_coverage` at the rates and seed spreads of :func:`coverage_table`,
    700 shared episodes (the seven cells of a density), a yardstick 1.5 x as likely to crash."""
    rows = []
    for name, kwargs in SETTINGS.items():
        for s in seeds:
            result = yardstick_coverage(
                Design(s, episodes=700, **kwargs), studies=studies, seed=seed
            )
            rows += [{"setting": name, "seeds": s, "method": m, **v} for m, v in result.items()]
    return rows

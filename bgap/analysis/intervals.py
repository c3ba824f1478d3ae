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

:func:`coverage` simulates studies of the study's design with a known true mean and counts
how often each method's nominal 95% interval covers it; :data:`METHODS` names the methods
it compares (the two-level bootstrap the study printed, Student t over seed means, and the
crossed interval) and the oracle that knows the true variance of the mean.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtri, stdtr, stdtrit

from bgap.analysis.stats import seed_bootstrap_diff, seed_rate_interval, wilson_interval

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


def _satterthwaite(terms: list[tuple[float, float]]) -> float:
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
    df = _satterthwaite([(ms_s, df_s), (ms_e, df_e), (-ms_r, df_r)])
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
    terms = [(ms_sa / (sa * e), df_sa), (ms_sb / (sb * e), df_sb), (ms_d / e, e - 1),
             (-ms_ra / (sa * e), df_ra), (-ms_rb / (sb * e), df_rb)]  # fmt: skip
    var = sum(v for v, _ in terms)
    df = _satterthwaite(terms)
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
    var, df = sum(v for v, _ in terms), _satterthwaite(terms)
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
    method covers in every setting of :func:`coverage_table`; this one does at 3, 5 and 10
    seeds."""
    mean, lo, hi = crossed_interval(y, level)
    _, _, hi_log = log_rate_interval(y, level)
    y = np.asarray(y, dtype=float)
    w_lo, w_hi = wilson_interval(int(round(y.sum())), y.size, z=float(ndtri(0.5 + level / 2)))
    return mean, max(0.0, min(lo, w_lo)), max(hi, hi_log, w_hi)


# --- methods the coverage simulation compares -------------------------------------------


def _seed_t(y: np.ndarray, level: float = LEVEL) -> tuple[float, float, float]:
    """Student t over the seeds' means: seeds as the units, shared episodes ignored."""
    m = y.mean(axis=1)
    half = _t(len(m) - 1, level) * m.std(ddof=1) / np.sqrt(len(m))
    return float(m.mean()), float(m.mean() - half), float(m.mean() + half)


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


def _welch(x: np.ndarray, y: np.ndarray, level: float = LEVEL) -> tuple[float, float]:
    vx, vy = x.var(ddof=1) / len(x), y.var(ddof=1) / len(y)
    df = (vx + vy) ** 2 / (vx**2 / (len(x) - 1) + vy**2 / (len(y) - 1)) if vx + vy > 0 else 1.0
    half = _t(max(df, 1.0), level) * np.sqrt(vx + vy)
    d = x.mean() - y.mean()
    return float(d - half), float(d + half)


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

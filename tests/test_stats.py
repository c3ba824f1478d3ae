"""bgap.stats against textbook values and a simulation with a known answer."""

from __future__ import annotations

import numpy as np
import pytest

from bgap.analysis.stats import (
    bootstrap_test,
    holm,
    seed_bootstrap,
    seed_bootstrap_diff,
    seed_rate_interval,
    wilson_interval,
)


def test_wilson_interval_equals_textbook_values():
    # Newcombe (1998), Table I: 0/10 -> [0, 0.2775]; 5/10 by the closed form
    assert wilson_interval(0, 10) == pytest.approx((0.0, 0.2775), abs=1e-4)
    assert wilson_interval(5, 10) == pytest.approx((0.2366, 0.7634), abs=1e-4)
    assert wilson_interval(300, 300)[0] < 1.0  # never of zero width
    assert wilson_interval(0, 300)[1] > 0.0


def test_holm_by_hand():
    # sorted 0.005, 0.01, 0.03, 0.04 -> x4, x3, x2, x1 = 0.02, 0.03, 0.06, 0.04 -> monotone
    adjusted = holm([0.01, 0.04, 0.03, 0.005])
    np.testing.assert_allclose(adjusted, [0.03, 0.06, 0.06, 0.02])
    assert holm([0.5, 0.9])[1] == 1.0  # capped


def test_seed_bootstrap_covers_a_known_difference_at_its_nominal_rate():
    """1,000 synthetic studies shaped like ours: 10 training seeds x 100 episodes per policy,
    collision rates 30% and 20%, between-seed standard deviation 8 points. The 95% interval
    covers the true difference in 95 +- 3% of them."""
    rng = np.random.default_rng(0)
    seeds, episodes, sd = 10, 100, 0.08
    # the true difference of the clipped seed-level rates, by a large simulation
    truth = (
        np.clip(rng.normal(0.30, sd, 10**6), 0, 1).mean()
        - np.clip(rng.normal(0.20, sd, 10**6), 0, 1).mean()
    )
    n = np.full(seeds, episodes)
    covered, rejected = 0, 0
    for _ in range(1000):
        a = rng.binomial(episodes, np.clip(rng.normal(0.30, sd, seeds), 0, 1))
        b = rng.binomial(episodes, np.clip(rng.normal(0.20, sd, seeds), 0, 1))
        diff, lo, hi, p = seed_bootstrap_diff(a, n, b, n, rng, draws=1000)
        assert lo <= diff <= hi
        covered += lo <= truth <= hi
        rejected += p < 0.05
    assert 0.92 <= covered / 1000 <= 0.98, covered / 1000
    assert rejected / 1000 > 0.5  # a 10-point difference is usually detected at 10 seeds


def test_seed_bootstrap_sees_no_difference_between_identical_arms():
    rng = np.random.default_rng(1)
    n = np.full(5, 100)
    diff, lo, hi, p = seed_bootstrap_diff([20, 25, 30, 22, 18], n, [20, 25, 30, 22, 18], n, rng)
    assert diff == 0.0 and lo < 0 < hi and p > 0.5


def test_two_level_bootstrap_spread_equals_the_closed_form_for_continuous_values():
    """One arm, S seeds with means drawn with sd 2 and n episodes each with sd 5: the mean
    over seeds has variance (sd_b^2 + sd_w^2 / n) / S; the bootstrap's (a plug-in estimate)
    is that times (S - 1) / S for each level. Checked on a large sample to 10%."""
    rng = np.random.default_rng(3)
    seeds, n = 40, 200
    groups = [rng.normal(rng.normal(20, 2), 5, n) for _ in range(seeds)]
    observed, dist = seed_bootstrap(groups, rng=rng, draws=4000)
    assert observed == pytest.approx(np.mean([g.mean() for g in groups]))
    seed_means = np.array([g.mean() for g in groups])
    within = np.mean([g.var(ddof=0) for g in groups]) / n
    # plug-in: between-seed variance of the observed means (ddof=0) already holds within / n
    expected = seed_means.var(ddof=0) / seeds + within / seeds
    assert dist.std() == pytest.approx(np.sqrt(expected), rel=0.1)


def test_pairing_by_model_removes_the_between_seed_spread():
    """The same 8 models in two conditions, each crashing 5 points more in the second, with
    rates spread widely between models: the paired interval is far narrower than the
    unpaired one and both cover the 5-point difference."""
    rng = np.random.default_rng(4)
    rates = np.linspace(0.1, 0.6, 8)
    a = [rng.binomial(1, r + 0.05, 2000) for r in rates]
    b = [rng.binomial(1, r, 2000) for r in rates]
    widths = {}
    for paired in (True, False):
        observed, dist = seed_bootstrap(a, b, rng=rng, draws=4000, paired=paired)
        lo, hi, _ = bootstrap_test(dist)
        assert lo < 0.05 < hi and lo <= observed <= hi
        widths[paired] = hi - lo
    assert widths[True] < 0.3 * widths[False]
    with pytest.raises(ValueError, match="same seeds"):
        seed_bootstrap(a, b[:3], rng=rng, paired=True)


def test_per_scene_differences_are_never_read_as_a_rates_events():
    """Speed differences of exactly 0 on every scene (a setting the policy ignores) are no
    rate of 0 events: no draw lies off 0, so the difference is not significant; crash
    differences are -1, 0 or +1 and nothing else."""
    rng = np.random.default_rng(6)
    zeros = [np.zeros(50)] * 4
    observed, dist = seed_bootstrap(zeros, rng=rng, draws=2000, differences="values")
    assert observed == 0.0 and bootstrap_test(dist)[2] == 1.0
    observed, dist = seed_bootstrap(zeros, rng=rng, draws=2000)  # read as rates: all above 0
    assert (dist > 0).all()
    observed, dist = seed_bootstrap(zeros, rng=rng, draws=2000, differences="events")
    lo, hi, p = bootstrap_test(dist, observed=observed)
    assert lo < 0.0 < hi and p > 0.5  # varies symmetrically about 0: no zero width
    with pytest.raises(ValueError, match="-1, 0 or"):
        seed_bootstrap([np.full(5, 100.0)], rng=rng, differences="events")
    with pytest.raises(ValueError, match="alone"):
        seed_bootstrap(zeros, zeros, rng=rng, differences="values")


def test_a_rate_interval_over_seeds_is_never_of_zero_width():
    rng = np.random.default_rng(5)
    lo, hi = seed_rate_interval([np.zeros(100)] * 3, rng)
    assert lo == 0.0 and hi >= wilson_interval(0, 300)[1] > 0  # never narrower than Wilson
    lo, hi = seed_rate_interval([np.zeros(100), np.ones(100) * (np.arange(100) < 40)], rng)
    assert lo < 0.1 < 0.3 < hi  # two seeds at 0% and 40%: the seeds' spread dominates
    assert bootstrap_test(np.array([-1.0, 1.0, 2.0, 3.0]), level=0.5)[2] == 0.5


def test_poisson_interval_equals_textbook_values():
    """Garwood's exact interval: 0 events -> [0, -ln(0.025)] = [0, 3.689]; 10 events ->
    [4.795, 18.390] (tables of the Poisson mean's exact limits), per unit of exposure."""
    from bgap.analysis.stats import poisson_interval

    assert poisson_interval(0, 1.0) == (0.0, pytest.approx(-np.log(0.025), rel=1e-9))
    lo, hi = poisson_interval(10, 2.0)
    assert (lo, hi) == (pytest.approx(4.7954 / 2, abs=1e-4), pytest.approx(18.3904 / 2, abs=1e-4))


def test_quantiles_are_scipy_stats_own_over_the_counts_the_study_sees():
    """The Garwood and t quantiles (scipy.special) equal scipy.stats' chi-square and Student t
    quantiles float for float, from 0 to 5,000 events and 1 to 5,000 degrees of freedom."""
    from scipy.stats import chi2
    from scipy.stats import t as student_t

    from bgap.analysis.stats import poisson_interval, t_interval

    tail = (1 - 0.95) / 2  # as poisson_interval computes it (0.025000000000000022)
    for k in (0, 1, 2, 3, 7, 10, 42, 100, 999, 5000):
        lo = 0.0 if k == 0 else chi2.ppf(tail, 2 * k) / 2
        assert poisson_interval(k, 1.0) == (lo, chi2.ppf(1 - tail, 2 * k + 2) / 2)
    for n in (2, 3, 5, 10, 30, 100, 1000, 5001):
        x = np.arange(n, dtype=float) ** 1.5
        half = student_t.ppf(0.975, n - 1) * x.std(ddof=1) / np.sqrt(n)
        assert t_interval(x) == (x.mean() - half, x.mean() + half)


def test_collisions_per_100km_of_a_hand_built_set_of_episodes():
    """Three episodes: 10 km without a crash, 20 km ending in one, 20 km ending in one:
    2 crashes over 50 km = 4 per 100 km; per seed, the mean of the seeds' own rates."""
    from bgap.analysis.stats import per_100km, seed_per_100km_interval

    crashes, metres = np.array([0, 1, 1]), np.array([10_000.0, 20_000.0, 20_000.0])
    rate, lo, hi = per_100km(crashes, metres)
    assert rate == pytest.approx(4.0) and lo < 4.0 < hi
    # two seeds: 0 crashes over 50 km and 2 over 50 km -> (0 + 4) / 2 = 2 per 100 km
    rng = np.random.default_rng(0)
    mean, lo, hi = seed_per_100km_interval(
        [np.zeros(3), crashes], [metres, metres], rng, draws=2000
    )
    assert mean == pytest.approx(2.0) and lo < 2.0 < hi
    # a policy that never crashed still gets an upper bound (3.689 events over 100 km)
    mean, lo, hi = seed_per_100km_interval([np.zeros(3)] * 2, [metres] * 2, rng, draws=200)
    assert (mean, lo) == (0.0, 0.0) and hi == pytest.approx(3.689, abs=1e-3)


def test_a_sample_without_spread_still_gets_an_interval_of_positive_width():
    """Lane changes that are 0 in all 100 episodes (an idle ego) read [0, 3.69 / 100], the
    exact Poisson bound of 0 events in 100 episodes; a constant speed gets its value +- its
    stored (single) precision; a sample with spread keeps Student's t interval."""
    from bgap.analysis.stats import spread_interval, t_interval

    lo, hi = spread_interval(np.zeros(100), counts=True)
    assert lo == 0 and hi == pytest.approx(-np.log(0.025) / 100, rel=1e-9)  # 3.689 / 100
    lo, hi = spread_interval(np.full(100, 2.0), counts=True)  # 200 events in 100 episodes
    assert lo < 2.0 < hi and hi - lo == pytest.approx(2 * 1.96 * np.sqrt(200) / 100, rel=0.05)
    lo, hi = spread_interval(np.full(50, 25.0))
    assert lo < 25.0 < hi and hi - lo == pytest.approx(2 * np.spacing(np.float32(25.0)))
    x = np.array([1.0, 2.0, 4.0])
    assert spread_interval(x) == t_interval(x)


def test_collisions_per_100km_by_hand():
    """20 m/s for 50 steps at 1 Hz is 1,000 m, 30 m/s for 10
    steps at 1 Hz 300 m; one crash over 1.3 km is 76.92 per 100 km."""
    import pandas as pd

    from bgap.common.scores import collisions_per_100km, episode_distance

    episodes = pd.DataFrame({"avg_speed": [20.0, 30.0], "steps": [50, 10], "crashed": [0, 1]})
    distance = episode_distance(episodes, 1)
    assert distance.tolist() == [1000.0, 300.0]
    assert episode_distance(episodes, 2).tolist() == [500.0, 150.0]  # steps of half a second
    assert collisions_per_100km(episodes.crashed, distance) == pytest.approx(100_000 / 1300)

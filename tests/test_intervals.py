"""The crossed-design intervals (bgap.analysis.intervals): the ANOVA against a hand-computed
table, the variance estimators against the closed-form variance of simulated crossed designs,
and the printed intervals' coverage against simulated studies with a known true rate
(bgap.analysis.coverage)."""

import numpy as np
import pytest

from bgap.analysis.coverage import (
    Design,
    coverage,
    coverage_table,
    difference_coverage,
    difference_table,
    paired_table,
    scene_table,
)
from bgap.analysis.intervals import (
    crossed_difference_interval,
    crossed_interval,
    crossed_variance,
    log_rate_interval,
    rate_interval,
)


def test_crossed_variance_matches_a_hand_computed_two_way_anova():
    y = np.array([[1.0, 0.0, 2.0, 1.0], [3.0, 1.0, 2.0, 2.0], [2.0, 2.0, 5.0, 3.0]])
    s, e = y.shape
    # by hand: grand mean 2; seed means 1, 2, 3; episode means 2, 1, 3, 2
    ms_seed = e * ((1 - 2) ** 2 + 0 + (3 - 2) ** 2) / (s - 1)  # 4
    ms_episode = s * (0 + 1 + 1 + 0) / (e - 1)  # 2
    resid = sum(
        (y[i, j] - [1, 2, 3][i] - [2, 1, 3, 2][j] + 2) ** 2 for i in range(s) for j in range(e)
    )
    ms_resid = resid / ((s - 1) * (e - 1))
    var, df = crossed_variance(y)
    assert var == pytest.approx((ms_seed + ms_episode - ms_resid) / (s * e))
    terms = [(ms_seed, s - 1), (ms_episode, e - 1), (-ms_resid, (s - 1) * (e - 1))]
    expect_df = sum(v for v, _ in terms) ** 2 / sum(v**2 / d for v, d in terms)
    assert df == pytest.approx(expect_df)
    mean, lo, hi = crossed_interval(y)
    assert mean == 2.0 and lo < 2.0 < hi and (hi - lo) / 2 > np.sqrt(var) * 1.96


def test_crossed_variance_is_unbiased_for_a_gaussian_crossed_design():
    """y = seed effect + episode effect + noise: Var(mean) = s2_s/S + s2_e/E + s2_r/(S E)
    in closed form; the estimator's average over many studies must match it."""
    rng = np.random.default_rng(1)
    s, e, sd_s, sd_e, sd_r = 5, 40, 1.0, 0.5, 2.0
    truth = sd_s**2 / s + sd_e**2 / e + sd_r**2 / (s * e)
    estimates, means = [], []
    for _ in range(4000):
        y = (
            sd_s * rng.standard_normal((s, 1))
            + sd_e * rng.standard_normal((1, e))
            + sd_r * rng.standard_normal((s, e))
        )
        estimates.append(crossed_variance(y)[0])
        means.append(y.mean())
    assert np.var(means) == pytest.approx(truth, rel=0.06)  # the simulation itself
    assert np.mean(estimates) == pytest.approx(truth, rel=0.04)


def test_difference_interval_sees_the_shared_episodes():
    """Two arms on the same episodes: the episode effects they share cancel from the
    difference, the ones they do not share stay; its width follows the closed form."""
    rng = np.random.default_rng(2)
    sa, sb, e = 5, 4, 30
    sd_s, sd_shared, sd_own, sd_r = 0.5, 3.0, 1.0, 1.0
    truth = (
        sd_s**2 / sa + sd_s**2 / sb + 2 * sd_own**2 / e + sd_r**2 / (sa * e) + sd_r**2 / (sb * e)
    )
    covered, halves = [], []
    for _ in range(3000):
        shared = sd_shared * rng.standard_normal(e)
        a = (sd_s * rng.standard_normal((sa, 1)) + shared + sd_own * rng.standard_normal(e)
             + sd_r * rng.standard_normal((sa, e)))  # fmt: skip
        b = (sd_s * rng.standard_normal((sb, 1)) + shared + sd_own * rng.standard_normal(e)
             + sd_r * rng.standard_normal((sb, e)))  # fmt: skip
        d, lo, hi = crossed_difference_interval(a, b)
        covered.append(lo <= 0 <= hi)
        halves.append((hi - lo) / 2)
    assert 0.93 <= np.mean(covered) <= 0.975
    # the shared effect (sd 3, the largest) must not enter: the median half-width is near
    # t * the true sd, far below what an interval carrying sd_shared would need
    assert np.median(halves) < 3.5 * np.sqrt(truth)
    with pytest.raises(ValueError, match="different episodes"):
        crossed_difference_interval(np.zeros((3, 4)), np.zeros((3, 5)))


def test_a_table_without_events_still_gets_an_interval():
    y = np.zeros((5, 100))
    mean, lo, hi = rate_interval(y)
    assert mean == 0 and lo == 0 and 0.005 < hi < 0.01  # Wilson's 0 of 500: [0, 0.0076]
    assert log_rate_interval(y)[2] > 0


def test_the_printed_interval_covers_where_the_two_level_bootstrap_did_not():
    """The audit's finding, reproduced: at 3 seeds of a 30% rate the two-level bootstrap
    covers far below 95%; the printed interval covers, also for rare skewed seed rates."""
    normal = coverage(Design(3, 0.3, episodes=700), studies=300)
    assert normal["two-level bootstrap"]["coverage"] < 0.88
    assert normal["printed"]["coverage"] >= 0.92
    skewed = coverage(Design(5, 0.005, "lognormal", episodes=700), studies=300)
    assert skewed["crossed t"]["coverage"] < 0.88  # symmetric intervals miss the high seeds
    assert skewed["printed"]["coverage"] >= 0.92
    diff = difference_coverage(Design(5, 0.3, episodes=700), Design(5, 0.2, episodes=700), 300)
    assert diff["printed"]["coverage"] >= 0.92


def test_coverage_is_derandomised():
    d = Design(3, 0.05, episodes=50)
    assert coverage(d, studies=20, seed=4) == coverage(d, studies=20, seed=4)


@pytest.mark.slow
def test_every_printed_interval_covers_at_5_and_10_seeds():
    """1,000 simulated studies per setting: 3, 5 and 10 seeds; rates of 0.5%, 5% and 30%;
    rare lognormal seed rates; seeds alike in episodes of unequal difficulty; one cell (100
    shared episodes) and one claim's pool (700); differences between two arms and between
    two conditions of the same models (whose skewed-seed setting is reported in
    docs/intervals.md, not bounded: no method tried reaches 93% there). At 5 and 10
    seeds the printed intervals cover at least 93% and are at most about twice as wide as
    the oracle's (2.03 at 0.5% over 700 episodes and 5 seeds, the widest); 3 seeds is
    reported, not bounded."""
    rows = coverage_table(1000, episodes=100) + coverage_table(1000, episodes=700)
    rows += difference_table(1000)
    rows += [r for r in paired_table(1000) if "lognormal" not in r["setting"]]
    printed = [r for r in rows if r["method"] == "printed" and r["seeds"] >= 5]
    assert len(printed) == 2 * 5 * 2 + 4 * 2 + 3 * 2
    # per-scene differences (two radii): 92.8% at 10 seeds of 30% vs 20%, just short
    scenes = [r for r in scene_table(1000) if "lognormal" not in r["setting"] and r["seeds"] >= 5]
    assert all(r["coverage"] >= 0.92 for r in scenes), scenes
    low = [r for r in printed if r["coverage"] < 0.93]
    assert not low, low
    wide = [r for r in printed if r["width"] > 2.05]
    assert not wide, wide

"""bgap.stats against textbook values and a simulation with a known answer."""

from __future__ import annotations

import numpy as np
import pytest

from bgap.stats import holm, seed_bootstrap_diff, wilson_interval


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
    """600 synthetic studies shaped like ours: 10 training seeds x 100 episodes per policy,
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
    for _ in range(600):
        a = rng.binomial(episodes, np.clip(rng.normal(0.30, sd, seeds), 0, 1))
        b = rng.binomial(episodes, np.clip(rng.normal(0.20, sd, seeds), 0, 1))
        diff, lo, hi, p = seed_bootstrap_diff(a, n, b, n, rng, draws=1000)
        assert lo <= diff <= hi
        covered += lo <= truth <= hi
        rejected += p < 0.05
    assert 0.92 <= covered / 600 <= 0.98, covered / 600
    assert rejected / 600 > 0.5  # a 10-point difference is usually detected at 10 seeds


def test_seed_bootstrap_sees_no_difference_between_identical_arms():
    rng = np.random.default_rng(1)
    n = np.full(5, 100)
    diff, lo, hi, p = seed_bootstrap_diff([20, 25, 30, 22, 18], n, [20, 25, 30, 22, 18], n, rng)
    assert diff == 0.0 and lo < 0 < hi and p > 0.5

"""The generalisation study's training mixture (bgap.traffic.mixture): its draws follow the
documented frequencies (chi-square and Kolmogorov-Smirnov tests), environments are shared
among the vehicle counts, and bad weights are refused in one line."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chisquare, kstest

from bgap.common.errors import ConfigError
from bgap.traffic.mixture import MixtureConfig, draw, vehicle_groups

N = 20_000


def _draws(cfg: MixtureConfig) -> list:
    rng = np.random.default_rng(12345)
    return [draw(cfg, rng, vehicles=10) for _ in range(N)]


def test_sources_and_classes_follow_their_weights():
    """Counts of 20,000 draws against the weights 0.5 / 0.2 / 0.3, and the three presets
    equally often among bgap's draws: chi-square does not reject at the 1% level."""
    cfg = MixtureConfig()
    episodes = _draws(cfg)
    counts = [sum(e.source == s for e in episodes) for s in cfg.sources]
    assert chisquare(counts, [N * w for w in cfg.sources.values()]).pvalue > 0.01
    bgap = [e for e in episodes if e.source == "bgap"]
    by_class = [sum(e.behavior == c for e in bgap) for c in cfg.classes]
    assert chisquare(by_class).pvalue > 0.01
    assert all(np.isnan(e.mix) and not e.scale for e in episodes if e.source != "bgap")


def test_shares_and_factors_are_uniform_on_their_ranges():
    cfg = MixtureConfig(mix=(0.2, 0.6), scale=(0.8, 1.2))
    bgap = [e for e in _draws(cfg) if e.source == "bgap"]
    mixes = np.array([e.mix for e in bgap])
    assert kstest(mixes, "uniform", args=(0.2, 0.4)).pvalue > 0.01
    factors = np.concatenate([e.scale for e in bgap])
    assert len(bgap[0].scale) == 10  # one per vehicle
    assert kstest(factors, "uniform", args=(0.8, 0.4)).pvalue > 0.01


def test_a_zero_weight_source_is_never_drawn_and_the_same_stream_draws_the_same():
    cfg = MixtureConfig(sources={"bgap": 1.0, "stock": 0.0, "replay": 0.0})
    assert {e.source for e in _draws(cfg)} == {"bgap"}
    assert _draws(cfg)[:50] == _draws(cfg)[:50]


def test_environments_are_shared_among_the_vehicle_counts():
    assert vehicle_groups(MixtureConfig(), 12) == [(5, 3), (10, 3), (20, 2), (30, 2), (40, 2)]
    assert sum(n for _, n in vehicle_groups(MixtureConfig(), 256)) == 256
    with pytest.raises(ConfigError, match="n_envs=3 is invalid"):
        vehicle_groups(MixtureConfig(), 3)


@pytest.mark.parametrize(
    ("kwargs", "says"),
    [
        ({"sources": {"bgap": -1.0}}, "mixture.sources"),
        ({"sources": {"sumo": 1.0}}, "mixture.sources"),
        ({"mix": (0.6, 0.2)}, "mixture.mix"),
        ({"scale": (0.0, 1.0)}, "mixture.scale"),
        ({"vehicles": []}, "mixture.vehicles"),
    ],
)
def test_bad_weights_and_ranges_are_refused_in_one_line(kwargs, says):
    with pytest.raises(ConfigError, match=says):
        MixtureConfig(**kwargs)

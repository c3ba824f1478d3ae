"""Learned policies against the hand-built drivers (bgap.analysis.yardsticks): figures and
verdicts on hand-computed episodes, and the interval's simulated coverage."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from bgap.analysis.aggregates import aggregates
from bgap.analysis.aggregates import markdown as aggregate_markdown
from bgap.analysis.coverage import Design, yardstick_coverage, yardstick_table
from bgap.analysis.stats import RULE_FLOOR
from bgap.analysis.yardsticks import MIN_SEEDS, markdown, versus, versus_yardsticks


def _episodes(family: str, seeds: list[int], crashes: dict, speed: float, arm: str = "x"):
    """Two cells (mixes 0 and 1) of 40 episodes each: episode k of every training seed
    drives 1 km at ``speed``, or half of it where ``crashes[(mix, seed)]`` lists k."""
    rows = []
    for s in seeds:
        for mix in (0.0, 1.0):
            for k in range(40):
                hit = k in crashes.get((mix, s), ())
                rows.append({"policy": family, "arm": arm, "family": family, "train_seed": s,
                             "traffic": "paper", "density": "dense", "radius": 180.0,
                             "mix": mix, "seed": 1000 + k, "crashed": hit,
                             "distance": 500.0 if hit else 1000.0, "avg_speed": speed})  # fmt: skip
    return pd.DataFrame(rows)


def test_figures_are_the_hand_computed_pooled_rates():
    """Seed 0 crashes once in each cell, seed 1 never; the yardstick twice in mix 0. The
    policy's pooled rate is the mean over seeds and cells of crashes over kilometres:
    seed 0: 1 / 39.5 km in each cell, seed 1: 0; the yardstick (1 seed): (2 / 39 + 0) / 2."""
    policy = _episodes("behavior_rich", [0, 1], {(0.0, 0): [3], (1.0, 0): [7]}, 25.0)
    yard = _episodes("rule", [-1], {(0.0, -1): [1, 2]}, 26.0, arm="")
    r = versus(policy, yard)
    assert r["per_100km"] == pytest.approx(100 * (1 / 39.5) / 2)
    assert r["yard_per_100km"] == pytest.approx(100 * (2 / 39) / 2)
    assert r["diff"] == pytest.approx(r["per_100km"] - r["yard_per_100km"])
    assert r["speed_ratio"] == pytest.approx(25.0 / 26.0)
    assert r["diff_lo"] < r["diff"] < r["diff_hi"]
    assert r["verdict"] == "too few seeds"  # 2 < MIN_SEEDS


def test_verdicts_need_the_whole_interval_below_zero_and_the_speed():
    """Many seeds crash-free against a yardstick that crashes in a quarter of its episodes:
    beats it at its speed, is 'safer, slower' below RULE_FLOOR x its speed; against a
    yardstick that crashes as often, no verdict either way."""
    seeds = list(range(MIN_SEEDS))
    yard = _episodes("rule", [-1], {(m, -1): list(range(0, 40, 4)) for m in (0.0, 1.0)}, 26.0,
                     arm="")  # fmt: skip
    assert versus(_episodes("behavior_rich", seeds, {}, 26.0), yard)["verdict"] == "beats"
    slow = _episodes("behavior_rich", seeds, {}, 26.0 * RULE_FLOOR - 0.1)
    assert versus(slow, yard)["verdict"] == "safer, slower"
    alike = {(m, s): list(range(s, 40, 4)) for m in (0.0, 1.0) for s in seeds}
    assert versus(_episodes("behavior_rich", seeds, alike, 26.0), yard)["verdict"] == (
        "not significant"
    )


def test_beats_the_hand_built_driver_only_by_beating_all_three():
    """A policy that beats rule and rule_tuned but not idm (crash-free) is not said to beat
    the hand-built driver; another grid's yardstick is not compared at all."""
    seeds = list(range(MIN_SEEDS))
    crashy = {(m, -1): list(range(0, 40, 4)) for m in (0.0, 1.0)}
    df = pd.concat([_episodes("behavior_rich", seeds, {}, 26.0),
                    _episodes("rule", [-1], crashy, 26.0, arm=""),
                    _episodes("rule_tuned", [-1], crashy, 26.0, arm=""),
                    _episodes("idm", [-1], {}, 26.0, arm="")])  # fmt: skip
    table = versus_yardsticks(df)
    assert list(table.verdict) == ["beats", "beats", "not significant"]
    assert not table.beats_all.any()
    assert "| x behavior-rich | " in markdown(table) and "| no |" in markdown(table)
    df.loc[df.family == "idm", "seed"] += 5000  # idm played other episodes
    again = versus_yardsticks(df)
    assert list(again.yardstick) == ["rule", "rule_tuned"]
    assert not again.beats_all.any()  # two of three is not all three


def test_yardstick_coverage_is_derandomised_and_covers_a_common_case():
    d = Design(5, 0.05, episodes=700)
    first = yardstick_coverage(d, studies=150, seed=3)
    assert first == yardstick_coverage(d, studies=150, seed=3)
    assert first["printed"]["coverage"] >= 0.9


@pytest.mark.slow
def test_the_yardstick_interval_covers_at_5_and_10_seeds():
    """1,000 simulated studies per setting (coverage_table's rates and seed spreads, 700
    shared episodes, a yardstick 1.5 x as likely to crash): at 5 and 10 seeds the paired
    interval covers at least 93% and is at most about twice the oracle's width."""
    rows = yardstick_table(1000, seeds=(5, 10))
    low = [r for r in rows if r["coverage"] < 0.93]
    assert not low, low
    wide = [r for r in rows if r["width"] > 2.05]
    assert not wide, wide
    assert np.isfinite([r["coverage"] for r in rows]).all()


def test_aggregate_views_are_the_hand_computed_iqm_and_probability_of_improvement():
    """Seed s crashes in s episodes of mix 0 and never in mix 1; the rule once in mix 0.
    The runs (seed x cell) are r_s = 100 s / (40 - s / 2) per 100 km in mix 0 and 0 in mix 1:
    sorted 0,0,0,0,0,r1,r2,r3, so the IQM is the mean of the middle four, r1 / 4. In mix 0
    seed 0 has fewer collisions than the rule (1), seed 1 as many (1/2), seeds 2 and 3 more;
    in mix 1 all tie: (1.5 / 4 + 1 / 2) / 2."""
    crashes = {(0.0, s): list(range(s)) for s in range(4)}
    df = pd.concat([_episodes("behavior_rich", list(range(4)), crashes, 26.0),
                    _episodes("rule", [-1], {(0.0, -1): [5]}, 26.0, arm="")])  # fmt: skip
    table, runs = aggregates(df)
    (row,) = table.itertuples()
    r = [100 * s / (40 - s / 2) for s in range(4)]
    assert (row.n_seeds, row.n_cells) == (4, 2)
    assert row.iqm_per_100km == pytest.approx(r[1] / 4)
    assert row.mean_per_100km == pytest.approx(sum(r) / 8)
    assert row.p_improve_rule == pytest.approx((1.5 / 4 + 0.5) / 2)
    assert "p_improve_idm" not in table  # no idm episodes: no column
    np.testing.assert_allclose(runs["dense"]["x/behavior_rich"][:, 0], r)
    assert "| x behavior-rich | 4 x 2 | " in aggregate_markdown(table)
    partial = df[~((df.family == "rule") & (df.mix == 1.0))]  # the rule missed a cell
    (again,) = aggregates(partial)[0].to_dict(orient="records")
    assert np.isnan(again.get("p_improve_rule", np.nan))  # compared on all its cells or not
    assert again["iqm_per_100km"] == pytest.approx(r[1] / 4)

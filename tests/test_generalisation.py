"""The generalisation table (bgap.analysis.generalisation) on hand-built episodes: the rates
it reports are the hand-computed ones, and the bar falls exactly where the study sets it
(all and at-fault collisions, a driver with none, the speed floor, every family)."""

from __future__ import annotations

import pandas as pd
import pytest

from bgap.analysis.generalisation import TESTS, clears_bar, generalisation_table, markdown
from bgap.common.vocab import YARDSTICKS

SEEDS = range(5)
EPISODES = 10
CELLS = {
    "bgap_dense": [("paper", "dense", 0.0, 180.0), ("paper", "dense", 0.5, 180.0)],
    "bgap_sparse": [("paper", "sparse", 0.0, 180.0), ("paper", "sparse", 0.5, 180.0)],
    "stock": [("stock", "sparse", 0.5, 180.0), ("stock", "dense", 0.5, 180.0)],
    "replay": [("replay/sumo-idm-dense/reactive", "dense", 0.3, 180.0)] * 1,
}


def _episodes(arm, family, seeds, crashes, ending, speed=25.0, lane_changes=2):
    """Every cell of every test family, ``EPISODES`` episodes of 1 km each; ``crashes``:
    (training seed, cell index within its family, episode) that end in a crash."""
    rows = []
    for cells in CELLS.values():
        for c, (traffic, density, mix, radius) in enumerate(cells):
            for s in seeds:
                for e in range(EPISODES):
                    crashed = (s, c, e) in crashes
                    rows.append({"arm": arm, "family": family, "train_seed": s,
                                 "traffic": traffic, "density": density, "mix": mix,
                                 "radius": radius, "seed": 100000 + e, "crashed": crashed,
                                 "ending": ending if crashed else "none", "distance": 1000.0,
                                 "avg_speed": speed, "lane_changes": lane_changes})  # fmt: skip
    return rows


def _yardsticks(crashes=frozenset({(-1, 0, 3)}), ending="lane_change", **kw):
    """Each hand-built driver (one "seed", -1): by default one at-fault crash in the first
    cell of every family."""
    return [r for y in YARDSTICKS for r in _episodes("", y, [-1], crashes, ending, **kw)]


def test_rates_are_the_hand_computed_ones_and_a_safer_policy_clears():
    """The policy's one crash (seed 0, first cell, rear-ended: not its fault) is 1 crash in
    10 km of one seed's cell: 10 per 100 km there, 5 for the seed over two cells, 1.0 over
    five seeds. The drivers' one at-fault crash per family: 5.0 per 100 km in the two-cell
    families, 10.0 in replay's one cell. Lane changes: 2 per km."""
    df = pd.DataFrame(_episodes("a", "pure", SEEDS, {(0, 0, 0)}, "rear_ended") + _yardsticks())
    table = generalisation_table(df)
    assert len(table) == len(TESTS) * len(YARDSTICKS)
    dense = table[(table.test == "bgap_dense") & (table.yardstick == "rule")].iloc[0]
    assert dense.per_100km == pytest.approx(1.0) and dense.yard_per_100km == pytest.approx(5.0)
    assert dense.fault_per_100km == 0 and dense.fault_yard_per_100km == pytest.approx(5.0)
    replay = table[(table.test == "replay") & (table.yardstick == "idm")].iloc[0]
    assert replay.per_100km == pytest.approx(2.0) and replay.yard_per_100km == pytest.approx(10.0)
    assert dense.lane_changes_per_km == pytest.approx(2.0)
    assert dense.diff_lo <= dense["diff"] <= dense.diff_hi
    assert clears_bar(table) == {("a", "pure"): True}
    assert "Clears the bar in every family, against every hand-built driver: a pure" in markdown(
        table
    )


@pytest.mark.parametrize(
    ("policy", "yards", "why"),
    [
        # more at-fault collisions than the drivers, though fewer in all
        (({(0, 0, 0)}, "rear_end"), ({(-1, 0, 3), (-1, 0, 4)}, "rear_ended"), "at fault"),
        # a crash where the drivers have none
        (({(0, 0, 0)}, "rear_ended"), (frozenset(), "none"), "none"),
        # safer, but slower than 0.95 x the drivers' speed
        (({(0, 0, 0)}, "rear_ended"), ({(-1, 0, 3)}, "lane_change"), "slow"),
    ],
)
def test_the_bar_falls_where_the_study_sets_it(policy, yards, why):
    speed = 23.0 if why == "slow" else 25.0  # 23 / 25 = 0.92 < 0.95
    df = pd.DataFrame(_episodes("a", "pure", SEEDS, *policy, speed=speed) + _yardsticks(*yards))
    table = generalisation_table(df)
    assert not table.clears.any()
    assert clears_bar(table) == {("a", "pure"): False}


def test_a_missing_family_or_other_episodes_fail_the_bar():
    """Without replay episodes the policy cannot clear every family; a seed that played
    other episodes is not compared at all."""
    df = pd.DataFrame(_episodes("a", "pure", SEEDS, set(), "none") + _yardsticks())
    no_replay = df[~df.traffic.str.startswith("replay/")]
    assert clears_bar(generalisation_table(no_replay)) == {("a", "pure"): False}
    moved = df.copy()
    moved.loc[(moved.arm == "a") & (moved.train_seed == 2), "seed"] += 1
    assert generalisation_table(moved).empty

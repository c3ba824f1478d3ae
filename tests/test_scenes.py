"""The replayed scenes' train/test split (bgap.traffic.scenes): disjoint, a third held out,
one per block of three, and stable when a table gains scenes."""

from __future__ import annotations

import hashlib

from bgap.traffic.scenes import split_scenes

TABLES = ("sumo-krauss-sparse", "sumo-krauss-dense", "sumo-idm-sparse", "sumo-idm-dense")


def test_the_sides_never_overlap_and_a_third_of_the_scenes_test():
    for table in TABLES:
        train, test = split_scenes(table, range(30))
        assert not set(train) & set(test)
        assert sorted(train + test) == list(range(30))
        assert len(test) == 10
        assert sorted(s // 3 for s in test) == list(range(10))  # one per block of three


def test_the_held_out_scene_is_the_smallest_hash_of_its_block():
    """By hand for the first block of one table: sha256 of "<table>/<scene>" for 0, 1, 2."""
    digests = {s: hashlib.sha256(f"sumo-idm-dense/{s}".encode()).hexdigest() for s in range(3)}
    _, test = split_scenes("sumo-idm-dense", range(3))
    assert test == [min(digests, key=digests.get)]


def test_a_table_that_gains_scenes_keeps_every_earlier_scene_on_its_side():
    for table in TABLES:
        train10, test10 = split_scenes(table, range(9))
        train30, test30 = split_scenes(table, range(30))
        assert set(train10) <= set(train30) and set(test10) <= set(test30)
    assert split_scenes(TABLES[0], range(30)) != split_scenes(TABLES[3], range(30))  # per table
    assert split_scenes(TABLES[0], range(2)) == ([0, 1], [])  # an incomplete block trains
    _, gap = split_scenes(TABLES[0], [s for s in range(30) if s != 4])  # block 3-5 lacks 4
    assert set(gap) == set(split_scenes(TABLES[0], range(30))[1]) - set(range(3, 6))

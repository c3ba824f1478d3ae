"""Which recorded scenes a policy may train on and which only test it: a replayed table's
scenes split two to one, before any training.

    train, test = split_scenes("sumo-idm-dense", range(30))

Scenes are numbered 0, 1, 2, ... (the replay's scene ids) and taken in blocks of three
(0-2, 3-5, ...): in each block, the scene with the smallest ``sha256("<table>/<scene>")``
is held out for testing. So exactly a third of a table's scenes test when their number is a
multiple of three; the split needs no stored list and is the same on every machine; and a
table that gains blocks keeps every earlier scene on its side. A last block of one or two
scenes holds none out, and completing it can move one of its scenes to test: generate
scenes in multiples of three. Why not a seeded shuffle: its sides move whenever the number
of scenes changes; why not a hash threshold per scene: at 30 scenes its held-out count
ranges widely (5 to 15 on the four SUMO tables' names).
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable

BLOCK = 3
"""Scenes per block, one of which is held out: the 2:1 split."""


def _rank(table: str, scene: int) -> str:
    return hashlib.sha256(f"{table}/{scene}".encode()).hexdigest()


def is_test_scene(table: str, scene: int, scenes: int) -> bool:
    """Whether scene ``scene`` of the table named ``table``, which has ``scenes`` scenes
    numbered from 0, is held out for testing."""
    start = scene - scene % BLOCK
    if start + BLOCK > scenes:
        return False  # an incomplete last block trains
    block = range(start, start + BLOCK)
    return scene == min(block, key=lambda s: _rank(table, s))


def split_scenes(table: str, scenes: Iterable[int]) -> tuple[list[int], list[int]]:
    """The scene ids ``scenes`` (0 to n - 1, in any order) of ``table`` as (training scenes,
    test scenes), each in the given order."""
    scenes = [int(s) for s in scenes]
    test = {s for s in scenes if is_test_scene(table, s, len(scenes))}
    return [s for s in scenes if s not in test], [s for s in scenes if s in test]

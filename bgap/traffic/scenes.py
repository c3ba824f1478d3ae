"""Which recorded scenes a policy may train on and which only test it: a replayed table's
scenes split two to one, before any training.

    train, test = split_scenes("sumo-idm-dense", range(30))

Scenes are numbered 0, 1, 2, ... (the replay's scene ids) and taken in blocks of three
(0-2, 3-5, ...): in each block, the scene with the smallest ``sha256("<table>/<scene>")``
is held out for testing. So exactly a third of a table's scenes test when their number is a
multiple of three; the split needs no stored list and is the same on every machine; and a
table that gains blocks keeps every earlier scene on its side. A block with an id missing
(the last of a table whose count is no multiple of three, or a gap in the ids) holds none
out, and completing it can move one of its scenes to test: generate scenes in multiples of
three, numbered from 0. Why not a seeded shuffle: its sides move whenever the number
of scenes changes; why not a hash threshold per scene: at 30 scenes its held-out count
ranges widely (5 to 15 on the four SUMO tables' names).
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from pathlib import Path

BLOCK = 3
"""Scenes per block, one of which is held out: the 2:1 split."""


def _rank(table: str, scene: int) -> str:
    return hashlib.sha256(f"{table}/{scene}".encode()).hexdigest()


def held_out_scenes(table: str, scenes: Iterable[int]) -> set[int]:
    """The scene ids among ``scenes`` of the table named ``table`` that are held out: in each
    block of three ids (0-2, 3-5, ...) whose three ids are all present, the one with the
    smallest hash (module docstring); a block with an id missing holds none out."""
    present = {int(s) for s in scenes}
    blocks = {s - s % BLOCK for s in present}
    held = set()
    for start in blocks:
        block = range(start, start + BLOCK)
        if all(s in present for s in block):
            held.add(min(block, key=lambda s: _rank(table, s)))
    return held


def split_scenes(table: str, scenes: Iterable[int]) -> tuple[list[int], list[int]]:
    """The scene ids ``scenes`` of ``table`` as (training scenes, test scenes), each in the
    given order (:func:`held_out_scenes`)."""
    scenes = [int(s) for s in scenes]
    held = held_out_scenes(table, scenes)
    return [s for s in scenes if s not in held], [s for s in scenes if s in held]


def table_name(table: str | Path) -> str:
    """The name a table's scenes are split by: its folder's for the pipeline's
    ``<name>/trajectories.parquet``, else the file's stem."""
    path = Path(table)
    return path.parent.name if path.stem == "trajectories" else path.stem

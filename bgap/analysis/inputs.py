"""Checks that every compared arm met the same traffic, before any comparison is made.

Comparisons across arms (a learned policy against the rule-based ego, one arm's claims
beside another's) mean something only when both played the same episodes: the same
replayed tables, the same episode seeds in every cell. ``figures`` joins cells by name, so
an arm evaluated on other tables (a rehearsal's, whose windows are shorter) would be
compared silently. :func:`mismatched_traffic` finds such cells from the episodes
themselves, against the baselines' (the rule-based ego and idle, evaluated once for every
arm); :func:`drop_mismatched` leaves them out of every table, and the results page names
them. Evaluations that recorded their inputs (``inputs.json``: per cell, content hashes of
the replayed table, behaviour preset, episode seeds and environment) are held to more:
:func:`check_inputs` refuses any cell whose inputs differ between two folders.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

import pandas as pd

from bgap.analysis.episodes import INPUTS, REPLAY, evaluation_folders, traffic_of
from bgap.common.errors import ConfigError


class Mismatch(NamedTuple):
    """An arm's cells whose traffic differs from the baselines'."""

    arm: str
    traffic: str
    reason: str

    def line(self) -> str:
        return f"evaluate@{self.arm}, {self.traffic}: {self.reason}"


def mismatched_traffic(df: pd.DataFrame) -> list[Mismatch]:
    """Every (arm, traffic) whose episodes cannot be the baselines' traffic.

    Replayed tables: each episode seed replays one window of a table, so an episode that
    ends without a collision lasts that window's steps, whichever policy drives; an arm
    whose episodes run past the baselines' window of the same seed, or end without a
    collision at another length, replayed other tables. Simulated traffic:
    every cell's episode seeds must be the baselines' seeds of that cell. Without baseline
    episodes of a traffic there is nothing to compare with, and nothing is reported."""
    out: list[Mismatch] = []
    refs = dict(tuple(df[df.arm == ""].groupby("traffic")))
    for traffic, arms in df[df.arm != ""].groupby("traffic", sort=True):
        ref = refs.get(traffic)
        if ref is None:
            continue
        if traffic.startswith(REPLAY):
            for arm, mine in arms.groupby("arm", sort=True):
                why = _other_windows(mine, ref)
                if why:
                    out.append(Mismatch(arm, traffic, why + ": it replayed other tables"))
            continue
        keys = ["density", "mix"]
        ref_seeds = ref.groupby(keys).seed.apply(frozenset)
        for arm, mine in arms.groupby("arm", sort=True):
            for key, seeds in mine.groupby(keys).seed.apply(frozenset).items():
                if key in ref_seeds and seeds != ref_seeds[key]:
                    why = f"its episode seeds at {key[0]}, mix {key[1]:g} are not the baselines'"
                    out.append(Mismatch(arm, traffic, why))
                    break
    return out


def drop_mismatched(df: pd.DataFrame, mismatches: list[Mismatch]) -> pd.DataFrame:
    """``df`` without the cells of ``mismatches``."""
    bad = pd.Series(False, index=df.index)
    for m in mismatches:
        bad |= (df.arm == m.arm) & (df.traffic == m.traffic)
    return df[~bad]


def _other_windows(mine: pd.DataFrame, ref: pd.DataFrame) -> str:
    """Why ``mine`` (one arm's episodes of one replayed traffic) did not replay the windows
    of ``ref`` (the baselines'), or "" where every episode fits them."""
    keys = ["density", "seed"]
    ended = ref[ref.collision_pct == 0].groupby(keys).steps.max().rename("window")
    joined = mine.join(ended, on=keys, how="inner")
    if joined.empty:
        return ""
    survived = joined.collision_pct == 0
    bad = (joined.steps > joined.window) | (survived & (joined.steps != joined.window))
    if not bad.any():
        return ""
    first = joined[bad].iloc[0]
    return (
        f"{int(bad.sum())} of its {len(joined)} episodes do not fit the baselines' "
        f"windows (seed {int(first.seed)}: {int(first.steps)} steps, the window "
        f"{int(first.window)})"
    )


def stage_of(folder: Path) -> str:
    """The pipeline stage that writes evaluation folder ``folder``
    (``results/evaluation/<arm>/<traffic>``), else the folder itself."""
    parts = folder.parts
    if len(parts) >= 3 and parts[-3] == "evaluation":
        arm = parts[-2]
        return "evaluate_baselines" if arm == "baselines" else f"evaluate@{arm}"
    return str(folder)


def check_inputs(sources: list[str | Path], stock: list[str | Path] = ()) -> int:
    """Refuse (:class:`ConfigError`) two evaluation folders whose recorded inputs of one
    cell differ, naming both stages, the cell and the input; folders read as stock traffic
    (``stock``) are compared with stock traffic only. Returns how many cells were compared
    across folders."""
    seen: dict[tuple[str, str], tuple[Path, dict[str, str]]] = {}
    compared = 0
    forced = [(s, None) for s in sources] + [(s, "stock") for s in stock]
    for source, traffic in forced:
        for folder in evaluation_folders(source):
            if not (folder / INPUTS).exists():
                continue  # an evaluation from before the inputs were recorded
            kind = traffic or traffic_of(folder)
            for cell, parts in json.loads((folder / INPUTS).read_text()).items():
                first = seen.setdefault((kind, cell), (folder, parts))
                if first[0] == folder:
                    continue
                compared += 1
                # the named inputs first: "environment" (the whole config) differs with any
                differ = sorted(
                    (k for k, v in parts.items() if first[1].get(k, v) != v),
                    key=lambda k: (k == "environment", k),
                )
                if differ:
                    raise ConfigError(
                        f"{stage_of(folder)} and {stage_of(first[0])} played other traffic "
                        f"in the cell {cell} ({kind}): their {differ[0]} differs; rerun the "
                        "stage that read an outdated input before comparing them"
                    )
    return compared

"""Traffic a policy never saw: each learned policy against each hand-built driver in the
generalisation study's four test families, and the bar the study sets
(``docs/notes/2026-12-07-generalisation-plan.md``).

    table = generalisation_table(episodes)      # parsed episodes (bgap.analysis.episodes)
    bar = clears_bar(table)                      # (arm, family) -> every family cleared?
    print(markdown(table))

The test families (:data:`TESTS`), each pooled on its own over its cells: bgap's dense and
sparse traffic at the largest radius (the yardstick table's cells), highway-env's stock
traffic at both densities, and reactive replay (the evaluation plays the tables' held-out
scenes there). Per family and hand-built driver: collisions per 100 km, all and at the
ego's fault (:data:`bgap.analysis.crashes.AT_FAULT`), each with its paired 95% interval
(:func:`bgap.analysis.yardsticks.compare`: seeds and shared episodes counted once each), the
mean speeds, and lane changes per km beside the driver's.

The bar (the issue's, decided by the point estimates, the intervals printed beside them): in
every family, against every hand-built driver, fewer collisions per 100 km, all and at
fault (no more, where that driver has none), at a mean speed of at least
:data:`~bgap.analysis.stats.RULE_FLOOR` x that driver's.
"""

from __future__ import annotations

import pandas as pd

from bgap.analysis.crashes import AT_FAULT
from bgap.analysis.episodes import is_replay
from bgap.analysis.stats import RULE_FLOOR
from bgap.analysis.yardsticks import METRICS, aligned, compare, read_cells, same_episodes
from bgap.common.vocab import YARDSTICK_NAMES, YARDSTICKS

TESTS = {
    "bgap_dense": "bgap's dense traffic",
    "bgap_sparse": "bgap's sparse traffic",
    "stock": "stock traffic",
    "replay": "observed traffic, held-out scenes",
}
"""The test families, each pooled on its own, and how the table names them."""
CELL = ["traffic", "density", "mix", "radius"]
"""What makes a cell: its episodes are pooled before cells are averaged."""
ARRAYS = (*METRICS, "fault", "lane_changes")
"""Each episode's figures the table reads: crashes, distance, speed, at-fault crashes and
lane changes."""


def test_episodes(df: pd.DataFrame, test: str) -> pd.DataFrame:
    """The episodes of ``df`` in the test family ``test`` (module docstring)."""
    if test.startswith("bgap_"):
        return read_cells(df, test.removeprefix("bgap_"))
    if test == "stock":
        return df[df.traffic == "stock"]
    if test == "replay":
        return df[is_replay(df.traffic) & df.traffic.astype(str).str.endswith("/reactive")]
    raise ValueError(f"unknown test family {test!r}; one of {list(TESTS)}")


def versus(policy: pd.DataFrame, yard: pd.DataFrame) -> dict[str, float] | None:
    """One learned policy's episodes against a hand-built driver's in one test family, or
    None where some training seed did not play exactly the driver's episodes."""
    key = [*CELL, "seed"]
    if not same_episodes(policy, yard, key):
        return None
    order = yard[key].drop_duplicates().sort_values(key).reset_index(drop=True)
    cells = order[CELL].astype(str).agg("|".join, axis=1).to_numpy()
    sides = []
    for episodes in (policy, yard):
        episodes = episodes.assign(fault=episodes.crashed & episodes.ending.isin(AT_FAULT))
        seeds = sorted(set(episodes.train_seed))
        sides.append(dict(zip(ARRAYS, aligned(episodes, seeds, order, ARRAYS), strict=True)))
    mine, theirs = sides
    row = compare(*(tuple(a[k] for k in METRICS) for a in sides), cells)
    fault = compare(*(tuple(a[k] for k in ("fault", *METRICS[1:])) for a in sides), cells)
    out = {k: row[k] for k in ("n_seeds", "per_100km", "yard_per_100km", "diff", "diff_lo")}
    out |= {k: row[k] for k in ("diff_hi", "avg_speed", "yard_speed", "speed_ratio")}
    out |= {f"fault_{k}": fault[k] for k in ("per_100km", "yard_per_100km", "diff_lo", "diff_hi")}
    for side, a in (("", mine), ("yard_", theirs)):
        out[f"{side}lane_changes_per_km"] = a["lane_changes"].sum() / a["distance"].sum() * 1000
    out["clears"] = clears(out)
    return out


def clears(row: dict[str, float]) -> bool:
    """Whether one comparison clears the bar: fewer collisions per 100 km than the driver,
    all and at fault (no more where it has none), at RULE_FLOOR x its speed or faster."""

    def fewer(mine: float, theirs: float) -> bool:
        return mine < theirs or mine == theirs == 0

    return (
        fewer(row["per_100km"], row["yard_per_100km"])
        and fewer(row["fault_per_100km"], row["fault_yard_per_100km"])
        and row["avg_speed"] >= RULE_FLOOR * row["yard_speed"]
    )


def generalisation_table(df: pd.DataFrame) -> pd.DataFrame:
    """Every learned policy (arm, family) against every hand-built driver in every test
    family where both played the same episodes: one row each (:func:`versus`)."""
    rows = []
    for test in TESTS:
        g = test_episodes(df, test)
        learned = g[g.arm != ""]
        for name in YARDSTICKS:
            yard = g[g.family == name]
            if yard.empty:
                continue
            for (arm, family), pol in learned.groupby(["arm", "family"], sort=True):
                row = versus(pol, yard)
                if row is not None:
                    rows.append(
                        {"arm": arm, "family": family, "test": test, "yardstick": name, **row}
                    )
    return pd.DataFrame(rows)


def clears_bar(table: pd.DataFrame) -> dict[tuple[str, str], bool]:
    """Per learned policy (arm, family): whether it clears the bar in every test family
    against every hand-built driver (a family or driver missing: it does not)."""
    out = {}
    for (arm, family), rows in table.groupby(["arm", "family"], sort=True):
        complete = {(t, y) for t in TESTS for y in YARDSTICKS} <= set(
            zip(rows.test, rows.yardstick, strict=True)
        )
        out[(arm, family)] = complete and bool(rows.clears.all())
    return out


def markdown(table: pd.DataFrame) -> str:
    """One table per test family: each learned policy against each hand-built driver, the
    collisions per 100 km (all, at fault) with their paired differences' 95% intervals, the
    speed ratio, lane changes per km, and whether the comparison clears the bar; then which
    policies clear it in every family."""
    if table.empty:
        return "(no learned policy shares a hand-built driver's episodes in a test family)\n"
    parts = []
    for test, here in table.groupby("test", sort=False):
        lines = [
            f"**{TESTS[test]}**\n",
            "| policy | vs | seeds | per 100 km: policy / driver, difference [95% CI] | at fault: "
            "policy / driver [95% CI] | speed ratio | lane changes per km: policy / driver "
            "| clears |",
            "|---" * 8 + "|",
        ]
        for r in here.itertuples(index=False):
            lines.append(
                f"| {r.arm} {r.family.replace('_', '-')} | {YARDSTICK_NAMES[r.yardstick]} | "
                f"{r.n_seeds} | {r.per_100km:.2f} / {r.yard_per_100km:.2f}, {r.diff:+.2f} "
                f"[{r.diff_lo:+.2f}, {r.diff_hi:+.2f}] | {r.fault_per_100km:.2f} / "
                f"{r.fault_yard_per_100km:.2f} [{r.fault_diff_lo:+.2f}, {r.fault_diff_hi:+.2f}] | "
                f"{r.speed_ratio:.3f} | {r.lane_changes_per_km:.2f} / "
                f"{r.yard_lane_changes_per_km:.2f} | {'yes' if r.clears else 'no'} |"
            )
        parts.append("\n".join(lines) + "\n")
    bar = clears_bar(table)
    met = [f"{a} {f.replace('_', '-')}" for (a, f), ok in bar.items() if ok]
    parts.append(
        "Clears the bar in every family, against every hand-built driver: "
        + (", ".join(met) if met else "none")
        + ". The bar is read on point estimates (the study's exception to its interval rule).\n"
    )
    return "\n".join(parts)

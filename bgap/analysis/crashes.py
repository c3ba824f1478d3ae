"""Crashes by cause and by time: collisions at the ego's fault (nuPlan's convention) and
after an episode's start, beside all collisions (the claims' measure), for the results page."""

from __future__ import annotations

import pandas as pd

from bgap.analysis.episodes import distinct_cells, n_of
from bgap.analysis.tables import policy_label

AT_FAULT = ("rear_end", "lane_change")
"""Endings that count as the ego's fault (nuPlan's convention: its own rear-ends and lane
changes, not being run into from behind; a crash without a reported partner is neither)."""
EARLY_STEPS = 3
"""Policy steps counted as an episode's start in the crash-timing table."""


def fault_markdown(df: pd.DataFrame) -> str:
    """Collisions by fault and by time in the cells read against the rule-based ego (the
    paper's traffic, largest radius, repeated cells once): per density and policy, the
    share of episodes with any collision (the claims' measure), with an at-fault one
    (:data:`AT_FAULT`), being rear-ended, in the first :data:`EARLY_STEPS` policy steps,
    and after the first policy period. Episodes pooled over seeds and cells: descriptive."""
    g = df[(df.traffic == "paper")] if "traffic" in df else df
    if "ending" not in g or "steps" not in g or g.empty:
        return "(the evaluations hold no crash endings: evaluate again)\n"
    g = distinct_cells(g)
    g = g[g.radius == g.radius.max()]
    crashed = g.collision_pct > 0
    g = g.assign(
        any=crashed,
        at_fault=crashed & g.ending.isin(AT_FAULT),
        rear_ended=crashed & (g.ending == "rear_ended"),
        early=crashed & (g.steps <= EARLY_STEPS),
        late=crashed & (g.steps > 1),
    )
    parts = []
    for density in [d for d in ("sparse", "dense") if d in set(g.density)]:
        here = g[g.density == density]
        head = (
            "| policy | episodes | any collision | at fault | rear-ended | in the first "
            f"{EARLY_STEPS} steps | after the first step |"
        )
        lines = [f"**{density} (n = {n_of(density)})**: % of episodes\n", head, "|---" * 7 + "|"]
        for (arm, family), p in here.groupby(["arm", "family"], sort=False):
            kinds = ("any", "at_fault", "rear_ended", "early", "late")
            shares = " | ".join(f"{100 * p[k].mean():.1f}" for k in kinds)
            lines.append(f"| {policy_label(arm, family)} | {len(p)} | {shares} |")
        order = sorted(lines[3:], key=lambda line: ("(baseline)" in line, line))
        parts.append("\n".join(lines[:3] + order) + "\n")
    return "\n".join(parts)

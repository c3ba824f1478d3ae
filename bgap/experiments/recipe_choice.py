"""How the recipe's check picks its candidate: per candidate, means and 95% intervals over
the check's training seeds, the objective of the means, best first (``mode=rule`` and the
constrained rule with the stock check)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from bgap.analysis.stats import poisson_interval, t_interval, wilson_interval
from bgap.common.vocab import CRASH_KINDS
from bgap.experiments.config import RecipeConfig
from bgap.experiments.sweep import RULE_KEYS, objective
from bgap.experiments.validation import rule_score


def choose_by_rule(cfg: RecipeConfig, table: pd.DataFrame) -> pd.DataFrame:
    """Mode ``rule``: per candidate, the means over seeds of :data:`RULE_KEYS`, 95% t
    intervals across seeds of the policies' rates and speeds, and the objective of the means
    (:func:`~bgap.experiments.validation.rule_score`); best first."""
    rows = []
    for trial, g in table.groupby("trial"):
        row: dict[str, Any] = {"trial": trial, "seeds": len(g)}
        row |= {key: float(g[key].mean()) for key in RULE_KEYS}
        # across seeds (the independent units), widened where needed to the pooled
        # episodes' exact interval: never of zero width
        for prefix in ("", "stock_"):
            crashes, km = int(g[f"{prefix}crashes"].sum()), float(g[f"{prefix}km"].sum())
            episodes = int(g[f"{prefix}episodes"].sum())
            pooled = {
                "per_100km": poisson_interval(crashes, km / 100.0),
                "collision_pct": tuple(100 * b for b in wilson_interval(crashes, episodes)),
                "avg_speed": (np.inf, -np.inf),
            }
            for key, (p_lo, p_hi) in pooled.items():
                lo, hi = t_interval(g[f"{prefix}{key}"].to_numpy())
                row[f"{prefix}{key}_lo"] = max(min(lo, p_lo), 0.0)
                row[f"{prefix}{key}_hi"] = max(hi, p_hi)
        row["objective"] = rule_score(cfg, row)
        rows.append(row)
    return pd.DataFrame(rows).sort_values(["objective", "trial"]).reset_index(drop=True)


STOCK_KEYS = (
    "stock_collision_pct",
    "stock_avg_speed",
    "stock_idle_collision_pct",
    "stock_idle_avg_speed",
)
"""The default policy's figures in stock traffic (``stock_check``), per check seed."""


def meets_stock_rule(cfg: RecipeConfig, row: Any) -> bool:
    """The stock rule for the default policy in its own traffic: fewer than
    ``stock_max_collision_pct`` collisions at ``speed_floor`` x idle's mean speed."""
    return bool(
        row["stock_collision_pct"] < cfg.stock_max_collision_pct
        and row["stock_avg_speed"] >= cfg.speed_floor * row["stock_idle_avg_speed"]
    )


def choose(cfg: RecipeConfig, table: pd.DataFrame) -> pd.DataFrame:
    """Per candidate: means over seeds, 95% t intervals across seeds, the objective of the
    means; sorted best first. With the stock check's columns, candidates whose default
    policy meets :func:`meets_stock_rule` (on its means over seeds) come first."""
    stock = all(key in table for key in STOCK_KEYS)
    rows = []
    for trial, g in table.groupby("trial"):
        row: dict[str, Any] = {"trial": trial, "seeds": len(g)}
        for key in (
            "collision_pct",
            "avg_speed",
            "idle_collision_pct",
            "idle_avg_speed",
            "rule_collision_pct",
            "rule_avg_speed",
            "lane_changes",
            *(f"{kind}_pct" for kind in CRASH_KINDS),
            *(STOCK_KEYS if stock else ()),
        ):
            row[key] = float(g[key].mean()) if key in g else 0.0
        for key, top in (("collision_pct", 100.0), ("avg_speed", np.inf)):
            lo, hi = t_interval(g[key].to_numpy())
            row[f"{key}_lo"], row[f"{key}_hi"] = max(lo, 0.0), min(hi, top)
        row["objective"] = objective(
            cfg, row["collision_pct"], row["avg_speed"], row["idle_avg_speed"]
        )
        if stock:
            row["stock_rule"] = meets_stock_rule(cfg, row)
        rows.append(row)
    summary = pd.DataFrame(rows)
    if not stock:
        return summary.sort_values(["objective", "trial"]).reset_index(drop=True)
    summary["_misses"] = ~summary.stock_rule
    order = summary.sort_values(["_misses", "objective", "trial"]).drop(columns="_misses")
    return order.reset_index(drop=True)

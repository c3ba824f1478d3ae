"""What an evaluation makes of its episodes: their stored types, the summary per policy
and cell (collision %, speed, lane changes, crash kinds, collisions per 100 km, with 95%
intervals), the traffic inputs each cell met, the files written, the text table and the
comparison figure."""

from __future__ import annotations

import copy
import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from bgap.analysis.episodes import EPISODES, INPUTS
from bgap.analysis.stats import per_100km, spread_interval, wilson_interval
from bgap.common.plotting import pyplot
from bgap.common.runs import file_digest, write_atomic
from bgap.common.vocab import CRASH_KINDS

STORED = {
    "avg_speed": "float32",
    "distance": "float32",
    "return": "float32",
    "lane_changes": "int16",
    "steps": "int16",
    "seed": "int64",
    "mix": "float64",
    "radius": "float64",
}
"""Stored types of the episode columns: single precision (7 digits) for the per-episode
measures keeps the study's episodes in a few MB of parquet. The commands apply it before
they summarise, so every summary, figure and claim reads the numbers that are stored
(:func:`evaluate` itself returns full precision)."""


def compact(episodes: pd.DataFrame) -> pd.DataFrame:
    """The episode table in its stored types (:data:`STORED`; reward terms ``r_*``
    single precision too)."""
    types = {c: t for c, t in STORED.items() if c in episodes}
    types |= {c: "float32" for c in episodes if c.startswith("r_")}
    return episodes.astype(types)


def summarize(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per policy and cell: collision %, average speed, lane changes, each with a 95% CI."""
    rows = []
    keys = ["policy", "mix", "density", "radius", *(["replay"] if "replay" in episodes else [])]
    for key, g in episodes.groupby(keys, sort=False):
        crashes, n = int(g.crashed.sum()), len(g)
        lo, hi = wilson_interval(crashes, n)
        s_lo, s_hi = spread_interval(g.avg_speed.to_numpy())
        l_lo, l_hi = spread_interval(g.lane_changes.to_numpy(dtype=float), counts=True)
        rows.append(
            dict(zip(keys, key, strict=True))
            | {
                "episodes": n,
                "collision_pct": 100.0 * crashes / n,
                "collision_lo": 100 * lo,
                "collision_hi": 100 * hi,
                "avg_speed": g.avg_speed.mean(),
                "speed_lo": s_lo,
                "speed_hi": s_hi,
                "lane_changes": g.lane_changes.mean(),
                "lane_changes_lo": l_lo,
                "lane_changes_hi": l_hi,
                "return": g["return"].mean(),
                **crash_split(g),
                **exposure(g),
            }
        )
    return pd.DataFrame(rows)


def exposure(episodes: pd.DataFrame) -> dict[str, float]:
    """Kilometres driven and collisions per 100 km with their exact Poisson interval
    (:func:`bgap.analysis.stats.per_100km`); nothing for episodes recorded without the
    ego's distance."""
    if "distance" not in episodes:
        return {}
    rate, lo, hi = per_100km(episodes.crashed.to_numpy(), episodes.distance.to_numpy(float))
    return {
        "km": float(episodes.distance.sum()) / 1000,
        "per_100km": rate,
        "per_100km_lo": lo,
        "per_100km_hi": hi,
    }


def crash_split(episodes: pd.DataFrame) -> dict[str, float]:
    """% of episodes ending in each kind of crash (``<kind>_pct``, :data:`CRASH_KINDS`)."""
    if "ending" not in episodes:  # episodes recorded before the endings were
        return {}
    share = episodes.ending.value_counts(normalize=True)
    return {f"{kind}_pct": 100.0 * float(share.get(kind, 0.0)) for kind in CRASH_KINDS}


def _hash(values: Any) -> str:
    return hashlib.sha256(json.dumps(values, sort_keys=True, default=str).encode()).hexdigest()


def traffic_inputs(
    keys: list[str], configs: list[dict], tables: list[str], seeds: list[int], behavior: Any
) -> dict[str, dict[str, str]]:
    """Per cell (``keys``, one per cell of ``configs``; ``tables``: each cell's replay table
    or ""), content hashes of what decides the traffic its episodes meet: the episode seeds,
    the behaviour preset, the replayed table's bytes and the whole environment config (the
    table's path replaced by its hash). ``bgap.figures`` compares arms cell by cell on them."""
    by_table: dict[str, str] = {}
    inputs = {}
    for key, config, table in zip(keys, configs, tables, strict=True):
        parts = {"episode seeds": _hash(seeds), "behaviour preset": _hash(behavior)}
        if table:
            by_table.setdefault(table, file_digest(table))
            parts["replay table"] = by_table[table]
            config = copy.deepcopy(config)
            config["traffic"]["table"] = by_table[table]
        parts["environment"] = _hash(config)
        inputs[key] = parts
    return inputs


def write_results(
    out: Path, episodes: pd.DataFrame, summary: pd.DataFrame, inputs: dict | None = None
) -> None:
    out.mkdir(parents=True, exist_ok=True)
    if inputs is not None:
        write_atomic(out / INPUTS, json.dumps(inputs, indent=1, sort_keys=True))
    write_atomic(
        out / EPISODES,
        lambda tmp: episodes.to_parquet(tmp, index=False, compression="zstd", compression_level=19),
    )
    write_atomic(out / "summary.csv", lambda tmp: summary.to_csv(tmp, index=False))
    write_atomic(out / "summary.json", json.dumps(summary.to_dict(orient="records"), indent=1))


def format_table(summary: pd.DataFrame) -> str:
    """The paper's three bars as text: collision %, speed, lane changes with 95% CIs, and
    collisions per 100 km of ego travel where the episodes hold the distance."""
    split = all(f"{kind}_pct" in summary for kind in CRASH_KINDS)
    km = "per_100km" in summary
    w = max(15, *(len(str(p)) + 1 for p in summary.policy))
    replays = summary.replay.fillna("") if "replay" in summary else pd.Series("", summary.index)
    rw = max(len(x) for x in replays) + 2 if replays.any() else 0  # the replay cells' names
    lines = [
        f"{'policy':<{w}}{'traffic' if rw else '':<{rw}}{'mix':>5}{'density':>9}{'radius':>8}"
        f"{'episodes':>9}"
        f"{'collisions %':>22}"
        + (f"{'per 100 km':>22}" if km else "")
        + f"{'speed m/s':>20}{'lane changes':>20}"
        + ("   crashes %: rear-end / rear-ended / lane change / other" if split else "")
    ]
    for r, replay in zip(summary.itertuples(), replays, strict=True):
        lines.append(
            f"{r.policy:<{w}}{(replay or 'simulated') if rw else '':<{rw}}{r.mix:>5.2f}"
            f"{r.density:>9}{r.radius:>8.0f}{r.episodes:>9}"
            f"{r.collision_pct:>8.1f} [{r.collision_lo:5.1f},{r.collision_hi:5.1f}]"
            + (f"{r.per_100km:>8.1f} [{r.per_100km_lo:5.1f},{r.per_100km_hi:5.1f}]" if km else "")
            + f"{r.avg_speed:>8.2f} [{r.speed_lo:5.2f},{r.speed_hi:5.2f}]"
            f"{r.lane_changes:>8.2f} [{r.lane_changes_lo:5.2f},{r.lane_changes_hi:5.2f}]"
            + (
                "   " + " / ".join(f"{getattr(r, f'{kind}_pct'):.0f}" for kind in CRASH_KINDS)
                if split
                else ""
            )
        )
    return "\n".join(lines)


MAX_BARS = 240
"""Policies x cells beyond which :func:`plot_comparison` draws nothing (a study's 40
trainings on 42 cells would be 1,680 bars: the figures stage plots those)."""


def plot_comparison(summary: pd.DataFrame, path: Path, title: str = "") -> bool:
    """Bars per policy (one group per cell) with 95% CIs, as in the paper's figures; False
    (nothing drawn) beyond :data:`MAX_BARS` bars."""
    if len(summary) > MAX_BARS:
        return False
    plt = pyplot()

    metrics = [
        ("collision_pct", "collision_lo", "collision_hi", "collisions [% episodes]"),
        ("avg_speed", "speed_lo", "speed_hi", "ego speed [m/s]"),
        ("lane_changes", "lane_changes_lo", "lane_changes_hi", "lane changes / episode"),
    ]
    keys = ["mix", "density", "radius", *(["replay"] if "replay" in summary else [])]
    cells = [tuple(c) for c in summary[keys].drop_duplicates().itertuples(index=False)]
    policies = list(dict.fromkeys(summary.policy))
    fig, axes = plt.subplots(1, 3, figsize=(4 + 1.2 * len(cells) * len(policies) / 2, 3.8))
    width = 0.8 / len(policies)
    for ax, (col, lo, hi, label) in zip(axes, metrics, strict=True):
        for p_i, pol in enumerate(policies):
            sub = summary[summary.policy == pol].set_index(keys)
            vals = [sub.loc[c] if c in sub.index else None for c in cells]
            x = np.arange(len(cells)) + p_i * width
            y = [v[col] if v is not None else np.nan for v in vals]
            err = np.array(
                [[v[col] - v[lo], v[hi] - v[col]] if v is not None else [0, 0] for v in vals]
            ).T
            ax.bar(x, y, width, yerr=np.nan_to_num(err), capsize=2, label=pol)
        ax.set_xticks(np.arange(len(cells)) + 0.4 - width / 2)
        ax.set_xticklabels([_cell_label(*c) for c in cells], fontsize=7)
        ax.set_ylabel(label)
    axes[0].legend(fontsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=120))
    plt.close(fig)
    return True


def _cell_label(mix: float, density: str, radius: float, replay: str = "") -> str:
    if replay:  # a replay's mix is its table's aggressive share
        return f"{replay}\n{density}\nmix {mix:.2f}\nr {radius:g}"
    return f"{density}\nmix {mix:g}\nr {radius:g}"

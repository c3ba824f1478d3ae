"""The paper's figures and claims from fresh numbers: ``python -m bgap.figures RESULTS_DIR``.

Reads the ``episodes.csv`` that ``bgap.evaluate`` wrote for the study's trainings (named by
their run folders, ``<arm>/<density>/<density>-<behavior_rich|default>-s<seed>``; a bare
``<density>-<family>-s<seed>`` is arm ``main``) and the baselines, plus optionally the same
policies in stock traffic (``--stock``) and the run folders (``--runs``: the checkpoints
each training kept), and writes to ``--out`` (default ``outputs/figures``; the pipeline's stage:
``results/``):

- ``cells.csv``: per arm, policy family and cell, the mean over training seeds of collision
  %, speed and lane changes with 95% intervals, ``n_seeds`` and ``n_episodes``, the crash
  split, and ``duplicate_of`` where a mix gives the same traffic as another one;
- ``claims.csv``: each of the paper's claims (:data:`CLAIMS`) with our difference, its 95%
  interval and the Holm-corrected one, p-values, sample sizes and the verdict;
- ``own_traffic.csv``: whether each trained policy beats idle in its own training traffic;
- ``table2.md``: Table II with every policy of ours in the same cell;
- ``figures/``: ``fig4.png`` (and ``fig4_<arm>.png`` per other arm), ``fig6.png``,
  ``paper_vs_ours.png`` (the paper's bars beside ours), ``ablation.png`` (training mix);
- ``README.md`` and ``metrics.json``.

Statistics (:mod:`bgap.analysis.stats`): training seeds are the independent units. A difference
between two policy families is a two-level bootstrap over their (unrelated) seeds; one model
in two traffic conditions is paired by training seed; two perception radii play the same
scenes, so their per-episode differences are bootstrapped. Holm's correction runs across the
whole claims table; the verdict follows from the corrected p-values.
"""

from __future__ import annotations

import argparse
import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bgap.analysis.stats import (
    beats_idle,
    bootstrap_test,
    holm,
    mean_interval,
    seed_bootstrap,
    seed_rate_interval,
)
from bgap.common.vocab import CRASH_KINDS, SPEED_FLOOR
from bgap.traffic.behaviors import count_aggressive
from bgap.traffic.scenario import env_preset

MODEL = re.compile(
    r"^(?:(?P<arm>[^/]+)/(?:[^/]+/)*)?(?P<density>[a-z]+)-(?P<family>behavior_rich|default)"
    r"-s(?P<seed>\d+)$"
)
METRICS = {"collision_pct": "collision %", "avg_speed": "speed m/s", "lane_changes": "lane changes"}
KEYS = ["arm", "family", "traffic", "density", "mix", "radius"]
MIXTURE_ARMS = ("main", "authors")
"""Arms that train both families, behaviour-rich on the mixture of the paper's mixes."""
ARM_NAMES = {
    "main": "recipe (main arm)",
    "authors": "authors' 2020 configuration",
    "mix0": "behaviour-rich trained at 0% aggressive",
    "mix50": "behaviour-rich trained at 50% aggressive",
    "mix100": "behaviour-rich trained at 100% aggressive",
}
ALPHA = 0.05


def n_of(density: str) -> int | str:
    """The paper's name of a density: its number of background vehicles n."""
    try:
        return env_preset(density).vehicles_count
    except ValueError:
        return density


# The paper's bars (FACTS.md): crashes per 100 episodes, at 0% / 50% / 100% aggressive.
PAPER_CRASHES = {
    ("dense", "default"): {0.0: 65, 0.5: 70, 1.0: 30},
    ("dense", "behavior_rich"): {0.0: 27, 0.5: 36, 1.0: 4},
    ("sparse", "default"): {0.0: 21, 0.5: 31, 1.0: 11},
    ("sparse", "behavior_rich"): {0.0: 5, 0.5: 14, 1.0: 3},
}
PAPER_SPEED = {("dense", "behavior_rich"): {0.0: 17.8, 0.5: 20.1, 1.0: 26.0},
               ("dense", "default"): {0.0: 18.6, 0.5: 18.7, 1.0: 19.1}}  # fmt: skip
PAPER_LANE_CHANGES = {("dense", "behavior_rich"): {0.0: 10.6, 0.5: 9.5, 1.0: 3.75}}
TABLE_II = {"DDPG": 10.13, "PS-DDPG": 11.40, "B-GAP (paper)": 3.00}


# ---------------------------------------------------------------------- episodes
def load_episodes(results_dir: str | Path, traffic: str = "paper") -> pd.DataFrame:
    """Episode rows with the arm, family, training seed and traffic parsed and added."""
    path = Path(results_dir) / "episodes.csv"
    if not path.exists():
        raise FileNotFoundError(f"{path} not found: run python -m bgap.evaluate first")
    df = parse_policies(pd.read_csv(path))
    df["traffic"] = traffic
    return df


def parse_policies(df: pd.DataFrame) -> pd.DataFrame:
    """``arm``, ``family`` and ``train_seed`` columns parsed from policy names (baselines:
    their own name as family, arm "" and seed -1), and ``collision_pct`` per episode."""
    df = df.copy()
    parsed = df.policy.str.extract(MODEL)
    trained = parsed["family"].notna()
    df["family"] = parsed["family"].fillna(df.policy)
    df["arm"] = parsed["arm"].where(parsed["arm"].notna(), "main").where(trained, "")
    df["train_seed"] = pd.to_numeric(parsed["seed"]).fillna(-1).astype(int)
    df["collision_pct"] = 100.0 * df.crashed.astype(float)
    if "traffic" not in df:
        df["traffic"] = "paper"
    return df


def duplicates(df: pd.DataFrame) -> dict[tuple[str, float], float]:
    """(density, mix) -> the earlier mix that gives the same traffic (the same number of
    aggressive drivers, e.g. 3 of 5 at mixes 0.5 and 0.6): such a cell repeats the other's
    episodes and is counted once in averages over mixes."""
    out = {}
    for density in sorted(set(df.density)):
        seen: dict[int, float] = {}
        n = n_of(density)
        for mix in sorted(set(df[df.density == density].mix)):
            k = count_aggressive(mix, n) if isinstance(n, int) else mix
            if k in seen:
                out[(density, mix)] = seen[k]
            else:
                seen[k] = mix
    return out


def _distinct(df: pd.DataFrame) -> pd.DataFrame:
    """Rows of cells that are not duplicates of another mix."""
    dup = duplicates(df)
    keep = [(d, m) not in dup for d, m in zip(df.density, df.mix, strict=True)]
    return df[np.asarray(keep, dtype=bool)]


def _groups(df: pd.DataFrame, metric: str) -> dict[int, np.ndarray]:
    """Training seed -> that seed's episode values of ``metric`` (seed order, the episodes
    in a fixed order: cell, then episode seed)."""
    ordered = df.sort_values(["mix", "radius", "seed"])
    return {s: g[metric].to_numpy(dtype=float) for s, g in ordered.groupby("train_seed")}


def _crashes(df: pd.DataFrame) -> list[np.ndarray]:
    """Each training seed's episodes as 0/1 crashes (:func:`_groups` order)."""
    return [x / 100 for x in _groups(df, "collision_pct").values()]


def _rate(df: pd.DataFrame, rng: np.random.Generator) -> tuple[float, float, float, int]:
    """Collision % averaged over training seeds, its 95% interval
    (:func:`bgap.analysis.stats.seed_rate_interval`) and the number of seeds."""
    pct = list(_groups(df, "collision_pct").values())
    lo, hi = seed_rate_interval([x / 100 for x in pct], rng)
    return float(np.mean([x.mean() for x in pct])), 100 * lo, 100 * hi, len(pct)


# ---------------------------------------------------------------------- cells
def cell_stats(df: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per arm, family, traffic and cell: mean over training seeds of each metric and its 95%
    interval; returns (cells, per-seed means). Collision %: the two-level bootstrap across
    seeds widened to the pooled Wilson interval (:func:`bgap.analysis.stats.seed_rate_interval`,
    never of zero width); speed and lane changes: Student t across seed means (across
    episodes with one seed)."""
    keys = [k for k in KEYS if k in df]
    per_seed = df.groupby([*keys, "train_seed"])[list(METRICS)].mean().reset_index()
    dup = duplicates(df)
    rng = np.random.default_rng(0)
    seed_means = dict(iter(per_seed.groupby(keys, sort=True)))
    rows = []
    for key, episodes in df.groupby(keys, sort=True):
        row = dict(zip(keys, key, strict=True))
        g = seed_means[key]
        rate, lo, hi, n_seeds = _rate(episodes, rng)
        row |= {"seeds": n_seeds, "n_seeds": n_seeds, "n_episodes": len(episodes)}
        row |= {"collision_pct": rate, "collision_pct_lo": lo, "collision_pct_hi": hi}
        for m in ("avg_speed", "lane_changes"):
            row[m] = float(g[m].mean())
            values = g[m].to_numpy() if len(g) > 1 else episodes[m].to_numpy(dtype=float)
            lo, hi = mean_interval(values)
            row[f"{m}_lo"], row[f"{m}_hi"] = max(lo, 0.0), hi
        if "ending" in episodes:
            share = episodes.ending.value_counts(normalize=True)
            row |= {f"{k}_pct": 100.0 * float(share.get(k, 0.0)) for k in CRASH_KINDS}
        row["duplicate_of"] = dup.get((row["density"], row["mix"]), np.nan)
        rows.append(row)
    return pd.DataFrame(rows), per_seed


# ---------------------------------------------------------------------- claims
@dataclass(frozen=True)
class Claim:
    """One of the paper's claims as a comparison of two selections of episodes."""

    text: str
    figure: str
    metric: str
    a: dict
    b: dict | None
    expect: int
    """+1: the paper says a > b; -1: a < b."""
    design: str
    """``unpaired`` (different trainings), ``model`` (one model, two conditions), ``scene``
    (one model, the same scenes: per-episode differences) or ``value`` (a against a number)."""
    paper: str
    null: float = 0.0
    densities: tuple[str, ...] = ("sparse", "dense")


def _claims_for(radii: list[float], mixes: list[float]) -> list[Claim]:
    r = max(radii)
    mixed = [m for m in mixes if 0.0 < m < 1.0]
    out = [
        Claim("behaviour-rich collides less than default (all mixes)", "Fig. 4", "collision_pct",
              {"family": "behavior_rich", "radius": r}, {"family": "default", "radius": r},
              -1, "unpaired", "n=40: 27/36/4 vs 65/70/30; n=5: 5/14/3 vs 21/31/11"),
        Claim("behaviour-rich collides less at 0% than in mixed traffic", "Fig. 4",
              "collision_pct", {"family": "behavior_rich", "radius": r, "mix": [0.0]},
              {"family": "behavior_rich", "radius": r, "mix": mixed}, -1, "model",
              "n=40: 27 vs 36; n=5: 5 vs 14"),
        Claim("behaviour-rich collides less at 100% than in mixed traffic", "Fig. 4",
              "collision_pct", {"family": "behavior_rich", "radius": r, "mix": [1.0]},
              {"family": "behavior_rich", "radius": r, "mix": mixed}, -1, "model",
              "n=40: 4 vs 36; n=5: 3 vs 14"),
        Claim("default collides less at 100% than at 50% aggressive", "Fig. 4", "collision_pct",
              {"family": "default", "radius": r, "mix": [1.0]},
              {"family": "default", "radius": r, "mix": [0.5]}, -1, "model",
              "n=40: 30 vs 70; n=5: 11 vs 31"),
    ]  # fmt: skip
    for small in sorted(radii)[:-1]:
        out.append(
            Claim(
                f"behaviour-rich collides more with a {small:g} m than a {r:g} m perception radius",
                "Fig. 6",
                "collision_pct",
                {"family": "behavior_rich", "radius": small},
                {"family": "behavior_rich", "radius": r},
                +1,
                "scene",
                "more collisions at smaller radii (Fig. 6)",
            )  # fmt: skip
        )
    out += [
        Claim("behaviour-rich drives faster at 100% than at 0% aggressive", "Fig. 4 (speed)",
              "avg_speed", {"family": "behavior_rich", "radius": r, "mix": [1.0]},
              {"family": "behavior_rich", "radius": r, "mix": [0.0]}, +1, "model",
              "26.0 vs 17.8 m/s", densities=("dense",)),
        Claim("behaviour-rich drives faster than default at 100% aggressive", "Fig. 4 (speed)",
              "avg_speed", {"family": "behavior_rich", "radius": r, "mix": [1.0]},
              {"family": "default", "radius": r, "mix": [1.0]}, +1, "unpaired",
              "26.0 vs ~19.1 m/s", densities=("dense",)),
        Claim("behaviour-rich changes lanes less at 100% than at 0% aggressive",
              "Fig. 4 (lane changes)", "lane_changes",
              {"family": "behavior_rich", "radius": r, "mix": [1.0]},
              {"family": "behavior_rich", "radius": r, "mix": [0.0]}, -1, "model",
              "3.75 vs 10.6 per episode", densities=("dense",)),
        Claim("behaviour-rich collides in fewer than DDPG's 10.13% at 100% aggressive",
              "Table II", "collision_pct", {"family": "behavior_rich", "radius": r,
              "mix": [1.0]}, None, -1, "value", "3.00% (DDPG 10.13%, PS-DDPG 11.40%)",
              null=TABLE_II["DDPG"], densities=("sparse",)),
    ]  # fmt: skip
    return out


CLAIMS = _claims_for
"""The claims table's rows (per arm that trains both families, per density)."""


def _select(df: pd.DataFrame, where: dict) -> pd.DataFrame:
    mask = np.ones(len(df), dtype=bool)
    for key, value in where.items():
        mask &= df[key].isin(value).to_numpy() if isinstance(value, list) else df[key] == value
    return df[mask]


def _test(claim: Claim, df: pd.DataFrame, rng: np.random.Generator) -> dict | None:
    """Observed difference and bootstrap replicates of one claim on ``df`` (one arm, one
    density, the grid's traffic, duplicate cells removed)."""
    a = _select(df, claim.a)
    b = _select(df, claim.b) if claim.b is not None else None
    if a.empty or (b is not None and b.empty):
        return None
    if claim.design == "scene":
        keys = ["train_seed", "mix", "seed"]
        both = a.merge(b, on=keys, suffixes=("_a", "_b"))
        both["d"] = both[f"{claim.metric}_a"] - both[f"{claim.metric}_b"]
        groups = _groups(both.assign(radius=0.0), "d")
        observed, dist = seed_bootstrap(list(groups.values()), rng=rng)
        sizes = (len(groups), len(groups), len(both), len(both))
        values = (a[claim.metric].mean(), b[claim.metric].mean())
    else:
        # crashes as 0/1 (bgap.stats resamples a rate from its posterior), then in %
        scale = 100.0 if claim.metric == "collision_pct" else 1.0
        ga = {s: x / scale for s, x in _groups(a, claim.metric).items()}
        gb = None if b is None else {s: x / scale for s, x in _groups(b, claim.metric).items()}
        if claim.design == "model":  # the same models: aligned by training seed
            common = sorted(set(ga) & set(gb))
            ga, gb = {s: ga[s] for s in common}, {s: gb[s] for s in common}
        observed, dist = seed_bootstrap(
            list(ga.values()), None if gb is None else list(gb.values()), rng=rng,
            paired=claim.design == "model",
        )  # fmt: skip
        observed, dist = scale * observed - claim.null, scale * dist - claim.null
        sizes = (len(ga), len(gb) if gb else 0, len(a), len(b) if b is not None else 0)
        mean_a = scale * float(np.mean([x.mean() for x in ga.values()]))
        mean_b = (
            claim.null if gb is None else scale * float(np.mean([x.mean() for x in gb.values()]))
        )
        values = (mean_a, mean_b)
    lo, hi, p = bootstrap_test(dist, observed=observed)
    return {
        "difference": observed, "lo": lo, "hi": hi, "p": p, "dist": dist,
        "value_a": values[0], "value_b": values[1],
        "n_seeds_a": sizes[0], "n_seeds_b": sizes[1],
        "n_episodes_a": sizes[2], "n_episodes_b": sizes[3],
    }  # fmt: skip


def claims(df: pd.DataFrame, seed: int = 0) -> pd.DataFrame:
    """The claims table: every claim of :data:`CLAIMS` for every arm that trains both
    families and every density, with Holm's correction across the table."""
    rng = np.random.default_rng(seed)
    grid = _distinct(df[df.traffic == "paper"])
    rows = []
    for arm in [a for a in MIXTURE_ARMS if a in set(grid.arm)]:
        trained = grid[grid.arm == arm]
        for density in sorted(set(trained.density)):
            d = trained[trained.density == density]
            for claim in CLAIMS(sorted(set(d.radius)), sorted(set(d.mix))):
                if density not in claim.densities:
                    continue
                result = _test(claim, d, rng)
                if result is None:
                    continue
                rows.append({"claim": claim.text, "figure": claim.figure, "arm": arm,
                             "n": n_of(density), "metric": claim.metric,
                             "expect": claim.expect, "paper": claim.paper, **result})  # fmt: skip
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    table["p_holm"] = holm(table.p.to_numpy())
    # Holm's step for each claim: the k-th smallest p is tested at alpha / (m - k + 1); the
    # corrected interval is the bootstrap interval at that level
    m = len(table)
    rank = table.p.rank(method="first").astype(int).to_numpy()
    levels = 1 - ALPHA / (m - rank + 1)
    corrected = [bootstrap_test(r.dist, level, observed=r.difference)
                 for r, level in zip(table.itertuples(), levels, strict=True)]  # fmt: skip
    table["lo_holm"] = [c[0] for c in corrected]
    table["hi_holm"] = [c[1] for c in corrected]
    table["verdict"] = [_verdict(r.difference, r.p_holm, r.expect) for r in table.itertuples()]
    table["reading"] = [_reading(r) for r in table.itertuples()]
    return table.drop(columns="dist")


def ablation_table(df: pd.DataFrame, seed: int = 2) -> pd.DataFrame:
    """Behaviour-rich trained at one mix (arms ``mix<percent>``) against behaviour-rich
    trained on the mixture (main arm), collision %: over all test mixes, and at the arm's own
    mix. Unrelated trainings, so unpaired; exploratory (no correction), for the question
    whether the mixture or the mix matters."""
    rng = np.random.default_rng(seed)
    grid = _distinct(df[(df.traffic == "paper") & (df.family == "behavior_rich")])
    grid = grid[grid.radius == grid.radius.max()] if len(grid) else grid
    rows = []
    for arm in sorted({a for a in set(grid.arm) if a.startswith("mix")}, key=lambda a: int(a[3:])):
        mix = int(arm[3:]) / 100
        for density in sorted(set(grid[grid.arm == arm].density)):
            d = grid[grid.density == density]
            for where, mixes in (("all test mixes", sorted(set(d.mix))), (f"{mix:.0%}", [mix])):
                a = d[(d.arm == arm) & d.mix.isin(mixes)]
                b = d[(d.arm == "main") & d.mix.isin(mixes)]
                if a.empty or b.empty:
                    continue
                ga, gb = _crashes(a), _crashes(b)
                observed, dist = seed_bootstrap(ga, gb, rng=rng)
                lo, hi, p = bootstrap_test(100 * dist, observed=100 * observed)
                rows.append({"arm": arm, "n": n_of(density), "test traffic": where,
                             "one mix %": 100 * np.mean([x.mean() for x in ga]),
                             "mixture %": 100 * np.mean([x.mean() for x in gb]),
                             "difference": 100 * observed, "lo": lo, "hi": hi, "p": p,
                             "seeds": f"{len(ga)} / {len(gb)}"})  # fmt: skip
    return pd.DataFrame(rows)


def _verdict(difference: float, p_holm: float, expect: int) -> str:
    if not np.isfinite(difference):
        return "no data"
    if p_holm >= ALPHA:
        return "not significant"
    return "holds" if np.sign(difference) == expect else "contradicted"


UNITS = {"collision_pct": "% collisions", "avg_speed": "m/s", "lane_changes": "lane changes"}


def _reading(r) -> str:
    """One sentence of interpretation of a claims row."""
    unit = UNITS[r.metric]
    ours = f"ours {r.value_a:.1f} vs {r.value_b:.1f} {unit}" if r.figure != "Table II" else (
        f"ours {r.value_a:.1f}%")  # fmt: skip
    if r.verdict == "holds":
        return f"The paper's direction is confirmed ({ours}) after Holm's correction."
    if r.verdict == "contradicted":
        return f"The opposite of the paper's direction is significant ({ours})."
    return (f"Not distinguishable at {r.n_seeds_a} training seeds ({ours}; corrected interval "
            f"{r.lo_holm:+.1f} to {r.hi_holm:+.1f}).")  # fmt: skip


# ---------------------------------------------------------------------- own traffic
def own_traffic(df: pd.DataFrame) -> pd.DataFrame:
    """Each arm's trained families in their own training traffic against idle on the same
    episodes: behaviour-rich of a mixture arm on the paper's mixes (duplicates once),
    behaviour-rich of a one-mix arm at its mix, default in stock traffic; all at the largest
    radius. ``beats_idle``: fewer collisions at >= 0.9 x idle's speed (point estimates)."""
    rng = np.random.default_rng(1)
    rows = []
    r = df[df.traffic == "paper"].radius.max() if (df.traffic == "paper").any() else 180.0
    for (arm, family, density), g in df[df.train_seed >= 0].groupby(["arm", "family",
                                                                      "density"]):  # fmt: skip
        if family == "default":
            own, label = {"traffic": "stock"}, "stock traffic"
        elif arm.startswith("mix"):
            mix = float(arm[3:]) / 100
            own, label = {"traffic": "paper", "mix": [mix]}, f"{mix:.0%} aggressive"
        else:
            own, label = {"traffic": "paper"}, "the paper's mixes"
        sel = _distinct(_select(df[df.density == density], {**own, "radius": r}))
        mine, idle = sel[sel.policy.isin(g.policy.unique())], sel[sel.family == "idle"]
        if mine.empty or idle.empty:
            continue
        rate, lo, hi, n_seeds = _rate(mine, rng)
        row = {
            "arm": arm, "family": family, "n": n_of(density), "own_traffic": label,
            "n_seeds": n_seeds, "n_episodes": len(mine),
            "collision_pct": rate, "collision_lo": lo, "collision_hi": hi,
            "avg_speed": float(mine.groupby("train_seed").avg_speed.mean().mean()),
            "idle_collision_pct": float(idle.collision_pct.mean()),
            "idle_avg_speed": float(idle.avg_speed.mean()),
        }  # fmt: skip
        if "ending" in mine:
            for who, rows_ in (("", mine), ("idle_", idle)):
                share = rows_.ending.value_counts(normalize=True)
                row |= {f"{who}{k}_pct": 100.0 * float(share.get(k, 0.0)) for k in CRASH_KINDS}
        row["beats_idle"] = beats_idle(
            row["collision_pct"], row["avg_speed"], row["idle_collision_pct"], row["idle_avg_speed"]
        )
        rows.append(row)
    return pd.DataFrame(rows)


# ---------------------------------------------------------------------- tables
def table2(stats: pd.DataFrame) -> str:
    """Table II: the paper's reported rates, then every policy of ours in that cell (n = 5,
    100% aggressive, largest radius), the baselines included."""
    s = stats[(stats.density == "sparse") & (stats.mix == 1.0) & (stats.traffic == "paper")]
    s = s[s.radius == s.radius.max()] if len(s) else s
    lines = ["| method (n = 5, 100% aggressive) | collision % [95% CI] | seeds x episodes |",
             "|---|---|---|"]  # fmt: skip
    lines += [f"| {k} (as reported) | {v:.2f} | - |" for k, v in TABLE_II.items()]
    for r in s.sort_values(["arm", "family"], key=_arm_order).itertuples():
        who = _label(r.arm, r.family)
        per = r.n_episodes // r.n_seeds
        lines.append(
            f"| {who} | {r.collision_pct:.2f} [{r.collision_pct_lo:.2f}, "
            f"{r.collision_pct_hi:.2f}] | {r.n_seeds} x {per} |"
        )
    return "\n".join(lines) + "\n"


def _arm_order(column: pd.Series) -> pd.Series:
    order = {a: i for i, a in enumerate(["main", "authors", "mix0", "mix50", "mix100", ""])}
    return column.map(lambda v: order.get(v, 99)) if column.name == "arm" else column


def _label(arm: str, family: str) -> str:
    if not arm:
        return f"{family} (baseline)"
    return f"bgap {family.replace('_', '-')} DQN, {ARM_NAMES.get(arm, arm)}"


def paper_comparison(stats: pd.DataFrame, arm: str = "main") -> str:
    lines = [
        "| n | policy | aggressive | paper crashes/100 | bgap collision % [95% CI] | idle % | "
        "paper speed | bgap speed m/s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    g = stats[stats.traffic == "paper"]
    r = g.radius.max()
    for (density, family), paper in PAPER_CRASHES.items():
        for mix, value in paper.items():
            s = g[(g.arm == arm) & (g.family == family) & (g.density == density)
                  & (g.mix == mix) & (g.radius == r)]  # fmt: skip
            idle = g[(g.family == "idle") & (g.density == density) & (g.mix == mix)
                     & (g.radius == r)]  # fmt: skip
            if s.empty:
                continue
            x = s.iloc[0]
            speed = PAPER_SPEED.get((density, family), {}).get(mix)
            lines.append(
                f"| {n_of(density)} | {family} | {mix:.0%} | {value} | {x.collision_pct:.1f} "
                f"[{x.collision_pct_lo:.1f}, {x.collision_pct_hi:.1f}] | "
                f"{idle.iloc[0].collision_pct:.1f} | {'-' if speed is None else speed} | "
                f"{x.avg_speed:.2f} |"
            )
    return "\n".join(lines) + "\n"


def claims_markdown(table: pd.DataFrame) -> str:
    lines = [
        "| arm | n | claim (paper figure) | paper | ours: a - b [95% CI] | Holm-corrected "
        "interval | p (Holm) | seeds a / b | episodes a / b | verdict | reading |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in table.itertuples():
        lines.append(
            f"| {r.arm} | {r.n} | {r.claim} ({r.figure}) | {r.paper} | {r.difference:+.2f} "
            f"[{r.lo:+.2f}, {r.hi:+.2f}] | [{r.lo_holm:+.2f}, {r.hi_holm:+.2f}] | "
            f"{_p(r.p_holm)} | {r.n_seeds_a} / {r.n_seeds_b} | {r.n_episodes_a} / "
            f"{r.n_episodes_b} | **{r.verdict}** | {r.reading} |"
        )
    return "\n".join(lines) + "\n"


def _p(p: float) -> str:
    """A bootstrap p-value: 0 means no replicate on the other side (below 1e-4 at 20,000)."""
    return "< 1e-4" if p == 0 else f"{p:.2g}"


def own_markdown(own: pd.DataFrame) -> str:
    lines = [
        "| arm | policy | n | own traffic | collision % [95% CI] | crashes: rear-end / "
        "rear-ended / lane change | speed m/s | idle % (rear-end / rear-ended / lane change) | "
        "idle m/s | seeds | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in own.sort_values(["arm", "family"], key=_arm_order).itertuples():
        verdict = "beats idle" if r.beats_idle else "**FLAGGED: does not beat idle**"
        split, idle_split = (
            " / ".join(f"{getattr(r, f'{who}{k}_pct', float('nan')):.1f}"
                       for k in ("rear_end", "rear_ended", "lane_change"))
            for who in ("", "idle_")
        )  # fmt: skip
        lines.append(
            f"| {r.arm} | {r.family} | {r.n} | {r.own_traffic} | {r.collision_pct:.1f} "
            f"[{r.collision_lo:.1f}, {r.collision_hi:.1f}] | {split} | {r.avg_speed:.2f} | "
            f"{r.idle_collision_pct:.1f} ({idle_split}) | {r.idle_avg_speed:.2f} | "
            f"{r.n_seeds} | {verdict} |"
        )
    return "\n".join(lines) + "\n"


def selection_markdown(runs: Path | None) -> str:
    """Where the trainings' kept checkpoints come from (``best.json`` of each run folder)."""
    if runs is None or not Path(runs).exists():
        return "(run folders not given)\n"
    rows = []
    for path in sorted(Path(runs).rglob("best.json")):
        best = json.loads(path.read_text())
        ev = pd.read_csv(path.parent / "evaluations.csv")
        arm = path.relative_to(runs).parts[0]
        rows.append({"arm": arm, "run": path.parent.name, "chosen": best["episodes"],
                     "of": int(ev.episodes.max()), "collision": best["collision_pct"],
                     "last": float(ev.collision_pct.iloc[-1])})  # fmt: skip
    if not rows:
        return "(no training validated periodically: the last parameters are evaluated)\n"
    t = pd.DataFrame(rows)
    lines = ["| arm | trainings | chosen at episode (median, range) | validation collision % "
             "chosen / last (means) |", "|---|---|---|---|"]  # fmt: skip
    for arm, g in t.groupby("arm"):
        lines.append(f"| {arm} | {len(g)} | {g.chosen.median():.0f} ({g.chosen.min()}-"
                     f"{g.chosen.max()} of {g['of'].max()}) | {g.collision.mean():.1f} / "
                     f"{g['last'].mean():.1f} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def departures_markdown(runs: Path | None) -> str:
    """The settings in which the main arm (the recipe) departs from the authors' arm (their
    2020 configuration under the paper's protocol), read from the trainings' saved configs."""
    configs = {}
    for arm in MIXTURE_ARMS:
        found = sorted((Path(runs) / arm).rglob("config.yaml")) if runs else []
        if found:
            from omegaconf import OmegaConf

            configs[arm] = OmegaConf.to_container(OmegaConf.load(found[0]))
    if len(configs) < 2:
        return "(needs the run folders of both arms)\n"
    lines = ["| setting | authors' arm (their 2020 configuration) | main arm (recipe) |",
             "|---|---|---|"]  # fmt: skip
    for group in ("reward", "agent", "profile"):
        a, b = configs["authors"][group], configs["main"][group]
        for key in sorted(set(a) | set(b)):
            if key != "name" and a.get(key) != b.get(key):
                shown = [f"{v:.4g}" if isinstance(v, float) else str(v)
                         for v in (a.get(key), b.get(key))]  # fmt: skip
                lines.append(f"| {group}.{key} | {shown[0]} | {shown[1]} |")
    lines.append(
        "\nThe recipe's settings come from `bgap.recipe` (results/recipe/, validation episodes "
        "only); the authors' from their code (FACTS.md). `agent.gradient_steps` -1 is one "
        "update per transition; 1 is one per vector step of 2 environments."
    )
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------- figures
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _errorbar(ax, s: pd.DataFrame, metric: str, **kwargs) -> None:
    err = [np.clip(s[metric] - s[f"{metric}_lo"], 0, None),
           np.clip(s[f"{metric}_hi"] - s[metric], 0, None)]  # fmt: skip
    ax.errorbar(s.mix, s[metric], yerr=err, capsize=3, **kwargs)


def fig4(stats: pd.DataFrame, per_seed: pd.DataFrame, path: Path, arm: str = "main") -> None:
    """Collision %, speed and lane changes against the aggressive fraction: the arm's two
    families (mean over seeds, 95% interval, small dots each seed) and the idle and
    rule-based egos on the same episodes."""
    plt = _plt()
    g = stats[stats.traffic == "paper"]
    radius = g.radius.max()
    densities = [d for d in ("sparse", "dense") if d in set(g.density)]
    fig, axes = plt.subplots(len(densities), 3, figsize=(12, 3.3 * len(densities)), squeeze=False)
    colors = {"behavior_rich": "tab:green", "default": "tab:gray"}
    for r, density in enumerate(densities):
        here = g[(g.density == density) & (g.radius == radius)]
        for c, (metric, label) in enumerate(METRICS.items()):
            ax = axes[r, c]
            for family, color in colors.items():
                s = here[(here.arm == arm) & (here.family == family)].sort_values("mix")
                if s.empty:
                    continue
                _errorbar(ax, s, metric, fmt="-o", color=color, label=family.replace("_", "-"))
                p = per_seed[(per_seed.arm == arm) & (per_seed.family == family)
                             & (per_seed.density == density) & (per_seed.radius == radius)
                             & (per_seed.traffic == "paper")]  # fmt: skip
                ax.plot(p.mix, p[metric], ".", color=color, alpha=0.35)
            for name, style in (("idle", "--"), ("rule", ":")):
                s = here[here.family == name].sort_values("mix")
                if len(s):
                    ax.plot(s.mix, s[metric], style, color="k", lw=1, label=name)
            ax.set_title(f"n = {n_of(density)}: {label}", fontsize=10)
            ax.set_xlabel("aggressive fraction")
            if r == 0 and c == 0:
                ax.legend(fontsize=8)
    fig.suptitle(f"Fig. 4 (bgap, {ARM_NAMES.get(arm, arm)}): radius {radius:g} m", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def fig6(stats: pd.DataFrame, path: Path, arm: str = "main") -> None:
    plt = _plt()
    g = stats[(stats.traffic == "paper") & (stats.arm == arm)]
    densities = [d for d in ("sparse", "dense") if d in set(g.density)]
    fig, axes = plt.subplots(1, len(densities), figsize=(5.5 * len(densities), 3.4), squeeze=False)
    for ax, density in zip(axes[0], densities, strict=True):
        for radius in sorted(set(g.radius), reverse=True):
            s = g[(g.family == "behavior_rich") & (g.density == density)
                  & (g.radius == radius)].sort_values("mix")  # fmt: skip
            _errorbar(ax, s, "collision_pct", fmt="-o", label=f"{radius:g} m")
        ax.set_title(f"n = {n_of(density)}: behaviour-rich collisions", fontsize=10)
        ax.set_xlabel("aggressive fraction")
        ax.set_ylabel("collision %")
        ax.legend(title="perception radius", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def paper_vs_ours(stats: pd.DataFrame, path: Path, arm: str = "main") -> None:
    """The paper's crash bars (hatched) beside ours (solid, 95% interval) at 0, 50 and 100%
    aggressive, per density and family, with idle's rate on the same episodes."""
    plt = _plt()
    g = stats[(stats.traffic == "paper")]
    g = g[g.radius == g.radius.max()]
    densities = [d for d in ("sparse", "dense") if d in set(g.density)]
    fig, axes = plt.subplots(1, len(densities), figsize=(6 * len(densities), 3.6), squeeze=False)
    for ax, density in zip(axes[0], densities, strict=True):
        x = np.arange(3)
        for i, (family, color) in enumerate((("default", "tab:gray"),
                                             ("behavior_rich", "tab:green"))):  # fmt: skip
            paper = PAPER_CRASHES[(density, family)]
            ax.bar(x + i * 0.4 - 0.3, list(paper.values()), 0.2, color=color, alpha=0.35,
                   hatch="//", label=f"{family.replace('_', '-')} (paper)")  # fmt: skip
            s = g[(g.arm == arm) & (g.family == family) & (g.density == density)]
            s = s.set_index("mix").reindex(list(paper))
            err = [np.clip(s.collision_pct - s.collision_pct_lo, 0, None).fillna(0),
                   np.clip(s.collision_pct_hi - s.collision_pct, 0, None).fillna(0)]  # fmt: skip
            ax.bar(x + i * 0.4 - 0.1, s.collision_pct, 0.2, yerr=err, color=color, capsize=2,
                   label=f"{family.replace('_', '-')} (bgap)")  # fmt: skip
        idle = g[(g.family == "idle") & (g.density == density)].set_index("mix")
        idle = idle.reindex([0.0, 0.5, 1.0])
        ax.plot(x, idle.collision_pct, "k_", ms=30, mew=2, label="idle (bgap)")
        ax.set_xticks(x, ["0%", "50%", "100%"])
        ax.set_xlabel("aggressive fraction")
        ax.set_ylabel("collisions per 100 episodes")
        ax.set_title(f"n = {n_of(density)}", fontsize=10)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"The paper's bars beside ours ({ARM_NAMES.get(arm, arm)})", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def ablation(stats: pd.DataFrame, path: Path) -> bool:
    """Behaviour-rich collision % and speed against the test mix, one line per training
    traffic (the mixture of the main arm, one mix per ablation arm); False without arms."""
    g = stats[(stats.traffic == "paper") & (stats.family == "behavior_rich")]
    g = g[g.radius == g.radius.max()]
    arms = [a for a in ("main", "mix0", "mix50", "mix100") if a in set(g.arm)]
    if len(arms) < 2:
        return False
    plt = _plt()
    densities = [d for d in ("sparse", "dense") if d in set(g.density)]
    fig, axes = plt.subplots(len(densities), 2, figsize=(10, 3.3 * len(densities)),
                             squeeze=False)  # fmt: skip
    for r, density in enumerate(densities):
        for c, metric in enumerate(("collision_pct", "avg_speed")):
            ax = axes[r, c]
            for arm in arms:
                s = g[(g.arm == arm) & (g.density == density)].sort_values("mix")
                label = "mixture of the paper's mixes" if arm == "main" else (
                    f"trained at {float(arm[3:]):g}%")  # fmt: skip
                _errorbar(ax, s, metric, fmt="-o", label=label)
            ax.set_title(f"n = {n_of(density)}: {METRICS[metric]}", fontsize=10)
            ax.set_xlabel("test aggressive fraction")
    axes[0, 0].legend(fontsize=7, title="behaviour-rich training traffic")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


# ---------------------------------------------------------------------- the page
def make_figures(
    results_dir: str | Path,
    out: str | Path = "results",
    stock: str | Path | None = None,
    runs: str | Path | None = None,
) -> dict[str, Path]:
    out = Path(out)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    df = load_episodes(results_dir)
    if stock is not None:
        df = pd.concat([df, load_episodes(stock, traffic="stock")], ignore_index=True)
    stats, per_seed = cell_stats(df)
    paths = {name: out / f"{name}.csv" for name in ("cells", "claims", "own_traffic")}
    stats.to_csv(paths["cells"], index=False)
    table = claims(df)
    table.to_csv(paths["claims"], index=False)
    own = own_traffic(df)
    own.to_csv(paths["own_traffic"], index=False)
    grid = df[df.traffic == "paper"]
    headline = {
        f"{arm or 'baseline'}/{density}/{family}": {
            m: round(float(g[m].mean()), 3) for m in METRICS
        }
        for (arm, density, family), g in _distinct(grid).groupby(["arm", "density", "family"])
    }
    (out / "metrics.json").write_text(json.dumps(headline, indent=1, sort_keys=True))
    paths["table2"] = out / "table2.md"
    paths["table2"].write_text(table2(stats))
    arms = [a for a in MIXTURE_ARMS if a in set(stats.arm)]
    for arm in arms:
        name = "fig4" if arm == "main" else f"fig4_{arm}"
        paths[name] = out / "figures" / f"{name}.png"
        fig4(stats, per_seed, paths[name], arm)
    paths["fig6"] = out / "figures" / "fig6.png"
    fig6(stats, paths["fig6"], arms[0] if arms else "main")
    paths["paper_vs_ours"] = out / "figures" / "paper_vs_ours.png"
    paper_vs_ours(stats, paths["paper_vs_ours"], arms[0] if arms else "main")
    if ablation(stats, out / "figures" / "ablation.png"):
        paths["ablation"] = out / "figures" / "ablation.png"
    paths["readme"] = out / "README.md"
    paths["readme"].write_text(readme(df, stats, table, own, results_dir, stock, runs, paths))
    return paths


def readme(df, stats, table, own, results_dir, stock, runs, paths) -> str:
    ablated = ablation_table(df)
    trained = df[df.train_seed >= 0]
    seeds = trained.groupby(["arm", "density", "family"]).train_seed.nunique()
    sizes = ", ".join(f"{arm}: {int(n)}" for arm, n in seeds.groupby(level=0).max().items())
    dup = duplicates(df[df.traffic == "paper"])
    dup_text = "; ".join(f"n = {n_of(d)}: mix {m:g} repeats mix {o:g}"
                         for (d, m), o in sorted(dup.items())) or "none"  # fmt: skip
    figures = ", ".join(f"`figures/{p.name}`" for k, p in paths.items() if p.suffix == ".png")
    flagged = own[~own.beats_idle] if len(own) else own
    parts = [
        "# Results (written by `python -m bgap.figures`; do not edit)\n",
        f"Source: `{results_dir}`"
        + (f" and `{stock}` (stock traffic)" if stock else "")
        + f": {len(df):,} evaluation episodes; training seeds per policy and arm: {sizes}. "
        f"Figures: {figures}. Per-cell numbers: `cells.csv` (with `n_seeds`, `n_episodes`); "
        f"claims: `claims.csv`; own traffic: `own_traffic.csv`.\n",
        f"Cells that repeat another cell's traffic (the same number of aggressive drivers, "
        f"so the same episodes): {dup_text}. They are shown in the per-cell tables and "
        "counted once in every average over mixes and in the claims.\n",
        "## Does each trained policy beat idle in its own training traffic?\n",
        "Own traffic: behaviour-rich on the mixes it trained on, default in highway-env's "
        "stock traffic; largest radius; fewer collisions than the idle ego at a mean speed of "
        f"at least {SPEED_FLOOR:g} x idle's, on the same episodes. A flagged policy's "
        "comparisons below are not evidence about behaviour-rich training.\n",
        own_markdown(own) if len(own) else "(no trained policies)\n",
        (f"**{len(flagged)} flagged.**\n" if len(flagged) else "None flagged.\n"),
        "## The paper's claims\n",
        "a - b as the claim reads (collision percentage points, m/s or lane changes per "
        "episode). Training seeds are the independent units: two-level bootstrap (seeds, then "
        "episodes within each); one model in two traffic conditions is paired by training "
        "seed; two perception radii play the same scenes, so per-episode differences are "
        "resampled; two policy families are never paired. Holm's correction runs across the "
        f"{len(table)} rows; the verdict follows from the corrected p-value (alpha "
        f"{ALPHA:g}) and the Holm-corrected interval is the bootstrap interval at the level "
        "Holm's step tests the claim at.\n",
        claims_markdown(table) if len(table) else "(no claims: one family only)\n",
        "## Training traffic: one mix or the mixture (ablation)\n",
        "Behaviour-rich trained at one mix minus behaviour-rich trained on the mixture of the "
        "paper's mixes (main arm), collision percentage points, largest radius; unpaired "
        "two-level bootstrap, exploratory (not in the Holm family). Figure: "
        "`figures/ablation.png`.\n",
        (ablated.to_markdown(index=False, floatfmt=".2f") if len(ablated) else "(no ablation arms)")
        + "\n",
        "## Collisions and speed beside the paper's bars (main arm)\n",
        paper_comparison(stats),
        "## Table II\n",
        "Our rates for every policy in Table II's cell; the paper reports no interval and no "
        "baseline in that cell, so its 3.00% should be read against idle's and default's "
        "rates there.\n",
        table2(stats),
        "## Where the arms differ\n",
        departures_markdown(Path(runs) if runs else None),
        "## Checkpoints the trainings kept\n",
        "Each training validates every 50 episodes on 20 episodes of its own traffic and "
        "keeps the validation with the highest mean return under its own reward "
        "(`best_model.zip`, SB3's EvalCallback rule; ours: the paper keeps none); the test "
        "episodes play that checkpoint.\n",
        selection_markdown(Path(runs) if runs else None),
    ]
    return "\n".join(parts)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m bgap.figures",
        description=__doc__.split("\n\n")[0] + " What it writes: docs/pipeline.md.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("results_dir", help="folder with bgap.evaluate's episodes.csv")
    parser.add_argument("--stock", help="bgap.evaluate's folder of the same policies in "
                        "stock traffic (behavior=stock)")  # fmt: skip
    parser.add_argument("--runs", help="the run folders (the checkpoints each training kept)")
    parser.add_argument(
        "--out",
        default="outputs/figures",
        help="where figures and tables go (the pipeline: results)",
    )
    args = parser.parse_args(argv)
    for name, path in make_figures(args.results_dir, args.out, args.stock, args.runs).items():
        print(f"{name}: {path}")


if __name__ == "__main__":
    main()

"""Testing the paper's claims on our episodes: bootstrap over training seeds, Holm's
correction across the table, and each trained policy against idle in its own traffic."""

from __future__ import annotations

import numpy as np
import pandas as pd

from bgap.analysis.episodes import (
    ALPHA,
    _crashes,
    _distinct,
    _groups,
    _rate,
    is_replay,
    mixture_arms,
    n_of,
)
from bgap.analysis.paper import CLAIMS, Claim, replay_claim
from bgap.analysis.stats import (
    beats_idle,
    bootstrap_test,
    holm,
    seed_bootstrap,
)
from bgap.common.vocab import CRASH_KINDS


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
        if claim.metric == "collision_pct":  # crashes in points: -100, 0 or +100 per scene
            observed, dist = seed_bootstrap(
                [x / 100.0 for x in groups.values()], rng=rng, differences="events"
            )
            observed, dist = 100.0 * observed, 100.0 * dist
        else:
            observed, dist = seed_bootstrap(list(groups.values()), rng=rng, differences="values")
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
    families and every density, and :func:`replay_claim` for every replayed table, with
    Holm's correction across the table."""
    rng = np.random.default_rng(seed)
    grid = _distinct(df[df.traffic == "paper"])
    rows = []
    for arm in mixture_arms(grid.arm):
        trained = grid[grid.arm == arm]
        for density in sorted(set(trained.density)):
            d = trained[trained.density == density]
            for claim in CLAIMS(sorted(set(d.radius)), sorted(set(d.mix))):
                if density not in claim.densities:
                    continue
                result = _test(claim, d, rng)
                if result is None:
                    continue
                rows.append(_row(claim, arm, density, result))
    replayed = df[is_replay(df.traffic)]  # the same claim in observed traffic, per table
    for (arm, traffic, density), d in replayed.groupby(["arm", "traffic", "density"]):
        if arm not in mixture_arms([arm]):
            continue
        claim = replay_claim(traffic)
        result = _test(claim, d, rng)
        if result is not None:
            rows.append(_row(claim, arm, density, result))
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


def _row(claim: Claim, arm: str, density: str, result: dict) -> dict:
    return {"claim": claim.text, "figure": claim.figure, "arm": arm, "n": n_of(density),
            "metric": claim.metric, "expect": claim.expect, "paper": claim.paper,
            **result}  # fmt: skip


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

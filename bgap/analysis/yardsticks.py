"""Learned policies against the hand-built drivers, paired on the same seeded episodes.

The hand-built drivers (:data:`~bgap.common.vocab.YARDSTICKS`) are the rule-based ego with
highway-env's parameters (``rule``), with the parameters ``bgap.tune_rule`` chose on
validation episodes (``rule_tuned``), and IDM in its lane (``idm``). A learned policy *beats
the hand-built driver* in a density only by beating each of them there: fewer collisions per
100 km (the upper end of the paired difference's 95% interval below zero) at a mean speed of
at least :data:`~bgap.analysis.stats.RULE_FLOOR` x theirs. Everything is pooled over the cells
learned policies are read against the rules in: bgap's traffic at the largest radius, mixes
that repeat another's traffic left out (as the yardstick table's).

The interval. A yardstick is one deterministic driver: only the episodes vary with it, and
they are the learned policy's episodes too. Each episode's part in the difference of the two
pooled rates is linearised (the delta method on each cell's crashes over its kilometres),
which gives a seeds x episodes table whose mean is the difference's fluctuation; its crossed
variance (:func:`bgap.analysis.intervals.crossed_variance`) counts the training seeds and the
shared episodes once each. Its coverage is simulated by
:func:`bgap.analysis.coverage.yardstick_coverage`; below :data:`MIN_SEEDS` the table gives the
numbers and no verdict.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from bgap.analysis.episodes import distinct_cells, n_of
from bgap.analysis.intervals import crossed_variance, t_test
from bgap.analysis.stats import PER_KM, RULE_FLOOR
from bgap.common.vocab import YARDSTICK_NAMES, YARDSTICKS

MIN_SEEDS = 5
"""Fewest training seeds for a verdict against a yardstick: at 3 seeds the simulated
coverage falls to about 90% where seeds differ much (:func:`bgap.analysis.coverage.
yardstick_table`, docs/intervals.md), at 5 and 10 it reaches 93%."""

KEY = ["mix", "seed"]
"""What aligns a policy's episodes with a yardstick's: the cell's mix and the episode seed."""


def read_cells(df: pd.DataFrame, density: str) -> pd.DataFrame:
    """The episodes of ``density`` learned policies are read against the rules on: bgap's
    traffic, the largest radius, repeated mixes left out."""
    g = df[(df.traffic == "paper") & (df.density == density)] if len(df) else df
    if g.empty or "distance" not in g:
        return g.iloc[0:0]
    g = distinct_cells(g)
    return g[g.radius == g.radius.max()]


METRICS = ("crashed", "distance", "avg_speed")
"""What :func:`compare` reads of each episode."""


def aligned(
    episodes: pd.DataFrame, seeds: list[int], order: pd.DataFrame, metrics: tuple = METRICS
) -> tuple:
    """The ``metrics`` (default: crashes, distances and speeds) of ``episodes`` as
    ``[seed, episode]`` arrays in the episode order ``order`` (its columns name an episode:
    here ``mix`` and ``seed``)."""
    keys = list(order.columns)
    index = pd.MultiIndex.from_tuples(
        [(s, *row) for s in seeds for row in order.itertuples(index=False)],
        names=["train_seed", *keys],
    )
    e = episodes.set_index(["train_seed", *keys])[list(metrics)].reindex(index)
    shape = (len(seeds), len(order))
    return tuple(e[k].to_numpy(float).reshape(shape) for k in metrics)


def linearised(c: np.ndarray, d: np.ndarray, v: np.ndarray, mixes: np.ndarray) -> tuple:
    """A policy's pooled collisions per 100 km and mean speed over the cells (``mixes``, one
    per episode column: the mean over seeds of each cell's crashes over its kilometres, then
    over cells), and the rate's per-episode linearisation (each cell's crashes less its
    pooled rate times the distance, over its mean distance), ``[seed, episode]``."""
    table = np.empty(c.shape)
    rates = np.zeros(c.shape[0])
    cells = np.unique(mixes)
    for m in cells:
        j = mixes == m
        pooled, dbar = c[:, j].sum() / d[:, j].sum(), d[:, j].mean()
        table[:, j] = (c[:, j] - pooled * d[:, j]) / dbar * PER_KM
        rates += c[:, j].sum(axis=1) / d[:, j].sum(axis=1) * PER_KM / len(cells)
    speed = float(np.mean([v[:, mixes == m].mean() for m in cells]))
    return float(rates.mean()), speed, table


def compare(policy: tuple, yard: tuple, mixes: np.ndarray) -> dict[str, float]:
    """A policy's (crashes, distances, speeds) ``[seed, episode]`` arrays against a
    yardstick's on the same episode columns (:func:`aligned`): both figures, the differences
    with their 95% intervals and p-values, and the verdict (module docstring)."""
    rate, speed, rate_t = linearised(*policy, mixes)
    y_rate, y_speed, y_rate_t = linearised(*yard, mixes)
    diff = rate - y_rate
    var, df = crossed_variance(rate_t - y_rate_t)
    # one crash's worth of Poisson variance per side: an interval over a few crashes is never
    # narrower than one more or one fewer crash would move it (the rare settings' coverage)
    var += sum((PER_KM / side[1].sum()) ** 2 for side in (policy, yard))
    lo, hi, p = t_test(diff, var, df)
    s_diff = speed - y_speed
    s_lo, s_hi, _ = t_test(s_diff, *crossed_variance(policy[2] - yard[2]))
    fast = speed >= RULE_FLOOR * y_speed
    n_seeds = policy[0].shape[0]
    if n_seeds < MIN_SEEDS or not np.isfinite(hi):
        verdict = "too few seeds"
    elif hi < 0:
        verdict = "beats" if fast else "safer, slower"
    elif lo > 0:
        verdict = "beaten" if not fast or s_diff <= 0 else "faster, less safe"
    else:
        verdict = "not significant"
    return {
        "n_seeds": n_seeds,
        "per_100km": rate,
        "yard_per_100km": y_rate,
        "diff": diff,
        "diff_lo": lo,
        "diff_hi": hi,
        "p": p,
        "avg_speed": speed,
        "yard_speed": y_speed,
        "speed_diff": s_diff,
        "speed_diff_lo": s_lo,
        "speed_diff_hi": s_hi,
        "speed_ratio": speed / y_speed,
        "verdict": verdict,
    }


def versus(policy: pd.DataFrame, yard: pd.DataFrame) -> dict[str, float]:
    """One learned policy's episodes (every training seed) against one yardstick's on the
    same cells (:func:`compare`)."""
    order = yard[KEY].drop_duplicates().sort_values(KEY).reset_index(drop=True)
    mine = aligned(policy, sorted(set(policy.train_seed)), order)
    theirs = aligned(yard, sorted(set(yard.train_seed)), order)
    return compare(mine, theirs, order.mix.to_numpy())


def same_episodes(policy: pd.DataFrame, yard: pd.DataFrame, key: list[str] = KEY) -> bool:
    """Whether every training seed of ``policy`` played exactly the yardstick's episodes
    (named by ``key``)."""
    want = set(map(tuple, yard[key].to_numpy()))
    return all(set(map(tuple, g[key].to_numpy())) == want for _, g in policy.groupby("train_seed"))


def versus_yardsticks(df: pd.DataFrame) -> pd.DataFrame:
    """Every learned policy family (arm, family) against every yardstick in each density
    (:func:`versus`), and whether it beats each: one row per density, arm, family and
    yardstick; ``beats_all`` on every row of a policy that beats all three."""
    rows = []
    for density in ("sparse", "dense"):
        g = read_cells(df, density)
        if g.empty:
            continue
        yards = {y: g[g.family == y] for y in YARDSTICKS if (g.family == y).any()}
        learned = g[g.arm != ""]
        for (arm, family), pol in learned.groupby(["arm", "family"], sort=True):
            for name, yard in yards.items():
                if not same_episodes(pol, yard):
                    continue  # another grid: not the same episodes
                rows.append(
                    {
                        "density": density,
                        "arm": arm,
                        "family": family,
                        "yardstick": name,
                        **versus(pol, yard),
                    }
                )
    out = pd.DataFrame(rows)
    if out.empty:
        return out
    every = out.groupby(["density", "arm", "family"]).verdict.agg(
        lambda v: len(v) == len(YARDSTICKS) and (v == "beats").all()
    )
    out["beats_all"] = [every[k] for k in zip(out.density, out.arm, out.family, strict=True)]
    return out


def _label(arm: str, family: str) -> str:
    return f"{arm} {family.replace('_', '-')}"


def markdown(table: pd.DataFrame) -> str:
    """One table per density: each learned policy family against each yardstick, the
    difference in collisions per 100 km with its 95% interval, the speed ratio and the
    verdict; the last column says whether it beats the hand-built driver (all three)."""
    if table.empty:
        return "(no hand-built driver shares the learned policies' episodes)\n"
    parts = []
    for density, here in table.groupby("density", sort=False):
        yards = [y for y in YARDSTICKS if y in set(here.yardstick)]
        first = here.drop_duplicates("yardstick").set_index("yardstick")
        known = " · ".join(
            f"{YARDSTICK_NAMES[y]} (`{y}`): {first.loc[y, 'yard_per_100km']:.2f} per 100 km at "
            f"{first.loc[y, 'yard_speed']:.2f} m/s"
            for y in yards
        )
        lines = [
            f"**{density} (n = {n_of(density)})**: {known}\n",
            "| policy | seeds | per 100 km at m/s | "
            + " | ".join(f"vs `{y}`: difference [95% CI], speed ratio" for y in yards)
            + " | beats the hand-built driver? |",
            "|---|---|---|" + "---|" * (len(yards) + 1),
        ]
        for (arm, family), rows in here.groupby(["arm", "family"], sort=True):
            rows = rows.set_index("yardstick")
            r0 = rows.iloc[0]
            cells = []
            for y in yards:
                if y not in rows.index:
                    cells.append("-")
                    continue
                r = rows.loc[y]
                cells.append(
                    f"{r['diff']:+.2f} [{r.diff_lo:+.2f}, {r.diff_hi:+.2f}], "
                    f"{r.speed_ratio:.2f}: {r.verdict}"
                )
            if (rows.verdict == "too few seeds").any():
                answer = "too few seeds"
            else:
                answer = "**yes**" if bool(r0.beats_all) else "no"
            head = f"| {_label(arm, family)} | {int(r0.n_seeds)} | {r0.per_100km:.2f} at "
            lines.append(f"{head}{r0.avg_speed:.2f} | " + " | ".join(cells) + f" | {answer} |")
        parts.append("\n".join(lines) + "\n")
    return "\n".join(parts)

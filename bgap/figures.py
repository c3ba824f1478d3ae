"""The paper's figures and claims from fresh numbers: ``python -m bgap.figures RESULTS_DIR``.

Reads the ``episodes.csv`` that ``bgap.evaluate`` wrote for the pipeline's policies (named
``<density>-<behavior_rich|default>-s<seed>``) and baselines, and writes to ``--out``
(default ``results/``):

- ``figures/fig4.png``: collision %, average speed and lane changes per episode against the
  aggressive fraction, n = 5 and n = 40, behaviour-rich vs default (the paper's Fig. 4);
  points are the mean over training seeds, bars its 95% interval across seeds (within
  episodes when there is one seed), small dots each seed;
- ``figures/fig6.png``: the behaviour-rich policy's collision % per perception radius;
- ``table2.md``: our n = 5, all-aggressive collision rate beside the paper's Table II;
- ``claims.csv`` and ``README.md``: our numbers beside the paper's and, for each of the
  paper's claims, the paired statistics that support or contradict it.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np
import pandas as pd

from bgap.scenario import env_preset
from bgap.stats import mean_interval, wilson_interval

MODEL = re.compile(r"^(?P<density>[a-z]+)-(?P<family>behavior_rich|default)-s(?P<seed>\d+)$")
METRICS = {"collision_pct": "collision %", "avg_speed": "speed m/s", "lane_changes": "lane changes"}


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
TABLE_II = {"DDPG": 10.13, "PS-DDPG": 11.40, "B-GAP (paper)": 3.00}


def load_episodes(results_dir: str | Path) -> pd.DataFrame:
    """Episode rows with the policy family and training seed parsed from the policy name."""
    path = Path(results_dir) / "episodes.csv"
    if not path.exists():
        raise FileNotFoundError(f"{path} not found: run python -m bgap.evaluate first")
    return parse_policies(pd.read_csv(path))


def parse_policies(df: pd.DataFrame) -> pd.DataFrame:
    """``family`` and ``train_seed`` columns parsed from policy names
    ``<density>-<family>-s<seed>`` (baselines: their own name, seed -1)."""
    df = df.copy()
    parsed = df.policy.str.extract(MODEL)
    df["family"] = parsed["family"].fillna(df.policy)
    df["train_seed"] = pd.to_numeric(parsed["seed"]).fillna(-1).astype(int)
    df["collision_pct"] = 100.0 * df.crashed.astype(float)
    return df


def cell_stats(df: pd.DataFrame) -> pd.DataFrame:
    """Per family and cell: mean over training seeds of each metric and its 95% interval
    (across seeds with >= 2 seeds that differ; across episodes otherwise)."""
    keys = ["family", "density", "mix", "radius"]
    per_seed = df.groupby([*keys, "train_seed"])[list(METRICS)].mean().reset_index()
    rows = []
    for key, g in per_seed.groupby(keys):
        row = dict(zip(keys, key, strict=True)) | {"seeds": len(g)}
        episodes = df.set_index(keys).loc[key]
        for m in METRICS:
            row[m] = g[m].mean()
            spread = len(g) > 1 and g[m].nunique() > 1
            if spread:
                row[f"{m}_lo"], row[f"{m}_hi"] = mean_interval(g[m].to_numpy())
            elif m == "collision_pct":
                # one seed, or seeds that all agree (a zero-width t interval): the Wilson
                # interval of all their episodes' crashes, which is never of zero width
                lo, hi = wilson_interval(int(episodes.crashed.sum()), len(episodes))
                row[f"{m}_lo"], row[f"{m}_hi"] = 100 * lo, 100 * hi
            else:
                row[f"{m}_lo"], row[f"{m}_hi"] = mean_interval(episodes[m].to_numpy())
        for m in METRICS:  # every metric is non-negative; a rate is at most 100
            row[f"{m}_lo"] = max(row[f"{m}_lo"], 0.0)
        row["collision_pct_hi"] = min(row["collision_pct_hi"], 100.0)
        rows.append(row)
    return pd.DataFrame(rows), per_seed


def fig4(stats: pd.DataFrame, per_seed: pd.DataFrame, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    radius = stats.radius.max()
    densities = [d for d in ("sparse", "dense") if d in set(stats.density)]
    fig, axes = plt.subplots(len(densities), 3, figsize=(12, 3.3 * len(densities)), squeeze=False)
    colors = {"behavior_rich": "tab:green", "default": "tab:gray"}
    for r, density in enumerate(densities):
        for c, (metric, label) in enumerate(METRICS.items()):
            ax = axes[r, c]
            for family, color in colors.items():
                s = stats[
                    (stats.family == family) & (stats.density == density) & (stats.radius == radius)
                ].sort_values("mix")
                if s.empty:
                    continue
                err = [s[metric] - s[f"{metric}_lo"], s[f"{metric}_hi"] - s[metric]]
                ax.errorbar(
                    s.mix,
                    s[metric],
                    yerr=err,
                    fmt="-o",
                    color=color,
                    capsize=3,
                    label=family.replace("_", "-"),
                )
                p = per_seed[
                    (per_seed.family == family)
                    & (per_seed.density == density)
                    & (per_seed.radius == radius)
                ]
                ax.plot(p.mix, p[metric], ".", color=color, alpha=0.35)
            ax.set_title(f"n = {n_of(density)}: {label}", fontsize=10)
            ax.set_xlabel("aggressive fraction")
            if r == 0 and c == 0:
                ax.legend(fontsize=8)
    fig.suptitle(f"Fig. 4 (bgap): behaviour-rich vs default, radius {radius:g} m", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def fig6(stats: pd.DataFrame, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    densities = [d for d in ("sparse", "dense") if d in set(stats.density)]
    fig, axes = plt.subplots(1, len(densities), figsize=(5.5 * len(densities), 3.4), squeeze=False)
    for ax, density in zip(axes[0], densities, strict=True):
        for radius in sorted(set(stats.radius), reverse=True):
            s = stats[
                (stats.family == "behavior_rich")
                & (stats.density == density)
                & (stats.radius == radius)
            ].sort_values("mix")
            err = [s.collision_pct - s.collision_pct_lo, s.collision_pct_hi - s.collision_pct]
            ax.errorbar(
                s.mix, s.collision_pct, yerr=err, fmt="-o", capsize=3, label=f"{radius:g} m"
            )
        ax.set_title(f"n = {n_of(density)}: behaviour-rich collisions", fontsize=10)
        ax.set_xlabel("aggressive fraction")
        ax.set_ylabel("collision %")
        ax.legend(title="perception radius", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _paired(df: pd.DataFrame, a: dict, b: dict, metric: str = "collision_pct") -> dict:
    """Mean of metric(a) - metric(b) over episodes played on the same seeds (and training
    seed), with a 95% interval across training seeds (across episodes with one seed)."""
    keys = ["train_seed", "seed"]
    sel_a = df.loc[np.logical_and.reduce([df[k] == v for k, v in a.items()])]
    sel_b = df.loc[np.logical_and.reduce([df[k] == v for k, v in b.items()])]
    same_train = set(sel_a.train_seed) == set(sel_b.train_seed)
    differing = {k for k in {*a, *b} if a.get(k) != b.get(k)}  # what the claim compares
    join = [k for k in (*(keys if same_train else ["seed"]), "mix", "radius") if k not in differing]
    xa = sel_a.groupby(join)[metric].mean()
    xb = sel_b.groupby(join)[metric].mean()
    d = (xa - xb).dropna()
    if d.empty:
        return {"difference": np.nan, "lo": np.nan, "hi": np.nan, "n": 0}
    if same_train and d.index.get_level_values("train_seed").nunique() > 1:
        per_seed = d.groupby(level="train_seed").mean()
        lo, hi = mean_interval(per_seed.to_numpy())
    else:
        lo, hi = mean_interval(d.to_numpy())
    return {"difference": float(d.mean()), "lo": lo, "hi": hi, "n": int(len(d))}


def _verdict(lo: float, hi: float, expect_negative: bool) -> str:
    if not np.isfinite(lo):
        return "no data"
    if expect_negative:
        return "holds" if hi < 0 else ("contradicted" if lo > 0 else "not significant")
    return "holds" if lo > 0 else ("contradicted" if hi < 0 else "not significant")


def claims(df: pd.DataFrame) -> pd.DataFrame:
    """The paper's claims, each with the paired difference behind our verdict."""
    rows = []
    radius = df.radius.max()
    for density in sorted(set(df.density)):
        base = {"density": density}
        # 1. behaviour-rich collides less than default (all mixes, full perception)
        r = _paired(
            df[df.radius == radius],
            {**base, "family": "behavior_rich"},
            {**base, "family": "default"},
        )
        rows.append(
            {
                "claim": f"n={n_of(density)}: behaviour-rich collides less than "
                "default (all mixes, paired)",
                **r,
                "verdict": _verdict(r["lo"], r["hi"], True),
            }
        )
        # 2. behaviour-rich: fewer collisions in homogeneous than mixed traffic
        br = df[(df.family == "behavior_rich") & (df.density == density) & (df.radius == radius)]
        homo = br[br.mix.isin([0.0, 1.0])].collision_pct.to_numpy()
        mixed = br[~br.mix.isin([0.0, 1.0])].collision_pct.to_numpy()
        if len(homo) and len(mixed):
            diff = homo.mean() - mixed.mean()
            se = np.sqrt(homo.var(ddof=1) / len(homo) + mixed.var(ddof=1) / len(mixed))
            lo, hi = diff - 1.96 * se, diff + 1.96 * se
            rows.append(
                {
                    "claim": f"n={n_of(density)}: behaviour-rich collides less in "
                    "homogeneous (0%, 100%) than mixed traffic",
                    "difference": diff,
                    "lo": lo,
                    "hi": hi,
                    "n": len(homo) + len(mixed),
                    "verdict": _verdict(lo, hi, True),
                }
            )
        # 3. default: fewer collisions with all-aggressive traffic than at 50%
        r = _paired(
            df[df.radius == radius],
            {**base, "family": "default", "mix": 1.0},
            {**base, "family": "default", "mix": 0.5},
        )
        rows.append(
            {
                "claim": f"n={n_of(density)}: default collides less at 100% than at 50% aggressive",
                **r,
                "verdict": _verdict(r["lo"], r["hi"], True),
            }
        )
        # 4. smaller perception radius, more collisions (behaviour-rich)
        radii = sorted(set(df.radius))
        if len(radii) > 1:
            r = _paired(
                df,
                {**base, "family": "behavior_rich", "radius": radii[0]},
                {**base, "family": "behavior_rich", "radius": radii[-1]},
            )
            rows.append(
                {
                    "claim": f"n={n_of(density)}: behaviour-rich collides more with a "
                    f"{radii[0]:g} m than a {radii[-1]:g} m perception radius",
                    **r,
                    "verdict": _verdict(r["lo"], r["hi"], False),
                }
            )
    return pd.DataFrame(rows)


def table2(stats: pd.DataFrame) -> str:
    s = stats[
        (stats.family == "behavior_rich")
        & (stats.density == "sparse")
        & (stats.mix == 1.0)
        & (stats.radius == stats.radius.max())
    ]
    lines = ["| method (n = 5, 100% aggressive) | collision % |", "|---|---|"]
    lines += [f"| {k} (as reported) | {v:.2f} |" for k, v in TABLE_II.items()]
    if not s.empty:
        row = s.iloc[0]
        lines.append(
            f"| bgap behaviour-rich DQN | {row.collision_pct:.2f} "
            f"[{row.collision_pct_lo:.2f}, {row.collision_pct_hi:.2f}] |"
        )
    return "\n".join(lines) + "\n"


def paper_comparison(stats: pd.DataFrame) -> str:
    radius = stats.radius.max()
    lines = [
        "| n | policy | aggressive | paper crashes/100 | bgap collision % [95% CI] |",
        "|---|---|---|---|---|",
    ]
    for (density, family), paper in PAPER_CRASHES.items():
        for mix, value in paper.items():
            s = stats[
                (stats.family == family)
                & (stats.density == density)
                & (stats.mix == mix)
                & (stats.radius == radius)
            ]
            ours = (
                "-"
                if s.empty
                else (
                    f"{s.iloc[0].collision_pct:.1f} "
                    f"[{s.iloc[0].collision_pct_lo:.1f}, "
                    f"{s.iloc[0].collision_pct_hi:.1f}]"
                )
            )
            lines.append(f"| {n_of(density)} | {family} | {mix:.0%} | {value} | {ours} |")
    return "\n".join(lines) + "\n"


def make_figures(results_dir: str | Path, out: str | Path = "results") -> dict[str, Path]:
    out = Path(out)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    df = load_episodes(results_dir)
    stats, per_seed = cell_stats(df)
    stats.to_csv(out / "cells.csv", index=False)
    headline = {
        f"{density}/{family}": {m: round(float(g[m].mean()), 3) for m in METRICS}
        for (density, family), g in df.groupby(["density", "family"])
    }
    (out / "metrics.json").write_text(json.dumps(headline, indent=1, sort_keys=True))
    paths = {
        "fig4": out / "figures" / "fig4.png",
        "fig6": out / "figures" / "fig6.png",
        "table2": out / "table2.md",
        "claims": out / "claims.csv",
        "readme": out / "README.md",
    }
    fig4(stats, per_seed, paths["fig4"])
    fig6(stats, paths["fig6"])
    paths["table2"].write_text(table2(stats))
    table = claims(df)
    table.to_csv(paths["claims"], index=False)
    seeds = int(stats.seeds.max()) if len(stats) else 0
    fmt = table.copy()
    for col in ("difference", "lo", "hi"):
        fmt[col] = fmt[col].map(lambda v: f"{v:+.1f}")
    paths["readme"].write_text(
        "# Results (written by `python -m bgap.figures`; do not edit)\n\n"
        f"Source: `{results_dir}` ({len(df):,} evaluation episodes, {seeds} training seed(s) "
        "per policy). Figures: `figures/fig4.png`, `figures/fig6.png`; per-cell numbers: "
        "`cells.csv`.\n\n## Collisions beside the paper's bars\n\n"
        + paper_comparison(stats)
        + "\n## Table II\n\n"
        + table2(stats)
        + "\n## The paper's claims\n\nDifferences are in collision percentage points, paired "
        "by episode seed (and training seed); intervals are 95% across training seeds when "
        "there are several, across episodes otherwise.\n\n" + fmt.to_markdown(index=False) + "\n"
    )
    return paths


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m bgap.figures", description=__doc__)
    parser.add_argument("results_dir", help="folder with bgap.evaluate's episodes.csv")
    parser.add_argument("--out", default="results", help="where figures and tables go")
    args = parser.parse_args(argv)
    for name, path in make_figures(args.results_dir, args.out).items():
        print(f"{name}: {path}")


if __name__ == "__main__":
    main()

"""The study's figures: Fig. 4 and Fig. 6 redone, the paper's bars beside ours, the
training-mix ablation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from bgap.analysis.aggregates import aggregates, profiles_figure
from bgap.analysis.claims import claims, own_traffic
from bgap.analysis.episodes import (
    METRICS,
    arm_name,
    cell_stats,
    distinct_cells,
    load_evaluations,
    mixture_arms,
    n_of,
)
from bgap.analysis.inputs import check_inputs, drop_mismatched, mismatched_traffic
from bgap.analysis.page import readme
from bgap.analysis.paper import PAPER_CRASHES
from bgap.analysis.stats import RULE_FLOOR, STOCK_MARGIN, keeps_up, versus_rule
from bgap.analysis.tables import Yardstick, table2, yardstick_cells
from bgap.analysis.yardsticks import versus_yardsticks
from bgap.common.plotting import pyplot
from bgap.common.runs import write_atomic
from bgap.common.vocab import YARDSTICK_NAMES


# ---------------------------------------------------------------------- figures
def _errorbar(ax, s: pd.DataFrame, metric: str, **kwargs) -> None:
    err = [
        np.clip(s[metric] - s[f"{metric}_lo"], 0, None),
        np.clip(s[f"{metric}_hi"] - s[metric], 0, None),
    ]
    ax.errorbar(s.mix, s[metric], yerr=err, capsize=3, **kwargs)


def fig4(stats: pd.DataFrame, per_seed: pd.DataFrame, path: Path, arm: str = "main") -> None:
    """Collision %, speed and lane changes against the aggressive fraction: the arm's two
    families (mean over seeds, 95% interval, small dots each seed) and the idle and
    rule-based egos on the same episodes."""
    plt = pyplot()
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
                p = per_seed[
                    (per_seed.arm == arm)
                    & (per_seed.family == family)
                    & (per_seed.density == density)
                    & (per_seed.radius == radius)
                    & (per_seed.traffic == "paper")
                ]
                ax.plot(p.mix, p[metric], ".", color=color, alpha=0.35)
            for name, style in (("idle", "--"), ("rule", ":")):
                s = here[here.family == name].sort_values("mix")
                if len(s):
                    ax.plot(s.mix, s[metric], style, color="k", lw=1, label=name)
            ax.set_title(f"n = {n_of(density)}: {label}", fontsize=10)
            ax.set_xlabel("aggressive fraction")
            if r == 0 and c == 0:
                ax.legend(fontsize=8)
    fig.suptitle(f"Fig. 4 (bgap, {arm_name(arm)}): radius {radius:g} m", fontsize=11)
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=120))
    plt.close(fig)


def fig6(stats: pd.DataFrame, path: Path, arm: str = "main") -> None:
    plt = pyplot()
    g = stats[(stats.traffic == "paper") & (stats.arm == arm)]
    densities = [d for d in ("sparse", "dense") if d in set(g.density)]
    fig, axes = plt.subplots(1, len(densities), figsize=(5.5 * len(densities), 3.4), squeeze=False)
    for ax, density in zip(axes[0], densities, strict=True):
        for radius in sorted(set(g.radius), reverse=True):
            s = g[
                (g.family == "behavior_rich") & (g.density == density) & (g.radius == radius)
            ].sort_values("mix")
            _errorbar(ax, s, "collision_pct", fmt="-o", label=f"{radius:g} m")
        ax.set_title(f"n = {n_of(density)}: behaviour-rich collisions", fontsize=10)
        ax.set_xlabel("aggressive fraction")
        ax.set_ylabel("collision %")
        ax.legend(title="perception radius", fontsize=8)
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=120))
    plt.close(fig)


def paper_vs_ours(stats: pd.DataFrame, path: Path, arm: str = "main") -> None:
    """The paper's crash bars (hatched) beside ours (solid, 95% interval) at 0, 50 and 100%
    aggressive, per density and family, with idle's rate on the same episodes."""
    plt = pyplot()
    g = stats[(stats.traffic == "paper")]
    g = g[g.radius == g.radius.max()]
    densities = [d for d in ("sparse", "dense") if d in set(g.density)]
    fig, axes = plt.subplots(1, len(densities), figsize=(6 * len(densities), 3.6), squeeze=False)
    for ax, density in zip(axes[0], densities, strict=True):
        x = np.arange(3)
        for i, (family, color) in enumerate(
            (("default", "tab:gray"), ("behavior_rich", "tab:green"))
        ):
            paper = PAPER_CRASHES[(density, family)]
            ax.bar(
                x + i * 0.4 - 0.3,
                list(paper.values()),
                0.2,
                color=color,
                alpha=0.35,
                hatch="//",
                label=f"{family.replace('_', '-')} (paper)",
            )
            s = g[(g.arm == arm) & (g.family == family) & (g.density == density)]
            s = s.set_index("mix").reindex(list(paper))
            err = [
                np.clip(s.collision_pct - s.collision_pct_lo, 0, None).fillna(0),
                np.clip(s.collision_pct_hi - s.collision_pct, 0, None).fillna(0),
            ]
            ax.bar(
                x + i * 0.4 - 0.1,
                s.collision_pct,
                0.2,
                yerr=err,
                color=color,
                capsize=2,
                label=f"{family.replace('_', '-')} (bgap)",
            )
        idle = g[(g.family == "idle") & (g.density == density)].set_index("mix")
        idle = idle.reindex([0.0, 0.5, 1.0])
        ax.plot(x, idle.collision_pct, "k_", ms=30, mew=2, label="idle (bgap)")
        ax.set_xticks(x, ["0%", "50%", "100%"])
        ax.set_xlabel("aggressive fraction")
        ax.set_ylabel("collisions per 100 episodes")
        ax.set_title(f"n = {n_of(density)}", fontsize=10)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"The paper's bars beside ours ({arm_name(arm)})", fontsize=11)
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=120))
    plt.close(fig)


def ablation(stats: pd.DataFrame, path: Path) -> bool:
    """Behaviour-rich collision % and speed against the test mix, one line per training
    traffic (the mixture of the main arm, one mix per ablation arm); False without arms."""
    g = stats[(stats.traffic == "paper") & (stats.family == "behavior_rich")]
    g = g[g.radius == g.radius.max()]
    arms = [a for a in ("main", "mix0", "mix50", "mix100") if a in set(g.arm)]
    if len(arms) < 2:
        return False
    plt = pyplot()
    densities = [d for d in ("sparse", "dense") if d in set(g.density)]
    fig, axes = plt.subplots(len(densities), 2, figsize=(10, 3.3 * len(densities)), squeeze=False)
    for r, density in enumerate(densities):
        for c, metric in enumerate(("collision_pct", "avg_speed")):
            ax = axes[r, c]
            for arm in arms:
                s = g[(g.arm == arm) & (g.density == density)].sort_values("mix")
                label = (
                    "mixture of the paper's mixes"
                    if arm == "main"
                    else (f"trained at {float(arm[3:]):g}%")
                )
                _errorbar(ax, s, metric, fmt="-o", label=label)
            ax.set_title(f"n = {n_of(density)}: {METRICS[metric]}", fontsize=10)
            ax.set_xlabel("test aggressive fraction")
    axes[0, 0].legend(fontsize=7, title="behaviour-rich training traffic")
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=120))
    plt.close(fig)
    return True


def speed_vs_safety(stats: pd.DataFrame, path: Path) -> bool:
    """Per density (rows) and mix (columns), largest radius: each trained policy's mean
    speed against its collisions per 100 km (95% intervals both ways), the rule-based ego
    (star) and idle (square) on the same episodes; the shaded corner is where a policy beats
    the rule-based ego (fewer collisions per 100 km at >= RULE_FLOOR x its speed)."""
    g = stats[(stats.traffic == "paper") & stats.duplicate_of.isna()] if len(stats) else stats
    if "per_100km" not in g or g.empty:
        return False
    g = g[g.radius == g.radius.max()]
    densities = [d for d in ("sparse", "dense") if d in set(g.density)]
    mixes = sorted(set(g.mix))
    plt = pyplot()
    fig, axes = plt.subplots(
        len(densities), len(mixes), squeeze=False, figsize=(2.6 * len(mixes), 2.6 * len(densities))
    )
    trained = g[g.arm != ""][["arm", "family"]].drop_duplicates()
    # A colour per arm and a marker per policy family: one colour per (arm, family) ran out
    # of matplotlib's ten once the learner arms joined (C7, grey, is idle's)
    palette = [f"C{i}" for i in range(10) if i != 7]
    arm_color = {a: palette[i % len(palette)] for i, a in enumerate(dict.fromkeys(trained.arm))}
    markers = {"behavior_rich": "o", "default": "D"}
    colors = {(a, f): arm_color[a] for a, f in trained.itertuples(index=False)}
    for r, density in enumerate(densities):
        for c, mix in enumerate(mixes):
            ax, here = axes[r, c], g[(g.density == density) & (g.mix == mix)]
            if here.empty:  # a mix that repeats another's traffic at this density
                ax.set_axis_off()
                continue
            rule = here[here.family == "rule"]
            if len(rule):
                x, y = float(rule.per_100km.iloc[0]), float(rule.avg_speed.iloc[0])
                ax.fill_between([0, x], RULE_FLOOR * y, 40, color="tab:green", alpha=0.12)
            for _, s in here.iterrows():
                style = {
                    "rule": dict(marker="*", ms=11, color="k"),
                    "idle": dict(marker="s", ms=6, color="0.5"),
                }.get(s.family)
                if style is None and (s.arm, s.family) not in colors:  # random, left
                    continue
                if style is None:
                    style = dict(
                        marker=markers.get(s.family, "o"), ms=5, color=colors[(s.arm, s.family)]
                    )
                _point(ax, s, "per_100km", capsize=2, lw=0.8, **style)
            ax.set_ylim(max(here.avg_speed_lo.min() - 1, 0), here.avg_speed_hi.max() + 1)
            ax.set_xlim(0, max(here.per_100km_hi.max() * 1.05, 1e-3))
            ax.set_title(f"{density}, mix {mix:g}", fontsize=8)
            ax.tick_params(labelsize=7)
            if r == len(densities) - 1:
                ax.set_xlabel("collisions per 100 km", fontsize=8)
            if c == 0:
                ax.set_ylabel("speed [m/s]", fontsize=8)
    handles = [
        plt.Line2D(
            [],
            [],
            marker=markers.get(family, "o"),
            ls="none",
            color=col,
            label=f"{arm} {family.replace('_', '-')}",
        )
        for (arm, family), col in colors.items()
    ]
    handles += [
        plt.Line2D([], [], marker="*", ms=11, ls="none", color="k", label="rule-based"),
        plt.Line2D([], [], marker="s", ls="none", color="0.5", label="idle"),
    ]
    ncol = min(len(handles), 8)
    fig.legend(handles=handles, loc="lower center", ncol=ncol, fontsize=7)
    rows = -(-len(handles) // ncol)  # the legend's rows, kept clear of the x labels
    fig.tight_layout(rect=(0, (0.02 + 0.035 * rows) * 2 / len(densities), 1, 1))
    write_atomic(path, lambda p: fig.savefig(p, dpi=110))
    plt.close(fig)
    return True


def _point(ax, row: pd.Series, metric: str, capsize: float = 3, **style) -> None:
    """One policy's point, ``metric`` against speed, with both intervals (``<column>_lo``,
    ``<column>_hi``) as error bars."""

    def err(column: str) -> list[list[float]]:
        v = row[column]
        return [[max(v - row[f"{column}_lo"], 0)], [max(row[f"{column}_hi"] - v, 0)]]

    ax.errorbar(
        row[metric],
        row.avg_speed,
        capsize=capsize,
        ls="none",
        xerr=err(metric),
        yerr=err("avg_speed"),
        **style,
    )


def _yardstick_panel(
    ax, table: pd.DataFrame, family: str, metric: str, xlabel: str, title: str, arms: list[str]
) -> None:
    """One panel of :func:`yardstick`: each arm's ``family`` policy, the rule-based ego and
    the other yardsticks in ``table``, ``metric`` against the speed, and the corner where a
    policy meets the rule."""
    rule = table.loc[("", "rule")]
    x_edge = rule[metric] + (STOCK_MARGIN if metric == "collision_pct" else 0.0)
    floor = RULE_FLOOR * rule.avg_speed
    for j, arm in enumerate(arms):
        if (arm, family) not in table.index:
            continue
        p = table.loc[(arm, family)]
        if metric == "per_100km":
            verdict = versus_rule(p[metric], p.avg_speed, rule[metric], rule.avg_speed)
        else:
            ok = keeps_up(p[metric], p.avg_speed, rule[metric], rule.avg_speed)
            verdict = "keeps up" if ok else "falls short"
        _point(ax, p, metric, marker="o", ms=6, color=f"C{j}", label=f"{arm}: {verdict}")
    _point(ax, rule, metric, marker="*", ms=13, color="k", label="rule-based ego")
    for name, marker in (("rule_tuned", "D"), ("idm", "X")):  # the other yardsticks
        if ("", name) in table.index:
            _point(
                ax,
                table.loc[("", name)],
                metric,
                marker=marker,
                ms=8,
                color="0.35",
                label=YARDSTICK_NAMES[name],
            )
    top = max(ax.get_ylim()[1], floor + 1)
    rule_text = (
        f"fewer than it, at >= {RULE_FLOOR:g} x its speed"
        if metric == "per_100km"
        else f"<= {STOCK_MARGIN:g} point above it, at >= {RULE_FLOOR:g} x its speed"
    )
    ax.fill_between(
        [0, x_edge],
        floor,
        top,
        color="tab:green",
        alpha=0.15,
        lw=0,
        label=f"meets the rule: {rule_text}",
    )
    ax.axhline(floor, color="tab:green", lw=0.8, ls="--")
    ax.set_ylim(top=top)
    ax.set_xscale("symlog", linthresh=1.0)
    ax.set_xlim(left=-0.1)  # a point at 0 stays whole
    ax.set_xlabel(xlabel)
    ax.set_ylabel("mean speed [m/s]")
    ax.set_title(title, fontsize=10)
    # below the panel: inside it would hide points
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)


def yardstick(yard: Yardstick, path: Path) -> bool:
    """The two rules against the rule-based ego at a glance, per arm that trains both families
    (:func:`bgap.analysis.tables.yardstick_cells`): left, the behaviour-rich policy's
    collisions per 100 km against its speed pooled over the dense cells (95% intervals across
    training seeds); right, the default policy's collision % against its speed in dense stock
    traffic (:func:`bgap.analysis.episodes.cell_stats`' intervals). The rule-based ego is the
    star (the tuned rule and IDM alone, where evaluated, in grey); the shaded corner is where
    a policy meets the rule. Symmetric-log x axes keep the
    authors' configuration on the page without crowding the learners."""
    dense, stock = yard.dense, yard.stock
    if ("", "rule") not in dense.index:
        return False
    arms = [a for a in yard.arms if (a, "behavior_rich") in dense.index]
    if not arms:
        return False
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 5.4))
    panels = [
        (
            axes[0],
            dense,
            "behavior_rich",
            "per_100km",
            "collisions per 100 km",
            "behaviour-rich, dense traffic (pooled over the cells)",
        )
    ]
    if len(stock) and ("", "rule") in stock.index:
        panels.append(
            (
                axes[1],
                stock,
                "default",
                "collision_pct",
                "episodes with a collision [%]",
                "default, dense stock traffic",
            )
        )
    else:
        axes[1].set_axis_off()
    for ax, table, family, metric, xlabel, title in panels:
        _yardstick_panel(ax, table, family, metric, xlabel, title, arms)
    fig.suptitle("Against the rule-based ego (the two rules; 95% intervals)", fontsize=11)
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=120))
    plt.close(fig)
    return True


# ---------------------------------------------------------------------- the page
def make_figures(
    sources: list[str | Path],
    out: str | Path = "outputs/figures",
    stock: list[str | Path] = (),
) -> dict[str, Path]:
    """The results page, its tables and figures in ``out`` from the evaluations under
    ``sources`` (and ``stock``, read as stock traffic): :func:`load_evaluations`."""
    out = Path(out)
    check_inputs(list(sources), list(stock))  # before anything is written
    df, models = load_evaluations(list(sources), list(stock))
    left_out = mismatched_traffic(df)  # compared with nothing: other traffic than the baselines'
    df = drop_mismatched(df, left_out)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    stats, per_seed = cell_stats(df)
    paths = {name: out / f"{name}.csv" for name in ("cells", "claims", "own_traffic")}
    write_atomic(paths["cells"], lambda p: stats.to_csv(p, index=False))
    table = claims(df)
    write_atomic(paths["claims"], lambda p: table.to_csv(p, index=False))
    own = own_traffic(df)
    write_atomic(paths["own_traffic"], lambda p: own.to_csv(p, index=False))
    grid = df[df.traffic == "paper"]
    headline = {
        f"{arm or 'baseline'}/{density}/{family}": {
            m: round(float(g[m].mean()), 3) for m in METRICS
        }
        for (arm, density, family), g in distinct_cells(grid).groupby(["arm", "density", "family"])
    }
    write_atomic(out / "metrics.json", json.dumps(headline, indent=1, sort_keys=True))
    paths["table2"] = out / "table2.md"
    write_atomic(paths["table2"], table2(stats))
    arms = mixture_arms(stats.arm)
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
    if speed_vs_safety(stats, out / "figures" / "speed_vs_safety.png"):
        paths["speed_vs_safety"] = out / "figures" / "speed_vs_safety.png"
    yard = yardstick_cells(stats, df)
    if yardstick(yard, out / "figures" / "yardstick.png"):
        paths["yardstick"] = out / "figures" / "yardstick.png"
    versus = versus_yardsticks(df)
    paths["yardsticks"] = out / "yardsticks.csv"
    write_atomic(paths["yardsticks"], lambda p: versus.to_csv(p, index=False))
    summary, runs = aggregates(df)
    paths["aggregates"] = out / "aggregates.csv"
    write_atomic(paths["aggregates"], lambda p: summary.to_csv(p, index=False))
    if profiles_figure(runs, out / "figures" / "profiles.png"):
        paths["profiles"] = out / "figures" / "profiles.png"
    paths["readme"] = out / "README.md"
    page = readme(
        df, stats, table, own, [*sources, *stock], models, paths, yard, left_out, versus, summary
    )
    write_atomic(paths["readme"], page)
    return paths

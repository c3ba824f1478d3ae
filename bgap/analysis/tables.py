"""The study's tables as markdown: Table II, the paper beside ours, the claims, the
checkpoints each training selected and the departures from the paper."""

from __future__ import annotations

import json
from typing import NamedTuple

import numpy as np
import pandas as pd

from bgap.analysis.episodes import (
    LEARNER_ARM,
    MIXTURE_ARMS,
    REPLAY,
    arm_algo,
    arm_name,
    distinct_cells,
    is_replay,
    n_of,
    policy_parts,
)
from bgap.analysis.paper import HEADLINE, PAPER_CRASHES, PAPER_SPEED, TABLE_II
from bgap.analysis.stats import PER_KM, keeps_up, per_100km, spread_interval, versus_rule
from bgap.common.vocab import CRASH_KINDS


# ---------------------------------------------------------------------- tables
def _pm(row, metric: str, digits: int) -> str:
    """``row``'s ``metric`` with its interval (``<metric>_lo``, ``_hi``), a cells row or
    tuple: "2.3 [0.0, 6.0]"."""
    value, lo, hi = (getattr(row, f"{metric}{end}") for end in ("", "_lo", "_hi"))
    return f"{value:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def table2(stats: pd.DataFrame) -> str:
    """Table II: the paper's reported rates, then every policy of ours in that cell (n = 5,
    100% aggressive, largest radius), the baselines included."""
    s = stats[(stats.density == "sparse") & (stats.mix == 1.0) & (stats.traffic == "paper")]
    s = s[s.radius == s.radius.max()] if len(s) else s
    lines = [
        "| method (n = 5, 100% aggressive) | collision % [95% CI] | seeds x episodes |",
        "|---|---|---|",
    ]
    lines += [f"| {k} (as reported) | {v:.2f} | - |" for k, v in TABLE_II.items()]
    for r in s.sort_values(["arm", "family"], key=_arm_order).itertuples():
        who = policy_label(r.arm, r.family)
        per = r.n_episodes // r.n_seeds
        lines.append(
            f"| {who} | {r.collision_pct:.2f} [{r.collision_pct_lo:.2f}, "
            f"{r.collision_pct_hi:.2f}] | {r.n_seeds} x {per} |"
        )
    return "\n".join(lines) + "\n"


def _arm_order(column: pd.Series) -> pd.Series:
    """Sort key of an ``arm`` column: the paper's arms, the learners' arms, the baselines."""
    if column.name != "arm":
        return column
    order = {a: i for i, a in enumerate(["main", "authors", "mix0", "mix50", "mix100"])}
    order[""] = 98  # the baselines

    def key(arm: str) -> int:
        return order.get(arm, 50 if str(arm).startswith(LEARNER_ARM) else 99)

    return column.map(key)


def policy_label(arm: str, family: str) -> str:
    """How a policy is named in the page's tables: "bgap <family> <algorithm>, <arm>"."""
    if not arm:
        return f"{family} (baseline)"
    return f"bgap {family.replace('_', '-')} {arm_algo(arm)}, {arm_name(arm)}"


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
            s = g[
                (g.arm == arm)
                & (g.family == family)
                & (g.density == density)
                & (g.mix == mix)
                & (g.radius == r)
            ]
            idle = g[
                (g.family == "idle") & (g.density == density) & (g.mix == mix) & (g.radius == r)
            ]
            if s.empty:
                continue
            x = s.iloc[0]
            speed = PAPER_SPEED.get((density, family), {}).get(mix)
            lines.append(
                f"| {n_of(density)} | {family} | {mix:.0%} | {value} | "
                f"{_pm(x, 'collision_pct', 1)} | "
                f"{idle.iloc[0].collision_pct:.1f} | {'-' if speed is None else speed} | "
                f"{x.avg_speed:.2f} |"
            )
    return "\n".join(lines) + "\n"


def claims_markdown(table: pd.DataFrame) -> str:
    """The claims table, confirmatory family first, then each exploratory one."""
    lines = [
        "| family | arm | n | claim (paper figure) | paper | ours: a - b [95% CI] | "
        "Holm-corrected interval | p (Holm) | seeds a / b | episodes a / b | verdict | reading |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    order = table.family.ne("confirmatory")
    for r in table.assign(_o=order).sort_values("_o", kind="stable").itertuples():
        lines.append(
            f"| {r.family} | {r.arm} | {r.n} | {r.claim} ({r.figure}) | {r.paper} | "
            f"{r.difference:+.2f} [{r.lo:+.2f}, {r.hi:+.2f}] | [{r.lo_holm:+.2f}, "
            f"{r.hi_holm:+.2f}] | {_p(r.p_holm)} | {r.n_seeds_a} / {r.n_seeds_b} | "
            f"{r.n_episodes_a} / {r.n_episodes_b} | **{r.verdict}** | {r.reading} |"
        )
    return "\n".join(lines) + "\n"


def _p(p: float) -> str:
    """An analytic p-value, printed to two significant digits."""
    return "< 1e-4" if p < 1e-4 else f"{p:.2g}"


def own_markdown(own: pd.DataFrame) -> str:
    lines = [
        "| arm | policy | n | own traffic | collision % [95% CI] | crashes: rear-end / "
        "rear-ended / lane change | speed m/s | idle % (rear-end / rear-ended / lane change) | "
        "idle m/s | seeds | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in own.sort_values(["arm", "family"], key=_arm_order).itertuples():
        verdict = "beats idle" if r.beats_idle else "**does not beat idle**"
        split, idle_split = (
            " / ".join(
                f"{getattr(r, f'{who}{k}_pct', float('nan')):.1f}"
                for k in ("rear_end", "rear_ended", "lane_change")
            )
            for who in ("", "idle_")
        )
        lines.append(
            f"| {r.arm} | {r.family} | {r.n} | {r.own_traffic} | {r.collision_pct:.1f} "
            f"[{r.collision_lo:.1f}, {r.collision_hi:.1f}] | {split} | {r.avg_speed:.2f} | "
            f"{r.idle_collision_pct:.1f} ({idle_split}) | {r.idle_avg_speed:.2f} | "
            f"{r.n_seeds} | {verdict} |"
        )
    return "\n".join(lines) + "\n"


def _arms(models: pd.DataFrame) -> pd.Series:
    return policy_parts(models.policy)["arm"]


def selection_markdown(models: pd.DataFrame) -> str:
    """Where the trainings' kept checkpoints come from (the evaluations' ``models.csv``: each
    run folder's ``best.json`` and last validation)."""
    if "chosen_episodes" not in models:
        return "(no models table: the evaluations wrote no models.csv)\n"
    t = models.dropna(subset=["chosen_episodes"]).assign(arm=_arms)
    if not len(t):
        return "(no training validated periodically: the last parameters are evaluated)\n"
    lines = [
        "| arm | trainings | chosen at episode (median, range) | validation collision % "
        "chosen / last (means) |",
        "|---|---|---|---|",
    ]
    for arm, g in t.groupby("arm"):
        chosen = g.chosen_episodes.astype(int)
        collisions = f"{g.chosen_collision_pct.mean():.1f} / {g.last_collision_pct.mean():.1f}"
        of = int(g.validated_episodes.max())
        lines.append(
            f"| {arm} | {len(g)} | {chosen.median():.0f} ({chosen.min()}-"
            f"{chosen.max()} of {of}) | {collisions} |"
        )
    return "\n".join(lines) + "\n"


def departures_markdown(models: pd.DataFrame) -> str:
    """The settings in which the main arm (the recipe) departs from the authors' arm (their
    2020 configuration under the paper's protocol), from the trainings' saved settings."""
    configs = {}
    if "settings" in models:
        found = models.dropna(subset=["settings"]).assign(arm=_arms).sort_values("policy")
        for arm in MIXTURE_ARMS:
            rows = found[found.arm == arm]
            if len(rows):
                configs[arm] = json.loads(rows.settings.iloc[0])
    if len(configs) < 2:
        return "(needs the models tables of both arms)\n"
    lines = [
        "| setting | authors' arm (their 2020 configuration) | main arm (recipe) |",
        "|---|---|---|",
    ]
    for group in ("reward", "agent", "profile"):
        a, b = configs["authors"][group], configs["main"][group]
        for key in sorted(set(a) | set(b)):
            if key != "name" and a.get(key) != b.get(key):
                shown = [
                    f"{v:.4g}" if isinstance(v, float) else str(v) for v in (a.get(key), b.get(key))
                ]
                lines.append(f"| {group}.{key} | {shown[0]} | {shown[1]} |")
    lines.append(
        "\nThe recipe's settings come from `bgap.recipe` (results/recipe/, validation episodes "
        "only); the authors' from their code (FACTS.md). `agent.gradient_steps` -1 is one "
        "update per transition; 1 is one per vector step of 2 environments."
    )
    return "\n".join(lines) + "\n"


SYMBOLS = {
    "beats": "**beats**",
    "beaten": "beaten",
    "safer, slower": "safer, slower",
    "faster, less safe": "faster, less safe",
}


def rule_markdown(stats: pd.DataFrame) -> str:
    """Every policy against the rule-based ego in each cell of the paper's traffic (largest
    radius, cells that repeat another's traffic left out): collisions per 100 km at mean
    speed, and the verdict of :func:`bgap.analysis.stats.versus_rule`; the last column pools
    the cells (the mean of their rates and speeds) and judges the pool the same way."""
    if "per_100km" not in stats:
        return "(the evaluations hold no distance travelled: evaluate again)\n"
    g = _rule_cells(stats)
    parts = []
    for density in [d for d in ("sparse", "dense") if d in set(g.density)]:
        here = g[g.density == density]
        mixes = sorted(set(here.mix))
        rule = here[here.family == "rule"].set_index("mix")
        if rule.empty:
            continue
        pooled_rule = (rule.per_100km.mean(), rule.avg_speed.mean())
        head = " | ".join(f"mix {m:g}" for m in mixes)
        lines = [
            f"**{density} (n = {n_of(density)})**: collisions per 100 km at m/s; verdict "
            "against the rule-based ego in the same cell\n",
            f"| policy | {head} | pooled |",
            "|---|" + "---|" * (len(mixes) + 1),
        ]
        for (arm, family), p in here.groupby(["arm", "family"], sort=False):
            p = p.set_index("mix")
            cells = []
            for m in mixes:
                if m not in p.index:
                    cells.append("-")
                    continue
                r, b = p.loc[m], rule.loc[m]
                text = f"{r.per_100km:.1f} at {r.avg_speed:.2f}"
                if family != "rule":
                    text += (
                        ", "
                        + SYMBOLS[versus_rule(r.per_100km, r.avg_speed, b.per_100km, b.avg_speed)]
                    )
                cells.append(text)
            pooled = (p.per_100km.mean(), p.avg_speed.mean())
            pooled_text = f"{pooled[0]:.1f} at {pooled[1]:.2f}"
            if family != "rule" and len(p) == len(mixes):
                pooled_text += ", " + SYMBOLS[versus_rule(*pooled, *pooled_rule)]
            lines.append(
                f"| {policy_label(arm, family)} | " + " | ".join(cells) + f" | {pooled_text} |"
            )
        order = sorted(lines[3:], key=lambda line: ("(baseline)" in line, line))
        parts.append("\n".join(lines[:3] + order) + "\n")
    return "\n".join(parts) if parts else "(no rule-based ego in the evaluations)\n"


def _rule_cells(stats: pd.DataFrame) -> pd.DataFrame:
    """The cells policies are read against the rule-based ego in: the paper's traffic at
    its largest radius, cells that repeat another's traffic left out."""
    g = stats[(stats.traffic == "paper") & stats.duplicate_of.isna()]
    return g[g.radius == g.radius.max()] if len(g) else g


def pooled_intervals(df: pd.DataFrame, density: str, draws: int = 4000) -> pd.DataFrame:
    """Per (arm, family) of the episodes ``df``: the mean over the rule cells of one density
    (:func:`_rule_cells`) of collisions per 100 km and of mean speed, :func:`rule_markdown`'s
    pooled column, with their 95% intervals and ``n_seeds``. Training seeds are the units:
    each seed's pooled value is the mean over the cells of its crashes over its kilometres
    (and of its speed), the interval Student t across seeds; a one-seed policy (the
    rule-based ego, idle) resamples its episodes within each cell. Collisions' interval is
    widened to the Poisson interval of all the episodes' crashes over their kilometres, so it
    never has zero width (as :func:`bgap.analysis.episodes.cell_stats`). Empty where the
    episodes lack ``distance``."""
    cols = [
        "per_100km",
        "per_100km_lo",
        "per_100km_hi",
        "avg_speed",
        "avg_speed_lo",
        "avg_speed_hi",
        "n_seeds",
    ]
    g = df[df.traffic == "paper"] if "traffic" in df else df
    if "distance" not in g or g.empty:
        return pd.DataFrame(columns=["arm", "family", *cols]).set_index(["arm", "family"])
    g = distinct_cells(g)
    g = g[(g.radius == g.radius.max()) & (g.density == density)]
    rng = np.random.default_rng(0)
    rows = {}
    for key, pol in g.groupby(["arm", "family"], sort=True):
        cells = pol.groupby(["train_seed", "mix"])
        per_cell = pd.DataFrame(
            {
                "rate": cells.crashed.sum() / cells.distance.sum() * PER_KM,
                "speed": cells.avg_speed.mean(),
            }
        )
        seeds = per_cell.groupby(level="train_seed").mean()
        if len(seeds) > 1:
            (r_lo, r_hi), (s_lo, s_hi) = spread_interval(seeds.rate), spread_interval(seeds.speed)
        else:  # one run: its episodes resampled within each cell
            rate_draws, speed_draws = np.zeros(draws), np.zeros(draws)
            for _, cell in pol.groupby("mix"):
                c, d, v = (cell[k].to_numpy(float) for k in ("crashed", "distance", "avg_speed"))
                idx = rng.integers(len(c), size=(draws, len(c)))
                rate_draws += c[idx].sum(axis=1) / d[idx].sum(axis=1) * PER_KM
                speed_draws += v[idx].mean(axis=1)
            n = pol.mix.nunique()
            r_lo, r_hi = np.percentile(rate_draws / n, [2.5, 97.5])
            s_lo, s_hi = np.percentile(speed_draws / n, [2.5, 97.5])
            if s_hi <= s_lo:  # no spread: the precision speeds are stored in (spread_interval)
                s_lo, s_hi = spread_interval(np.full(2, s_lo))
        _, p_lo, p_hi = per_100km(pol.crashed.to_numpy(float), pol.distance.to_numpy(float))
        rows[key] = [
            seeds.rate.mean(),
            max(min(r_lo, p_lo), 0.0),
            max(r_hi, p_hi),
            seeds.speed.mean(),
            max(s_lo, 0.0),
            s_hi,
            len(seeds),
        ]
    out = pd.DataFrame.from_dict(rows, orient="index", columns=cols)
    out.index = pd.MultiIndex.from_tuples(out.index, names=["arm", "family"])
    return out


def _beside_rule(table: pd.DataFrame, arm: str, family: str):
    """(the policy's row, the rule-based ego's row) of ``table`` (indexed by arm and
    family), or None where either is missing."""
    if (arm, family) in table.index and ("", "rule") in table.index:
        return table.loc[(arm, family)], table.loc[("", "rule")]
    return None


class Yardstick(NamedTuple):
    """What the two rules are read on, by the results page's table and
    ``figures/yardstick.png`` (:func:`yardstick_cells`)."""

    arms: list[str]
    """Arms that train both families: the mixture arms, then the learner arms."""
    dense: pd.DataFrame
    """:func:`pooled_intervals` of the dense cells."""
    sparse: pd.DataFrame
    """:func:`pooled_intervals` of the sparse cells."""
    stock: pd.DataFrame
    """Cells of dense stock traffic at the largest radius, indexed by (arm, family)."""


def yardstick_cells(stats: pd.DataFrame, df: pd.DataFrame) -> Yardstick:
    """:class:`Yardstick` of the cells ``stats`` and their episodes ``df``, computed once
    for the table and the figure."""
    present = set(stats.arm) if len(stats) else set()
    arms = [a for a in MIXTURE_ARMS if a in present]
    arms += sorted(a for a in present if str(a).startswith(LEARNER_ARM))
    stock = stats[(stats.traffic == "stock") & (stats.density == "dense")] if len(stats) else stats
    if len(stock):
        stock = stock[stock.radius == stock.radius.max()].set_index(["arm", "family"])
    return Yardstick(arms, pooled_intervals(df, "dense"), pooled_intervals(df, "sparse"), stock)


def yardstick_markdown(stats: pd.DataFrame, claims: pd.DataFrame, yard: Yardstick) -> str:
    """The two rules, read per arm that trains both families on the mixture
    (:func:`yardstick_cells`): does its behaviour-rich policy beat the rule-based ego in the
    paper's dense traffic (pooled over the cells, :func:`pooled_intervals`: fewer collisions
    per 100 km at 0.95 x its speed, :func:`bgap.analysis.stats.versus_rule`), and does its
    default policy keep up with it in stock traffic (collision % at most 1 point above its, at
    0.95 x its speed, :func:`bgap.analysis.stats.keeps_up`)? Beside them, the sparse cells
    judged the same way (reported, not a rule) and the arm's verdict on the paper's headline
    claim, so the claim can be read with a learner that drives as well as the hand-built
    driver. Point estimates decide; 95% intervals across training seeds in brackets."""
    if "per_100km" not in stats or stats.empty:
        return "(the evaluations hold no distance travelled: evaluate again)\n"
    arms, dense, sparse, stock = yard
    headline = claims[claims.claim == HEADLINE]
    lines = [
        "| arm | behaviour-rich, dense (pooled): per 100 km at m/s | rule-based ego | beats "
        "it? | default, stock traffic (dense): collision % at m/s | rule-based ego | keeps "
        "up? | behaviour-rich, sparse (pooled, reported) | headline claim (n = 40 / n = 5) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for arm in arms:
        cells = ["-", "-", "-"]
        if pair := _beside_rule(dense, arm, "behavior_rich"):
            p, r = pair
            verdict = versus_rule(p.per_100km, p.avg_speed, r.per_100km, r.avg_speed)
            cells = [
                f"{_pm(p, 'per_100km', 1)} at {_pm(p, 'avg_speed', 2)}",
                f"{_pm(r, 'per_100km', 1)} at {_pm(r, 'avg_speed', 2)}",
                "**yes**" if verdict == "beats" else f"no ({verdict})",
            ]
        if pair := _beside_rule(stock, arm, "default"):
            p, r = pair
            keeps = keeps_up(p.collision_pct, p.avg_speed, r.collision_pct, r.avg_speed)
            cells += [
                f"{_pm(p, 'collision_pct', 1)} at {_pm(p, 'avg_speed', 2)}",
                f"{_pm(r, 'collision_pct', 1)} at {_pm(r, 'avg_speed', 2)}",
                "**yes**" if keeps else "no",
            ]
        else:
            cells += ["-", "-", "-"]
        if pair := _beside_rule(sparse, arm, "behavior_rich"):
            p, r = pair
            verdict = versus_rule(p.per_100km, p.avg_speed, r.per_100km, r.avg_speed)
            cells.append(f"{_pm(p, 'per_100km', 1)} at {p.avg_speed:.2f} ({verdict})")
        else:
            cells.append("-")
        verdicts = headline[headline.arm == arm].sort_values("n", ascending=False).verdict
        cells.append(" / ".join(verdicts) if len(verdicts) else "-")
        lines.append(f"| {arm_name(arm)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def replay_markdown(stats: pd.DataFrame) -> str:
    """Every policy in replayed (observed) traffic, one table per density: per replayed table
    and mode, collision % and collisions per 100 km with their intervals, mean speed, the
    split of the crashes by kind, and the verdict against the rule-based ego on the same
    windows."""
    g = stats[is_replay(stats.traffic)] if len(stats) else stats
    if g.empty:
        return "(no replay cells in the evaluations)\n"
    kinds = [k for k in CRASH_KINDS if f"{k}_pct" in g]
    parts = []
    for density in [d for d in ("sparse", "dense") if d in set(g.density)]:
        here = g[g.density == density].sort_values(["traffic", "arm", "family"], key=_arm_order)
        lines = [
            f"**{density} (the {n_of(density)}-vehicle observation)**\n",
            "| replayed table / mode | aggressive share | policy | collision % [95% CI] | "
            "per 100 km [95% CI] | m/s | crashes %: " + " / ".join(kinds) + " | against "
            "the rule-based ego |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for traffic, t in here.groupby("traffic", sort=False):
            rule = t[t.family == "rule"]
            for r in t.itertuples():
                verdict = "-"
                if r.family != "rule" and len(rule):
                    b = rule.iloc[0]
                    verdict = SYMBOLS[
                        versus_rule(r.per_100km, r.avg_speed, b.per_100km, b.avg_speed)
                    ]
                split = " / ".join(f"{getattr(r, f'{k}_pct'):.0f}" for k in kinds)
                lines.append(
                    f"| {traffic[len(REPLAY) :]} | {r.mix:.2f} | {policy_label(r.arm, r.family)} | "
                    f"{_pm(r, 'collision_pct', 1)} | {_pm(r, 'per_100km', 1)} | "
                    f"{r.avg_speed:.2f} | {split} | {verdict} |"
                )
        parts.append("\n".join(lines) + "\n")
    return "\n".join(parts)

"""What the recipe's check writes for a reader: the candidates' ``table.md`` (both modes),
the levers' ``levers.md``, and the chosen candidate's validation curves
(``learning_curves.png``)."""

from __future__ import annotations

from pathlib import Path

import optuna
import pandas as pd

from bgap.common.plotting import pyplot
from bgap.common.runs import write_atomic
from bgap.experiments.config import RecipeConfig


def markdown(cfg: RecipeConfig, summary: pd.DataFrame, params: dict[str, dict]) -> str:
    lines = [
        f"# Recipe check: the {len(summary)} best sweep trials, {len(cfg.check_seeds)} training "
        f"seeds each, {cfg.check_episodes} validation episodes per seed",
        "",
        f"Traffic: {cfg.env.name}, mix sampling {cfg.mix_sampling}. Rule: fewest collisions "
        f"among candidates whose mean speed is at least {cfg.speed_floor:g} x idle's. "
        "Intervals: 95% t across training seeds.",
        "",
        "| trial | collisions % [95% CI] | crashes %: rear-end / rear-ended / lane change "
        "| speed m/s [95% CI] | idle % / m/s | rule % / m/s | lane changes | settings |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in summary.itertuples():
        settings = ", ".join(f"{k}={v:.4g}" for k, v in params[r.trial].items())
        lines.append(
            f"| {r.trial}{' (chosen)' if r.Index == 0 else ''} | {r.collision_pct:.1f} "
            f"[{r.collision_pct_lo:.1f}, {r.collision_pct_hi:.1f}] | {r.rear_end_pct:.1f} / "
            f"{r.rear_ended_pct:.1f} / {r.lane_change_pct:.1f} | {r.avg_speed:.2f} "
            f"[{r.avg_speed_lo:.2f}, {r.avg_speed_hi:.2f}] | {r.idle_collision_pct:.1f} / "
            f"{r.idle_avg_speed:.2f} | {r.rule_collision_pct:.1f} / {r.rule_avg_speed:.2f} "
            f"| {r.lane_changes:.1f} | {settings} |"
        )
    if "stock_collision_pct" in summary:
        lines += [
            "",
            "The default policy (the same recipe, trained in highway-env's stock traffic), on "
            f"stock validation episodes; rule: under {cfg.stock_max_collision_pct:g}% "
            f"collisions at {cfg.speed_floor:g} x idle's speed or more. Candidates that miss "
            "it rank after those that meet it.",
            "",
            "| trial | collisions % | speed m/s | idle % / m/s | meets the rule |",
            "|---|---|---|---|---|",
            *(
                f"| {r.trial} | {r.stock_collision_pct:.1f} | {r.stock_avg_speed:.2f} | "
                f"{r.stock_idle_collision_pct:.1f} / {r.stock_idle_avg_speed:.2f} | "
                f"{'yes' if r.stock_rule else '**no**'} |"
                for r in summary.itertuples()
            ),
        ]
    return "\n".join(lines) + "\n"


def markdown_by_rule(cfg: RecipeConfig, summary: pd.DataFrame, params: dict) -> str:
    lines = [
        f"# Recipe check: the {len(summary)} best sweep trials, {len(cfg.check_seeds)} training "
        f"seeds each, {cfg.check_episodes} validation episodes per seed and policy",
        "",
        f"Learner: {cfg.agent.algo} (agent={cfg.agent.name}). Traffic: {cfg.env.name}, mix "
        f"sampling {cfg.mix_sampling} for the behaviour-rich policy; highway-env's stock "
        "traffic for the default policy. Objective (fixed before the search): each "
        f"policy at {cfg.rule_floor:g} x the rule-based ego's speed or more, then the worse of "
        "the behaviour-rich policy's collisions per 100 km minus the rule-based ego's and the "
        "default policy's collision % minus the rule-based ego's minus "
        f"{cfg.stock_margin:g}; below 0 both rules are met. Intervals: 95% t across seeds.",
        "",
        "| trial | behaviour-rich per 100 km [95% CI] | speed m/s [95% CI] | rule per 100 km / "
        "m/s | default in stock % [95% CI] | speed m/s | rule in stock % / m/s | objective "
        "| settings |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in summary.itertuples():
        settings = ", ".join(
            f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
            for k, v in params[r.trial].items()
        )
        lines.append(
            f"| {r.trial}{' (chosen)' if r.Index == 0 else ''} | {r.per_100km:.2f} "
            f"[{r.per_100km_lo:.2f}, {r.per_100km_hi:.2f}] | {r.avg_speed:.2f} "
            f"[{r.avg_speed_lo:.2f}, {r.avg_speed_hi:.2f}] | {r.rule_per_100km:.2f} / "
            f"{r.rule_avg_speed:.2f} | {r.stock_collision_pct:.1f} "
            f"[{r.stock_collision_pct_lo:.1f}, {r.stock_collision_pct_hi:.1f}] | "
            f"{r.stock_avg_speed:.2f} | "
            f"{r.stock_rule_collision_pct:.1f} / {r.stock_rule_avg_speed:.2f} | "
            f"{r.objective:.2f} | {settings} |"
        )
    return "\n".join(lines) + "\n"


def markdown_levers(
    cfg: RecipeConfig, chosen: pd.Series, levers: pd.DataFrame, kept: list[str]
) -> str:
    trial = int(chosen.trial)  # a row of numbers only: pandas reads the number as a float
    lines = [
        f"# Levers of the chosen recipe (trial {trial}), one switched at a time",
        "",
        f"Each row trains the chosen recipe with one setting changed, on the check's "
        f"{len(cfg.check_seeds)} training seeds x {cfg.check_episodes} validation episodes per "
        "seed and policy, scored by the search's objective (below 0: both rules "
        "are met). The change in objective is the row's minus the recipe's: positive, the "
        "lever as the recipe has it helps. Intervals: 95% t across seeds.",
        "",
        "| setting | behaviour-rich per 100 km [95% CI] | speed m/s | default in stock % "
        "[95% CI] | speed m/s | objective | change |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, r in [(f"the recipe (trial {trial})", chosen)] + [
        (f"`{r.trial}`", r) for _, r in levers.iterrows()
    ]:
        lines.append(
            f"| {label} | {r.per_100km:.2f} [{r.per_100km_lo:.2f}, {r.per_100km_hi:.2f}] | "
            f"{r.avg_speed:.2f} | {r.stock_collision_pct:.1f} [{r.stock_collision_pct_lo:.1f}, "
            f"{r.stock_collision_pct_hi:.1f}] | {r.stock_avg_speed:.2f} | {r.objective:.2f} | "
            f"{r.objective - chosen.objective:+.2f} |"
        )
    if kept:
        lines += [
            "",
            "Left out (the recipe already has them): " + ", ".join(f"`{k}`" for k in kept),
        ]
    if not cfg.levers:
        lines += ["", "No lever was asked for (`levers=[]`): the recipe's row alone."]
    return "\n".join(lines) + "\n"


def curves(run_dirs: list[str], study: optuna.Study | None = None) -> dict[str, pd.DataFrame]:
    """Each training's validation curve by its run folder's name: its ``evaluations.csv``,
    or where the folder is gone, the curve its check row kept in ``study``
    (:func:`kept_row`); trainings with neither are left out."""
    kept = {}
    if study is not None:
        kept = {
            Path(dict(attr["row"])["run_dir"]).name: attr["curve"]
            for key, attr in study.user_attrs.items()
            if key.startswith("check-") and attr.get("curve")
        }
    found = {}
    for run_dir in run_dirs:
        name, evaluations = Path(run_dir).name, Path(run_dir) / "evaluations.csv"
        if evaluations.exists():
            found[name] = pd.read_csv(evaluations)
        elif name in kept:
            found[name] = pd.DataFrame(kept[name])
    return found


NO_VALIDATION = "no periodic validation in these trainings\n(profile.eval_every_episodes=0)"
"""The learning curves' text where the trainings kept no validation curve."""


def plot_curves(
    found: dict[str, pd.DataFrame], path: Path, title: str, why_none: str = NO_VALIDATION
) -> None:
    """Validation collision % and speed against gradient updates, one line per seed
    (:func:`curves`); without any, ``why_none`` in their place."""
    plt = pyplot()

    if not found:  # no curve to draw: say why in the figure itself
        fig, ax = plt.subplots(figsize=(6, 1.5))
        ax.text(0.5, 0.5, why_none, ha="center", va="center")
        ax.set_axis_off()
        write_atomic(path, lambda p: fig.savefig(p, dpi=110))
        plt.close(fig)
        return

    from matplotlib.ticker import FuncFormatter  # loaded by pyplot() above

    thousands = FuncFormatter(lambda v, _: f"{v / 1000:g}k")
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
    for name, ev in found.items():
        label = name.rsplit("-", 1)[-1]
        for ax, key in zip(axes, ("collision_pct", "avg_speed"), strict=True):
            ax.plot(ev.gradient_updates, ev[key].rolling(5, min_periods=1).mean(), label=label)
    first = next(iter(found.values()))
    for ax, key, label in zip(
        axes,
        ("collision_pct", "avg_speed"),
        ("collisions [% episodes]", "mean speed [m/s]"),
        strict=True,
    ):
        for name, style in (("idle", "--"), ("rule", ":")):
            ax.axhline(first[f"{name}_{key}"].iloc[-1], ls=style, color="gray", label=name)
        ax.set_xlabel("gradient updates")
        ax.xaxis.set_major_formatter(thousands)
        ax.set_ylabel(f"validation {label}\n(running mean of 5 evaluations)")
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=110))
    plt.close(fig)

"""The main job: ``python -m bgap.run env=dense mix=0.6 [profile=paper]``.

Trains (or reuses, when a finished run with the same config exists under ``root``) the
behaviour-rich policy and the default policy for the chosen density, evaluates both with
the scripted baselines on identical seeded episodes at the chosen mix and radius (or the
``grid``), prints a comparison table like the paper's bars and writes, under
``<root>/results/<name>/``: ``summary.csv`` / ``.json``, ``episodes.parquet``,
``comparison.png``, ``config.yaml`` and ``command.txt``.
"""

from __future__ import annotations

import time
from dataclasses import asdict, replace
from pathlib import Path

import pandas as pd
from omegaconf import DictConfig

from bgap.analysis.episodes import cell_stats, parse_policies
from bgap.analysis.stats import RULE_FLOOR, beats_idle, versus_rule
from bgap.common.runs import (
    VOLATILE,
    digest,
    model_file,
    save_run_metadata,
    write_atomic,
)
from bgap.common.vocab import POLICIES, YARDSTICK_NAMES, YARDSTICKS
from bgap.experiments.compat import as_before, upgrade
from bgap.experiments.config import ExperimentConfig
from bgap.experiments.evaluate import evaluate
from bgap.experiments.evaluate_results import (
    compact,
    crash_split,
    format_table,
    plot_comparison,
    summarize,
    write_results,
)
from bgap.experiments.train import trainings
from bgap.experiments.training import run_dir_for, training_config


def results_dir(cfg: ExperimentConfig) -> Path:
    """``out``, or a folder under ``<root>/results`` named by the main settings and a hash of
    all of them (reward, behaviour, backend, budget, ...), so runs of other settings never
    share a folder."""
    if cfg.out:
        return Path(cfg.out)
    settings = as_before({k: v for k, v in asdict(cfg).items() if k not in VOLATILE})
    name = (
        f"{cfg.env.name}-mix{cfg.mix:g}-r{cfg.radius:g}-{cfg.grid.name}-{cfg.profile.name}"
        f"-s{cfg.seed}-{digest(settings)}"
    )
    return Path(cfg.root) / "results" / name


def run(cfg: ExperimentConfig, dcfg: DictConfig | None = None) -> Path:
    start = time.perf_counter()
    seeds = cfg.seeds or [cfg.seed]
    pairs = [(seed, policy) for seed in seeds for policy in POLICIES]
    configs = [training_config(replace(cfg, seed=s, resume=True), p) for s, p in pairs]
    for (seed, policy), c in zip(pairs, configs, strict=True):
        d = run_dir_for(c)
        print(f"[{policy} s{seed}] {'reusing' if (d / 'model.zip').exists() else 'training'} {d}")
    # resume=true: a training this command started and was interrupted continues. Parallel
    # jobs of a multirun can need the same model (the default policy of a density): one
    # trains it, the others wait for it and reuse it.
    dirs = trainings(configs, wait=True)
    models = {}
    for (seed, policy), d in zip(pairs, dirs, strict=True):
        # One seed: the family's name; several: the pipeline's <density>-<family>-s<seed>.
        name = policy if len(seeds) == 1 else f"{cfg.env.name}-{policy}-s{seed}"
        models[name] = str(model_file(d, cfg.checkpoint))
    out = results_dir(cfg)
    if dcfg is not None:
        save_run_metadata(out, dcfg, upgrade=upgrade)
    policies = {**models, **{b: b for b in cfg.baselines}}
    episodes = compact(evaluate(cfg, policies))  # what is stored is what is summarised
    summary = summarize(episodes)
    write_results(out, episodes, summary)
    title = f"{cfg.env.name}, behaviour {cfg.behavior.name}, {cfg.profile.name} profile"
    plot_comparison(summary, out / "comparison.png", title)
    print(format_table(summary))
    compared = summary  # what the idle flags read: the seed-level table with several seeds
    if len(seeds) > 1:
        compared = across = seed_summary(episodes)
        write_atomic(out / "seeds.csv", lambda p: across.to_csv(p, index=False))
        plot_comparison(across, out / "comparison_seeds.png", f"{title}, {len(seeds)} seeds")
        print(f"\nacross {len(seeds)} training seeds (mean and 95% interval over seeds):")
        print(format_table(across))
    for line in [*idle_flags(compared, cfg), *rule_verdicts(compared)]:
        print(line)
    print(f"results in {out} ({time.perf_counter() - start:.0f} s)")
    return out


def seed_summary(episodes):
    """Per policy family and cell, the mean over training seeds of each figure and its 95%
    interval across seeds (:func:`bgap.analysis.episodes.cell_stats`), in :func:`summarize`'s
    columns."""
    parsed = parse_policies(episodes)
    stats, _ = cell_stats(parsed)
    renamed = stats.rename(
        columns={
            "family": "policy",
            "collision_pct_lo": "collision_lo",
            "collision_pct_hi": "collision_hi",
            "avg_speed_lo": "speed_lo",
            "avg_speed_hi": "speed_hi",
        }
    )
    keys = list(zip(stats.family, stats.density, stats.mix, stats.radius, strict=True))
    pooled = parsed.groupby(["family", "density", "mix", "radius"])
    renamed["episodes"] = pooled.size().reindex(keys).to_numpy()  # all seeds' episodes
    split = pooled.apply(lambda g: pd.Series(crash_split(g))).reindex(keys)
    for column in split:
        renamed[column] = split[column].to_numpy()
    return renamed


def idle_flags(summary, cfg: ExperimentConfig) -> list[str]:
    """A line per trained policy evaluated in its own training traffic that does not beat
    idle there (fewer collisions at a mean speed of at least 90% of idle's): such a policy is
    flagged, never silently compared."""
    lines = []
    idle = summary[summary.policy == "idle"].set_index(["mix", "density", "radius"])
    for r in summary[summary.policy.str.contains("|".join(POLICIES))].itertuples():
        own = ("default" in r.policy and cfg.behavior.name == "stock") or (
            "behavior_rich" in r.policy and cfg.mix_sampling == "fixed" and r.mix == cfg.mix
        )
        key = (r.mix, r.density, r.radius)
        if not own or key not in idle.index:
            continue
        i = idle.loc[key]
        beats = beats_idle(r.collision_pct, r.avg_speed, i.collision_pct, i.avg_speed)
        verdict = "beats idle" if beats else "does not beat idle (read its comparisons with care)"
        lines.append(
            f"{r.policy} in its own traffic (mix {r.mix:g}): {r.collision_pct:.1f}% collisions, "
            f"{r.avg_speed:.2f} m/s; idle {i.collision_pct:.1f}%, {i.avg_speed:.2f} m/s: {verdict}"
        )
    return lines


def rule_verdicts(summary) -> list[str]:
    """A line per trained policy, cell and hand-built driver (the rule-based ego with
    highway-env's and with tuned parameters, IDM in its lane: those evaluated) read on the
    same episodes: collisions per 100 km and speed, and whether the policy beats it, is
    beaten by it, or trades speed for safety either way
    (:func:`bgap.analysis.stats.versus_rule`)."""
    if "per_100km" not in summary:
        return []
    lines = []
    for name in [y for y in YARDSTICKS if y in set(summary.policy)]:
        yard = summary[summary.policy == name].set_index(["mix", "density", "radius"])
        for r in summary[summary.policy.str.contains("|".join(POLICIES))].itertuples():
            key = (r.mix, r.density, r.radius)
            if key not in yard.index:
                continue
            b = yard.loc[key]
            verdict = versus_rule(r.per_100km, r.avg_speed, b.per_100km, b.avg_speed)
            lines.append(
                f"{r.policy} against {YARDSTICK_NAMES[name]} (mix {r.mix:g}, radius "
                f"{r.radius:g}): {r.per_100km:.1f} collisions per 100 km at {r.avg_speed:.2f} "
                f"m/s; {name} {b.per_100km:.1f} at {b.avg_speed:.2f} m/s: {VERDICTS[verdict]}"
            )
    return lines


VERDICTS = {
    "beats": f"beats it (safer per km at >= {RULE_FLOOR:g} x its speed)",
    "beaten": "beaten by it (no safer per km, no faster)",
    "safer, slower": f"safer per km but slower (under {RULE_FLOOR:g} x its speed)",
    "faster, less safe": "faster but no safer per km",
}

"""Training seeds chosen on validation: ``python -m bgap.select runs=RUNS group=K out=DIR``.

A learner that trains ``K`` seeds and keeps the one its validation prefers. Per density and
policy family, the run folders under ``RUNS`` (in the order of their training seeds) fall
into consecutive groups of ``K``; each run's validation-chosen checkpoint plays
``episodes`` validation episodes of its own training traffic (seeds ``val_seed + k``, apart
from the test's) beside the rule-based ego, and is scored by its half of the recipe
objective (:func:`bgap.analysis.stats.policy_score`). The lowest score of each group is kept
(the lower seed on a tie).

Writes a copy of each kept run folder to ``out`` (``<density>/<run>``, without its resume
checkpoints: what ``bgap.evaluate models=[OUT]`` plays) and the table of every run's
validation figures, score and group to ``table`` (``selection.csv``, ``selection.md``).
The unit of such a learner is its group: ``G`` groups are ``G`` independent draws of it.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import pandas as pd
from omegaconf import OmegaConf

from bgap.analysis.stats import RULE_FLOOR, SHORT_PENALTY, STOCK_MARGIN, policy_score
from bgap.common.config import validate
from bgap.common.errors import ConfigError, check
from bgap.common.runs import (
    CONFIG,
    MODEL,
    model_file,
    only_metadata,
    refuse_foreign,
    run_folders,
    save_run_metadata,
    write_atomic,
)
from bgap.experiments.compat import upgrade
from bgap.experiments.config import ExperimentConfig, compose
from bgap.experiments.validation import figures_with_rule, split_rule
from bgap.runner.jobs import run_jobs

__all__ = ["SelectConfig", "groups", "markdown", "run_config", "runs", "select"]

SKIPPED = ("checkpoints", "tb")
"""What a kept run's copy leaves out: resume state and TensorBoard logs (evaluation reads
neither)."""


def run_config(folder: Path) -> ExperimentConfig:
    """A run folder's settings (its ``config.yaml``) as the config it trained under: its
    traffic, environment and policy family, whatever was set on its command line."""
    stored = OmegaConf.load(folder / CONFIG)
    return validate(OmegaConf.merge(compose("train", []), stored))


def runs(root: Path) -> pd.DataFrame:
    """Every run folder under ``root`` (one with ``model.zip`` and ``config.yaml``): its path,
    density, policy family, training seed and config (:func:`run_config`)."""
    rows = []
    for folder in run_folders(root):
        if not (folder / CONFIG).exists():
            continue
        cfg = run_config(folder)
        cfg.check_inputs()  # a replayed table moved or changed since: refused before any job
        rows.append(
            {
                "run": folder,
                "density": cfg.env.name,
                "policy": cfg.policy,
                "seed": cfg.seed,
                "config": cfg,
            }
        )
    if not rows:
        raise FileNotFoundError(f"no run folders ({MODEL} with {CONFIG}) in {root}")
    return pd.DataFrame(rows).sort_values(["density", "policy", "seed"], ignore_index=True)


def groups(table: pd.DataFrame, k: int) -> pd.Series:
    """Each run's group: consecutive runs of ``k`` seeds within its density and family."""
    for (density, policy), part in table.groupby(["density", "policy"]):
        if len(part) % k:
            raise ConfigError(
                f"group={k} does not divide the {len(part)} {policy} runs of {density} "
                f"(seeds {part.seed.tolist()}); train a multiple of {k} seeds, or give a "
                f"group= that divides {len(part)}"
            )
    return table.groupby(["density", "policy"]).cumcount() // k


def _validate(job: tuple[ExperimentConfig, str, int]) -> dict[str, Any]:
    """One run's chosen checkpoint and the rule-based ego on the same validation episodes
    of its training traffic (``job``: the run's config, its folder, the number of episodes)."""
    cfg, run_dir, episodes = job
    return figures_with_rule(str(model_file(run_dir, "best")), cfg, episodes)


def select(
    runs_dir: Path, out: Path, table_dir: Path, k: int, episodes: int, workers: int = 1
) -> pd.DataFrame:
    """Validate every run under ``runs_dir``, keep the best of each group (copied under
    ``out``), and write the table to ``table_dir``; returns it."""
    for folder in dict.fromkeys((out, table_dir)):
        refuse_foreign(folder)
        if folder.is_dir() and any(folder.iterdir()) and not only_metadata(folder):
            raise ConfigError(
                f"{folder} holds an earlier selection; give another folder, or remove it to "
                "select again"
            )
    settings = {
        "runs": str(runs_dir),
        "group": k,
        "episodes": episodes,
        "out": str(out),
        "table": str(table_dir),
    }
    for folder in dict.fromkeys((out, table_dir)):
        save_run_metadata(folder, OmegaConf.create(settings), upgrade=upgrade)
    table = runs(runs_dir)
    table["group"] = groups(table, k)
    jobs = [(row.config, str(row.run), episodes) for row in table.itertuples()]
    kept = "nothing was written; the same command validates them again"
    calls = [(job,) for job in jobs]
    figures = run_jobs(_validate, calls, workers=workers, numba_threads=1, kept=kept)
    table["score"] = [
        policy_score(p, *split_rule(f)) for p, f in zip(table.policy, figures, strict=True)
    ]
    table = pd.concat([table.drop(columns="config"), pd.DataFrame(figures)], axis=1)
    best = table.sort_values("seed").groupby(["density", "policy", "group"]).score.idxmin()
    table["kept"] = table.index.isin(best)
    for row in table[table.kept].itertuples():
        shutil.copytree(
            row.run, out / row.density / row.run.name, ignore=shutil.ignore_patterns(*SKIPPED)
        )
    table_dir.mkdir(parents=True, exist_ok=True)
    written = table.assign(run=table.run.map(str))
    write_atomic(table_dir / "selection.csv", lambda p: written.to_csv(p, index=False))
    write_atomic(table_dir / "selection.md", markdown(written, k, episodes))
    return table


def markdown(table: pd.DataFrame, k: int, episodes: int) -> str:
    """The selection as a page: per density and family, each run's validation figures."""
    lines = [
        f"# Training seeds chosen on validation: the best of each group of {k}",
        "",
        f"Each run's validation-chosen checkpoint on {episodes} validation episodes of its own "
        "training traffic, beside the rule-based ego on the same episodes; score: its half of "
        "the recipe objective (behaviour-rich: collisions per 100 km minus the "
        "rule-based ego's; default: collision % minus the rule-based ego's minus "
        f"{STOCK_MARGIN:g}; {SHORT_PENALTY:g} + the shortfall below {RULE_FLOOR:g} x its "
        "speed). Kept: the lowest score of each group.",
        "",
        "| density | policy | group | seed | per 100 km | collision % | speed m/s | rule per "
        "100 km / % / m/s | score | kept |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in table.itertuples():
        lines.append(
            f"| {r.density} | {r.policy} | {r.group} | {r.seed} | {r.per_100km:.2f} | "
            f"{r.collision_pct:.1f} | {r.avg_speed:.2f} | {r.rule_per_100km:.2f} / "
            f"{r.rule_collision_pct:.1f} / {r.rule_avg_speed:.2f} | {r.score:.2f} | "
            f"{'**yes**' if r.kept else ''} |"
        )
    return "\n".join(lines) + "\n"


@dataclass
class SelectConfig:
    """``python -m bgap.select runs=RUNS out=DIR``: keep the best of each group of seeds."""

    runs: str = "???"
    """A folder of run folders (bgap.train's ``run_dir=``)."""
    out: str = "???"
    """Where the kept run folders are copied."""
    group: int = 3
    """Seeds per group: the best of each is kept."""
    episodes: int = 200
    """Validation episodes per run."""
    table: Optional[str] = None
    """Where ``selection.csv`` and ``.md`` go; default ``out``."""
    workers: int = 1
    """Processes validating runs side by side."""

    def __post_init__(self) -> None:
        for key in ("group", "episodes", "workers"):
            check(getattr(self, key) >= 1, key, getattr(self, key), "must be a whole number >= 1")


SCHEMAS = ((None, "base_select", SelectConfig),)

"""A training recipe that learns to avoid crashes: ``python -m bgap.recipe``.

    python -m bgap.recipe                       # dense traffic, the paper's mixes, 40 trials
    python -m bgap.recipe trials=60 candidates=5

Three steps, all on validation episodes (seeds ``val_seed + k``; the test episodes of
``bgap.evaluate`` are never looked at):

1. **Sweep** (:mod:`bgap.experiments.sweep`, search space
   ``bgap/experiments/sweeps/recipe.yaml``: the reward's
   weights and DQN's discount, target update, learning rate and final exploration) with the
   objective fixed before any result was seen: the fewest validation collisions among
   policies whose mean speed reaches ``speed_floor`` (0.9) x the idle ego's on the same
   episodes (``mode=constrained``). One training seed per trial.
2. **Check**: the ``candidates`` best trials are trained again with every seed of
   ``check_seeds`` and played on ``check_episodes`` validation episodes, beside the idle and
   rule-based egos on the same episodes. One trial's single lucky seed does not make a
   recipe: the chosen candidate is the best by the same rule applied to its mean over seeds.
   The checks run ``workers`` (2) at a time, each in its own process; each finished row is
   kept in the study (with its validation curve), so a check resumes from the study's trial
   log (``bgap.pipeline trials``) on a machine without its run folders.
   With ``stock_check=true`` each candidate's default policy is trained too (stock traffic,
   the same seeds), and candidates whose default policy misses the stock rule (under
   half of the episodes crashed, at 0.9 x idle's speed) rank after those that meet it.
3. **Presets**: the chosen candidate's reward and agent groups as
   ``reward/<preset_name>.yaml`` and ``agent/<preset_name>.yaml`` under ``preset_dir``
   (default ``<root>/presets/.../user_recipe.yaml``, then ``reward=user_recipe
   agent=user_recipe``; the pipeline's stage writes ``results/presets/.../recipe.yaml``, the
   default of ``bgap.run`` and ``bgap.train``).

Outputs under ``out`` (default ``<root>/recipe``): ``sweep/trials.csv`` and ``pareto.png``
(every trial), ``candidates.csv`` (candidate x seed), ``table.md``, ``chosen.json`` and
``learning_curves.png`` (the chosen candidate's validation curves, every seed).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import optuna
import pandas as pd

from bgap.common.config import validate
from bgap.common.presets import write_preset
from bgap.common.runs import write_atomic
from bgap.experiments.config import ExperimentConfig, RecipeConfig, compose
from bgap.experiments.evaluate_results import crash_split
from bgap.experiments.recipe_choice import choose, choose_by_rule
from bgap.experiments.recipe_report import (
    NO_VALIDATION,
    curves,
    markdown,
    markdown_by_rule,
    markdown_levers,
    plot_curves,
)
from bgap.experiments.sweep import finished, study_name, sweep, write_outputs
from bgap.experiments.train import SIDE_BY_SIDE_STEPS, train
from bgap.experiments.validation import figures_with_rule, rule_score, validation_episodes
from bgap.runner.jobs import run_jobs

GROUPS = ("reward", "agent")
"""Config groups a recipe sets (the search space's keys must stay inside them)."""


def candidates(study: optuna.Study, k: int) -> list[optuna.trial.FrozenTrial]:
    """The ``k`` finished trials with the lowest objective (ties: the earlier trial)."""
    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    return sorted(done, key=lambda t: (t.value, t.number))[:k]


class Variant(NamedTuple):
    """Settings the check trains: a sweep trial's, or the chosen trial's with one lever
    switched (:func:`lever_variants`)."""

    label: int | str
    """The tables' ``trial`` column: the trial's number, or the lever."""
    folder: str
    """Its run folders' stem under the check's root (``trial-0005``, ``trial-0005-lever1``)."""
    overrides: list[str]


def variant(trial: optuna.trial.FrozenTrial) -> Variant:
    return Variant(trial.number, f"trial-{trial.number:04d}", list(trial.user_attrs["overrides"]))


def switched(overrides: list[str], lever: str) -> list[str]:
    """``overrides`` with ``lever``'s settings (``KEY=VALUE``, several separated by spaces) in
    place of their own: a dotted key replaces that key; a group (``agent=recipe``) replaces
    the group and every key under it, so a preset comes back whole (``agent=recipe
    reward=recipe agent.extractor=attention``: the main arm's recipe with this network)."""
    parts = lever.split()
    keys = [part.split("=", 1)[0] for part in parts]

    def replaced(override: str) -> bool:
        key = override.split("=", 1)[0]
        return any(key == k or ("." not in k and key.startswith(f"{k}.")) for k in keys)

    return [o for o in overrides if not replaced(o)] + parts


def lever_variants(cfg: RecipeConfig, trial: optuna.trial.FrozenTrial) -> list[Variant]:
    """The chosen ``trial`` with each of ``cfg.levers`` in place of its own settings
    (:func:`switched`); a lever the trial already has is left out."""
    own = variant(trial)
    out = []
    for k, lever in enumerate(cfg.levers, 1):
        overrides = switched(own.overrides, lever)
        if sorted(overrides) != sorted(own.overrides):
            out.append(Variant(lever, f"{own.folder}-lever{k}", overrides))
    return out


def check_all(
    cfg: RecipeConfig,
    variants: list[Variant],
    root: Path,
    progress: bool = True,
    study: optuna.Study | None = None,
) -> list[dict[str, Any]]:
    """:func:`check_seed` of every variant and check seed, the rows in that order. With
    ``workers`` > 1, the checks run that many at a time in processes, as ``bgap.train`` runs
    trainings side by side (each seeds itself: the same rows as one after the other);
    trainings too short to pay for a process's start run here.

    With ``study``, each finished row is kept in the study's attributes (:func:`kept_row`)
    and a row found there is not trained again: the check resumes from the study's trial log
    (``bgap.pipeline trials``) on a machine that has none of its run folders."""
    calls = [(v, seed) for v in variants for seed in cfg.check_seeds]
    keys = [check_key(cfg, v, seed) for v, seed in calls]
    found = {} if study is None else study.user_attrs
    rows: dict[int, dict[str, Any]] = {}
    for i, (v, seed) in enumerate(calls):
        if (kept := found.get(keys[i])) is not None:
            row = dict(kept["row"])  # (key, value) pairs: the row's column order
            rows[i] = row | {"trial": v.label, "run_dir": str(check_run_dir(root, v, seed))}
    todo = [i for i in range(len(calls)) if i not in rows]

    def finished(i: int, row: dict[str, Any]) -> None:
        rows[i] = row
        if study is not None:
            study.set_user_attr(keys[i], kept_row(row))

    short = cfg.profile.train_steps < SIDE_BY_SIDE_STEPS
    workers = 1 if short else cfg.workers
    kept = (
        f"its finished trainings are kept in {root} (and their rows in the study, saved with "
        "its trial log) and are reused when the same command runs again"
    )
    jobs = [(cfg, *calls[i], root, progress and workers <= 1) for i in todo]
    done = lambda k, row: finished(todo[k], row)  # noqa: E731
    run_jobs(check_seed, jobs, workers=workers, numba_threads=1, done=done, kept=kept)
    return [rows[i] for i in range(len(calls))]


def check_run_dir(root: Path, v: Variant, seed: int) -> Path:
    """The run folder of ``v``'s check training with ``seed``."""
    return root / f"{v.folder}-s{seed}"


def check_key(cfg: RecipeConfig, v: Variant, seed: int) -> str:
    """The study attribute that keeps the check's row of ``v`` with ``seed``: a hash of what
    decides the row (the training's settings, the validation episodes, what is measured),
    not of the variant's label or folder."""
    what = {
        "train": sorted(train_overrides(cfg, v, seed)),
        "episodes": cfg.check_episodes,
        "mode": cfg.mode,
        "stock_check": cfg.stock_check,
    }
    return "check-" + hashlib.sha1(json.dumps(what, sort_keys=True).encode()).hexdigest()[:16]


def kept_row(row: dict[str, Any]) -> dict[str, Any]:
    """A finished check row as a study attribute (JSON): the row (key, value pairs) and its
    training's validation curve (``evaluations.csv``'s collision % and speed, for the
    learning curves' figure once the run folder is gone)."""
    curve = None
    evaluations = Path(row["run_dir"]) / "evaluations.csv"
    if evaluations.exists():
        ev = pd.read_csv(evaluations)
        curve = {key: ev[key].tolist() for key in CURVE_KEYS if key in ev}
    # the row as (key, value) pairs: a trial log sorts a dict's keys, and the reused rows
    # would give candidates.csv its columns in another order
    return json.loads(json.dumps({"row": list(row.items()), "curve": curve}, default=float))


CURVE_KEYS = tuple(
    f"{who}{key}" for who in ("", "idle_", "rule_") for key in ("collision_pct", "avg_speed")
) + ("gradient_updates",)
"""The columns of a training's ``evaluations.csv`` that the learning curves plot."""


def train_overrides(cfg: RecipeConfig, v: Variant, seed: int) -> list[str]:
    """The training settings of ``v`` with ``seed``: the trial's settings with this run's
    profile (the same budget, part of the study's identity, and the periodic validation
    whose curves the check plots)."""
    overrides = [o for o in v.overrides if not o.startswith(("seed=", "profile.", "profile="))]
    budget = [
        f"profile.{key}={'null' if value is None else value}"
        for key, value in asdict(cfg.profile).items()
        if key != "name"
    ]
    return [*overrides, f"profile={cfg.profile.name}", *budget, f"seed={seed}"]


def check_seed(
    cfg: RecipeConfig, v: Variant, seed: int, root: Path, progress: bool
) -> dict[str, Any]:
    """Train ``v``'s settings with training seed ``seed`` (reused once finished); its row:
    the policy's, the idle ego's and the rule-based ego's validation figures."""
    tcfg = validate(compose("train", train_overrides(cfg, v, seed)))
    run_dir = check_run_dir(root, v, seed)
    tcfg = replace(tcfg, run_dir=str(run_dir), root=cfg.root)
    train(replace(tcfg, resume=True), progress=progress)  # reused once finished
    row: dict[str, Any] = {"trial": v.label, "seed": seed, "run_dir": str(run_dir)}
    if cfg.mode == "rule":  # both policies, each beside the rule-based ego
        return row | _check_both(cfg, tcfg, run_dir, progress)
    for name, policy in (("policy", str(run_dir)), ("idle", "idle"), ("rule", "rule")):
        ep = validation_episodes(policy, tcfg, cfg.check_episodes)
        prefix = "" if name == "policy" else f"{name}_"
        row[f"{prefix}collision_pct"] = 100.0 * float(ep.crashed.mean())
        row[f"{prefix}avg_speed"] = float(ep.avg_speed.mean())
        if name == "policy":
            row["lane_changes"] = float(ep.lane_changes.mean())
            row.update(crash_split(ep))
    if cfg.stock_check:  # the same recipe's default policy, in its own (stock) traffic
        stock = replace(tcfg, policy="default", run_dir=f"{run_dir}-default")
        train(replace(stock, resume=True), progress=progress)
        for name, policy in (("stock", stock.run_dir), ("stock_idle", "idle")):
            ep = validation_episodes(policy, stock, cfg.check_episodes)
            row[f"{name}_collision_pct"] = 100.0 * float(ep.crashed.mean())
            row[f"{name}_avg_speed"] = float(ep.avg_speed.mean())
    message = (
        f"trial {v.label} seed {seed}: {row['collision_pct']:.0f}% collisions at "
        f"{row['avg_speed']:.2f} m/s (idle {row['idle_collision_pct']:.0f}%, "
        f"{row['idle_avg_speed']:.2f} m/s)"
    )
    if cfg.stock_check:
        message += (
            f"; default in stock traffic {row['stock_collision_pct']:.0f}% at "
            f"{row['stock_avg_speed']:.2f} m/s (idle {row['stock_idle_avg_speed']:.2f})"
        )
    print(message, flush=True)
    return row


def _check_both(
    cfg: RecipeConfig, tcfg: ExperimentConfig, run_dir: Path, progress: bool
) -> dict[str, Any]:
    """Mode ``rule``: the behaviour-rich policy trained in ``run_dir`` and the same recipe's
    default policy (trained beside it) against the rule-based ego, on validation episodes."""
    row = figures_with_rule(str(run_dir), tcfg, cfg.check_episodes)
    stock = replace(tcfg, policy="default", run_dir=f"{run_dir}-default")
    train(replace(stock, resume=True), progress=progress)
    stock_row = figures_with_rule(stock.run_dir, stock, cfg.check_episodes)
    row |= {f"stock_{k}": v for k, v in stock_row.items()}
    print(
        f"trial {run_dir.name}: behaviour-rich {row['per_100km']:.2f} collisions per 100 km at "
        f"{row['avg_speed']:.2f} m/s (rule {row['rule_per_100km']:.2f} at "
        f"{row['rule_avg_speed']:.2f}); default in stock traffic {row['stock_collision_pct']:.0f}% "
        f"at {row['stock_avg_speed']:.2f} m/s (rule {row['stock_rule_collision_pct']:.0f}% at "
        f"{row['stock_rule_avg_speed']:.2f}); objective {rule_score(cfg, row):.2f}",
        flush=True,
    )
    return row


def check_levers(
    cfg: RecipeConfig,
    trial: optuna.trial.FrozenTrial,
    summary: pd.DataFrame,
    root: Path,
    out: Path,
    progress: bool,
    study: optuna.Study | None = None,
) -> dict[str, Path]:
    """The chosen ``trial`` with each lever switched (:func:`lever_variants`), checked as
    the candidates were (the same seeds and validation episodes): ``levers.csv`` (lever x
    seed) and ``levers.md``, each lever's figures beside the recipe's (``summary``'s row of
    ``trial``) and how far it moves the objective."""
    variants = lever_variants(cfg, trial)
    table = pd.DataFrame(check_all(cfg, variants, root, progress, study))
    write_atomic(out / "levers.csv", lambda p: table.to_csv(p, index=False))
    chosen = summary[summary.trial == trial.number]
    levers = choose_by_rule(cfg, table) if len(table) else chosen.iloc[:0]
    kept = [lever for lever in cfg.levers if lever not in {v.label for v in variants}]
    write_atomic(out / "levers.md", markdown_levers(cfg, chosen.iloc[0], levers, kept))
    return {"levers": out / "levers.md"}


def recipe(cfg: RecipeConfig, progress: bool = True) -> dict[str, Path]:
    """Sweep, check and write the chosen recipe (module docstring); returns the paths."""
    out = Path(cfg.out or Path(cfg.root) / "recipe")
    study = sweep(cfg, progress=progress)
    paths = write_outputs(
        study,
        replace(cfg, out=str(out / "sweep"), write_preset=False),
        chosen_label="best single-seed trial (before the check)",
    )
    root = Path(cfg.root) / "sweeps" / study_name(cfg) / "check"  # beside the sweep's trials
    chosen_from = candidates(study, cfg.candidates)
    rows = check_all(cfg, [variant(t) for t in chosen_from], root, progress, study)
    table = pd.DataFrame(rows)
    write_atomic(out / "candidates.csv", lambda p: table.to_csv(p, index=False))
    params = {t.number: t.params for t in chosen_from}
    if cfg.mode == "rule":
        summary = choose_by_rule(cfg, table)
        write_atomic(out / "table.md", markdown_by_rule(cfg, summary, params))
    else:
        summary = choose(cfg, table)
        write_atomic(out / "table.md", markdown(cfg, summary, params))
    best = summary.iloc[0]
    trial = next(t for t in chosen_from if t.number == best.trial)
    run_dirs = list(table[table.trial == best.trial].run_dir)
    plot_curves(
        curves(run_dirs, study),
        out / "learning_curves.png",
        f"recipe (trial {trial.number}): validation during training, each seed",
        NO_VALIDATION
        if any(Path(d).exists() for d in run_dirs)
        else "the run folders are gone and the study kept no curves\n"
        "(rows reused from its trial log)",
    )
    if cfg.mode == "rule":  # levers.md also without levers: the pipeline declares it
        paths |= check_levers(cfg, trial, summary, root, out, progress, study)
    tcfg = validate(compose("train", trial.user_attrs["overrides"]))
    preset_dir = Path(cfg.preset_dir or Path(cfg.root) / "presets")
    note = (
        f"Written by python -m bgap.recipe (study {study.study_name}, sweep trial "
        f"{trial.number}, checked on {len(cfg.check_seeds)} seeds x {cfg.check_episodes} "
        "validation episodes: "
        f"{best.collision_pct:.1f}% collisions at {best.avg_speed:.2f} m/s; idle "
        f"{best.idle_collision_pct:.1f}% at {best.idle_avg_speed:.2f} m/s)"
        if cfg.mode != "rule"
        else f"Written by python -m bgap.recipe mode=rule (study {study.study_name}, sweep trial "
        f"{trial.number}, checked "
        f"on {len(cfg.check_seeds)} seeds x {cfg.check_episodes} validation episodes: "
        f"behaviour-rich {best.per_100km:.2f} collisions per 100 km at {best.avg_speed:.2f} m/s "
        f"(rule-based ego {best.rule_per_100km:.2f} at {best.rule_avg_speed:.2f}); default in "
        f"stock traffic {best.stock_collision_pct:.1f}% at {best.stock_avg_speed:.2f} m/s "
        f"(rule-based ego {best.stock_rule_collision_pct:.1f}% at "
        f"{best.stock_rule_avg_speed:.2f}))"
    )
    converged = finished(study, cfg)
    for group in GROUPS:
        node = replace(getattr(tcfg, group), name=cfg.preset_name, converged=converged)
        paths[f"preset_{group}"] = write_preset(
            node,
            group,
            preset_dir / group / f"{cfg.preset_name}.yaml",
            note,
            f"(study {study.study_name}, ",
        )
    chosen = {
        "trial": trial.number,
        "params": trial.params,
        "sweep": {k: v for k, v in trial.user_attrs.items() if k != "overrides"},
        "check": {
            k: (None if isinstance(v, float) and np.isnan(v) else v)
            for k, v in best.to_dict().items()
        },
    }
    write_atomic(out / "chosen.json", json.dumps(chosen, indent=1, default=float))
    paths.update(
        candidates=out / "candidates.csv",
        table=out / "table.md",
        curves=out / "learning_curves.png",
        chosen=out / "chosen.json",
    )
    return paths

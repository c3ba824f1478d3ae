"""``python -m bgap.tune_rule``: the rule-based ego's IDM and MOBIL parameters searched with
Optuna on validation episodes, so that learned policies are read against the hand-built driver
at its best, not at highway-env's defaults.

    python -m bgap.tune_rule situation=dense env=dense grid=paper grid.densities=[dense]
    python -m bgap.tune_rule situation=stock behavior=stock grid=paper grid.mixes=[0.0]

The objective, fixed before any test episode is played: collisions per 100 km over every
validation episode (each cell of the grid, ``episodes`` each, seeded ``tune_seed + k``), among
parameter sets whose mean speed reaches :data:`~bgap.common.vocab.SPEED_FLOOR` x idle's on
the same episodes (the learners' constrained form, :func:`bgap.common.scores.constrained_score`,
on kilometres); ties go to the faster. Trial 0 is highway-env's defaults (the baseline
``rule``), so the chosen set is never worse than the default on validation. The seeds
``tune_seed + k`` (70000 + k) lie apart from every other search's validation episodes
(``val_seed`` 50000 + k) and from the tests' (``eval_seed`` 100000 + k).

Writes the preset ``preset`` (default ``<root>/presets/rule/<situation>.yaml``; the pipeline's
stage writes ``results/presets/rule/<situation>.yaml``, which the baseline ``rule_tuned``
plays: :func:`bgap.agents.rule_based.tuned`), and into ``out``: ``trials.csv`` (every trial's
parameters and figures) and ``search.png`` (the objective by trial, the defaults marked).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import pandas as pd

from bgap.agents.rule_based import DEFAULT, SITUATIONS, RuleParams, TunedRule, rule_based
from bgap.common.errors import check, check_apart
from bgap.common.plotting import pyplot
from bgap.common.presets import check_owner, user_preset, write_preset
from bgap.common.runs import save_run_metadata, write_atomic
from bgap.common.scores import collisions_per_100km, constrained_score, episode_distance
from bgap.common.vocab import SPEED_FLOOR
from bgap.experiments.compat import upgrade
from bgap.experiments.config import SCHEMAS as EXPERIMENT_SCHEMAS
from bgap.experiments.config import ExperimentConfig
from bgap.experiments.evaluate import cell_env_config, grid_cells
from bgap.sim.rollout import rollout
from bgap.traffic.road import IDLE

SPACE = {
    "time_wanted": (0.5, 3.0),
    "comfort_acc_max": (1.0, 6.0),
    "comfort_acc_min": (-9.0, -1.0),
    "politeness": (0.0, 1.0),
    "lane_change_min_acc_gain": (0.0, 1.0),
    "lane_change_max_braking_imposed": (1.0, 9.0),
}
"""The searched parameters and their ranges: they span highway-env's defaults and both of
bgap's driver classes (``bgap/conf/behavior/paper.yaml``: time gaps 1.2-1.5 s, accelerations
3-6, decelerations 6-9, politeness 0-0.5, thresholds 0-0.2, safe braking 3-9 m/s^2)."""


@dataclass
class TuneRuleConfig(ExperimentConfig):
    """``python -m bgap.tune_rule``: the search (module docstring) over the grid's cells."""

    situation: str = "???"
    """Which preset: sparse, dense (bgap's traffic at that density) or stock."""
    trials: int = 60
    """Trials, trial 0 the defaults (at least a learner's recipe search: 40)."""
    episodes: int = 20
    """Validation episodes per cell of the grid."""
    tune_seed: int = 70_000
    """Episode k of every cell is seeded tune_seed + k."""
    preset: str = ""
    """Where the preset goes; default ``<root>/presets/rule/<situation>.yaml`` (the pipeline's
    stage: ``results/presets/rule/<situation>.yaml``, the one ``rule_tuned`` plays)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        check(self.situation in SITUATIONS, "situation", self.situation, f"use one of {SITUATIONS}")
        check(self.trials >= 1, "trials", self.trials, "must be >= 1")
        check(self.episodes >= 1, "episodes", self.episodes, "must be >= 1")
        for name, seed in (("val_seed", self.val_seed), ("eval_seed", self.eval_seed)):
            check_apart(
                "tune_seed",
                self.tune_seed,
                seed,
                f"{name}={seed} (the tuning's episodes are its own)",
            )


SCHEMAS = (*EXPERIMENT_SCHEMAS, (None, "base_tune_rule", TuneRuleConfig))


def play(cfg: TuneRuleConfig, driver: Callable[[dict], Any]) -> dict[str, float]:
    """The validation figures over every cell of the policy ``driver(env config)``:
    collisions per 100 km, collision %, mean speed and lane changes per episode."""
    seeds = range(cfg.tune_seed, cfg.tune_seed + cfg.episodes)
    frames = []
    for cell in grid_cells(cfg):
        env = cell_env_config(cfg, cell)
        episodes = rollout(env, driver(env), seeds, cfg.backend).episodes
        episodes["distance"] = episode_distance(episodes, env["policy_frequency"])
        frames.append(episodes)
    e = pd.concat(frames, ignore_index=True)
    return {
        "per_100km": collisions_per_100km(e.crashed, e.distance),
        "collision_pct": float(100.0 * e.crashed.mean()),
        "avg_speed": float(e.avg_speed.mean()),
        "lane_changes": float(e.lane_changes.mean()),
    }


def objective(figures: dict[str, float], idle_speed: float) -> float:
    """Lower is better: collisions per 100 km where the speed reaches the floor, else 100 +
    the shortfall (:func:`~bgap.common.scores.constrained_score`)."""
    return constrained_score(figures["per_100km"], figures["avg_speed"], idle_speed, SPEED_FLOOR)


def search(cfg: TuneRuleConfig, progress: bool = True) -> pd.DataFrame:
    """Every trial's parameters, figures and objective (trial 0: the defaults)."""
    idle = play(cfg, lambda env: lambda obs: np.full(len(obs), IDLE))
    sampler = optuna.samplers.TPESampler(seed=cfg.seed)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(direction="minimize", sampler=sampler)
    study.enqueue_trial({k: getattr(DEFAULT, k) for k in SPACE})
    rows = []

    def trial_value(trial: optuna.Trial) -> float:
        params = RuleParams(**{k: trial.suggest_float(k, lo, hi) for k, (lo, hi) in SPACE.items()})
        figures = play(cfg, lambda env: rule_based(env, params))
        value = objective(figures, idle["avg_speed"])
        rows.append({"trial": trial.number, **asdict(params), **figures, "objective": value})
        if progress:
            print(
                f"trial {trial.number + 1}/{cfg.trials}: {figures['per_100km']:.2f} per 100 km "
                f"at {figures['avg_speed']:.2f} m/s",
                file=sys.stderr,
                flush=True,
            )
        return value

    study.optimize(trial_value, n_trials=cfg.trials)
    table = pd.DataFrame(rows)
    table["idle_speed"] = idle["avg_speed"]
    return table


def best(table: pd.DataFrame) -> pd.Series:
    """The chosen trial: the lowest objective, ties to the faster, then the earlier."""
    order = table.assign(neg_speed=-table.avg_speed).sort_values(
        ["objective", "neg_speed", "trial"], kind="stable"
    )
    return order.iloc[0]


def plot(table: pd.DataFrame, path: Path, title: str) -> None:
    """The objective by trial, the defaults (trial 0) and the chosen trial marked."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 3.5))
    feasible = table.objective < 100
    ax.plot(
        table.trial[feasible],
        table.objective[feasible],
        "o",
        ms=3,
        color="0.5",
        label="trial (fast enough)",
    )
    ax.plot(
        table.trial, table.objective.where(feasible).cummin(), "-", color="C0", label="best so far"
    )
    ax.plot([0], [table.objective.iloc[0]], "k*", ms=11, label="highway-env's defaults")
    chosen = best(table)
    ax.plot([chosen.trial], [chosen.objective], "o", mfc="none", mec="C3", ms=10, label="chosen")
    ax.set(xlabel="trial", ylabel="collisions per 100 km (validation)", title=title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run(cfg: TuneRuleConfig) -> Path:
    """Search, then write the trials, their plot and the chosen preset; returns the preset."""
    owner = f"bgap.tune_rule situation={cfg.situation}"
    target = cfg.preset or user_preset(cfg.root, "rule", cfg.situation)
    check_owner(target, owner)  # before minutes of search, not after
    out = save_run_metadata(cfg.out or f"outputs/tune_rule/{cfg.situation}", cfg, upgrade=upgrade)
    table = search(cfg)
    write_atomic(out / "trials.csv", table.to_csv(index=False))
    plot(table, out / "search.png", f"the rule-based ego tuned: {cfg.situation}")
    chosen = best(table)
    rows = 0 if cfg.situation == "stock" else cfg.env.observed_vehicles
    preset = TunedRule(
        **{f.name: float(chosen[f.name]) for f in fields(RuleParams)},
        situation=cfg.situation,
        observed_vehicles=rows,
    )
    default = table.iloc[0]
    note = (
        f"{owner}: trial {int(chosen.trial)} of {len(table)} ({chosen.per_100km:.2f} "
        f"collisions per 100 km at {chosen.avg_speed:.2f} m/s on validation; highway-env's "
        f"defaults: {default.per_100km:.2f} at {default.avg_speed:.2f})"
    )
    path = write_preset(preset, "rule", target, note, owner)
    print(note.partition(": ")[2] + f"; wrote {path}")
    return path

"""Optuna sweeps over reward weights or DQN hyperparameters: ``python -m bgap.sweep``.

    python -m bgap.sweep sweep=reward                     # multi-objective (Pareto front)
    python -m bgap.sweep sweep=reward mode=single         # scalarised, with pruning
    python -m bgap.sweep sweep=dqn env=dense trials=40
    python -m bgap.sweep storage=journal:outputs/sweeps/journal.log   # start N times: N workers

Each trial composes its config with Hydra's compose API (the Hydra Optuna sweeper plugin
does not work with Optuna 5), trains a policy on the profile's budget (its own run folder
with the resolved config and TensorBoard logs), evaluates it greedily on fixed seeds and
reports collision % (minimised) and average speed (maximised). ``mode=single`` minimises
``collision % - speed_weight * speed`` and prunes trials whose intermediate evaluations are
poor. The search space is the packaged ``bgap/experiments/sweeps/<sweep>.yaml``. The chosen
parameters
are written as a preset (default ``<root>/presets/<group>/user_tuned.yaml``, then
``reward=user_tuned`` or ``agent=user_tuned``), the Pareto front to ``<out>/pareto.csv`` and
``pareto.png``.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import optuna
import pandas as pd
import yaml
from optuna.trial import TrialState
from stable_baselines3.common.callbacks import BaseCallback

from bgap.agents.policies import baseline, load_model
from bgap.analysis.stats import policy_score
from bgap.common import studies
from bgap.common.config import validate
from bgap.common.errors import ConfigError
from bgap.common.plotting import pyplot
from bgap.common.presets import user_preset, write_preset
from bgap.common.runs import VOLATILE, digest, write_atomic
from bgap.common.scores import constrained_score
from bgap.common.studies import open_storage, resumable_study, run_until, sqlite_url
from bgap.experiments import trial_log
from bgap.experiments.compat import as_before
from bgap.experiments.config import ExperimentConfig, SweepConfig, compose
from bgap.experiments.train import train
from bgap.experiments.validation import (
    evaluate_model,
    figures_with_rule,
    rule_score,
    split_rule,
    validation_rates,
)
from bgap.runner.cluster import ENV_ADDRESS, ClusterConfig
from bgap.runner.jobs import run_jobs

RULE_KEYS = tuple(
    f"{policy}{who}{k}"
    for policy in ("", "stock_")
    for who in ("", "rule_")
    for k in ("collision_pct", "per_100km", "avg_speed")
)
"""Mode ``rule``'s figures per trial: the behaviour-rich policy and the rule-based ego in its
traffic, then (``stock_``) the default policy and the rule-based ego in stock traffic."""

SWEEPS_DIR = Path(__file__).resolve().parent / "sweeps"
"""The packaged Optuna search spaces of ``bgap.sweep``."""


def load_space(name: str) -> dict[str, dict[str, Any]]:
    """The search space ``sweeps/<name>.yaml``: {override key: {low, high[, log, int]} or
    {choices}}; checked against the experiment schema so a typo fails before training."""
    path = SWEEPS_DIR / f"{name}.yaml"
    if not path.exists():
        options = sorted(p.stem for p in SWEEPS_DIR.glob("*.yaml"))
        raise ConfigError(f"sweep={name!r} has no search space {path}; use one of {options}")
    space = yaml.safe_load(path.read_text())["params"]
    probe = ExperimentConfig()  # the schema's defaults: no preset file needed
    for key, spec in space.items():
        group, _, leaf = key.partition(".")
        if not leaf or not hasattr(getattr(probe, group, None), leaf):
            raise ConfigError(f"sweeps/{name}.yaml: {key!r} is not a config key")
        ok = "choices" in spec or ("low" in spec and "high" in spec and spec["low"] < spec["high"])
        if not ok:
            raise ConfigError(f"sweeps/{name}.yaml: {key} needs low < high or choices")
    return space


def suggest(trial: optuna.Trial, space: dict[str, dict[str, Any]]) -> dict[str, Any]:
    values = {}
    for key, spec in space.items():
        if "choices" in spec:
            values[key] = trial.suggest_categorical(key, spec["choices"])
        elif spec.get("int"):
            values[key] = trial.suggest_int(
                key, int(spec["low"]), int(spec["high"]), log=bool(spec.get("log"))
            )
        else:
            values[key] = trial.suggest_float(
                key, spec["low"], spec["high"], log=bool(spec.get("log"))
            )
    return values


STUDY_VOLATILE = (
    *VOLATILE,
    "trials",
    "storage",
    "study",
    "trial_log",
    "write_preset",
    "preset",
    "seeds",
    # bgap.recipe's settings of what follows the sweep
    "candidates",
    "check_seeds",
    "check_episodes",
    "preset_dir",
    "preset_name",
    "levers",
)
"""Sweep settings that do not change a trial's value (the trial budget may grow on a rerun)."""


def study_name(cfg: SweepConfig) -> str:
    """``study``, or the search, mode and density with a hash of every setting that changes a
    trial's value (budget, traffic, reward, evaluation, ...): sweeps of other settings never
    pool their trials."""
    settings = {k: v for k, v in asdict(cfg).items() if k not in STUDY_VOLATILE}
    # settings added later, at the value every earlier study had, leave its name as it was
    if cfg.mode != "rule":
        settings = {k: v for k, v in settings.items() if k not in ("rule_floor", "stock_margin")}
    settings = as_before(settings)
    return cfg.study or f"{cfg.sweep}-{cfg.mode}-{cfg.env.name}-{digest(settings)}"


class PruneCallback(BaseCallback):
    """Greedy evaluation every ``every`` steps, reported to the trial; stops a poor trial."""

    def __init__(self, trial: optuna.Trial, cfg: ExperimentConfig, every: int, score) -> None:
        super().__init__()
        self.trial, self.cfg, self.every, self.score = trial, cfg, every, score

    def _on_step(self) -> bool:
        if self.num_timesteps and self.num_timesteps % self.every < self.training_env.num_envs:
            value = self.score(self.model, self.cfg, episodes=10)
            self.trial.report(value, self.num_timesteps)
            if self.trial.should_prune():
                raise optuna.TrialPruned()
        return True


def objective(cfg: SweepConfig, crash: float, speed: float, idle_speed: float) -> float:
    """The single-valued objective (minimised). ``single``: collision % - speed_weight *
    speed. ``constrained``: collision %, for a policy whose mean speed reaches ``speed_floor``
    x idle's on the same episodes; below it, 100 + the shortfall in % of that floor, so any
    policy fast enough ranks above any that is not (safety bought by crawling is no win)."""
    if cfg.mode == "single":
        return crash - cfg.speed_weight * speed
    return constrained_score(crash, speed, idle_speed, cfg.speed_floor)


def run_trial(trial: optuna.Trial, cfg: SweepConfig, space: dict, root: Path) -> Any:

    values = suggest(trial, space)
    budget = [  # the sweep's own profile values (profile.train_steps=... on its command line)
        f"profile.{k}={'null' if v is None else v}" for k, v in asdict(cfg.profile).items()
    ]
    overrides = [
        f"env={cfg.env.name}",
        f"behavior={cfg.behavior.name}",
        f"reward={cfg.reward.name}",
        f"agent={cfg.agent.name}",
        f"backend={cfg.backend}",
        f"seed={cfg.seed}",
        f"policy={cfg.policy}",  # policy=default: every trial trains in stock traffic
        f"mix={cfg.mix}",
        f"mix_sampling={cfg.mix_sampling}",
        f"profile={cfg.profile.name}",
        *budget,
        *cfg.overrides,
        *(f"{k}={v}" for k, v in values.items()),
    ]
    tcfg = validate(compose("train", overrides))
    run_dir = root / study_name(cfg) / f"trial-{trial.number:04d}"
    tcfg = replace(tcfg, run_dir=str(run_dir), root=cfg.root)
    trial.set_user_attr("run_dir", str(run_dir))
    trial.set_user_attr("overrides", overrides)

    def score(model, c, episodes):
        if cfg.mode == "rule":  # the behaviour-rich half of the objective, while it trains
            mine, rule = split_rule(figures_with_rule(model, c, episodes))
            return policy_score("behavior_rich", mine, rule, cfg.rule_floor)
        idle = validation_rates(baseline("idle"), c, episodes)[1]
        return objective(cfg, *evaluate_model(model, c, episodes), idle)

    callbacks = []
    if cfg.mode != "multi":
        every = cfg.prune_every or max(tcfg.profile.train_steps // 4, 1)
        callbacks.append(PruneCallback(trial, tcfg, every, score))
    train(tcfg, progress=False, callbacks=callbacks)
    model = load_model(run_dir / "model.zip")  # of the trial's algorithm (agent.algo)
    if cfg.mode == "rule":  # the same recipe's default policy, in stock traffic
        stock = replace(tcfg, policy="default", run_dir=f"{run_dir}-default")
        train(stock, progress=False)
        figures = figures_with_rule(model, tcfg, cfg.sweep_eval_episodes)
        stock_figures = figures_with_rule(load_model(stock.run_dir), stock, cfg.sweep_eval_episodes)
        figures |= {f"stock_{k}": v for k, v in stock_figures.items()}
        for key, value in figures.items():
            trial.set_user_attr(key, value)
        return rule_score(cfg, figures)
    crash, speed = evaluate_model(model, tcfg, cfg.sweep_eval_episodes)
    idle_crash, idle_speed = validation_rates(baseline("idle"), tcfg, cfg.sweep_eval_episodes)
    for key, value in (
        ("collision_pct", crash),
        ("avg_speed", speed),
        ("idle_collision_pct", idle_crash),
        ("idle_avg_speed", idle_speed),
    ):
        trial.set_user_attr(key, value)
    if cfg.mode == "multi":
        return crash, speed
    return objective(cfg, crash, speed, idle_speed)


def sweep(cfg: SweepConfig, progress: bool = True) -> optuna.Study:
    """Run (or continue) the study until it holds ``cfg.trials`` finished trials."""

    space = load_space(cfg.sweep)
    root = Path(cfg.root) / "sweeps"
    root.mkdir(parents=True, exist_ok=True)
    url, name = cfg.storage or sqlite_url(root), study_name(cfg)
    # a new machine: the trials git kept, restored before the study is opened
    if cfg.trial_log and (n := trial_log.restore_if_missing(url, name, cfg.trial_log)):
        print(f"restored {n} trials of {name} from {cfg.trial_log} into {url}")
    multi = cfg.mode == "multi"
    study = resumable_study(
        open_storage(url),
        name,
        ["minimize", "maximize"] if multi else ["minimize"],
        optuna.samplers.TPESampler(seed=None),  # workers must not repeat draws
        None if multi else optuna.pruners.MedianPruner(n_startup_trials=5),
    )
    finished = (TrialState.COMPLETE, TrialState.PRUNED)
    if cfg.cluster.enabled:  # cfg.workers Optuna workers as Ray tasks, one shared study
        calls = [(cfg, url, studies.HEARTBEAT)] * cfg.workers
        kept = f"every finished trial is kept in the study ({url}); rerun to continue"
        run_jobs(_sweep_worker, calls, cluster=cfg.cluster, kept=kept)
        return study
    run_until(
        study,
        lambda t: run_trial(t, cfg, space, root),
        cfg.trials,
        progress,
        finished,
        (ValueError,),
    )
    return study


def _sweep_worker(cfg: SweepConfig, url: str, heartbeat: tuple[int, int]) -> int:
    """On a node: one Optuna worker of ``cfg``'s study in ``url``, trials until the study holds
    them all (a retried worker fails the trials a dead one left running, once their heartbeat
    is stale: RDB storages only). Returns its node's count of finished trials."""
    studies.HEARTBEAT = heartbeat  # the driver's (the tests shorten it)
    # The worker runs its trials in its own process. ClusterConfig() would read the address
    # back from the environment (how `dvc repro` sends a stage to a cluster), and each worker
    # would send the sweep to the cluster again: workers starting workers without end.
    os.environ.pop(ENV_ADDRESS, None)
    study = sweep(replace(cfg, cluster=ClusterConfig(), storage=url), progress=False)
    return len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED)))


def finished(study: optuna.Study, cfg: SweepConfig) -> bool:
    """Whether the study holds its ``cfg.trials`` finished (complete or pruned) trials: a
    sweep stopped before (failed trials, an interruption) writes presets marked
    ``converged: false`` and says so."""
    done = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
    count = len(study.get_trials(deepcopy=False, states=done))
    if count < cfg.trials:
        warnings.warn(
            f"the study {study.study_name} holds {count} of its {cfg.trials} trials: its "
            "preset is marked converged: false; rerun the same command to finish it",
            stacklevel=2,
        )
    return count >= cfg.trials


def chosen_trial(study: optuna.Study, cfg: SweepConfig) -> optuna.trial.FrozenTrial:
    """Single and constrained mode: the best trial. Multi: the Pareto trial with the best
    scalarisation."""
    if cfg.mode != "multi":
        return study.best_trial
    front = study.best_trials
    return min(front, key=lambda t: t.values[0] - cfg.speed_weight * t.values[1])


def _trials_table(study: optuna.Study, cfg: SweepConfig) -> pd.DataFrame:
    """One row per completed trial: its number, parameters, value and the scores it kept
    (the rule's in rule mode, the policy's and the idle ego's otherwise), and its run folder."""
    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    return pd.DataFrame(
        [
            {
                "trial": t.number,
                **t.params,
                "value": t.value if len(t.values) == 1 else None,
                **{
                    k: t.user_attrs.get(k)
                    for k in ("collision_pct", "avg_speed", "idle_collision_pct", "idle_avg_speed")
                    if cfg.mode != "rule"
                },
                **{k: t.user_attrs.get(k) for k in RULE_KEYS if cfg.mode == "rule"},
                "run_dir": t.user_attrs.get("run_dir"),
            }
            for t in done
        ]
    )


def _plot_trials(
    table: pd.DataFrame,
    cfg: SweepConfig,
    chosen: optuna.trial.FrozenTrial,
    chosen_label: str,
    path: Path,
) -> None:
    """The trials' scatter: speed against collisions, the Pareto front in multi mode, idle
    (and its speed floor) or the rule-based ego (and its), the chosen trial starred."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.6))
    y = "per_100km" if cfg.mode == "rule" else "collision_pct"
    ax.scatter(table.avg_speed, table[y], c="lightgray", label="trials")
    if cfg.mode == "multi":
        p = table[table.pareto].sort_values("avg_speed")
        ax.plot(p.avg_speed, p.collision_pct, "o-", color="tab:red", label="Pareto front")
    if "idle_avg_speed" in table and table.idle_avg_speed.notna().any():
        idle_speed = float(table.idle_avg_speed.mean())
        ax.scatter(
            [idle_speed],
            [float(table.idle_collision_pct.mean())],
            marker="s",
            color="tab:blue",
            label="idle",
            zorder=4,
        )
        if cfg.mode == "constrained":
            ax.axvline(
                cfg.speed_floor * idle_speed,
                ls="--",
                color="tab:blue",
                lw=0.8,
                label=f"{cfg.speed_floor:g} x idle speed",
            )
    if cfg.mode == "rule" and len(table):  # the yardstick: the rule-based ego
        rule_speed = float(table.rule_avg_speed.mean())
        ax.scatter(
            [rule_speed],
            [float(table.rule_per_100km.mean())],
            marker="s",
            color="tab:green",
            label="rule-based ego",
            zorder=4,
        )
        ax.axvline(
            cfg.rule_floor * rule_speed,
            ls="--",
            color="tab:green",
            lw=0.8,
            label=f"{cfg.rule_floor:g} x its speed",
        )
    ax.scatter(
        [chosen.user_attrs["avg_speed"]],
        [chosen.user_attrs[y]],
        marker="*",
        s=200,
        color="k",
        label=chosen_label,
        zorder=5,
    )
    ax.set_xlabel("validation mean speed m/s (maximise)")
    ax.set_ylabel(
        "behaviour-rich policy's validation\ncollisions per 100 km (minimise)"
        if cfg.mode == "rule"
        else "validation collision % (minimise)"
    )
    ax.set_title(f"{cfg.sweep} sweep ({cfg.mode}), {cfg.env.name}")
    ax.legend(fontsize=8)
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=120))
    plt.close(fig)


def write_outputs(
    study: optuna.Study, cfg: SweepConfig, chosen_label: str = "chosen"
) -> dict[str, Path]:
    """``trials.csv``, the trials' scatter ``pareto.png`` (the Pareto front in multi mode; the
    chosen trial starred, ``chosen_label``), ``chosen.json`` and the preset."""
    out = Path(cfg.out or Path(cfg.root) / "sweeps" / study_name(cfg))
    out.mkdir(parents=True, exist_ok=True)
    table = _trials_table(study, cfg)
    write_atomic(out / "trials.csv", lambda p: table.to_csv(p, index=False))
    chosen = chosen_trial(study, cfg)
    paths = {"trials": out / "trials.csv"}
    if cfg.mode == "multi":
        front = {t.number for t in study.best_trials}
        table["pareto"] = table.trial.isin(front)
        write_atomic(out / "pareto.csv", lambda p: table[table.pareto].to_csv(p, index=False))
        paths["pareto"] = out / "pareto.csv"
    _plot_trials(table, cfg, chosen, chosen_label, out / "pareto.png")
    paths["plot"] = out / "pareto.png"
    if cfg.write_preset:
        paths.update({f"preset_{g}": path for g, path in write_tuned(cfg, study, chosen).items()})
    (out / "chosen.json").write_text(
        json.dumps({"trial": chosen.number, "params": chosen.params, **chosen.user_attrs}, indent=1)
    )
    return paths


def write_tuned(
    cfg: SweepConfig, study: optuna.Study, trial: optuna.trial.FrozenTrial
) -> dict[str, Path]:
    """The chosen trial's config groups (reward, agent) as presets: ``sweep.preset`` for a
    one-group search, else ``<root>/presets/<group>/user_tuned.yaml`` per group; marked
    ``converged: false`` where the study has not :func:`finished`."""
    groups = sorted({key.split(".")[0] for key in trial.params})
    if cfg.preset and len(groups) > 1:
        raise ConfigError(
            f"preset={cfg.preset} names one file but sweep={cfg.sweep} tunes {groups}; "
            "leave preset unset (one user_tuned.yaml per group under <root>/presets)"
        )
    tcfg = validate(compose("train", [*trial.user_attrs["overrides"]]))
    note = (
        f"Written by python -m bgap.sweep sweep={cfg.sweep} mode={cfg.mode} "
        f"(study {study.study_name}) "
        f"(trial {trial.number}: {json.dumps(trial.user_attrs.get('collision_pct'))}% "
        f"collisions, {trial.user_attrs.get('avg_speed', float('nan')):.2f} m/s)"
    )
    paths, converged = {}, finished(study, cfg)
    for group in groups:
        path = Path(cfg.preset or user_preset(cfg.root, group, "user_tuned"))
        node = replace(getattr(tcfg, group), name=path.stem, converged=converged)
        paths[group] = write_preset(node, group, path, note, f"(study {study.study_name})")
    return paths

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
poor. The search space is the packaged ``bgap/sweeps/<sweep>.yaml``. The chosen parameters
are written as a preset (default ``<root>/presets/<group>/user_tuned.yaml``, then
``reward=user_tuned`` or ``agent=user_tuned``), the Pareto front to ``<out>/pareto.csv`` and
``pareto.png``.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import optuna
import pandas as pd
import yaml
from omegaconf import DictConfig
from stable_baselines3.common.callbacks import BaseCallback

from bgap.config import ExperimentConfig, SweepConfig, app, compose, load, validate
from bgap.errors import ConfigError
from bgap.presets import SWEEPS_DIR, selection_hint, write_preset
from bgap.rollout import greedy, rollout
from bgap.runs import VOLATILE, digest
from bgap.scenario import env_config
from bgap.studies import open_storage, sqlite_url


def load_space(name: str) -> dict[str, dict[str, Any]]:
    """The search space ``sweeps/<name>.yaml``: {override key: {low, high[, log, int]} or
    {choices}}; checked against the experiment schema so a typo fails before training."""
    path = SWEEPS_DIR / f"{name}.yaml"
    if not path.exists():
        options = sorted(p.stem for p in SWEEPS_DIR.glob("*.yaml"))
        raise ConfigError(f"sweep={name!r} has no search space {path}; use one of {options}")
    space = yaml.safe_load(path.read_text())["params"]
    probe = validate(compose("train", []))
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


STUDY_VOLATILE = (*VOLATILE, "trials", "storage", "study", "write_preset", "preset")
"""Sweep settings that do not change a trial's value (the trial budget may grow on a rerun)."""


def study_name(cfg: SweepConfig) -> str:
    """``study``, or the search, mode and density with a hash of every setting that changes a
    trial's value (budget, traffic, reward, evaluation, ...): sweeps of other settings never
    pool their trials."""
    settings = {k: v for k, v in asdict(cfg).items() if k not in STUDY_VOLATILE}
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


def evaluate_model(model, cfg: ExperimentConfig, episodes: int) -> tuple[float, float]:
    """Collision % and average speed of the greedy model on fixed seeds."""
    seeds = range(cfg.eval_seed, cfg.eval_seed + episodes)
    rows = rollout(env_config(cfg), greedy(model), seeds, cfg.backend).episodes
    return 100.0 * float(rows.crashed.mean()), float(rows.avg_speed.mean())


def run_trial(trial: optuna.Trial, cfg: SweepConfig, space: dict, root: Path) -> Any:
    from bgap.agents.dqn import DQN
    from bgap.train import train

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
        crash, speed = evaluate_model(model, c, episodes)
        return crash - cfg.speed_weight * speed

    callbacks = []
    if cfg.mode == "single":
        every = cfg.prune_every or max(tcfg.profile.train_steps // 4, 1)
        callbacks.append(PruneCallback(trial, tcfg, every, score))
    train(tcfg, progress=False, callbacks=callbacks)
    model = DQN.load(run_dir / "model.zip", device="cpu")
    crash, speed = evaluate_model(model, tcfg, cfg.sweep_eval_episodes)
    trial.set_user_attr("collision_pct", crash)
    trial.set_user_attr("avg_speed", speed)
    if cfg.mode == "multi":
        return crash, speed
    return crash - cfg.speed_weight * speed


def sweep(cfg: SweepConfig, progress: bool = True) -> optuna.Study:
    """Run (or continue) the study until it holds ``cfg.trials`` finished trials."""
    from optuna.study import MaxTrialsCallback
    from optuna.trial import TrialState

    space = load_space(cfg.sweep)
    root = Path(cfg.root) / "sweeps"
    root.mkdir(parents=True, exist_ok=True)
    storage = open_storage(cfg.storage or sqlite_url(root))
    multi = cfg.mode == "multi"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        study = optuna.create_study(
            study_name=study_name(cfg),
            storage=storage,
            directions=["minimize", "maximize"] if multi else None,
            direction=None if multi else "minimize",
            sampler=optuna.samplers.TPESampler(seed=None),  # workers must not repeat draws
            pruner=None if multi else optuna.pruners.MedianPruner(n_startup_trials=3),
            load_if_exists=True,
        )
    finished = (TrialState.COMPLETE, TrialState.PRUNED)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study.optimize(
        lambda t: run_trial(t, cfg, space, root),
        n_trials=max(cfg.trials - len(study.get_trials(deepcopy=False, states=finished)), 0),
        callbacks=[MaxTrialsCallback(cfg.trials, states=finished)],
        show_progress_bar=progress,
        catch=(ValueError,),
    )
    return study


def chosen_trial(study: optuna.Study, cfg: SweepConfig) -> optuna.trial.FrozenTrial:
    """Single mode: the best trial. Multi: the Pareto trial with the best scalarisation."""
    if cfg.mode == "single":
        return study.best_trial
    front = study.best_trials
    return min(front, key=lambda t: t.values[0] - cfg.speed_weight * t.values[1])


def write_outputs(study: optuna.Study, cfg: SweepConfig) -> dict[str, Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(cfg.out or Path(cfg.root) / "sweeps" / study_name(cfg))
    out.mkdir(parents=True, exist_ok=True)
    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    table = pd.DataFrame(
        [
            {
                "trial": t.number,
                **t.params,
                "collision_pct": t.user_attrs.get("collision_pct"),
                "avg_speed": t.user_attrs.get("avg_speed"),
                "run_dir": t.user_attrs.get("run_dir"),
            }
            for t in done
        ]
    )
    table.to_csv(out / "trials.csv", index=False)
    chosen = chosen_trial(study, cfg)
    paths = {"trials": out / "trials.csv"}
    if cfg.mode == "multi":
        front = {t.number for t in study.best_trials}
        table["pareto"] = table.trial.isin(front)
        table[table.pareto].to_csv(out / "pareto.csv", index=False)
        fig, ax = plt.subplots(figsize=(5, 3.6))
        ax.scatter(table.avg_speed, table.collision_pct, c="lightgray", label="trials")
        p = table[table.pareto].sort_values("avg_speed")
        ax.plot(p.avg_speed, p.collision_pct, "o-", color="tab:red", label="Pareto front")
        ax.scatter(
            [chosen.user_attrs["avg_speed"]],
            [chosen.user_attrs["collision_pct"]],
            marker="*",
            s=200,
            color="k",
            label="chosen",
            zorder=5,
        )
        ax.set_xlabel("average speed m/s (maximise)")
        ax.set_ylabel("collision % (minimise)")
        ax.set_title(f"{cfg.sweep} sweep, {cfg.env.name}")
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / "pareto.png", dpi=120)
        plt.close(fig)
        paths.update(pareto=out / "pareto.csv", plot=out / "pareto.png")
    if cfg.write_preset:
        paths["preset"] = write_tuned(cfg, chosen)
    (out / "chosen.json").write_text(
        json.dumps({"trial": chosen.number, "params": chosen.params, **chosen.user_attrs}, indent=1)
    )
    return paths


def write_tuned(cfg: SweepConfig, trial: optuna.trial.FrozenTrial) -> Path:
    """The chosen trial's group (reward or agent) as a preset (``sweep.preset``, default
    ``<root>/presets/<group>/user_tuned.yaml``)."""
    groups = {key.split(".")[0] for key in trial.params}
    if len(groups) != 1:
        raise ConfigError(f"a sweep must stay inside one config group, got {sorted(groups)}")
    group = groups.pop()
    tcfg = validate(compose("train", [*trial.user_attrs["overrides"]]))
    note = (
        f"Written by python -m bgap.sweep sweep={cfg.sweep} mode={cfg.mode} "
        f"(trial {trial.number}: {json.dumps(trial.user_attrs.get('collision_pct'))}% "
        f"collisions, {trial.user_attrs.get('avg_speed', float('nan')):.2f} m/s)"
    )
    path = Path(cfg.preset or Path(cfg.root) / "presets" / group / "user_tuned.yaml")
    return write_preset(replace(getattr(tcfg, group), name=path.stem), group, path, note)


@app(
    "sweep",
    "bgap.sweep",
    "every finished trial is kept in the Optuna study; rerun the same command to continue",
)
def main(dcfg: DictConfig) -> None:
    cfg: SweepConfig = load(dcfg)
    study = sweep(cfg)
    paths = write_outputs(study, cfg)
    chosen = chosen_trial(study, cfg)
    print(
        json.dumps(
            {
                "chosen_trial": chosen.number,
                "params": chosen.params,
                **{k: v for k, v in chosen.user_attrs.items() if k != "overrides"},
            },
            indent=1,
            default=str,
        )
    )
    for name, path in paths.items():
        print(f"{name}: {path}")
    if "preset" in paths:
        group = paths["preset"].parent.name
        print(f"use the preset with: {selection_hint(group, paths['preset'])}")


if __name__ == "__main__":
    main()

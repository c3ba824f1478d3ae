"""A policy scored on validation episodes of its own training traffic (seeds ``val_seed + k``,
apart from the tests'), alone or beside the rule-based ego on the same episodes: what the
sweeps, the recipe's search and check, and the seed selection choose by."""

from __future__ import annotations

import pandas as pd

from bgap.agents.policies import baseline, rollout
from bgap.analysis.stats import per_100km, rule_objective
from bgap.common.scores import episode_distance
from bgap.experiments.config import ExperimentConfig, SweepConfig
from bgap.experiments.training import training_config
from bgap.traffic.scenario import env_config


def evaluate_model(model, cfg: ExperimentConfig, episodes: int) -> tuple[float, float]:
    """Collision % and average speed of the greedy model on the validation episodes of its
    own training traffic (the mix drawn as in training)."""
    return validation_rates(model, cfg, episodes)


def validation_episodes(policy, cfg: ExperimentConfig, episodes: int) -> pd.DataFrame:
    """``policy`` on the first ``episodes`` validation episodes (seeds ``val_seed + k``) of
    ``cfg``'s training traffic, its mix drawn as in training."""

    cfg = training_config(cfg)
    seeds = range(cfg.val_seed, cfg.val_seed + episodes)
    return rollout(env_config(cfg, cfg.mix_sampling), policy, seeds, cfg.backend).episodes


def validation_rates(policy, cfg: ExperimentConfig, episodes: int) -> tuple[float, float]:
    """Collision % and mean speed of ``policy`` on :func:`validation_episodes`."""
    rows = validation_episodes(policy, cfg, episodes)
    return 100.0 * float(rows.crashed.mean()), float(rows.avg_speed.mean())


def validation_figures(policy, cfg: ExperimentConfig, episodes: int) -> dict[str, float]:
    """``collision_pct``, ``per_100km`` (collisions per 100 km of ego travel) and
    ``avg_speed`` of ``policy`` on :func:`validation_episodes`, with the counts behind them
    (``crashes``, ``episodes``, ``km``)."""
    rows = validation_episodes(policy, cfg, episodes)
    distance = episode_distance(rows, cfg.env.policy_frequency)
    return {
        "collision_pct": 100.0 * float(rows.crashed.mean()),
        "per_100km": per_100km(rows.crashed.to_numpy(), distance.to_numpy())[0],
        "avg_speed": float(rows.avg_speed.mean()),
        "crashes": int(rows.crashed.sum()),
        "episodes": len(rows),
        "km": float(distance.sum()) / 1000.0,
    }


def figures_with_rule(policy, cfg: ExperimentConfig, episodes: int) -> dict[str, float]:
    """:func:`validation_figures` of ``policy`` and, prefixed ``rule_``, of the rule-based ego
    on the same episodes."""
    mine = validation_figures(policy, cfg, episodes)
    rule = validation_figures(baseline("rule", env_config(training_config(cfg))), cfg, episodes)
    return {**mine, **{f"rule_{k}": v for k, v in rule.items()}}


def split_rule(figures: dict[str, float], prefix: str = "") -> tuple[dict, dict]:
    """The policy's and the rule-based ego's figures out of :func:`figures_with_rule`'s keys (with
    ``prefix``, e.g. ``stock_``)."""
    keys = ("collision_pct", "per_100km", "avg_speed")
    return (
        {k: figures[f"{prefix}{k}"] for k in keys},
        {k: figures[f"{prefix}rule_{k}"] for k in keys},
    )


def rule_score(cfg: SweepConfig, figures: dict[str, float]) -> float:
    """Mode ``rule``: :func:`bgap.analysis.stats.rule_objective` of both policies' figures
    (keys of :func:`figures_with_rule`, the default policy's prefixed ``stock_``)."""
    return rule_objective(
        *split_rule(figures),
        *split_rule(figures, "stock_"),
        floor=cfg.rule_floor,
        margin=cfg.stock_margin,
    )

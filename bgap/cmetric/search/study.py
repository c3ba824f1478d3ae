"""The search's parts: datasets split and cropped, one trial's parameters, its objective."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import pandas as pd

from bgap.cmetric.io import check_scoreable, load_trajectories
from bgap.cmetric.params import AGGREGATES, DEGREE_RULES, EVIDENCE, CMetricConfig, StyleWeights
from bgap.cmetric.score import label_auc, score_trajectories
from bgap.cmetric.search.params import CMetricSearchConfig
from bgap.common.tables import read_table

SCORED = ("aggressive", "conservative")


def crop(table: pd.DataFrame, radius: float) -> pd.DataFrame:
    """Rows of vehicles within ``radius`` of the ego of their episode and frame."""
    if "is_ego" not in table:
        raise ValueError("a crop by radius needs the column is_ego (one ego per episode)")
    ego = table[table.is_ego][["episode", "frame", "x", "y"]]
    ego = ego.rename(columns={"x": "ego_x", "y": "ego_y"})
    joined = table.merge(ego, on=["episode", "frame"], how="inner")
    near = np.hypot(joined.x - joined.ego_x, joined.y - joined.ego_y) <= radius
    return joined[near].drop(columns=["ego_x", "ego_y"]).reset_index(drop=True)


@dataclass
class Part:
    """One dataset's search or validation part, loaded and validated once."""

    dataset: str
    part: str  # "search" or "validation"
    table: pd.DataFrame


def load_parts(cfg: CMetricSearchConfig) -> list[Part]:
    """Every dataset, cropped and split by episode parity, as validated tables."""
    parts = []
    for d in cfg.datasets:
        table = read_table(d.path)
        name = d.name or Path(d.path).stem + (f"@{d.radius:g}m" if d.radius else "")
        if "label" not in table or not set(SCORED) <= set(table.label):
            raise ValueError(f"{d.path}: needs a label column with aggressive and conservative")
        if d.radius:
            table = crop(table, d.radius)
        table = load_trajectories(table, fps=cfg.fps)
        check_scoreable(table)
        if not d.split:
            parts.append(Part(name, "validation", table))
            continue
        even = table.episode.astype(int) % 2 == 0
        parts += [Part(name, "search", table[even]), Part(name, "validation", table[~even])]
    return parts


def evaluate(part: Part, cmetric: CMetricConfig) -> dict[str, Any]:
    """AUC (flagged vehicles at the median), flagged share, vehicles and their scores."""
    vehicles = score_trajectories(part.table, cmetric).vehicles
    vehicles = vehicles[vehicles.label.isin(SCORED)]
    auc = label_auc(vehicles)
    positives = int((vehicles.label == "aggressive").sum())
    return {
        "dataset": part.dataset,
        "part": part.part,
        "auc": auc,
        "auc_se": auc_standard_error(auc, positives, len(vehicles) - positives),
        "flagged": float(vehicles.flagged.mean()),
        "vehicles": len(vehicles),
        "scores": vehicles[["label", "aggressiveness", "flagged"]],
    }


def auc_standard_error(auc: float, positives: int, negatives: int) -> float:
    """Hanley and McNeil's (1982) standard error of an ROC AUC from its two sample sizes
    (their eq. 2, with the exponential approximation of Q1 and Q2)."""
    q1, q2 = auc / (2 - auc), 2 * auc**2 / (1 + auc)
    var = (auc * (1 - auc) + (positives - 1) * (q1 - auc**2) + (negatives - 1) * (q2 - auc**2)) / (
        positives * negatives
    )
    return float(np.sqrt(max(var, 0.0)))


def objective_value(results: list[dict[str, Any]], max_flagged: float, z: float = 0.0) -> float:
    """The worst AUC over the parts, less any flagged share above ``max_flagged``.

    With ``z`` > 0 each part counts with its AUC less ``z`` standard errors: a small,
    noisy part can then not decide the search by a lucky or unlucky draw alone."""
    return min(
        r["auc"] - z * r.get("auc_se", 0.0) - max(0.0, r["flagged"] - max_flagged) for r in results
    )


def suggest(trial, start: CMetricConfig) -> CMetricConfig:
    """One point of the search space (ranges in the README, "Tuning CMetric").

    Weights are searched relative to overspeeding's (fixed at 1); the scales stay, since a
    weight and a scale only act through their ratio."""
    scale = trial.suggest_categorical("scale", ["fixed", "spacing"])
    window = trial.suggest_float("window", 1.5, 6.0)
    degree = trial.suggest_int("degree", 2, 4)
    aggregate = trial.suggest_categorical("aggregate", list(AGGREGATES))
    return replace(
        start,
        name="tuned",
        mu=trial.suggest_float("mu", 15.0, 150.0, log=True) if scale == "fixed" else start.mu,
        mu_spacing=trial.suggest_float("mu_spacing", 1.0, 5.0) if scale == "spacing" else None,
        window=window,
        stride=trial.suggest_float("stride", 0.5, min(2.0, window)),
        degree=degree,
        epsilon=trial.suggest_float("epsilon", 0.2, 1.5),
        degree_rule=trial.suggest_categorical("degree_rule", list(DEGREE_RULES)),
        evidence=trial.suggest_categorical("evidence", list(EVIDENCE)),
        aggregate=aggregate,
        q=trial.suggest_float("q", 0.5, 0.95) if aggregate == "quantile" else start.q,
        weights=StyleWeights(
            overtaking=trial.suggest_float("w_overtaking", 1e-3, 3.0, log=True),
            overspeeding=1.0,
            weaving=trial.suggest_float("w_weaving", 1e-3, 3.0, log=True),
        ),
    )


def start_params(start: CMetricConfig) -> dict[str, Any]:
    """The starting preset as a point of the search space (enqueued as trial 0)."""
    values = {
        k: getattr(start, k)
        for k in ("window", "degree", "aggregate", "stride", "epsilon", "degree_rule", "evidence")
    }
    if start.mu_spacing is None:
        values |= {"scale": "fixed", "mu": start.mu}
    else:
        values |= {"scale": "spacing", "mu_spacing": start.mu_spacing}
    values["stride"] = min(values["stride"], values["window"], 2.0)
    values |= {"w_overtaking": start.weights.overtaking, "w_weaving": start.weights.weaving}
    if start.aggregate == "quantile":
        values["q"] = start.q
    return values


def params_of(study_params: dict[str, Any], start: CMetricConfig) -> CMetricConfig:
    """The CMetricConfig a finished trial's parameters describe."""

    return suggest(optuna.trial.FixedTrial(study_params), start)


def config_values(cmetric: CMetricConfig) -> dict[str, Any]:
    """Flat settings of a config, for tables."""
    out = {}
    for f in fields(cmetric):
        value = getattr(cmetric, f.name)
        if isinstance(value, StyleWeights):
            out |= {f"{f.name}.{k.name}": getattr(value, k.name) for k in fields(value)}
        else:
            out[f.name] = value
    return out

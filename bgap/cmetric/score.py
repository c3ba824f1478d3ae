"""Scoring a whole trajectory table: scenes -> centralities -> windows -> styles -> scores."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from bgap.cmetric.centrality import Scene, centralities
from bgap.cmetric.io import (
    TrajectoryError,
    check_duration,
    check_scale,
    check_scoreable,
    load_trajectories,
)
from bgap.cmetric.params import CMetricConfig
from bgap.cmetric.poly import fit_polynomials, sliding_windows, window_view
from bgap.cmetric.styles import STYLES, window_aggressiveness, window_styles


@dataclass
class CMetricResult:
    """``centrality``: per vehicle and frame; ``windows``: per vehicle and window;
    ``vehicles``: per vehicle, with the ``aggressiveness`` score."""

    centrality: pd.DataFrame
    windows: pd.DataFrame
    vehicles: pd.DataFrame


def score_trajectories(
    source: str | Path | pd.DataFrame,
    cfg: CMetricConfig | None = None,
    fps: float = 15.0,
    progress: bool = False,
) -> CMetricResult:
    """Score every vehicle of a trajectory table (DataFrame, CSV or Parquet)."""
    if not isinstance(source, (str, Path, pd.DataFrame)):
        raise TrajectoryError(
            f"score_trajectories takes a DataFrame or a .csv/.parquet path, not "
            f"{type(source).__name__} ({source!r:.40})"
        )
    cfg = cfg or CMetricConfig()
    table = load_trajectories(source, fps=fps)
    check_scoreable(table)
    check_scale(table)
    check_duration(table, cfg.window)
    labels = table.groupby(["episode", "vehicle_id"]).label.first() if "label" in table else None
    bar = tqdm(
        total=int(table.groupby("episode").frame.nunique().sum()),
        unit="frame",
        desc="cmetric",
        disable=not progress,
    )
    cent_parts, window_parts = [], []
    for episode, sub in table.groupby("episode", sort=True):
        scene = Scene.from_table(sub)
        mu = cfg.mu if cfg.mu_spacing is None else cfg.mu_spacing * spacing(scene)
        close, degree = centralities(scene, mu, progress=bar.update, degree_rule=cfg.degree_rule)
        fi, vi = np.nonzero(scene.present)
        cent_parts.append(
            pd.DataFrame(
                {
                    "episode": episode,
                    "frame": scene.frames[fi],
                    "time": scene.times[fi],
                    "vehicle_id": scene.vehicle_ids[vi],
                    "closeness": close[fi, vi],
                    "degree": degree[fi, vi],
                }
            )
        )
        window_parts.append(_scene_windows(scene, close, degree, cfg, episode))
    bar.close()
    centrality = pd.concat(cent_parts, ignore_index=True)
    windows = pd.concat(window_parts, ignore_index=True)
    vehicles = _vehicle_summary(windows, cfg)
    if labels is not None:
        vehicles = vehicles.join(labels, on=["episode", "vehicle_id"])
    return CMetricResult(centrality, windows, vehicles)


def spacing(scene: Scene, frames: int = 600) -> float:
    """The scene's typical spacing [m]: the median, over vehicles and frames, of the distance
    from a vehicle to its nearest neighbour (at most ``frames`` evenly spaced frames are
    read; a scene that never has two vehicles at once counts as 1 km)."""
    step = max(1, len(scene.frames) // frames)
    x, y, present = scene.x[::step], scene.y[::step], scene.present[::step]
    d = np.hypot(x[:, :, None] - x[:, None, :], y[:, :, None] - y[:, None, :])
    d[:, np.arange(d.shape[1]), np.arange(d.shape[1])] = np.inf
    d[np.isnan(d)] = np.inf
    nearest = d.min(axis=2)[present]
    nearest = nearest[np.isfinite(nearest)]
    return float(np.median(nearest)) if len(nearest) else 1000.0


def _scene_windows(
    scene: Scene, close: np.ndarray, degree: np.ndarray, cfg: CMetricConfig, episode
) -> pd.DataFrame:
    """Windows of every vehicle's contiguous runs, fitted and scored in batches by length."""
    dt = float(np.median(np.diff(scene.times))) if len(scene.times) > 1 else 1.0
    size = max(cfg.degree + 1, int(round(cfg.window / dt)))
    stride = max(1, int(round(cfg.stride / dt)))
    batches: dict[int, list] = {}
    for v in range(scene.present.shape[1]):
        rows = np.flatnonzero(scene.present[:, v])
        for run in np.split(rows, np.flatnonzero(np.diff(rows) > 1) + 1):
            starts = sliding_windows(len(run), size, stride)
            if len(starts) == 0:
                continue
            w = min(size, len(run))
            batches.setdefault(w, []).append((v, run, starts))
    parts = []
    for w, items in batches.items():
        t = np.concatenate([window_view(scene.times[run], s, w) for _, run, s in items])
        zc = np.concatenate([window_view(close[run, v], s, w) for v, run, s in items])
        zd = np.concatenate([window_view(degree[run, v], s, w) for v, run, s in items])
        # share of the window's frames with a neighbour within mu (closeness 0: none)
        ev = np.concatenate([window_view(close[run, v] > 0, s, w) for v, run, s in items])
        vid = np.concatenate([np.full(len(s), scene.vehicle_ids[v]) for v, _, s in items])
        cfit = fit_polynomials(t, zc, cfg.degree, cfg.regularization)
        dfit = fit_polynomials(t, zd, cfg.degree, cfg.regularization)
        signed = cfg.degree_rule == "net_passes"
        styles = window_styles(cfit, dfit, cfg.epsilon, cfg.sharpness_min, signed)
        agg = window_aggressiveness(styles, cfg.weights, cfg.scales)
        parts.append(
            pd.DataFrame(
                {
                    "episode": episode,
                    "vehicle_id": vid,
                    "t_start": t[:, 0],
                    "t_end": t[:, -1],
                    **styles,
                    "aggressiveness": agg,
                    "conservative_sle": np.exp(-agg),
                    "neighbours": ev.mean(axis=1),
                }
            )
        )
    if not parts:
        return pd.DataFrame()
    return pd.concat(parts, ignore_index=True).sort_values(["vehicle_id", "t_start"])


def _vehicle_summary(windows: pd.DataFrame, cfg: CMetricConfig) -> pd.DataFrame:
    """Per vehicle: mean SLE/SIE per style over its evidence windows, how many windows it
    has and how many are evidence, ``flagged`` (no evidence at all) and the score."""
    columns = [f"{k}_{e}" for k in STYLES for e in ("sle", "sie")]
    columns += ["conservative_sle", "conservative_sie"]
    keys = ["episode", "vehicle_id"]
    counted = windows.assign(evidence=windows["neighbours"] > 0 if cfg.evidence != "all" else True)
    every = counted.groupby(keys)
    grouped = counted[counted["evidence"]].groupby(keys)
    summary = grouped[columns].mean().reindex(every.size().index)
    summary["windows"] = every.size()
    summary["evidence_windows"] = every["evidence"].sum()
    summary["flagged"] = summary["evidence_windows"] == 0
    a = grouped["aggressiveness"]
    m = {"mean": a.mean, "max": a.max, "quantile": lambda: a.quantile(cfg.q)}[cfg.aggregate]()
    m = m.reindex(summary.index)
    summary["aggressiveness"] = np.sign(m) * (1.0 - np.exp(-np.abs(m)))
    return summary.reset_index()


def label_auc(vehicles: pd.DataFrame, score: str = "aggressiveness") -> float:
    """ROC AUC of ``score`` for telling aggressive from conservative labels (Mann-Whitney U).

    1.0: every aggressive vehicle scores above every conservative one; 0.5: chance.
    Vehicles without a score (flagged: no evidence) count at the median of the scored ones,
    so flagging cannot raise the AUC by dropping hard cases.
    """
    # Imported here: scipy.stats takes ~0.3 s to import; only this statistic needs it.
    from scipy.stats import rankdata

    sub = vehicles[vehicles["label"].isin(["aggressive", "conservative"])]
    if sub[score].isna().any():
        sub = sub.assign(**{score: sub[score].fillna(sub[score].median())})
    positive = (sub["label"] == "aggressive").to_numpy()
    n_pos, n_neg = positive.sum(), (~positive).sum()
    if n_pos == 0 or n_neg == 0:
        raise ValueError("AUC needs both aggressive and conservative vehicles")
    ranks = rankdata(sub[score].to_numpy())
    return float((ranks[positive].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))

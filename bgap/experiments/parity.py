"""Statistical parity of the two backends: ``python -m bgap.parity``.

Runs the same number of seeded episodes on highway-env (``backend=highway``) and on the
vectorised simulator (``backend=vector``) for several mixes, with a fixed scripted ego
policy, and compares per class the mean vehicle speed and lane changes per vehicle-minute,
and the ego collision rate, with 95% confidence intervals. Writes ``parity.csv`` and
``parity.png`` to ``out``. Both backends are measured from per-frame states in the same
way (:func:`episode_stats`), from the trajectories :func:`bgap.sim.rollout.rollout` records.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd

from bgap.agents.policies import rollout
from bgap.analysis.stats import t_interval, wilson_interval
from bgap.common.config import SEED_MAX
from bgap.common.errors import check
from bgap.common.plotting import pyplot
from bgap.common.runs import write_atomic
from bgap.common.vocab import CLASSES

# The scripted ego: a fixed cycle of meta-actions (indexed by the policy step), busy enough
# to crash now and then in dense traffic.
SCRIPT = (3, 0, 1, 2, 4, 1, 2, 0)


class ScriptedEgo:
    """The cycle :data:`SCRIPT`, one action per policy step, the same for every episode of a
    batch (the rollout steps its episodes in lock step and calls :meth:`reset` per batch)."""

    def __init__(self) -> None:
        self.step = 0

    def reset(self) -> None:
        self.step = 0

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        action = SCRIPT[self.step % len(SCRIPT)]
        self.step += 1
        return np.full(len(obs), action)


def episode_stats(
    speeds: np.ndarray, lanes: np.ndarray, labels: np.ndarray, dt: float, crashed: bool
) -> dict[str, float]:
    """Per-class mean speed and lane changes per vehicle-minute of one episode.

    ``speeds`` and ``lanes`` are (frames, vehicles) for the background vehicles, ``labels``
    their class names."""
    minutes = (lanes.shape[0] - 1) * dt / 60.0
    changes = (np.diff(lanes, axis=0) != 0).sum(axis=0)
    out: dict[str, float] = {"crashed": float(crashed)}
    for name in CLASSES:
        cols = labels == name
        if cols.any() and minutes > 0:
            out[f"speed_{name}"] = float(speeds[:, cols].mean())
            out[f"lane_changes_{name}"] = float(changes[cols].sum() / (cols.sum() * minutes))
        else:
            out[f"speed_{name}"] = np.nan
            out[f"lane_changes_{name}"] = np.nan
    return out


def run(config: dict, seeds: list[int], backend: str) -> pd.DataFrame:
    """The scripted ego's episodes on ``backend``, one row of :func:`episode_stats` each."""
    result = rollout(
        config, ScriptedEgo(), seeds, backend, batch=64 if backend == "vector" else 1, record=True
    )
    dt = 1.0 / float(config["simulation_frequency"])
    rows = []
    table = result.trajectories.sort_values(["episode", "frame", "vehicle_id"])
    for (episode, group), crashed in zip(
        table.groupby("episode", sort=True), result.episodes.crashed, strict=True
    ):
        n = group.vehicle_id.nunique()
        speeds = group.speed.to_numpy().reshape(-1, n)[:, 1:]
        lanes = group.lane.to_numpy(dtype=float).reshape(-1, n)[:, 1:]
        labels = group.label.to_numpy()[1:n]
        stats = episode_stats(speeds, lanes, labels, dt, bool(crashed))
        rows.append({"seed": seeds[episode], **stats})
    return pd.DataFrame(rows)


def compare(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per mix, metric and backend: mean and 95% CI; per mix and metric: whether the
    backends' intervals overlap."""
    rows = []
    metrics = [c for c in episodes.columns if c not in ("seed", "mix", "backend")]
    for (mix, backend), group in episodes.groupby(["mix", "backend"]):
        for metric in metrics:
            x = group[metric].dropna().to_numpy()
            if metric == "crashed":
                k = int(x.sum())
                lo, hi = wilson_interval(k, len(x))
                mean = k / max(len(x), 1)
            else:
                mean = float(x.mean()) if len(x) else np.nan
                lo, hi = t_interval(x)
            rows.append(
                {
                    "mix": mix,
                    "backend": backend,
                    "metric": metric,
                    "n": len(x),
                    "mean": mean,
                    "ci_low": lo,
                    "ci_high": hi,
                }
            )
    table = pd.DataFrame(rows)
    wide = table.pivot_table(
        index=["mix", "metric"], columns="backend", values=["mean", "ci_low", "ci_high"]
    )
    overlap = (wide[("ci_low", "vector")] <= wide[("ci_high", "highway")]) & (
        wide[("ci_low", "highway")] <= wide[("ci_high", "vector")]
    )
    table = table.merge(overlap.rename("overlap").reset_index(), on=["mix", "metric"])
    return table


def plot(table: pd.DataFrame, path: Path) -> None:
    plt = pyplot()

    metrics = list(dict.fromkeys(table["metric"]))
    fig, axes = plt.subplots(1, len(metrics), figsize=(3.2 * len(metrics), 3.2))
    for ax, metric in zip(np.atleast_1d(axes), metrics, strict=True):
        for k, (backend, color) in enumerate((("highway", "tab:blue"), ("vector", "tab:orange"))):
            t = table[(table.metric == metric) & (table.backend == backend)].sort_values("mix")
            x = t["mix"].to_numpy() + (k - 0.5) * 0.04
            err = [t["mean"] - t["ci_low"], t["ci_high"] - t["mean"]]
            ax.errorbar(x, t["mean"], yerr=err, fmt="o", color=color, label=backend, capsize=3)
        ax.set_title(metric, fontsize=9)
        ax.set_xlabel("mix")
    np.atleast_1d(axes)[0].legend(fontsize=8)
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=120))
    plt.close(fig)


@dataclass
class ParityConfig:
    """``python -m bgap.parity``: the backends' statistical comparison."""

    env: str = "dense"
    """The env preset (``bgap/conf/env``)."""
    mixes: list[float] = field(default_factory=lambda: [0.0, 0.5, 1.0])
    """Aggressive fractions, each in [0, 1]."""
    episodes: int = 200
    """Episodes per backend and mix."""
    duration: Optional[float] = None
    """Episode length [s]; default the env's."""
    seed: int = 0
    """Episode k is seeded seed + k."""
    out: str = "outputs/parity"
    """Folder for episodes.csv, parity.csv and parity.png (the pipeline: results/parity)."""
    backends: list[str] = field(default_factory=lambda: ["vector", "highway"])
    """Backends to play."""
    fast: bool = False
    """The vector backend in the fast mode (bgap.traffic.scenario.fast_mode: 10 Hz); with
    ``backends=[vector] reuse=true`` it is compared with the stored highway-env episodes."""
    reuse: bool = False
    """Keep the other backends' rows of an existing episodes.csv (same settings)."""

    def __post_init__(self) -> None:
        check(self.episodes >= 1, "episodes", self.episodes, "must be a whole number >= 1")
        if self.duration is not None:
            check(
                math.isfinite(self.duration) and self.duration > 0,
                "duration",
                self.duration,
                "must be a finite number of seconds > 0",
            )
        check(
            all(0 <= m <= 1 for m in self.mixes),
            "mixes",
            self.mixes,
            "every mix must lie in [0, 1]",
        )
        self.mixes = [float(m) + 0.0 for m in self.mixes]  # -0.0 is 0.0
        unknown = sorted(set(self.backends) - {"vector", "highway"})
        check(not unknown, "backends", self.backends, "use [vector], [highway] or [vector,highway]")
        check(
            0 <= self.seed <= SEED_MAX - self.episodes,
            "seed",
            self.seed,
            f"must lie in [0, {SEED_MAX} - episodes] (numpy's seeds)",
        )


SCHEMAS = ((None, "base_parity", ParityConfig),)

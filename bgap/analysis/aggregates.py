"""The field's aggregate views of the learned policies against the hand-built drivers:
rliable's interquartile mean and probability of improvement, and performance profiles.

The tables pool each policy's training seeds and cells into one rate. These views keep
them apart and ask how consistently a policy does well: a *run* is one training seed in one
cell (bgap's traffic at the largest radius, mixes that repeat another's traffic left out, as
:func:`bgap.analysis.yardsticks.read_cells`), scored by its collisions per 100 km. A
hand-built driver is deterministic: one run per cell, on the same episodes.

- **IQM** (:func:`rliable.metrics.aggregate_iqm`): the mean of the middle half of the runs,
  which one seed that collapsed cannot move as it moves the mean.
- **Probability of improvement** (:func:`rliable.metrics.probability_of_improvement`):
  the chance that a training seed has fewer collisions per 100 km than the hand-built driver
  in a cell drawn at random, ties counting half (a Mann-Whitney statistic per cell,
  averaged over cells).
- **Performance profile**: the share of runs at or below each rate.

Descriptive, with no interval: rliable's intervals are a stratified bootstrap over training
seeds alone, which leaves out that every seed plays the same episodes, the design whose
seed-only intervals undercovered in the simulated studies (``docs/intervals.md``); the
paired intervals and verdicts are :mod:`bgap.analysis.yardsticks`'.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from rliable.metrics import aggregate_iqm, probability_of_improvement

from bgap.analysis.episodes import n_of
from bgap.analysis.yardsticks import read_cells
from bgap.common.plotting import pyplot
from bgap.common.runs import write_atomic
from bgap.common.scores import PER_KM
from bgap.common.vocab import YARDSTICK_NAMES, YARDSTICKS

FAMILIES = ("behavior_rich", "default")
"""The learned policy families, one panel each in :func:`profiles_figure`."""


def run_rates(episodes: pd.DataFrame, mixes: list[float]) -> np.ndarray:
    """Collisions per 100 km of each training seed (row) in each cell (column, ``mixes``):
    the seed's crashes over its kilometres there."""
    g = episodes.groupby(["train_seed", "mix"])[["crashed", "distance"]].sum()
    rates = (g.crashed / g.distance * PER_KM).unstack("mix")
    return rates.reindex(columns=mixes).to_numpy(float)


def aggregates(df: pd.DataFrame) -> tuple[pd.DataFrame, dict[str, dict[str, np.ndarray]]]:
    """Per density and learned policy family (arm, family): its runs' mean and IQM of
    collisions per 100 km, and its probability of improvement over each hand-built driver
    that played the same cells; and each density's runs (``{density: {label: [seed,
    cell]}}``, the hand-built drivers under their own names) for the profiles."""
    rows, runs = [], {}
    for density in ("sparse", "dense"):
        g = read_cells(df, density)
        if g.empty:
            continue
        here = {}
        for (arm, family), pol in g[g.arm != ""].groupby(["arm", "family"], sort=True):
            mixes = sorted(set(pol.mix))  # the policy's own cells; each driver on the same
            scores = run_rates(pol, mixes)
            if np.isnan(scores).any():
                continue  # a training seed missed one of its arm's cells: not comparable
            here[f"{arm}/{family}"] = scores
            row = {
                "density": density,
                "arm": arm,
                "family": family,
                "n_seeds": scores.shape[0],
                "n_cells": scores.shape[1],
                "mean_per_100km": float(scores.mean()),
                "iqm_per_100km": float(aggregate_iqm(scores)),
            }
            for y in YARDSTICKS:
                yard = run_rates(g[g.family == y], mixes)
                if yard.size and not np.isnan(yard).any():  # played every one of the cells
                    # rliable counts higher as better: fewer collisions, negated
                    row[f"p_improve_{y}"] = float(probability_of_improvement(-scores, -yard))
            rows.append(row)
        for y in YARDSTICKS:  # the profiles: each driver on every cell it played
            if (g.family == y).any():
                here[y] = run_rates(g[g.family == y], sorted(set(g[g.family == y].mix)))
        if here:
            runs[density] = here
    return pd.DataFrame(rows), runs


def markdown(table: pd.DataFrame) -> str:
    """One table per density: each learned policy family's mean and IQM over its runs, and
    its probability of improvement over each hand-built driver."""
    if table.empty:
        return "(no learned policy shares the hand-built drivers' cells)\n"
    parts = []
    for density, here in table.groupby("density", sort=False):
        yards = [
            y
            for y in YARDSTICKS
            if f"p_improve_{y}" in here and here[f"p_improve_{y}"].notna().any()
        ]
        lines = [
            f"**{density} (n = {n_of(density)})**\n",
            "| policy | seeds x cells | mean per 100 km | IQM per 100 km | "
            + " | ".join(f"P(fewer than `{y}`)" for y in yards)
            + " |",
            "|---|---|---|---|" + "---|" * len(yards),
        ]
        for r in here.itertuples():
            values = [getattr(r, f"p_improve_{y}") for y in yards]
            cells = " | ".join("-" if np.isnan(v) else f"{v:.2f}" for v in values)
            lines.append(
                f"| {r.arm} {r.family.replace('_', '-')} | {r.n_seeds} x {r.n_cells} | "
                f"{r.mean_per_100km:.2f} | {r.iqm_per_100km:.2f} | {cells} |"
            )
        parts.append("\n".join(lines) + "\n")
    return "\n".join(parts)


def profiles_figure(runs: dict[str, dict[str, np.ndarray]], path: Path) -> bool:
    """Performance profiles, one panel per density and learned family: the share of runs
    (training seed x cell) with at most tau collisions per 100 km, each arm's policy beside
    the hand-built drivers. False (nothing written) without runs."""
    if not any(runs.values()):
        return False
    plt = pyplot()
    densities = list(runs)
    fig, axes = plt.subplots(
        len(densities), len(FAMILIES), figsize=(11, 3.8 * len(densities)), squeeze=False
    )
    for i, density in enumerate(densities):
        here = runs[density]
        top = max(float(np.nanmax(s)) for s in here.values())
        taus = np.linspace(0.0, max(top, 1e-9) * 1.02, 400)
        for j, family in enumerate(FAMILIES):
            ax = axes[i][j]
            learned = [k for k in here if k.endswith(f"/{family}")]
            for c, key in enumerate(learned):
                # the profile's one line: rliable.library's helper imports arch, which fails
                # to import beside pandas 3 at the versions rliable 1.2 admits
                share = (here[key].ravel()[None, :] <= taus[:, None]).mean(axis=1)
                ax.step(taus, share, where="post", color=f"C{c}", label=key.split("/")[0])
            for y, style in zip(YARDSTICKS, ("-", "--", ":"), strict=True):
                if y in here:
                    share = (here[y].ravel()[None, :] <= taus[:, None]).mean(axis=1)
                    ax.step(
                        taus, share, where="post", color="k", ls=style, label=YARDSTICK_NAMES[y]
                    )
            ax.set_title(f"{density}, {family.replace('_', '-')} policies", fontsize=10)
            ax.set_xscale("symlog", linthresh=1.0)  # the few-collision region, and the tails
            ax.set_xlim(0, taus[-1])
            ax.set_xlabel("collisions per 100 km (tau; linear below 1, logarithmic above)")
            ax.set_ylabel("share of runs at or below tau")
            ax.set_ylim(0, 1.02)
            ax.grid(alpha=0.3)
            if learned:
                ax.legend(fontsize=7, loc="lower right")
    fig.suptitle("Performance profiles: training seed x cell runs (rliable's score distributions)")
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=110))
    plt.close(fig)
    return True

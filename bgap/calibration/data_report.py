"""The report of a calibration to data: the statistics beside the target's, the
sensitivity of the objective to each parameter, and their plots."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import pandas as pd

from bgap.calibration.kinematics import ALL_STATISTICS
from bgap.common.plotting import pyplot
from bgap.common.runs import write_atomic
from bgap.common.studies import plot_convergence
from bgap.common.vocab import AGGRESSIVE, CLASSES, CONSERVATIVE
from bgap.traffic.behaviors import BehaviorConfig


def write_report(
    target: str,
    out: Path,
    observed: Any,
    study: optuna.Study,
    arms: dict[str, dict],
    table: pd.DataFrame,
    behavior: BehaviorConfig,
    simulated: dict[str, Any],
    sensitive: pd.DataFrame | None = None,
) -> dict[str, Any]:
    """``statistics.csv``/``.md``, ``statistics.png``, ``convergence.png``, ``scores.json``,
    and with ``sensitive`` ``sensitivity.csv``/``.md`` and ``sensitivity.png``.
    ``observed``: the target's statistics (:class:`bgap.calibration.data.Observed`);
    ``simulated``: the scene the trials simulated."""
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "statistics.csv", lambda p: table.to_csv(p, index=False))
    write_atomic(out / "statistics.md", table.to_markdown(index=False, floatfmt=".3f") + "\n")
    summary = {
        "target": target,
        "converged": behavior.converged,
        "objective": study.best_value,
        "trials": len(study.trials),
        "target_vehicles": observed.vehicles,
        "target_scene": asdict(observed.scene),
        "simulated_scene": simulated,
        "in_band": {arm: int(table[f"{arm}_in_band"].sum()) for arm in arms},
        "statistics": len(table),
        "crashed": {arm: sim["crashed"] for arm, sim in arms.items()},
        "parameters": {
            cls: {k: v for k, v in asdict(getattr(behavior, cls)).items() if v is not None}
            for cls in CLASSES
        },
    }
    if sensitive is not None:
        summary |= _write_sensitivity(sensitive, out)
    write_atomic(out / "scores.json", json.dumps(summary, indent=2, default=float))
    _plot_statistics(observed, arms, out / "statistics.png")
    plot_convergence(study, out / "convergence.png", "weighted scaled distance")
    return summary


def _write_sensitivity(sensitive: pd.DataFrame, out: Path) -> dict[str, Any]:
    """The sensitivity report's files; returns what ``scores.json`` says of it."""
    write_atomic(out / "sensitivity.csv", lambda p: sensitive.to_csv(p, index=False))
    noise = sensitive.attrs["noise"]
    (out / "sensitivity.md").write_text(
        f"Objective noise (standard deviation over scene sets): {noise:.4f}\n\n"
        + sensitive.to_markdown(index=False, floatfmt=".3f")
        + "\n"
    )
    _plot_sensitivity(sensitive, out / "sensitivity.png")
    return {
        "identified": sorted(sensitive.parameter[sensitive.identified == True]),  # noqa: E712
        "not_identified": sorted(sensitive.parameter[sensitive.identified == False]),  # noqa: E712
        "objective_noise": noise,
    }


def _plot_statistics(observed: Any, arms: dict[str, dict], path: Path) -> None:
    """Per class and statistic, the target's histogram beside each simulated arm's."""
    plt = pyplot()
    classes = [cls for cls in (CONSERVATIVE, AGGRESSIVE) if cls in observed.samples]
    fig, axes = plt.subplots(
        len(classes),
        len(ALL_STATISTICS),
        figsize=(3.2 * len(ALL_STATISTICS), 2.6 * len(classes)),
        squeeze=False,
    )
    for i, cls in enumerate(classes):
        for j, name in enumerate(ALL_STATISTICS):
            ax = axes[i][j]
            target = observed.samples[cls].get(name, np.empty(0))
            series = [("target", target, "k")] + [
                (arm, sim["samples"].get(cls, {}).get(name, np.empty(0)), color)
                for (arm, sim), color in zip(arms.items(), ("tab:gray", "tab:green"), strict=True)
            ]
            values = np.concatenate([s for _, s, _ in series if len(s)] or [np.zeros(1)])
            bins = np.linspace(*np.quantile(values, [0.01, 0.99]), 31)
            for arm, sample, color in series:  # dashed on top: equal arms both show
                if len(sample):
                    ax.hist(
                        sample,
                        bins=bins,
                        density=True,
                        histtype="step",
                        color=color,
                        ls="--" if arm == "calibrated" else "-",
                        label=arm,
                        lw=2.0 if arm == "table1" else 1.2,
                    )
            ax.set_title(f"{cls}: {name}", fontsize=9)
            if i == 0 and j == 0:
                ax.legend(fontsize=7)
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=110))
    plt.close(fig)


def _plot_sensitivity(table: pd.DataFrame, path: Path) -> None:
    """The objective along each parameter's sweep (best value marked, the noise margin
    shaded), one panel per parameter, the most important first."""
    plt = pyplot()

    curves = table.attrs["curves"]
    names = list(table.parameter)
    cols = 4
    rows = int(np.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.4 * rows), squeeze=False)
    margin = 2 * table.attrs["noise"] if np.isfinite(table.attrs["noise"]) else 0.0
    for ax, name in zip(axes.flat, names, strict=False):
        row = table[table.parameter == name].iloc[0]
        curve = curves[curves.parameter == name]
        ax.plot(curve.value, curve.objective, "o-", ms=3)
        ax.axhspan(row.objective_best, row.objective_best + margin, color="0.9")
        ax.axvline(row.best, color="tab:green", ls="--")
        flag = "" if row.identified else " (not identified)"
        ax.set_title(f"{name}{flag}", fontsize=8)
    for ax in axes.flat[len(names) :]:
        ax.axis("off")
    fig.supylabel("objective")
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=110))
    plt.close(fig)

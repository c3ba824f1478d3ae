"""``python -m bgap.cmetric.search datasets=[...]``: Optuna over CMetric's parameters.

    python -m bgap.cmetric.search trials=60 \
        'datasets=[{path: data/sparse.parquet}, {path: data/dense.parquet, radius: 100}]'

Writes into ``out`` (default ``outputs/cmetric_search``): ``optuna.db`` (the study; a rerun
continues it), ``auc.csv`` and ``report.md`` (AUC per dataset and part for the default, the
starting and the tuned parameters), ``roc.png``, ``scores.png``, ``convergence.png``,
``config.yaml``, ``command.txt``, and the tuned preset (``presets/cmetric/user_tuned.yaml``;
use it with ``cmetric=user_tuned``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import optuna
import pandas as pd
from omegaconf import DictConfig, OmegaConf

from bgap.cmetric.config import SCHEMAS
from bgap.cmetric.params import CMetricConfig
from bgap.cmetric.search.params import CMetricSearchConfig
from bgap.cmetric.search.study import (
    config_values,
    evaluate,
    load_parts,
    objective_value,
    params_of,
    start_params,
    suggest,
)
from bgap.cmetric.truths import broken_truths
from bgap.common.config import app, load
from bgap.common.plotting import pyplot
from bgap.common.presets import selection_hint, write_preset
from bgap.common.runs import VOLATILE, digest, file_digest, save_run_metadata, write_atomic
from bgap.common.studies import (
    open_storage,
    plot_convergence,
    resumable_study,
    run_until,
    sqlite_url,
)

NOT_CONTENT = (*VOLATILE, "trials", "storage", "preset")
"""Settings a rerun may change without changing what the study holds."""
ADDED_LATER = {"z": 0.0, "crops_tune": True, "known_truths": False}
"""Settings added after studies were first named, with the value those studies used."""


def search(cfg: CMetricSearchConfig, progress: bool = True):
    """Run (or continue) the study to ``cfg.trials`` complete trials; return it and the
    loaded parts."""

    parts = load_parts(cfg)
    tuning = [p for p in parts if p.part == "search"]
    storage = open_storage(cfg.storage or sqlite_url(cfg.out))
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = resumable_study(
        storage,
        cfg.study or study_name(cfg),  # named by run() for the command
        ["maximize"],
        optuna.samplers.TPESampler(seed=cfg.seed, n_startup_trials=10),
        start=start_params(cfg.cmetric),  # trial 0: the starting preset
    )

    def objective(trial) -> float:
        cmetric = suggest(trial, cfg.cmetric)
        results = [evaluate(p, cmetric) for p in tuning]
        for r in results:
            trial.set_user_attr(f"auc {r['dataset']}", r["auc"])
            trial.set_user_attr(f"flagged {r['dataset']}", r["flagged"])
        broken = broken_truths(cmetric) if cfg.known_truths else []
        trial.set_user_attr("broken truths", broken)
        return objective_value(results, cfg.max_flagged, cfg.z) - (1.0 if broken else 0.0)

    return run_until(study, objective, cfg.trials, progress), parts


def study_name(cfg: CMetricSearchConfig) -> str:
    """``cmetric-<hash>`` of the tables' bytes and every setting that changes a trial."""

    tables = {d.path: file_digest(d.path, "sha1") for d in cfg.datasets}
    settings = OmegaConf.to_container(OmegaConf.structured(cfg))
    for key in (*NOT_CONTENT, "study"):
        settings.pop(key, None)
    for key, value in ADDED_LATER.items():  # at their old value: the name stays the same
        if settings.get(key) == value:
            settings.pop(key)
    return f"cmetric-{digest([tables, settings])}"


def report(cfg: CMetricSearchConfig, study, parts, tuned: CMetricConfig) -> pd.DataFrame:
    """AUC per dataset and part for the default, starting and tuned parameters, with the
    figures; returns the AUC table."""
    out = Path(cfg.out)
    presets = {"default": CMetricConfig(), cfg.cmetric.name: cfg.cmetric, "tuned": tuned}
    rows, scores = [], {}
    for preset, cmetric in presets.items():
        for part in parts:
            r = evaluate(part, cmetric)
            scores[(preset, part.dataset, part.part)] = r.pop("scores")
            rows.append({"preset": preset, **r})
    table = pd.DataFrame(rows)
    write_atomic(out / "auc.csv", lambda p: table.to_csv(p, index=False))
    wide = table.pivot_table(index=["dataset", "part"], columns="preset", values="auc")
    wide = wide[list(presets)].reset_index()
    flagged = table[table.preset == "tuned"].set_index(["dataset", "part"]).flagged
    wide["tuned flagged"] = [flagged[key] for key in zip(wide.dataset, wide.part, strict=True)]
    chosen = pd.Series(config_values(tuned)).to_frame("tuned")
    chosen["start"] = pd.Series(config_values(cfg.cmetric))
    lines = [
        "# CMetric's parameters tuned by Optuna",
        "",
        f"{len(study.trials)} trials; objective: the worst search-part AUC over "
        f"{sum(p.part == 'search' for p in parts)} datasets (flagged vehicles at the median, "
        f"flagged share above {cfg.max_flagged:.0%} subtracted"
        f"{'; 1 subtracted where a hand-built truth breaks' if cfg.known_truths else ''}"
        "). Best: trial "
        f"{study.best_trial.number}, {study.best_value:.3f}.",
        "",
        "## ROC AUC, aggressive vs conservative",
        "",
        wide.to_markdown(index=False, floatfmt=".3f"),
        "",
        "## Parameters",
        "",
        chosen.to_markdown(),
        "",
    ]
    write_atomic(out / "report.md", "\n".join(lines))
    _plot_validation(parts, list(presets), scores, out)
    plot_convergence(study, out / "convergence.png", "worst search-part AUC")
    return table


def _plot_validation(parts, presets: list[str], scores: dict, out: Path) -> None:
    """ROC curves and score distributions of the tuned parameters on the validation parts
    (``roc.png``, ``scores.png``)."""
    plt = pyplot()
    valid = [p for p in parts if p.part == "validation"]
    cols = min(4, len(valid))
    rows_n = -(-len(valid) // cols)
    for kind in ("roc", "scores"):
        fig, axes = plt.subplots(rows_n, cols, figsize=(3.2 * cols, 2.8 * rows_n), squeeze=False)
        for ax, part in zip(axes.flat, valid, strict=False):  # more axes than parts
            for preset in presets:
                s = scores[(preset, part.dataset, part.part)]
                filled = s.aggressiveness.fillna(s.aggressiveness.median())
                if kind == "roc":
                    fpr, tpr = _roc(filled, s.label == "aggressive")
                    ax.plot(fpr, tpr, label=preset)
                elif preset == "tuned":
                    for label, color in (("aggressive", "C3"), ("conservative", "C0")):
                        ax.hist(
                            filled[s.label == label],
                            bins=30,
                            alpha=0.6,
                            color=color,
                            label=label,
                            density=True,
                        )
            if kind == "roc":
                ax.plot([0, 1], [0, 1], ":", color="grey")
            ax.set_title(part.dataset, fontsize=8)
            ax.legend(fontsize=6)
        for ax in list(axes.flat)[len(valid) :]:
            ax.axis("off")
        fig.suptitle(
            "ROC on validation episodes"
            if kind == "roc"
            else "tuned scores per class, validation episodes (flagged at the median)",
            fontsize=9,
        )
        fig.tight_layout()
        write_atomic(out / f"{kind}.png", lambda p, fig=fig: fig.savefig(p, dpi=110))
        plt.close(fig)


def _roc(score: pd.Series, positive: pd.Series) -> tuple[list[float], list[float]]:
    """False and true positive rates over every threshold (ties stepped together)."""
    order = score.sort_values(ascending=False)
    pos = positive.loc[order.index].to_numpy()
    grouped = pd.DataFrame({"s": order.to_numpy(), "p": pos, "n": ~pos}).groupby("s", sort=False)
    sums = grouped.sum()
    tp, fp = sums.p.cumsum(), sums.n.cumsum()
    return [0.0, *(fp / max(fp.iloc[-1], 1)).tolist()], [0.0, *(tp / max(tp.iloc[-1], 1)).tolist()]


def run(cfg: CMetricSearchConfig, dcfg: Any, progress: bool = True) -> dict[str, Path]:
    """The command: search, report, preset."""
    cfg = replace(cfg, study=cfg.study or study_name(cfg))
    # the study's name hashes the tables' bytes: other data in the same folder is refused
    out = save_run_metadata(cfg.out, OmegaConf.merge(dcfg, {"study": cfg.study}), NOT_CONTENT)
    study, parts = search(cfg, progress)
    tuned = params_of(study.best_params, cfg.cmetric)
    preset = Path(cfg.preset or out / "presets" / "cmetric" / "user_tuned.yaml")
    tuned = replace(tuned, name=preset.stem)
    report(cfg, study, parts, tuned)
    owner = f"report: {out / 'report.md'}"
    note = (
        f"CMetric parameters tuned by python -m bgap.cmetric.search (trial "
        f"{study.best_trial.number} of {len(study.trials)}, worst search AUC "
        f"{study.best_value:.3f}); {owner}"
    )
    write_preset(tuned, "cmetric", preset, note, owner)
    print(f"report: {out / 'report.md'}")
    print(f"preset: {preset} (use it with: {selection_hint('cmetric', preset)})")
    return {"out": out, "preset": preset}


@app(
    "cmetric_search",
    "bgap.cmetric.search",
    SCHEMAS,
    "finished trials are kept in the study; rerun the same command to continue",
)
def _hydra_main(dcfg: DictConfig) -> None:
    run(load(dcfg), dcfg)


def main() -> None:
    _hydra_main()


if __name__ == "__main__":
    main()

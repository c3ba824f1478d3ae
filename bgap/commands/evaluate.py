"""``bgap evaluate``: evaluate models and baselines on seeded episodes into a results folder."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

from omegaconf import DictConfig

from bgap.analysis.episodes import MODELS
from bgap.common.config import app, load
from bgap.common.errors import ConfigError
from bgap.common.runs import save_run_metadata, write_atomic
from bgap.experiments.compat import upgrade
from bgap.experiments.config import SCHEMAS, ExperimentConfig
from bgap.experiments.evaluate import default_out, grid_cells, plan, play_plan
from bgap.experiments.evaluate_policies import model_records, policy_specs
from bgap.experiments.evaluate_results import (
    MAX_BARS,
    compact,
    format_table,
    plot_comparison,
    summarize,
    traffic_inputs,
    write_results,
)
from bgap.runner.cluster import connected
from bgap.runner.locks import exclusive


@app("evaluate", "bgap.evaluate", SCHEMAS, "no results were written; rerun the command")
def main(dcfg: DictConfig) -> None:

    cfg: ExperimentConfig = load(dcfg)
    with connected(cfg.cluster):  # a cluster out of reach: one line before anything is written
        _main(cfg, dcfg)


def _main(cfg: ExperimentConfig, dcfg: DictConfig) -> None:
    out = Path(cfg.out or default_out(cfg))
    specs = policy_specs(cfg)  # a bad model list fails before the folder is made
    if not specs:
        raise ConfigError(
            "nothing to evaluate: models=[] and no baseline; give models=[RUN_DIR,...] (run "
            "folders, model.zip files or zoo names) or baselines=[idle,random,rule]"
        )
    with exclusive(out):  # a second evaluation into the same folder is refused
        save_run_metadata(out, dcfg, upgrade=upgrade)
        cells = grid_cells(cfg)
        seeds, configs = plan(cfg, cells)
        episodes = compact(play_plan(cfg, specs, cells, seeds, configs))  # stored is summarised
        summary = summarize(episodes)
        inputs = traffic_inputs(
            [c.key for c in cells], configs, [c.table for c in cells], seeds, asdict(cfg.behavior)
        )
        write_results(out, episodes, summary, inputs)
        models = model_records(specs)
        if len(models):
            write_atomic(out / MODELS, lambda tmp: models.to_csv(tmp, index=False))
        drawn = plot_comparison(summary, out / "comparison.png")
    if not drawn:
        print(f"comparison.png not drawn: {len(summary)} bars (at most {MAX_BARS})")
    if len(summary) <= MAX_BARS:
        print(format_table(summary))
    print(f"results in {out}")

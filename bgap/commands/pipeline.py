"""``bgap pipeline``: save or restore a search's trial log."""

from __future__ import annotations

import sys

from omegaconf import DictConfig

from bgap.common.cli import fail, older_command_line
from bgap.common.config import app, load
from bgap.common.errors import ConfigError
from bgap.experiments.pipeline import SCHEMAS, PipelineConfig


@app("pipeline", "bgap.pipeline", SCHEMAS, "the trial log is written whole or not")
def _hydra_main(dcfg: DictConfig) -> None:
    """Save or restore, one line each."""
    from bgap.experiments import trial_log  # optuna, loaded only when the command runs

    cfg: PipelineConfig = load(dcfg)
    storage = trial_log.storage_url(cfg.storage)
    if cfg.trials == "save":
        if not cfg.study:
            raise ConfigError("trials=save needs study=NAME (the search's study name)")
        n = trial_log.save(storage, cfg.study, cfg.log)
        hours, timed = trial_log.trial_hours(cfg.log)
        print(
            f"{n} finished trials of {cfg.study} -> {cfg.log} ({hours:.2f} h of trial time "
            f"over the {timed} whose times are known)"
        )
    else:
        n = trial_log.restore(storage, cfg.log)
        print(f"{n} trials from {cfg.log} -> {storage}; rerun the search's command to continue")


def main(argv: list[str] | None = None) -> None:
    """The Hydra app (``argv``: the arguments, for a script). The older command line still
    reads: ``trials save|restore LOG --storage DB [--study NAME]``."""
    if argv is not None:
        sys.argv[1:] = argv
    if sys.argv[1:2] in (["deps"], ["relock"]):
        fail(
            "bgap.pipeline",
            "deps and relock are a developer tool now: python "
            "tools/relock.py deps|relock in a checkout",
        )
    if sys.argv[1:2] == ["trials"]:  # the older form: trials ACTION LOG --options
        older = [f"{k}={v}" for k, v in zip(("trials", "log"), sys.argv[2:4], strict=False)]
        sys.argv[1:] = [*older, *sys.argv[4:]]
    older_command_line()
    _hydra_main()

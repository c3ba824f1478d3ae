"""``bgap train``: train navigation policies (one or many seeds, resumable)."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from bgap.common.config import app, load
from bgap.common.errors import ConfigError
from bgap.common.runs import CHECKPOINT_STATE
from bgap.experiments.config import SCHEMAS, ExperimentConfig
from bgap.experiments.train import task_folder_name, trainings
from bgap.experiments.training import member_configs, run_dir_for


@app("train", "bgap.train", SCHEMAS)
def main(dcfg: DictConfig) -> None:
    cfg: ExperimentConfig = load(dcfg)
    cfgs = member_configs(cfg)
    if cfg.resume:  # a user's resume=true with nothing to resume is a typo, not a new run
        where = [Path(cfg.run_dir)] if cfg.run_dir else [run_dir_for(c) for c in cfgs]
        if cfg.cluster.address and cfg.cluster.storage:  # where Ray tasks keep checkpoints
            where += [Path(cfg.cluster.storage) / task_folder_name(c) for c in cfgs]
        if not any(d.exists() for d in where):
            raise ConfigError(
                f"resume=true: nothing to resume at {where[0]} (no such folder); check "
                "run_dir, or drop resume=true to start a new training"
            )
        saved = (CHECKPOINT_STATE, "model.zip")  # a checkpoint, or a finished training
        if not any(any(d.rglob(name)) for d in where if d.exists() for name in saved):
            raise ConfigError(
                f"resume=true: nothing to resume at {where[0]} (no checkpoint was written "
                "there yet); drop resume=true to start the training anew"
            )
    for run_dir in trainings(cfgs):
        print(f"model: {run_dir / 'model.zip'}")

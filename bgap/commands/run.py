"""``bgap run``: the main job: train both policies, evaluate them beside the baselines, compare."""

from __future__ import annotations

from omegaconf import DictConfig

from bgap.common.config import app, load
from bgap.experiments.config import SCHEMAS
from bgap.experiments.run import run
from bgap.runner.cluster import connected


@app(
    "run",
    "bgap.run",
    SCHEMAS,
    "finished trainings are kept and reused by a rerun of the same command",
)
def main(dcfg: DictConfig) -> None:
    cfg = load(dcfg)
    with connected(cfg.cluster):  # a cluster out of reach: one line before anything is written
        run(cfg, dcfg)

"""``bgap tune_rule``: tune the rule-based ego's IDM and MOBIL on validation episodes."""

from __future__ import annotations

from omegaconf import DictConfig

from bgap.common.config import app, load
from bgap.experiments.tune_rule import SCHEMAS, run


@app("tune_rule", "bgap.tune_rule", SCHEMAS)
def main(dcfg: DictConfig) -> None:
    run(load(dcfg))

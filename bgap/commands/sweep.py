"""``bgap sweep``: an Optuna search over reward or learner settings."""

from __future__ import annotations

import json

from omegaconf import DictConfig

from bgap.common.config import app, load
from bgap.common.presets import selection_hint
from bgap.experiments.config import SCHEMAS, SweepConfig
from bgap.experiments.sweep import chosen_trial, sweep, write_outputs


@app(
    "sweep",
    "bgap.sweep",
    SCHEMAS,
    "every finished trial is kept in the Optuna study; rerun the same command to continue",
)
def main(dcfg: DictConfig) -> None:
    cfg: SweepConfig = load(dcfg)
    study = sweep(cfg)
    paths = write_outputs(study, cfg)
    chosen = chosen_trial(study, cfg)
    print(
        json.dumps(
            {
                "chosen_trial": chosen.number,
                "params": chosen.params,
                **{k: v for k, v in chosen.user_attrs.items() if k != "overrides"},
            },
            indent=1,
            default=str,
        )
    )
    for name, path in paths.items():
        print(f"{name}: {path}")
    for name, path in paths.items():
        if name.startswith("preset_"):
            print(f"use the preset with: {selection_hint(path.parent.name, path)}")

"""``bgap calibrate``: fit the driver classes to CMetric targets or to a labelled table."""

from __future__ import annotations

import json

from omegaconf import DictConfig

from bgap.calibration.calibrate import calibrate, preset_file, report_dir, storage_url
from bgap.calibration.config import SCHEMAS, CalibrateAppConfig
from bgap.calibration.data import calibrate_to_data, observe
from bgap.common.config import app, load
from bgap.common.presets import selection_hint
from bgap.common.runs import save_run_metadata


@app(
    "calibrate",
    "bgap.calibrate",
    SCHEMAS,
    "every finished trial is kept in the Optuna study; rerun the same command to continue",
)
def main(dcfg: DictConfig) -> None:

    cfg: CalibrateAppConfig = load(dcfg)
    # a target table that cannot be read is refused before the folder is written, which would
    # then refuse the corrected command as "other settings"
    observed = observe(cfg) if cfg.calibrate.target else None
    save_run_metadata(report_dir(cfg), dcfg)
    if observed is not None:  # to a labelled table's statistics (bgap.calibrate_data)
        summary = calibrate_to_data(
            cfg, storage_url(cfg), preset_file(cfg), report_dir(cfg), observed=observed
        )
    else:
        summary = calibrate(cfg)
    print(json.dumps(summary, indent=2))
    hint = selection_hint("behavior", preset_file(cfg))
    print(f"preset: {preset_file(cfg)} (use: {hint}); report: {report_dir(cfg)}")

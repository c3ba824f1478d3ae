"""``bgap zoo``: export trained run folders into the zoo."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from bgap.common.config import app, load
from bgap.common.errors import ConfigError
from bgap.common.runs import MODEL, run_folders
from bgap.experiments.zoo import SCHEMAS, ZooConfig, export
from bgap.runner.locks import exclusive


@app("zoo", "bgap.zoo", SCHEMAS)
def main(dcfg: DictConfig) -> None:
    cfg: ZooConfig = load(dcfg)
    runs = Path(cfg.runs)
    found = [runs] if (runs / MODEL).exists() else run_folders(runs)
    if not found:
        raise ConfigError(f"runs={cfg.runs!r} holds no run folder with {MODEL}; train first")
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    with exclusive(out):
        written = [export(run, cfg.arm, out, cfg.checkpoint) for run in found]
    size = sum(p.stat().st_size for p in written)
    print(f"{len(written)} policies in {out} ({size / 1e6:.1f} MB)")

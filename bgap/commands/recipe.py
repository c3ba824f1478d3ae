"""``bgap recipe``: search the training recipe and check its best candidates on more seeds."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from bgap.common.config import app, load
from bgap.common.presets import selection_hint
from bgap.common.runs import save_run_metadata
from bgap.experiments.compat import upgrade
from bgap.experiments.config import SCHEMAS, RecipeConfig
from bgap.experiments.recipe import GROUPS, recipe


@app(
    "recipe",
    "bgap.recipe",
    SCHEMAS,
    "every finished sweep trial and training is kept; rerun the same command to continue",
)
def main(dcfg: DictConfig) -> None:

    cfg: RecipeConfig = load(dcfg)
    out = Path(cfg.out or Path(cfg.root) / "recipe")
    save_run_metadata(out, dcfg, upgrade=upgrade)
    paths = recipe(cfg)
    print((out / "table.md").read_text())
    for name, path in paths.items():
        print(f"{name}: {path}")
    for group in GROUPS:
        path = paths[f"preset_{group}"]
        print(f"use the preset with: {selection_hint(group, path)}")

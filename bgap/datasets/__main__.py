"""``python -m bgap.datasets sumo [sumo.flow=0.6 sumo.car_following=IDM episodes=30 ...]``.

Writes ``<out>/trajectories.parquet`` (bgap's trajectory table, labelled ``aggressive``,
``conservative`` and ``ego``), ``config.yaml`` and ``command.txt``; default
``out=outputs/datasets/<source>``. A folder holding a dataset of other settings is
refused; the same settings are recorded again identically (same seeds, same table).
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig
from tqdm import tqdm

from bgap.cli import bare_first_argument
from bgap.config import DatasetsConfig, app, load
from bgap.runs import save_run_metadata


def make(cfg: DatasetsConfig, dcfg, progress: bool = True) -> Path:
    """Record the dataset ``cfg.source`` names into ``cfg.out``."""
    from bgap.datasets.sumo import record, sumo_home

    sumo_home()  # a missing optional extra fails before any folder is made
    out = save_run_metadata(cfg.out or f"outputs/datasets/{cfg.source}", dcfg)
    with tqdm(total=cfg.episodes, unit="ep", desc=cfg.source, disable=not progress) as bar:
        table = record(cfg.sumo, cfg.episodes, cfg.seed, bar.update)
    path = out / "trajectories.parquet"
    table.to_parquet(path, index=False)
    counts = table.drop_duplicates(["episode", "vehicle_id"]).label.value_counts().to_dict()
    print(f"{len(table)} rows, {cfg.episodes} episodes, vehicles per class {counts} -> {path}")
    return path


@app("datasets", "bgap.datasets", "nothing was saved; rerun the command")
def _hydra_main(dcfg: DictConfig) -> None:
    make(load(dcfg), dcfg)


def main() -> None:
    """The Hydra app; a first argument without ``=`` names the source (``sumo``)."""
    bare_first_argument("source")
    _hydra_main()


if __name__ == "__main__":
    main()

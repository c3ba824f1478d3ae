"""``python -m bgap.datasets sumo [sumo.flow=0.6 sumo.car_following=IDM episodes=30 ...]``,
``python -m bgap.datasets highd PATH``, ``python -m bgap.datasets ngsim PATH``.

Writes ``<out>/trajectories.parquet`` (bgap's trajectory table: SUMO's labelled
``aggressive``, ``conservative`` and ``ego``; highD's and NGSIM's by vehicle class),
``config.yaml`` and ``command.txt``; default ``out=outputs/datasets/<source>``. A folder
holding a dataset of other settings is refused; the same settings give the same table.
"""

from __future__ import annotations

from importlib import import_module
from pathlib import Path

from omegaconf import DictConfig
from tqdm import tqdm

from bgap.cmetric.io import load_trajectories
from bgap.common.cli import bare_first_argument
from bgap.common.config import app, load
from bgap.common.runs import save_run_metadata, write_atomic
from bgap.datasets.config import SCHEMAS, DatasetsConfig
from bgap.datasets.sumo import record, sumo_home
from bgap.runner.locks import exclusive


def make(cfg: DatasetsConfig, dcfg, progress: bool = True) -> Path:
    """Record (SUMO) or convert (highD, NGSIM) the dataset ``cfg.source`` names into
    ``cfg.out``."""
    out = Path(cfg.out or f"outputs/datasets/{cfg.source}")
    if cfg.source == "sumo":
        sumo_home()  # a missing optional extra fails before any folder is made
    with exclusive(out):  # a second command writing the same folder is refused
        if cfg.source == "sumo":
            save_run_metadata(out, dcfg)
            with tqdm(total=cfg.episodes, unit="ep", desc=cfg.source, disable=not progress) as bar:
                table = record(cfg.sumo, cfg.episodes, cfg.seed, bar.update)
            load_trajectories(table)  # CMetric reads what is written, a recording too
        else:
            table = import_module(f"bgap.datasets.{cfg.source}").read(cfg.path)
            load_trajectories(table)  # a file's defect fails here, before anything is written
            save_run_metadata(out, dcfg)
        path = out / "trajectories.parquet"
        write_atomic(path, lambda p: table.to_parquet(p, index=False))
    counts = table.drop_duplicates(["episode", "vehicle_id"]).label.value_counts().to_dict()
    scenes = table.episode.nunique()
    print(f"{len(table)} rows, {scenes} scenes, vehicles per class {counts} -> {path}")
    return path


@app("datasets", "bgap.datasets", SCHEMAS, "nothing was saved; rerun the command")
def _hydra_main(dcfg: DictConfig) -> None:
    make(load(dcfg), dcfg)


def main() -> None:
    """The Hydra app; leading arguments without ``=`` name the source and the path."""
    bare_first_argument("source", "path")
    _hydra_main()


if __name__ == "__main__":
    main()

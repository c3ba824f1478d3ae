"""``bgap select``: keep the best of each group of training seeds on validation."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from bgap.common.cli import older_command_line
from bgap.common.config import app, load
from bgap.experiments.select import SCHEMAS, SelectConfig, select


@app("select", "bgap.select", SCHEMAS, "nothing was kept; remove out= and rerun the command")
def _hydra_main(dcfg: DictConfig) -> None:
    cfg: SelectConfig = load(dcfg)
    out = Path(cfg.out)
    table_dir = Path(cfg.table) if cfg.table else out
    table = select(Path(cfg.runs), out, table_dir, cfg.group, cfg.episodes, cfg.workers)
    kept = table[table.kept]
    for r in kept.itertuples():
        print(f"kept {r.density} {r.policy} group {r.group}: seed {r.seed} (score {r.score:.2f})")
    print(f"kept runs in {out}; table in {table_dir / 'selection.md'}")


def main() -> None:
    """The Hydra app. The older command line still reads: the runs folder first, then
    ``--group``, ``--episodes``, ``--out``, ``--table`` and ``--workers``."""
    older_command_line("runs")
    _hydra_main()

"""``python -m bgap.cmetric.boundary tables=[...] cmetric_preset=tuned out=DIR [preset=PATH]``: fix
the class boundary on labelled tables (:mod:`bgap.cmetric.boundary`) and write its report
and preset."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import DictConfig, OmegaConf

from bgap.cmetric.boundary import fit
from bgap.cmetric.config import SCHEMAS, BoundaryConfig
from bgap.common.cli import older_command_line
from bgap.common.config import app, load
from bgap.common.errors import ConfigError
from bgap.common.plotting import pyplot
from bgap.common.runs import write_atomic
from bgap.common.vocab import AGGRESSIVE, CONSERVATIVE


def _tables(sources: list[str]) -> list[Path]:
    found = []
    for source in map(Path, sources):
        found += sorted(source.rglob("trajectories.parquet")) if source.is_dir() else [source]
    if not found:
        raise ConfigError(f"no trajectories.parquet in {sources}")
    return found


def _plot(scored: pd.DataFrame, boundary: float, path: Path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 3.4))
    bins = np.linspace(scored.aggressiveness.min(), scored.aggressiveness.max(), 40)
    for label, colour in ((CONSERVATIVE, "tab:blue"), (AGGRESSIVE, "tab:red")):
        ax.hist(
            scored[scored.label == label].aggressiveness,
            bins,
            alpha=0.5,
            color=colour,
            label=label,
            density=True,
        )
    ax.axvline(boundary, color="k", ls="--", label=f"boundary {boundary:.3f}")
    ax.set_xlabel("CMetric aggressiveness")
    ax.set_ylabel("density of vehicles")
    ax.legend(fontsize=8)
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=110))
    plt.close(fig)


def fix_boundary(cfg: BoundaryConfig) -> Path:
    """Fit, report and write the preset of ``cfg``; returns the preset's path. A rerun into
    an earlier run's files is refused (the pipeline's stage starts empty: DVC removes its
    outputs)."""
    out = Path(cfg.out)
    preset = Path(cfg.preset or out / f"{cfg.cmetric_preset}.yaml")
    earlier = [str(p) for p in (out / "boundary.json", preset) if p.exists()]
    if earlier:
        raise ConfigError(
            f"{', '.join(earlier)} exist(s) from an earlier run; give another "
            "out= (and preset=), or remove them"
        )
    result, report, scored = fit(_tables(cfg.tables), cfg.cmetric_preset)
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "boundary.json", json.dumps(report, indent=1))
    write_atomic(
        out / "command.txt", " ".join(["python -m bgap.cmetric.boundary", *sys.argv[1:]]) + "\n"
    )
    _plot(scored, result.boundary, out / "scores.png")
    note = (
        f"Class boundary of cmetric={cfg.cmetric_preset}, fixed by python -m "
        f"bgap.cmetric.boundary on {len(result.tables)} labelled tables (Youden's J on "
        f"their even episodes); report: {out / 'boundary.json'}"
    )
    preset.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(preset, f"# {note}\n{OmegaConf.to_yaml(OmegaConf.structured(result))}")
    tuned = report["tuning_balanced_accuracy"]
    print(
        f"boundary {result.boundary:.4f}: balanced accuracy {tuned:.3f} (even episodes), "
        f"{result.balanced_accuracy:.3f} (odd); preset {preset}"
    )
    return preset


@app("cmetric_boundary", "bgap.cmetric.boundary", SCHEMAS, "nothing was written; rerun the command")
def _hydra_main(dcfg: DictConfig) -> None:
    fix_boundary(load(dcfg))


def main() -> None:
    """The Hydra app. The older command line still reads: leading tables, ``--cmetric``
    (``cmetric_preset=``), ``--out`` and ``--preset``."""
    older_command_line("tables", listed=True, renamed={"cmetric": "cmetric_preset"})
    _hydra_main()


if __name__ == "__main__":
    main()

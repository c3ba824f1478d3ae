"""``bgap figures``: the study's figures, claims and results page from its evaluations."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from bgap.analysis.figures import SCHEMAS, WRITTEN, FiguresConfig
from bgap.analysis.plots import make_figures
from bgap.common.cli import older_command_line
from bgap.common.config import app, load
from bgap.common.errors import ConfigError


@app("figures", "bgap.figures", SCHEMAS, "the files written so far are in out; rerun the command")
def _hydra_main(dcfg: DictConfig) -> None:
    cfg: FiguresConfig = load(dcfg)
    earlier = [n for n in WRITTEN if (Path(cfg.out) / n).exists()]
    if earlier:  # a rerun refuses: it never overwrites an earlier result (the pipeline's
        # stage starts from an empty set: DVC removes a stage's outputs before it runs)
        raise ConfigError(
            f"out={cfg.out} holds the results of an earlier run ({', '.join(earlier)}); give "
            "another out=, or remove them to make them again"
        )
    paths = make_figures(cfg.evaluations, cfg.out, cfg.stock)
    for name, path in paths.items():
        print(f"{name}: {path}")


def main() -> None:
    """The Hydra app. The older command line still reads: leading arguments without ``=``
    are the evaluations, ``--out DIR`` is ``out=DIR`` and ``--stock A B`` is ``stock=[A,B]``."""
    older_command_line("evaluations", listed=True, lists=("stock",))
    _hydra_main()

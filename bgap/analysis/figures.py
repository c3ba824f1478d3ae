"""The paper's figures and claims from fresh numbers: ``python -m bgap.figures RESULTS_DIR``.

Reads the evaluation folders ``bgap.evaluate`` wrote (``episodes.parquet``, ``models.csv``
and ``config.yaml`` each; a folder of such folders, such as the pipeline's
``results/evaluation``, stands for all of them): the study's trainings (named by their run
folders, ``[...]/<arm>/<density>/<density>-<behavior_rich|default>-s<seed>``; a bare
``<density>-<family>-s<seed>`` is arm ``main``), the baselines, and the same policies in
highway-env's stock traffic (an evaluation with ``behavior=stock``, or any folder given with
``--stock``). Nothing else: no model and no run folder, so a clone recomputes every figure
from the committed episodes. Writes to ``--out`` (default ``outputs/figures``; the
pipeline's stage: ``results/``):

- ``cells.csv``: per arm, policy family and cell, the mean over training seeds of collision
  %, speed and lane changes with 95% intervals, ``n_seeds`` and ``n_episodes``, the crash
  split, and ``duplicate_of`` where a mix gives the same traffic as another one;
- ``claims.csv``: each of the paper's claims (:data:`bgap.analysis.paper.CLAIMS`) with our
  difference, its 95% interval and the Holm-corrected one, p-values, sample sizes and the
  verdict;
- ``own_traffic.csv``: whether each trained policy beats idle in its own training traffic;
- ``yardsticks.csv``: each learned policy family against each hand-built driver, paired on
  the same episodes (:mod:`bgap.analysis.yardsticks`);
- ``table2.md``: Table II with every policy of ours in the same cell;
- ``figures/``: ``fig4.png`` (and ``fig4_<arm>.png`` per other arm), ``fig6.png``,
  ``paper_vs_ours.png`` (the paper's bars beside ours), ``ablation.png`` (training mix);
- ``README.md`` and ``metrics.json``.

Statistics (:mod:`bgap.analysis.intervals`): training seeds are the independent units, and
every seed plays the same episodes. A difference between two policy families is a two-way
random-effects interval over their (unrelated) seeds and the shared episodes; one model in
two traffic conditions is paired by training seed; two perception radii play the same
scenes, so their per-scene differences are read. Holm's correction runs within each claim
family (the main arm's claims confirmatory, every other arm's exploratory); the verdict
follows from the corrected p-values.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bgap.analysis.plots import make_figures
from bgap.common.cli import OneLineParser, run

WRITTEN = ("README.md", "cells.csv", "claims.csv", "own_traffic.csv", "yardsticks.csv",
           "table2.md", "metrics.json", "figures")  # fmt: skip
"""What :func:`bgap.analysis.plots.make_figures` writes into ``--out``."""


def main(argv: list[str] | None = None) -> None:
    parser = OneLineParser(
        prog="bgap.figures",
        description=__doc__.split("\n\n")[0] + " What it writes: docs/pipeline.md.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("evaluations", nargs="+", help="bgap.evaluate's output folders, or "
                        "folders of them (the pipeline: results/evaluation)")  # fmt: skip
    parser.add_argument("--stock", nargs="*", default=[],
                        help="evaluation folders to read as stock traffic (one run with "
                        "behavior=stock is read so anyway)")  # fmt: skip
    parser.add_argument(
        "--out",
        default="outputs/figures",
        help="where figures and tables go (the pipeline: results)",
    )
    args = parser.parse_args(argv)
    earlier = [n for n in WRITTEN if (Path(args.out) / n).exists()]
    if earlier:  # a rerun refuses: it never overwrites an earlier result (the pipeline's
        # stage starts from an empty set: DVC removes a stage's outputs before it runs)
        parser.exit(2, f"bgap.figures: {args.out} holds the results of an earlier run "
                    f"({', '.join(earlier)}); give another --out, or remove them to make them "
                    "again\n")  # fmt: skip
    paths = run(
        "bgap.figures",
        lambda: make_figures(args.evaluations, args.out, args.stock),
        f"the files written so far are in {args.out}; rerun the command",
    )
    for name, path in paths.items():
        print(f"{name}: {path}")


if __name__ == "__main__":
    main()

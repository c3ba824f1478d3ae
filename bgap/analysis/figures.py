"""The paper's figures and claims from fresh numbers:
``python -m bgap.figures evaluations=[RESULTS_DIR] out=DIR``.

Reads the evaluation folders ``bgap.evaluate`` wrote (``episodes.parquet``, ``models.csv``
and ``config.yaml`` each; a folder of such folders, such as the pipeline's
``results/evaluation``, stands for all of them): the study's trainings (named by their run
folders, ``[...]/<arm>/<density>/<density>-<behavior_rich|default>-s<seed>``; a bare
``<density>-<family>-s<seed>`` is arm ``main``), the baselines, and the same policies in
highway-env's stock traffic (an evaluation with ``behavior=stock``, or any folder given in
``stock=[...]``). Nothing else: no model and no run folder, so a clone recomputes every
figure from the committed episodes. Writes to ``out`` (default ``outputs/figures``; the
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
- ``aggregates.csv``: rliable's views of every training seed in every cell against the
  hand-built drivers (:mod:`bgap.analysis.aggregates`);
- ``table2.md``: Table II with every policy of ours in the same cell;
- ``figures/``: ``fig4.png`` (and ``fig4_<arm>.png`` per other arm), ``fig6.png``,
  ``paper_vs_ours.png`` (the paper's bars beside ours), ``ablation.png`` (training mix),
  ``profiles.png`` (performance profiles);
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

from dataclasses import dataclass, field

WRITTEN = (
    "README.md",
    "cells.csv",
    "claims.csv",
    "own_traffic.csv",
    "yardsticks.csv",
    "aggregates.csv",
    "table2.md",
    "metrics.json",
    "figures",
)
"""What :func:`bgap.analysis.plots.make_figures` writes into ``out``."""


@dataclass
class FiguresConfig:
    """``python -m bgap.figures``: the results page from evaluation folders."""

    evaluations: list[str] = field(default_factory=lambda: ["results/evaluation"])
    """bgap.evaluate's output folders, or folders of them (the pipeline: results/evaluation)."""
    stock: list[str] = field(default_factory=list)
    """Evaluation folders read as stock traffic (one run with behavior=stock is read so anyway)."""
    out: str = "outputs/figures"
    """Where the page, its tables and figures go (the pipeline: results)."""


SCHEMAS = ((None, "base_figures", FiguresConfig),)

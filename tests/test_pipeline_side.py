"""The pipeline's stages that share nothing with the study's chain, run in their own
throwaway repository beside tests/test_pipeline.py: CMetric's datasets and parameter search,
and the backend parity study."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from tests.pipeline_repo import make_repo, run

# 70 s on 2 cores, under -m slow: the default suite checks these stages' parts
# (tests/test_cmetric_search.py, the boundary in tests/test_cmetric.py, the parity study in
# tests/test_sim.py) and their dvc.yaml entries (tests/test_layout.py, tests/test_reproducible.py)
pytestmark = pytest.mark.slow

STAGES = {"cmetric_data", "cmetric_sumo", "cmetric_search", "cmetric_boundary", "parity"}


def _tiny(params: dict) -> None:
    params["parity"] = {"episodes": 3, "duration": 2}
    search = params["cmetric_search"]  # two small bgap tables, one SUMO run, two trials
    search.update(trials=2, radii="[null]")
    data, sumo = search["data"], search["sumo"]
    search["data"] = {
        k: {**data[k], "episodes": 4} for k in ("sparse-paper-mix50", "sparse-paper-mix80")
    }
    search["sumo"] = {"sumo-krauss-dense": {**sumo["sumo-krauss-dense"], "episodes": 1}}


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory) -> Path:
    return make_repo(tmp_path_factory.mktemp("side"), STAGES, _tiny)


def test_cmetric_search_scores_every_table_and_writes_a_valid_preset(pipeline):
    from bgap.cmetric.params import CMetricConfig
    from bgap.common.presets import load_preset

    # every bgap table in both parts, SUMO's in validation only
    auc = pd.read_csv(pipeline / "results/cmetric/auc.csv")
    assert set(zip(auc.dataset, auc.part, strict=True)) == {
        ("sparse-paper-mix50", "search"), ("sparse-paper-mix50", "validation"),
        ("sparse-paper-mix80", "search"), ("sparse-paper-mix80", "validation"),
        ("sumo-krauss-dense", "validation"),
    }  # fmt: skip
    tuned = load_preset(CMetricConfig, pipeline / "results/presets/cmetric/tuned.yaml")
    assert tuned.name == "tuned"
    # the written preset is the one the report scored: SUMO's table rescored with it here
    # gives the report's AUC (pairwise comparison of every aggressive and conservative
    # vehicle, ties half, unscored vehicles at the median: an O(n^2) count, not ranks)
    from bgap.cmetric.score import score_trajectories

    table = pd.read_parquet(
        pipeline / "outputs/pipeline/cmetric_sumo/sumo-krauss-dense/trajectories.parquet"
    )
    v = score_trajectories(table, tuned).vehicles
    v = v[v.label.isin(["aggressive", "conservative"])]
    s = v.aggressiveness.fillna(v.aggressiveness.median()).to_numpy()
    agg, con = s[(v.label == "aggressive").to_numpy()], s[(v.label == "conservative").to_numpy()]
    pairs = (agg[:, None] > con[None, :]).sum() + 0.5 * (agg[:, None] == con[None, :]).sum()
    row = auc[(auc.preset == "tuned") & (auc.dataset == "sumo-krauss-dense")]
    assert row.auc.iloc[0] == pytest.approx(pairs / (len(agg) * len(con)), abs=1e-12)


def test_parity_writes_one_row_per_backend_and_mix(pipeline):
    parity = pd.read_csv(pipeline / "results/parity/parity.csv")
    assert len(parity) > 0 and (pipeline / "results/parity/parity.png").stat().st_size > 0
    assert "up to date" in run(["dvc", "repro"], pipeline)


def test_the_class_boundary_is_fixed_on_the_tuned_scores_of_bgaps_tables(pipeline):
    """cmetric_boundary reads every cmetric_data table with the tuned preset the search
    wrote: its preset loads, names both tables, and its boundary is the Youden threshold of
    their even episodes' scores, recomputed here."""
    import json

    from bgap.cmetric.boundary import ClassBoundary, labelled_scores, youden_threshold
    from bgap.cmetric.params import CMetricConfig
    from bgap.common.presets import load_preset

    fixed = load_preset(ClassBoundary, pipeline / "results/presets/cmetric/boundary/tuned.yaml")
    assert len(fixed.tables) == 2 and fixed.cmetric == "tuned"
    report = json.loads((pipeline / "results/cmetric/boundary/boundary.json").read_text())
    assert report["boundary"] == fixed.boundary
    tuned = load_preset(CMetricConfig, pipeline / "results/presets/cmetric/tuned.yaml")
    tables = sorted((pipeline / "outputs/pipeline/cmetric_data").rglob("trajectories.parquet"))
    scored = labelled_scores(tables, tuned)
    even = scored[scored.episode.astype(int) % 2 == 0]
    assert fixed.boundary == youden_threshold(even.aggressiveness.to_numpy(),
                                              even.positive.to_numpy())  # fmt: skip

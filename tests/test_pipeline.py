"""The study's DVC pipeline end to end (calibrate, recipe, train, evaluate, figures) on a
tiny profile, in a throwaway git repository. The stages that share nothing with it (CMetric's
search, the backend parity) run beside it: tests/test_pipeline_side.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from tests.pipeline_repo import run
from tools.relock import replay_cells

STAGES = {"calibrate", "recipe", "train", "zoo", "replay_data", "evaluate", "evaluate_baselines",
          "figures"}  # fmt: skip


def _tiny(params: dict) -> None:
    params.update(profile="tiny", grid="tiny", eval_episodes=4)
    # the study in miniature: the main arm (the other arms are the same stages with other
    # parameters; several arms' figures and claims: tests/test_figures.py), sparse only, one
    # seed;
    # periodic validations so that each training selects a checkpoint by the study's rule
    validate = " profile.eval_every_episodes=2"
    params["validation_episodes"] = 4
    params["study"] = {
        key: {**value, "seeds": "[0]", "settings": value["settings"] + validate}
        for key, value in params["study"].items()
        if key == "main-sparse"
    }
    params["arms"] = ["main"]
    params["zoo"] = {"main-sparse": params["zoo"]["main-sparse"]}
    params["calibrate"]["trials"] = 2
    params["recipe"].update(profile="tiny", trials=2, candidates=1, check_episodes=10)
    params["recipe"]["check_seeds"] = "[0,1]"  # the fewest the check accepts
    params["recipe"]["sweep_episodes"] = 4
    # replayed traffic: one short SUMO scene of one sparse table
    params["replay"].update(scenes=1, duration=30)
    params["replay"]["tables"] = {"sumo-idm-sparse": params["replay"]["tables"]["sumo-idm-sparse"]}
    params["replay"]["cells"] = replay_cells(params)


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory) -> Path:
    from tests.pipeline_repo import make_repo

    return make_repo(tmp_path_factory.mktemp("study"), STAGES, _tiny)


def _colour_pixels(path: Path, colour: str) -> int:
    """Pixels of a PNG within a small distance of a matplotlib colour."""
    import matplotlib.colors as mcolors
    import matplotlib.image as mimage

    image = mimage.imread(path)[..., :3]
    return int((np.abs(image - np.array(mcolors.to_rgb(colour))).max(axis=-1) < 0.02).sum())


def test_every_stage_writes_outputs_consistent_with_its_inputs(pipeline):
    import json

    from bgap.common.presets import load_preset
    from bgap.traffic.behaviors import BehaviorConfig

    for name in (
        "outputs/pipeline/runs/main/sparse/sparse-behavior_rich-s0/best_model.zip",
        "outputs/pipeline/runs/main/sparse/sparse-default-s0/best_model.zip",
        "dvc.lock",
    ):
        assert (pipeline / name).stat().st_size > 0, name
    # calibrate: the preset it wrote is a valid behaviour preset, within the searched bounds
    preset = load_preset(BehaviorConfig, pipeline / "results/presets/behavior/calibrated.yaml")
    scores = json.loads((pipeline / "results/calibration/scores.json").read_text())
    assert scores["trials"] == {"aggressive": 2 * 3, "conservative": 2 * 3}  # 2 x 3 rounds
    assert 0.5 <= preset.aggressive.time_gap <= 2.5 and 20 <= preset.aggressive.v0 <= 45
    # figures: every cell of cells.csv is the mean of its evaluation episodes (one training
    # seed per arm here); run folders are <arm>/<density>/<density>-<family>-s<seed>
    evaluations = pipeline / "results/evaluation"
    episodes = pd.concat(
        [pd.read_parquet(p) for p in sorted(evaluations.glob("*/paper/episodes.parquet"))]
    )
    # committed per-episode measures: the ego's distance is its speed samples x 1 s each
    np.testing.assert_allclose(episodes.distance, episodes.avg_speed * episodes.steps, rtol=1e-6)
    parts = episodes.policy.str.extract(r"^(?:([a-z0-9]+)/[a-z]+/)?[a-z]+-(behavior_rich|default)")
    episodes["arm"] = parts[0].fillna("")
    episodes["family"] = parts[1].fillna(episodes.policy)
    assert set(episodes.arm) == {"", "main"}
    cells = pd.read_csv(pipeline / "results/cells.csv")
    cells["arm"] = cells.arm.fillna("")
    assert set(cells.traffic) == {"paper", "stock", "replay/sumo-idm-sparse/log",
                                  "replay/sumo-idm-sparse/reactive"}  # fmt: skip
    cells = cells[cells.traffic == "paper"]
    keys = ["arm", "family", "density", "mix", "radius"]
    want = episodes.groupby(keys).crashed.mean().mul(100).rename("want").reset_index()
    merged = cells.merge(want, on=keys, how="outer", indicator=True)
    assert (merged["_merge"] == "both").all(), merged[merged["_merge"] != "both"]
    np.testing.assert_allclose(merged.collision_pct, merged.want)
    assert (merged.collision_pct_lo <= merged.collision_pct).all()
    assert (merged.collision_pct <= merged.collision_pct_hi).all()
    assert (merged.collision_pct_lo < merged.collision_pct_hi).all()  # never of zero width
    # Table II: every policy's rate in the all-aggressive sparse cell, the baselines included
    table2 = (pipeline / "results/table2.md").read_text()
    main = cells[(cells.arm == "main") & (cells.family == "behavior_rich") & (cells.mix == 1.0)]
    assert f"recipe (main arm) | {main.collision_pct.iloc[0]:.2f} [" in table2
    assert "| idle (baseline) |" in table2 and "| rule (baseline) |" in table2
    # claims: Holm-corrected, sample sizes in their own columns
    claims = pd.read_csv(pipeline / "results/claims.csv")
    assert set(claims.arm) == {"main"}
    assert (claims.p_holm >= claims.p.fillna(1.0)).all()
    assert {"n_seeds_a", "n_episodes_a", "family"} <= set(claims)
    assert set(claims.family) == {"confirmatory", "exploratory: main, replay"}
    # the rehearsal trains one seed: no verdict without the spread between seeds
    assert set(claims.verdict) <= {"holds", "contradicted", "not significant", "too few seeds"}
    assert (claims.figure == "replay").sum() == 2  # both modes
    own = pd.read_csv(pipeline / "results/own_traffic.csv")
    assert set(zip(own.arm, own.family, strict=True)) == {
        ("main", "behavior_rich"), ("main", "default")
    }  # fmt: skip
    assert "Checkpoints the trainings kept" in (pipeline / "results/README.md").read_text()
    assert (pipeline / "results/figures/paper_vs_ours.png").stat().st_size > 0
    # Fig. 4 draws both families (green and grey); Fig. 6 one colour per radius
    fig4 = pipeline / "results/figures/fig4.png"
    assert _colour_pixels(fig4, "tab:green") > 50 and _colour_pixels(fig4, "tab:gray") > 50
    fig6 = pipeline / "results/figures/fig6.png"
    assert _colour_pixels(fig6, "C0") > 50 and _colour_pixels(fig6, "C1") > 50


def _set_eval_episodes(pipeline: Path, episodes: int) -> None:
    params = yaml.safe_load((pipeline / "params.yaml").read_text())
    params["eval_episodes"] = episodes
    (pipeline / "params.yaml").write_text(yaml.safe_dump(params))


def test_a_second_repro_does_nothing_and_a_parameter_marks_only_its_stages(pipeline):
    """The fast half of the check below: DVC's own status, without rerunning anything."""
    import json

    assert "up to date" in run(["dvc", "repro"], pipeline)
    _set_eval_episodes(pipeline, 5)
    try:
        changed = json.loads(run(["dvc", "status", "--json"], pipeline))
    finally:
        _set_eval_episodes(pipeline, 4)
    assert set(changed) == {"evaluate@main", "evaluate_baselines"}, changed
    assert "up to date" in run(["dvc", "repro"], pipeline)


@pytest.mark.slow
def test_a_parameter_reruns_only_its_stages(pipeline):
    _set_eval_episodes(pipeline, 5)
    out = run(["dvc", "repro"], pipeline)
    ran = {line.split("'")[1] for line in out.splitlines() if line.startswith("Running stage")}
    assert ran == {"evaluate@main", "evaluate_baselines", "figures"}, out[-2000:]


def test_figures_recompute_byte_for_byte_from_the_committed_episodes_alone(pipeline, tmp_path):
    """Without a model or run folder (a fresh clone has none), the figures stage rewrites
    every file it wrote before, byte for byte, from results/evaluation."""
    import shutil

    from dvc.repo import Repo

    with Repo(str(pipeline)) as repo:
        (stage,) = repo.stage.collect("figures")
        written = [pipeline / str(o.def_path) for o in stage.outs]
    files = [f for p in written for f in (sorted(p.rglob("*")) if p.is_dir() else [p])]
    files = [f for f in files if f.is_file()]
    before = {f: f.read_bytes() for f in files}
    assert len(before) >= 10
    shutil.move(pipeline / "outputs", tmp_path / "outputs")  # models and run folders gone
    try:
        for f in files:
            f.unlink()
        run(["dvc", "repro", "--force", "--single-item", "figures"], pipeline)
        changed = [str(f.relative_to(pipeline)) for f in files if f.read_bytes() != before[f]]
        assert not changed, changed
    finally:
        shutil.rmtree(pipeline / "outputs", ignore_errors=True)
        shutil.move(tmp_path / "outputs", pipeline / "outputs")

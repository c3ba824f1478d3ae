"""The DVC pipeline end to end on a tiny profile, in a throwaway git repository."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent


def _run(args: list[str], cwd: Path) -> str:
    env = {**os.environ, "PYTHONPATH": str(cwd)}  # the copied package, with its own conf/
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env['PATH']}"
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done.stdout + done.stderr


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory) -> Path:
    from tests.conftest import warm_compiled_kernels

    repo = tmp_path_factory.mktemp("study")
    warm_compiled_kernels()  # the copy below keeps numba's cache: no compiling per stage
    shutil.copytree(ROOT / "bgap", repo / "bgap")
    for name in ("dvc.yaml", "params.yaml", ".dvcignore"):
        shutil.copy(ROOT / name, repo / name)
    for made_by_a_stage in (
        "behavior/calibrated",
        "reward/recipe",
        "agent/recipe",
        "cmetric/tuned",
    ):
        (repo / f"bgap/conf/{made_by_a_stage}.yaml").unlink(missing_ok=True)
    params = yaml.safe_load((repo / "params.yaml").read_text())
    params.update(profile="tiny", grid="tiny", eval_episodes=4)
    # the study in miniature: both arms (the ablation arms train the same way, with one
    # family: tests/test_figures.py), sparse only, one seed each;
    # periodic validations so that each training selects a checkpoint
    validate = " profile.eval_every_episodes=2 profile.eval_during_training=4"
    params["study"] = {
        key: {**value, "seeds": "[0]", "settings": value["settings"] + validate}
        for key, value in params["study"].items()
        if key in ("main-sparse", "authors-sparse")
    }
    params["calibrate"]["trials"] = 2
    params["recipe"].update(profile="tiny", trials=2, candidates=1, check_episodes=10)
    params["recipe"]["check_seeds"] = "[0,1]"  # the fewest the check accepts
    params["recipe"]["sweep_episodes"] = 4
    params["parity"] = {"episodes": 3, "duration": 3}
    search = params["cmetric_search"]  # two small bgap tables, one SUMO run, two trials
    search.update(trials=2, radii="[null]")
    data, sumo = search["data"], search["sumo"]
    search["data"] = {
        k: {**data[k], "episodes": 4} for k in ("sparse-paper-mix50", "sparse-paper-mix80")
    }
    search["sumo"] = {"sumo-krauss-dense": {**sumo["sumo-krauss-dense"], "episodes": 1}}
    (repo / "params.yaml").write_text(yaml.safe_dump(params))
    _run(["git", "init", "-q"], repo)
    _run(["git", "-c", "user.email=t@t", "-c", "user.name=t", "add", "-A"], repo)
    _run(["git", "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "study"], repo)
    _run(["dvc", "init", "-q"], repo)
    _run(["dvc", "repro"], repo)
    return repo


def _colour_pixels(path: Path, colour: str) -> int:
    """Pixels of a PNG within a small distance of a matplotlib colour."""
    import matplotlib.colors as mcolors
    import matplotlib.image as mimage

    image = mimage.imread(path)[..., :3]
    return int((np.abs(image - np.array(mcolors.to_rgb(colour))).max(axis=-1) < 0.02).sum())


def test_every_stage_writes_outputs_consistent_with_its_inputs(pipeline):
    import json

    from bgap.behaviors import BehaviorConfig
    from bgap.presets import load_preset

    for name in (
        "outputs/pipeline/runs/main/sparse/sparse-behavior_rich-s0/best_model.zip",
        "outputs/pipeline/runs/main/sparse/sparse-default-s0/best_model.zip",
        "outputs/pipeline/runs/authors/sparse/sparse-default-s0/best_model.zip",
        "results/parity/parity.csv",
        "dvc.lock",
    ):
        assert (pipeline / name).stat().st_size > 0, name
    # calibrate: the preset it wrote is a valid behaviour preset, within the searched bounds
    preset = load_preset(BehaviorConfig, pipeline / "bgap/conf/behavior/calibrated.yaml")
    scores = json.loads((pipeline / "results/calibration/scores.json").read_text())
    assert scores["trials"] == {"aggressive": 2 * 3, "conservative": 2 * 3}  # 2 x 3 rounds
    assert 0.5 <= preset.aggressive.time_gap <= 2.5 and 20 <= preset.aggressive.v0 <= 45
    # figures: every cell of cells.csv is the mean of its evaluation episodes (one training
    # seed per arm here); run folders are <arm>/<density>/<density>-<family>-s<seed>
    episodes = pd.read_csv(pipeline / "outputs/pipeline/evaluation/episodes.csv")
    parts = episodes.policy.str.extract(r"^(?:([a-z0-9]+)/[a-z]+/)?[a-z]+-(behavior_rich|default)")
    episodes["arm"] = parts[0].fillna("")
    episodes["family"] = parts[1].fillna(episodes.policy)
    assert set(episodes.arm) == {"", "main", "authors"}
    cells = pd.read_csv(pipeline / "results/cells.csv")
    cells["arm"] = cells.arm.fillna("")
    assert set(cells.traffic) == {"paper", "stock"}
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
    # claims: both arms, Holm-corrected, sample sizes in their own columns
    claims = pd.read_csv(pipeline / "results/claims.csv")
    assert set(claims.arm) == {"main", "authors"}
    assert (claims.p_holm >= claims.p).all() and {"n_seeds_a", "n_episodes_a"} <= set(claims)
    assert set(claims.verdict) <= {"holds", "contradicted", "not significant"}
    own = pd.read_csv(pipeline / "results/own_traffic.csv")
    assert set(zip(own.arm, own.family, strict=True)) == {
        ("main", "behavior_rich"), ("main", "default"), ("authors", "behavior_rich"),
        ("authors", "default"),
    }  # fmt: skip
    assert "Checkpoints the trainings kept" in (pipeline / "results/README.md").read_text()
    # CMetric's search: every bgap table in both parts, SUMO's in validation only, and the
    # tuned preset it wrote is a valid CMetric config
    auc = pd.read_csv(pipeline / "results/cmetric/auc.csv")
    assert set(zip(auc.dataset, auc.part, strict=True)) == {
        ("sparse-paper-mix50", "search"), ("sparse-paper-mix50", "validation"),
        ("sparse-paper-mix80", "search"), ("sparse-paper-mix80", "validation"),
        ("sumo-krauss-dense", "validation"),
    }  # fmt: skip
    from bgap.cmetric.params import CMetricConfig

    tuned = load_preset(CMetricConfig, pipeline / "bgap/conf/cmetric/tuned.yaml")
    assert tuned.name == "tuned"
    for name in ("fig4_authors.png", "paper_vs_ours.png"):
        assert (pipeline / "results/figures" / name).stat().st_size > 0
    # Fig. 4 draws both families (green and grey); Fig. 6 one colour per radius
    fig4 = pipeline / "results/figures/fig4.png"
    assert _colour_pixels(fig4, "tab:green") > 50 and _colour_pixels(fig4, "tab:gray") > 50
    fig6 = pipeline / "results/figures/fig6.png"
    assert _colour_pixels(fig6, "C0") > 50 and _colour_pixels(fig6, "C1") > 50


def test_a_second_repro_does_nothing_and_a_parameter_reruns_only_its_stages(pipeline):
    assert "up to date" in _run(["dvc", "repro"], pipeline)
    params = yaml.safe_load((pipeline / "params.yaml").read_text())
    params["eval_episodes"] = 5
    (pipeline / "params.yaml").write_text(yaml.safe_dump(params))
    out = _run(["dvc", "repro"], pipeline)
    ran = {line.split("'")[1] for line in out.splitlines() if line.startswith("Running stage")}
    assert ran == {"evaluate", "evaluate_stock", "figures"}, out[-2000:]

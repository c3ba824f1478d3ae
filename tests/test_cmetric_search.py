"""The Optuna search over CMetric's parameters: split, crops, objective, resume, preset."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bgap.cmetric.score import label_auc, score_trajectories
from bgap.cmetric.search.params import CMetricSearchConfig, SearchDataset
from bgap.cmetric.search.study import crop, load_parts, objective_value
from bgap.common.config import validate
from bgap.common.errors import ConfigError
from tests.configs import compose
from tests.conftest import make_cfg


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """Two labelled tables as bgap.simulate writes them: sparse traffic at mixes 0.5 and
    0.8 (8 episodes of 30 s each; dense traffic would cost the suite time, not coverage)."""
    from bgap.datasets.simulate import simulate

    root = tmp_path_factory.mktemp("cmetric_data")
    for name, mix, episodes in (("mix50", 0.5, 8), ("mix80", 0.8, 8)):
        cfg = make_cfg("env=sparse", f"mix={mix}", "seed=7000", "env.duration=30", "backend=vector")
        folder = root / name
        folder.mkdir()
        simulate(cfg, episodes, False).to_parquet(folder / "trajectories.parquet")
    return root


def search_cfg(*overrides: str) -> tuple[CMetricSearchConfig, object]:
    dcfg = compose("cmetric_search", list(overrides))
    return validate(dcfg), dcfg


def test_crop_keeps_the_vehicles_near_the_ego_in_each_frame():
    rows = [  # frame 0: cars at 40 m and 60 m from the ego; frame 1: the 60 m car closes in
        (0, 0, 0.0, True), (0, 1, 40.0, False), (0, 2, 60.0, False),
        (1, 0, 10.0, True), (1, 1, 70.0, False), (1, 2, 55.0, False),
    ]  # fmt: skip
    table = pd.DataFrame(rows, columns=["frame", "vehicle_id", "x", "is_ego"])
    table["episode"], table["y"] = 0, 0.0
    kept = crop(table, 50.0)
    assert sorted(zip(kept.frame, kept.vehicle_id, strict=True)) == [(0, 0), (0, 1), (1, 0), (1, 2)]


def test_objective_is_the_worst_auc_less_the_flagged_excess():
    parts = [{"auc": 0.97, "flagged": 0.05}, {"auc": 0.95, "flagged": 0.0}]
    assert objective_value(parts, 0.10) == pytest.approx(0.95)
    parts.append({"auc": 0.99, "flagged": 0.30})  # 20 points over the allowance
    assert objective_value(parts, 0.10) == pytest.approx(0.79)
    # with z = 1, a part counts with its AUC less one standard error
    parts = [
        {"auc": 0.97, "auc_se": 0.05, "flagged": 0.0},
        {"auc": 0.95, "auc_se": 0.01, "flagged": 0.0},
    ]
    assert objective_value(parts, 0.10, z=1.0) == pytest.approx(0.92)


def test_auc_standard_error_is_hanley_and_mcneils():
    from bgap.cmetric.search.study import auc_standard_error

    # At chance the formula is exact: the Mann-Whitney statistic's null variance is
    # (n1 + n2 + 1) / (12 n1 n2), whatever the sample sizes
    for n1, n2 in ((1000, 1000), (51, 58), (7, 300)):
        exact = np.sqrt((n1 + n2 + 1) / (12 * n1 * n2))
        assert auc_standard_error(0.5, n1, n2) == pytest.approx(exact, rel=1e-12)
    # Hanley & McNeil's worked example (51 abnormal, 58 normal, A = 0.893): SE 0.032
    assert auc_standard_error(0.893, 51, 58) == pytest.approx(0.032, abs=1e-3)
    assert auc_standard_error(1.0, 30, 30) == 0.0  # perfect separation: no spread


def test_datasets_split_by_episode_parity_and_validation_data_never_tunes(data, tmp_path):
    (tmp_path / "other").mkdir()
    other = pd.read_parquet(data / "mix50" / "trajectories.parquet")
    other.to_parquet(tmp_path / "other" / "sumo_like.parquet")
    cfg, _ = search_cfg(
        f"data_dir={data}", f"validation_dir={tmp_path / 'other'}", "radii=[null,80]"
    )
    names = [(d.name, d.split) for d in cfg.datasets]
    assert names == [
        ("mix50", True), ("mix50@80m", True), ("mix80", True), ("mix80@80m", True),
        ("sumo_like", False), ("sumo_like@80m", False),
    ]  # fmt: skip
    parts = load_parts(cfg)
    by = {(p.dataset, p.part): p.table for p in parts}
    search, valid = by[("mix50", "search")], by[("mix50", "validation")]
    assert set(search.episode) == {0, 2, 4, 6} and set(valid.episode) == {1, 3, 5, 7}
    assert ("sumo_like", "search") not in by and len(by[("sumo_like", "validation")]) > 0
    cropped = by[("mix50@80m", "search")]
    assert len(cropped) < len(search)  # the crop dropped far vehicles
    # crops_tune=false: the crops validate on every episode and never tune
    cfg, _ = search_cfg(f"data_dir={data}", "radii=[null,80]", "crops_tune=false")
    assert [(d.name, d.split) for d in cfg.datasets] == [
        ("mix50", True), ("mix50@80m", False), ("mix80", True), ("mix80@80m", False),
    ]  # fmt: skip
    by = {(p.dataset, p.part): p.table for p in load_parts(cfg)}
    assert ("mix50@80m", "search") not in by
    assert set(by[("mix50@80m", "validation")].episode) == set(range(8))


def test_search_runs_resumes_writes_a_preset_that_loads_everywhere(data, tmp_path, monkeypatch):
    from bgap.commands.cmetric_search import run

    out = tmp_path / "search"
    overrides = [f"data_dir={data}", f"out={out}", "seed=3"]
    cfg, dcfg = search_cfg(*overrides, "trials=3")
    paths = run(cfg, dcfg, progress=False)
    report = (out / "report.md").read_text()
    auc = pd.read_csv(out / "auc.csv")
    assert set(auc.preset) == {"default", "robust", "tuned"}
    assert set(zip(auc.dataset, auc.part, strict=True)) == {
        (d, p) for d in ("mix50", "mix80") for p in ("search", "validation")
    }
    for name in ("roc.png", "scores.png", "convergence.png", "config.yaml", "command.txt"):
        assert (out / name).stat().st_size > 0
    # the saved config is the composed one, with the study's name it resumes by added
    import yaml
    from omegaconf import OmegaConf

    saved = yaml.safe_load((out / "config.yaml").read_text())
    composed = OmegaConf.to_container(dcfg, resolve=True)
    saved_study, composed_study = saved.pop("study"), composed.pop("study")
    assert saved == composed and composed_study is None
    # trial 0 is the starting preset: its value is the worst search AUC computed here anew
    import optuna

    summary = optuna.get_all_study_summaries(f"sqlite:///{out / 'optuna.db'}")
    assert len(summary) == 1 and summary[0].n_trials == 3
    assert summary[0].study_name == saved_study  # the name it resumes by, recorded
    study = optuna.load_study(
        study_name=summary[0].study_name, storage=f"sqlite:///{out}/optuna.db"
    )
    parts = [p for p in load_parts(cfg) if p.part == "search"]
    worst = min(
        label_auc(score_trajectories(p.table, cfg.cmetric).vehicles.query("label != 'ego'"))
        for p in parts
    )
    assert study.trials[0].value == pytest.approx(worst)
    # every trial checks the hand-built truths; one that breaks them is never the best
    assert study.trials[0].user_attrs["broken truths"] == []
    assert not study.best_trial.user_attrs["broken truths"]
    # the tuned row of the report is the best trial's parameters, and the preset loads
    monkeypatch.setenv("BGAP_PRESETS", str(out / "presets"))
    tuned = validate(compose("cmetric_app", ["cmetric=user_tuned", "input=x.csv"])).cmetric
    best = study.best_params
    if best["scale"] == "fixed":
        assert tuned.mu == pytest.approx(best["mu"]) and tuned.mu_spacing is None
    else:
        assert tuned.mu_spacing == pytest.approx(best["mu_spacing"])
    assert tuned.degree_rule == study.best_params["degree_rule"]
    assert paths["preset"] == out / "presets" / "cmetric" / "user_tuned.yaml"
    calibration = validate(compose("calibrate", ["cmetric=user_tuned"]))  # calibration too
    assert calibration.cmetric.window == pytest.approx(tuned.window)
    assert f"{study.best_value:.3f}" in report
    # a rerun with a larger budget continues the same study
    cfg, dcfg = search_cfg(*overrides, "trials=4")
    run(cfg, dcfg, progress=False)
    assert optuna.get_all_study_summaries(f"sqlite:///{out / 'optuna.db'}")[0].n_trials == 4
    # other data in the same folder is refused, nothing overwritten
    before = (out / "auc.csv").read_bytes()
    cfg, dcfg = search_cfg(*overrides, "trials=4", "radii=[60]")
    with pytest.raises(ConfigError, match="holds a result of other settings"):
        run(cfg, dcfg, progress=False)
    assert (out / "auc.csv").read_bytes() == before


def test_bad_search_settings_are_refused(data, tmp_path):
    with pytest.raises(ConfigError, match="give at least one table"):
        search_cfg()
    with pytest.raises(ConfigError, match="data_dir"):
        search_cfg(f"data_dir={tmp_path / 'missing'}")
    with pytest.raises(ConfigError, match="radii"):
        search_cfg(f"data_dir={data}", "radii=[-5]")
    with pytest.raises(ConfigError, match="one must tune"):
        search_cfg(f"validation_dir={data}")
    table = pd.read_parquet(data / "mix50" / "trajectories.parquet")
    table[table.label != "aggressive"].to_parquet(tmp_path / "one_class.parquet")
    cfg = CMetricSearchConfig(datasets=[SearchDataset(str(tmp_path / "one_class.parquet"))])
    with pytest.raises(ValueError, match="aggressive and conservative"):
        load_parts(cfg)

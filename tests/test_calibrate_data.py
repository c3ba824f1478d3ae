"""Calibration to a labelled trajectory table (bgap.calibrate_data): defects are refused
before any simulation; a short run writes its report, preset and resumable study."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from bgap.cmetric.io import TrajectoryError
from bgap.common.config import validate
from tests.configs import compose


@pytest.fixture(scope="module")
def target(tmp_path_factory):
    """bgap's own dense traffic under Table I (3 scenes of 12 s, seeds other than the
    calibration's), relabelled as a user's data would be ("AGG"/"normal")."""
    from bgap.agents.policies import rollout
    from bgap.traffic.scenario import env_config
    from tests.conftest import make_cfg

    cfg = make_cfg("env=dense", "mix=0.5", "env.duration=12")
    table = rollout(env_config(cfg), "idle", [50, 51, 52], "vector", record=True).trajectories
    table["label"] = table.label.map({"aggressive": "AGG", "conservative": "normal"}).fillna(
        table.label
    )
    path = tmp_path_factory.mktemp("target") / "target.parquet"
    table.to_parquet(path)
    return path


def _cfg(tmp_path, target, *overrides):
    return validate(
        compose(
            "calibrate",
            [f"calibrate.target={target}", "calibrate.episodes=1", "calibrate.duration=12",
             f"root={tmp_path}", *overrides],
        )
    )  # fmt: skip


def test_defective_targets_fail_before_any_simulation(tmp_path, target, monkeypatch):
    import bgap.calibration.data as cd

    def no_simulation(*args, **kwargs):
        raise AssertionError("simulated before the target was checked")

    monkeypatch.setattr(cd, "rollout", no_simulation)
    table = pd.read_parquet(target)
    for name, frame, message in (
        ("unlabelled", table.drop(columns="label"), "no 'label' column"),
        ("one_class", table.assign(label="AGG"), r"too few vehicles of class \{'conservative': 0"),
        ("few", table[table.vehicle_id < 8], "too few vehicles"),
    ):
        path = tmp_path / f"{name}.parquet"
        frame.to_parquet(path)
        with pytest.raises(TrajectoryError, match=message):
            cd.observe(_cfg(tmp_path, path))
    observed = cd.observe(_cfg(tmp_path, target))  # the labels map through the prefix
    assert observed.vehicles == {"aggressive": 60, "conservative": 60}
    assert observed.scene.lanes == 4 and observed.scene.aggressive_share == pytest.approx(0.5)
    assert set(observed.samples["aggressive"]) == {*cd.ALL_STATISTICS}
    assert all(b > 0 for b in observed.band["conservative"].values())


def test_a_short_calibration_writes_its_report_and_resumes(tmp_path, target):
    import optuna

    from bgap.calibration.calibrate import preset_file, report_dir, storage_url
    from bgap.calibration.data import calibrate_to_data, study_name
    from bgap.common.presets import load_preset
    from bgap.traffic.behaviors import BehaviorConfig

    # v0 and T only (8 searched parameters fewer), and a small sensitivity report
    small = [
        *(f"calibrate.bounds.{k}=null" for k in
          ("min_distance", "acc", "dec", "politeness", "min_acc_gain", "b_safe")),
        "calibrate.sensitivity_points=3", "calibrate.noise_repeats=1",
    ]  # fmt: skip
    cfg = _cfg(tmp_path, target, "calibrate.trials=2", "calibrate.aggressive_prefix=agg", *small)
    with pytest.warns(UserWarning, match="outside the target's noise band"):
        summary = calibrate_to_data(
            cfg, storage_url(cfg), preset_file(cfg), report_dir(cfg), progress=False
        )
    out = tmp_path / "calibration"
    stats = pd.read_csv(out / "statistics.csv")
    assert len(stats) == 10 and set(stats.statistic) == {
        "score", "speed", "headway", "acceleration", "lane_changes"
    }  # fmt: skip
    # trial 0 is the starting preset (Table I), so the calibrated traffic is at least as
    # close in total; the target is Table I's own traffic: most statistics within the band
    assert stats.table1_in_band.sum() >= 6
    assert (out / "statistics.png").stat().st_size > 10_000
    assert json.loads((out / "scores.json").read_text())["trials"] == 2 == summary["trials"]
    preset = load_preset(BehaviorConfig, tmp_path / "presets/behavior/user_calibrated.yaml")
    assert preset.converged is False
    # what the data pins down: the target is Table I's traffic and trial 0 is Table I, so
    # moving the aggressive class's v0 across 20-45 m/s must worsen the fit beyond the noise
    sens = pd.read_csv(out / "sensitivity.csv").set_index("parameter")
    assert set(sens.index) == {f"{c}.{k}" for c in ("aggressive", "conservative")
                               for k in ("time_gap", "v0")}  # fmt: skip
    assert (sens.plausible_low <= sens.best).all() and (sens.best <= sens.plausible_high).all()
    assert sens.loc["aggressive.v0", "identified"]
    assert sens.loc["aggressive.v0", "objective_max"] > sens.loc["aggressive.v0", "objective_best"]
    assert (out / "sensitivity.png").stat().st_size > 10_000
    more = _cfg(
        tmp_path, target, "calibrate.trials=3", "calibrate.aggressive_prefix=agg", *small,
        "calibrate.sensitivity_points=0",  # (not part of the study's name)
    )  # fmt: skip
    assert study_name(more) == study_name(cfg)  # the trial budget is not in the name
    with pytest.warns(UserWarning):
        calibrate_to_data(more, storage_url(more), preset_file(more), report_dir(more), False)
    study = optuna.load_study(study_name=study_name(cfg), storage=storage_url(cfg))
    assert len(study.trials) == 3


def test_the_reference_penalty_charges_each_statistic_matched_worse_than_table1(tmp_path, target):
    """Hand-computed: simulated speeds [1, 3] against observed [0, 2] are 1 observed standard
    deviation away (Wasserstein-1), headways [0, 2] against [0, 2] none. With Table I at 0.4
    and 0.5, only speed is worse, by 0.6: a mean excess of 0.3, so a penalty of 2 adds 0.6
    to the mean distance of 0.5."""
    from types import SimpleNamespace

    import numpy as np

    from bgap.calibration.data import objective_value

    observed = SimpleNamespace(
        samples={"aggressive": {"speed": np.array([0.0, 2.0]), "headway": np.array([0.0, 2.0])}}
    )
    sim = {
        "samples": {"aggressive": {"speed": np.array([1.0, 3.0]), "headway": np.array([0.0, 2.0])}},
        "crashed": 0.0,
        "speed": {"aggressive": 20.0, "conservative": 20.0},
    }
    table1 = pd.Series(
        [0.4, 0.5],
        index=pd.MultiIndex.from_tuples([("aggressive", "speed"), ("aggressive", "headway")]),
    )
    plain = _cfg(tmp_path, target)
    penalised = _cfg(tmp_path, target, "calibrate.reference_penalty=2")
    assert objective_value(plain, observed, sim, table1) == pytest.approx(0.5)
    assert objective_value(penalised, observed, sim) == pytest.approx(0.5)  # no reference
    assert objective_value(penalised, observed, sim, table1) == pytest.approx(0.5 + 2 * 0.3)


def test_the_target_density_is_matched(tmp_path):
    """Traffic spawned at vehicles_density 0.5 (other seeds) is read back as 0.5: bgap's
    spawning gap scales as 1 / vehicles_density."""
    from bgap.agents.policies import rollout
    from bgap.calibration.data import matched_density, observe
    from bgap.traffic.scenario import env_config
    from tests.conftest import make_cfg

    # 4 s: longer than CMetric's 3-second window, which the observed table is scored on
    sparse_ish = make_cfg("env=dense", "mix=0.5", "env.duration=4", "env.vehicles_density=0.5")
    table = rollout(env_config(sparse_ish), "idle", [60, 61, 62], "vector", record=True)
    path = tmp_path / "half.parquet"
    table.trajectories.to_parquet(path)
    cfg = _cfg(tmp_path, path, "calibrate.episodes=3", "calibrate.min_vehicles=5")
    assert matched_density(cfg, observe(cfg)) == pytest.approx(0.5, rel=0.1)


@pytest.mark.slow
def test_known_parameters_are_recovered(tmp_path):
    """Issue 18's recovery test: bgap's dense traffic with known classes (not Table I's: the
    aggressive class at v0 36 m/s, T 0.8 s; the conservative at v0 27 m/s, T 1.8 s; the
    other parameters Table I's), 8 scenes of 30 s, used as the target. The search (v0 and T
    of both classes, starting from Table I) recovers v0 within 2 m/s and T within 0.15 s,
    and the calibrated traffic's statistics lie within their noise bands."""
    from dataclasses import replace

    from bgap.agents.policies import rollout
    from bgap.calibration.calibrate import preset_file, report_dir, storage_url
    from bgap.calibration.data import calibrate_to_data
    from bgap.common.presets import write_preset
    from bgap.traffic.behaviors import DriverParams, paper_behavior
    from bgap.traffic.scenario import env_config
    from tests.conftest import make_cfg

    paper = paper_behavior()
    truth = {"aggressive": {"v0": 36.0, "time_gap": 0.8},
             "conservative": {"v0": 27.0, "time_gap": 1.8}}  # fmt: skip
    known = replace(
        paper,
        name="known",
        **{c: DriverParams(**{**vars(getattr(paper, c)), **truth[c]}) for c in truth},
    )
    truth_note = "the recovery test's truth"
    write_preset(known, "behavior", tmp_path / "known.yaml", truth_note, truth_note)
    scene = replace(make_cfg("env=dense", "mix=0.5", "env.duration=30"), behavior=known)
    table = rollout(env_config(scene), "idle", range(500, 508), "vector", record=True)
    target = tmp_path / "known.parquet"
    table.trajectories.to_parquet(target)
    fixed = ("min_distance", "acc", "dec", "politeness", "min_acc_gain", "b_safe")
    cfg = _cfg(
        tmp_path, target, "calibrate.trials=120", "calibrate.episodes=8",
        "calibrate.duration=30", "calibrate.sensitivity_points=0",
        *(f"calibrate.bounds.{k}=null" for k in fixed),
    )  # fmt: skip
    summary = calibrate_to_data(cfg, storage_url(cfg), preset_file(cfg), report_dir(cfg))
    found = summary["parameters"]
    for cls, values in truth.items():
        assert found[cls]["v0"] == pytest.approx(values["v0"], abs=2.0), (cls, found[cls])
        assert found[cls]["time_gap"] == pytest.approx(values["time_gap"], abs=0.15), found
    stats = pd.read_csv(report_dir(cfg) / "statistics.csv")
    assert stats.calibrated_in_band.all(), stats[~stats.calibrated_in_band]

"""Behaviour calibration: Optuna moves a class's CMetric score to its target, resumably."""

from __future__ import annotations

from dataclasses import asdict, replace

import pytest
from hydra.errors import ConfigCompositionException
from omegaconf.errors import ConfigKeyError

from bgap.calibration import calibrate as cal
from bgap.calibration.config import CalibrateAppConfig
from bgap.common.config import validate
from bgap.common.errors import ConfigError
from bgap.common.presets import load_preset, preset_path
from bgap.traffic.behaviors import BehaviorConfig, DriverParams
from tests.configs import compose

PAPER = cal.PAPER_TABLE


def _cfg(tmp_path, *overrides: str) -> CalibrateAppConfig:
    cfg = validate(
        compose(
            "calibrate",
            [
                "calibrate.episodes=2",
                "calibrate.duration=20",
                "calibrate.tolerance=0.05",
                f"root={tmp_path}",
                f"calibrate.out={tmp_path}/out",
                f"calibrate.preset={tmp_path}/calibrated.yaml",
                *overrides,
            ],
        )
    )
    return cfg


def _start(cfg: CalibrateAppConfig, label: str, params: dict) -> CalibrateAppConfig:
    start = replace(cfg.calibrate.start, **{label: DriverParams(**params)})
    return replace(cfg, calibrate=replace(cfg.calibrate, start=start))


@pytest.mark.parametrize(
    "label,start_from", [("aggressive", "conservative"), ("conservative", "aggressive")]
)
def test_short_calibration_reaches_the_target_from_the_other_class(tmp_path, label, start_from):
    cfg = _cfg(tmp_path, f"calibrate.classes=[{label}]", "calibrate.trials=16")
    cfg = _start(cfg, label, PAPER[start_from])
    target = getattr(cfg.calibrate.targets, label)
    study = cal.calibrate_class(cfg, label, progress=False)
    first, best = study.trials[0], study.best_trial
    assert first.params == pytest.approx(cal.start_params(cfg, label))
    start_gap = abs(first.user_attrs[f"mean_{label}"] - target)
    best_gap = abs(best.user_attrs[f"mean_{label}"] - target)
    # The start is off: for the aggressive class its score is far from the target; a
    # conservative class driving like the aggressive one scores near the scene average
    # (CMetric is relative) but the two classes become inseparable, which is penalised.
    assert first.value > 1.0 if label == "conservative" else start_gap > 0.2
    assert best_gap < cfg.calibrate.tolerance
    assert best.value == pytest.approx(best_gap)  # no degeneracy penalty on the winner
    assert best.user_attrs["auc"] >= cfg.calibrate.min_auc


def test_rerun_resumes_the_stored_study(tmp_path):
    cfg = _cfg(tmp_path, "calibrate.classes=[aggressive]", "calibrate.trials=4")
    first = cal.calibrate_class(cfg, "aggressive", progress=False)
    best_before = first.best_value
    again = cal.calibrate_class(
        replace(cfg, calibrate=replace(cfg.calibrate, trials=7)), "aggressive", progress=False
    )
    assert [t.number for t in again.trials] == list(range(7))  # trials 0-3 kept, not redone
    assert again.trials[0].params == first.trials[0].params
    assert again.best_value <= best_before
    # the same command once more does nothing
    assert (
        len(
            cal.calibrate_class(
                replace(cfg, calibrate=replace(cfg.calibrate, trials=7)),
                "aggressive",
                progress=False,
            ).trials
        )
        == 7
    )


def test_written_preset_reproduces_its_scores(tmp_path):
    cfg = _cfg(tmp_path, "calibrate.classes=[aggressive]", "calibrate.trials=6")
    summary = cal.calibrate(cfg, progress=False)
    behavior = load_preset(BehaviorConfig, tmp_path / "calibrated.yaml")
    assert behavior.name == "calibrated"
    gap = abs(summary["achieved"]["aggressive"] - cfg.calibrate.targets.aggressive)
    assert behavior.converged == (gap <= cfg.calibrate.tolerance) == summary["converged"]
    assert asdict(behavior.conservative) == asdict(cfg.behavior.conservative)  # untouched
    again = cal.scene_scores(cfg, behavior)
    for label in ("aggressive", "conservative"):
        assert again[f"mean_{label}"] == pytest.approx(summary["achieved"][label], abs=1e-9)
    for name in ("table.md", "table.csv", "scores.json", "convergence.png", "scores.png"):
        assert (tmp_path / "out" / name).stat().st_size > 0
    assert "| time_gap" in (tmp_path / "out/table.md").read_text()


def test_the_repository_preset_loads_as_behavior_calibrated():
    import json
    from pathlib import Path

    preset = preset_path("behavior", "calibrated")
    if not preset.exists():
        pytest.skip("no calibrated preset yet (dvc repro calibrate)")
    repository = Path(__file__).resolve().parents[1]
    reported = json.loads((repository / "results/calibration/scores.json").read_text())
    # (knowingly: the repository's calibration ended 0.023 off its 0.02 tolerance)
    cfg = validate(compose("calibrate", ["behavior=calibrated", "behavior.converged=true"]))
    stats = cal.scene_scores(cfg, cfg.behavior)  # the calibration's own scenes: exact
    for label in reported["targets"]:
        assert stats[f"mean_{label}"] == pytest.approx(reported["achieved"][label], abs=1e-6)
    # Other scenes: class means move by up to ~0.05 between sets of 4 scenes for any
    # parameters (Table I's aggressive mean ranges 0.76-0.85 over seeds 0, 500, 600, 700).
    held_out = validate(
        compose(
            "calibrate",
            ["behavior=calibrated", "behavior.converged=true", "calibrate.scene_seed=600"],
        )
    )
    stats = cal.scene_scores(held_out, held_out.behavior)
    for label in reported["targets"]:
        assert abs(stats[f"mean_{label}"] - reported["achieved"][label]) < 0.1, label


def test_bad_input_fails_before_any_simulation(tmp_path, monkeypatch):
    def boom(*args, **kwargs):
        raise AssertionError("simulated despite bad input")

    monkeypatch.setattr(cal, "scene_scores", boom)
    with pytest.raises((ConfigCompositionException, ConfigKeyError)):
        _cfg(tmp_path, "calibrate.bounds.politness=[0,1]")  # unknown parameter name
    with pytest.raises(ConfigError, match=r"calibrate.bounds.acc.*low < high"):
        _cfg(tmp_path, "calibrate.bounds.acc=[6,1]")
    with pytest.raises(ConfigError, match=r"calibrate.bounds.v0"):
        _cfg(tmp_path, "calibrate.bounds.v0=[30,30]")
    with pytest.raises(ConfigError, match="calibrate.classes"):
        _cfg(tmp_path, "calibrate.classes=[reckless]")
    cfg = _cfg(tmp_path, "calibrate.storage=postgresql://bgap@127.0.0.1:9/none")
    with pytest.raises(ConfigError, match="calibrate.storage"):
        cal.calibrate(cfg, progress=False)

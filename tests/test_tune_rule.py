"""bgap.tune_rule: the rule-based ego's parameters searched on validation episodes."""

from __future__ import annotations

import pandas as pd
import pytest

from bgap.agents.rule_based import DEFAULT, RuleParams, TunedRule
from bgap.common.presets import load_preset
from tests.commands import command

TINY = ["env=dense", "grid=paper", "grid.densities=[dense]", "grid.mixes=[0.5]",
        "grid.radii=[180.0]", "env.duration=8", "trials=4", "episodes=6"]  # fmt: skip


def test_tunes_from_the_defaults_and_writes_a_preset_no_worse_on_validation(
    tmp_path, monkeypatch, capsys
):
    """Trial 0 plays highway-env's defaults; the preset written is the best trial's (never
    worse than trial 0 on the objective), tagged with its traffic, and loads as parameters."""
    monkeypatch.chdir(tmp_path)
    args = ["situation=dense", *TINY, "out=search", "preset=rule/dense.yaml"]
    status, out, err = command("bgap.tune_rule", args, monkeypatch, capsys)
    assert status == 0, err
    trials = pd.read_csv(tmp_path / "search" / "trials.csv")
    assert len(trials) == 4
    first = trials.iloc[0]
    assert all(first[k] == getattr(DEFAULT, k) for k in RuleParams.__dataclass_fields__)
    preset = load_preset(TunedRule, tmp_path / "rule" / "dense.yaml")
    chosen = trials[trials.time_wanted == preset.time_wanted].iloc[0]
    assert chosen.objective <= first.objective
    assert (preset.situation, preset.observed_vehicles) == ("dense", 40)
    assert (tmp_path / "search" / "search.png").stat().st_size > 0
    assert "wrote" in out
    # a file the command did not write is refused before any search
    (tmp_path / "rule" / "sparse.yaml").write_text("# my own notes\n")
    again = [*args[:-2], "out=again", "preset=rule/sparse.yaml"]
    status, _, err = command("bgap.tune_rule", again, monkeypatch, capsys)
    assert status == 2 and "did not write" in err and err.count("\n") == 1
    assert (tmp_path / "rule" / "sparse.yaml").read_text() == "# my own notes\n"
    assert not (tmp_path / "again").exists()


@pytest.mark.parametrize(
    "bad,words",
    [
        ("situation=urban", "situation"),
        ("tune_seed=95000", "eval_seed"),
        ("trials=0", "trials"),
    ],  # fmt: skip
)
def test_bad_settings_are_refused_in_one_line(bad, words, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    args = ["situation=dense", *TINY, bad]
    status, _, err = command("bgap.tune_rule", args, monkeypatch, capsys)
    assert status == 2 and words in err and err.count("\n") == 1, err
    assert not list(tmp_path.iterdir())


def test_the_tuned_rule_and_idm_play_as_baselines_of_an_evaluation(tmp_path, monkeypatch, capsys):
    """The packaged presets (the tune_rule stage's) drive rule_tuned in both densities;
    IDM alone never changes lane, the rule does."""
    monkeypatch.chdir(tmp_path)
    args = ["baselines=[rule,rule_tuned,idm]", "grid=paper", "grid.mixes=[0.5]",
            "grid.radii=[180.0]", "profile.eval_episodes=4", "env.duration=10",
            "out=e"]  # fmt: skip
    status, _, err = command("bgap.evaluate", args, monkeypatch, capsys)
    assert status == 0, err
    episodes = pd.read_parquet(tmp_path / "e" / "episodes.parquet")
    assert set(episodes.policy) == {"rule", "rule_tuned", "idm"}
    assert set(episodes.density) == {"sparse", "dense"}
    assert episodes[episodes.policy == "idm"].lane_changes.sum() == 0
    assert episodes[episodes.policy == "rule"].lane_changes.sum() > 0

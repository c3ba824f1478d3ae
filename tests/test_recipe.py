"""The recipe search: its objective, the choice among candidates, and one tiny run end to end."""

from __future__ import annotations

import pandas as pd
import pytest

from bgap.common.config import validate
from bgap.experiments.recipe import choose
from bgap.experiments.sweep import objective
from tests.configs import compose


def _cfg(*overrides: str):
    return validate(compose("recipe", list(overrides)))


def test_constrained_objective_ranks_any_fast_enough_policy_above_any_slow_one():
    cfg = _cfg()  # speed_floor 0.9
    idle = 25.0
    assert objective(cfg, 12.0, 24.0, idle) == 12.0  # 24 >= 22.5: its collision %
    slow_safe = objective(cfg, 0.0, 20.0, idle)  # safety bought by crawling
    assert slow_safe == pytest.approx(100 + 100 * (22.5 - 20.0) / 22.5)
    assert objective(cfg, 99.0, 22.5, idle) < slow_safe
    single = _cfg("mode=single", "speed_weight=2")
    assert objective(single, 12.0, 24.0, idle) == pytest.approx(12.0 - 48.0)


def test_choice_uses_the_mean_over_seeds_not_one_lucky_seed():
    cfg = _cfg()
    rows = []
    for trial, crashes, speeds in (
        (1, [0.0, 30.0, 30.0], [25.0, 25.0, 25.0]),  # one lucky seed, mean 20%
        (2, [10.0, 12.0, 8.0], [24.0, 24.0, 24.0]),  # steady 10%
        (3, [0.0, 0.0, 2.0], [21.0, 21.0, 21.0]),  # safe but below 0.9 x idle (22.5)
    ):
        for seed, (c, s) in enumerate(zip(crashes, speeds, strict=True)):
            rows.append(
                {"trial": trial, "seed": seed, "collision_pct": c, "avg_speed": s,
                 "idle_collision_pct": 9.0, "idle_avg_speed": 25.0,
                 "rule_collision_pct": 1.0, "rule_avg_speed": 27.0, "lane_changes": 1.0}
            )  # fmt: skip
    summary = choose(cfg, pd.DataFrame(rows))
    assert list(summary.trial) == [2, 1, 3]
    best = summary.iloc[0]
    assert best.collision_pct == pytest.approx(10.0)
    assert 0.0 <= best.collision_pct_lo < 10.0 < best.collision_pct_hi <= 100.0


def test_with_the_stock_check_a_candidate_whose_default_policy_crawls_ranks_last():
    """Trial 1 is best in behaviour-rich traffic, but its default policy drives 19.5 m/s in
    stock traffic against idle's 24 (floor 21.6); trial 2's drives 22 m/s at 10%: trial 2
    is chosen. Trial 3 meets the speed but crashes in 60% (bound 50%)."""
    from bgap.experiments.recipe import markdown

    cfg = _cfg("stock_check=true")
    rows = []
    for trial, crash, stock_crash, stock_speed in ((1, 5.0, 1.0, 19.5), (2, 8.0, 10.0, 22.0),
                                                   (3, 6.0, 60.0, 23.0)):  # fmt: skip
        for seed in range(2):
            rows.append(
                {"trial": trial, "seed": seed, "collision_pct": crash, "avg_speed": 24.0,
                 "idle_collision_pct": 9.0, "idle_avg_speed": 25.0,
                 "rule_collision_pct": 1.0, "rule_avg_speed": 27.0, "lane_changes": 1.0,
                 "stock_collision_pct": stock_crash, "stock_avg_speed": stock_speed,
                 "stock_idle_collision_pct": 100.0, "stock_idle_avg_speed": 24.0}
            )  # fmt: skip
    summary = choose(cfg, pd.DataFrame(rows))
    assert list(summary.trial) == [2, 1, 3]
    assert list(summary.stock_rule) == [True, False, False]
    table = markdown(cfg, summary, {t: {"gamma": 0.9} for t in (1, 2, 3)})
    assert "| 2 | 10.0 | 22.00 | 100.0 / 24.00 | yes |" in table
    without = choose(_cfg(), pd.DataFrame(rows).drop(columns=["stock_avg_speed"]))
    assert list(without.trial) == [1, 3, 2]  # no stock figures: the objective alone
    assert "stock_rule" not in without  # and the summary of a run without the check as before


def test_the_recipe_config_refuses_a_multi_objective_or_a_single_seed_check():
    from bgap.common.errors import ConfigError

    with pytest.raises(ConfigError, match="mode"):
        _cfg("mode=multi")
    with pytest.raises(ConfigError, match="check_seeds"):
        _cfg("check_seeds=[0]")


@pytest.mark.slow
def test_a_tiny_recipe_writes_its_presets_and_tables(tmp_path):
    from bgap.experiments.recipe import recipe

    cfg = _cfg(
        "profile=tiny", "profile.eval_every_episodes=3", "trials=2", "candidates=2",
        "check_seeds=[0,1]", "check_episodes=10", "sweep_eval_episodes=4", f"root={tmp_path}",
        "stock_check=true",
    )  # fmt: skip
    paths = recipe(cfg, progress=False)
    table = pd.read_csv(paths["candidates"])
    assert len(table) == 4 and set(table.seed) == {0, 1}
    # the stock check trained each candidate's default policy too, and idle crashes in stock
    assert table.stock_avg_speed.between(5, 40).all() and (table.stock_idle_avg_speed > 20).all()
    assert "meets the rule" in paths["table"].read_text()
    reward = validate(
        compose("train", ["reward=user_recipe", f"hydra.searchpath=[file://{tmp_path}/presets]"])
    ).reward
    chosen = pd.read_json(paths["chosen"], typ="series")
    assert reward.collision == pytest.approx(chosen["params"]["reward.collision"])
    assert paths["curves"].exists() and paths["table"].exists()


def test_a_lever_replaces_the_chosen_trials_own_setting_and_one_it_has_is_left_out():
    import optuna

    from bgap.common.errors import ConfigError
    from bgap.experiments.recipe import lever_variants

    overrides = ["env=dense", "agent.extractor=attention", "agent.observation=[closing,ttc]"]
    trial = optuna.trial.create_trial(value=1.0, user_attrs={"overrides": overrides})
    trial.number = 7
    cfg = _cfg("mode=rule", "levers=['agent.extractor=flatten','agent.extractor=attention',"
               "'agent.observation=[]','agent.gamma=0.9']")  # fmt: skip
    variants = lever_variants(cfg, trial)
    assert [v.label for v in variants] == [
        "agent.extractor=flatten", "agent.observation=[]", "agent.gamma=0.9"]  # fmt: skip
    assert variants[0].overrides == [
        "env=dense", "agent.observation=[closing,ttc]", "agent.extractor=flatten"]  # fmt: skip
    assert variants[2].overrides == [*overrides, "agent.gamma=0.9"]  # not in the trial: added
    assert [v.folder for v in variants] == [
        "trial-0007-lever1", "trial-0007-lever3", "trial-0007-lever4"]  # fmt: skip
    with pytest.raises(ConfigError, match="levers"):
        _cfg("levers=['agent.extractor=flatten']")  # needs mode=rule
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        _cfg("mode=rule", "levers=[flatten]")
    with pytest.raises(ConfigError, match="agent or reward"):
        _cfg("mode=rule", "levers=['agent.gamma=0.9 env=sparse']")  # not the recipe's
    with pytest.raises(ConfigError, match="each key once"):
        _cfg("mode=rule", "levers=['agent.gamma=0.9 agent.gamma=0.8']")


def test_a_lever_of_several_settings_brings_a_group_back_whole():
    """``agent=recipe reward=recipe agent.extractor=attention``: the trial's agent and reward
    settings go (the presets come back whole), its other settings stay, the lever's own
    settings come last in their order."""
    import optuna

    from bgap.experiments.recipe import lever_variants

    overrides = ["env=dense", "reward=highway", "agent=qrdqn", "agent.gamma=0.8",
                 "reward.collision=-2.0", "agent.extractor=attention", "seed=0"]  # fmt: skip
    trial = optuna.trial.create_trial(value=1.0, user_attrs={"overrides": overrides})
    trial.number = 3
    lever = "agent=recipe reward=recipe agent.extractor=attention"
    (only,) = lever_variants(_cfg("mode=rule", f"levers=['{lever}']"), trial)
    assert only.label == lever and only.folder == "trial-0003-lever1"
    assert only.overrides == ["env=dense", "seed=0", "agent=recipe", "reward=recipe",
                              "agent.extractor=attention"]  # fmt: skip
    # the variant composes: the main arm's recipe with the lever's network
    agent = validate(compose("train", only.overrides)).agent
    assert agent.name == "recipe" and agent.extractor == "attention"


def test_without_levers_the_levers_files_hold_the_recipes_row_alone(tmp_path):
    """``levers=[]`` (the pipeline declares levers.csv and levers.md for every learner): the
    files are written, nothing is trained, the page says no lever was asked for."""
    import optuna

    from bgap.experiments.recipe import check_levers

    trial = optuna.trial.create_trial(value=0.5, user_attrs={"overrides": ["env=dense"]})
    trial.number = 4
    summary = pd.DataFrame([{
        "trial": 4, "per_100km": 1.0, "per_100km_lo": 0.5, "per_100km_hi": 1.5,
        "avg_speed": 27.0, "stock_collision_pct": 0.0, "stock_collision_pct_lo": 0.0,
        "stock_collision_pct_hi": 1.2, "stock_avg_speed": 21.5, "objective": 0.5}])  # fmt: skip
    paths = check_levers(_cfg("mode=rule"), trial, summary, tmp_path, tmp_path, False)
    text = paths["levers"].read_text()
    assert "No lever was asked for" in text and text.count("\n| ") == 2  # header + recipe
    assert "(trial 4)" in text  # the trial's number, not the float a row of numbers makes
    assert (tmp_path / "levers.csv").exists() and not any(tmp_path.glob("trial-*"))


def test_by_the_rule_the_mean_over_seeds_decides_and_intervals_have_width():
    """mode=rule's choice (issue 32): candidates ranked by the objective of their means over
    seeds; a candidate whose seeds agree exactly still gets an interval of non-zero width
    (widened to its pooled episodes' exact interval)."""
    from bgap.experiments.recipe import choose_by_rule

    cfg = _cfg("mode=rule")
    rule = {"rule_collision_pct": 3.0, "rule_per_100km": 2.0, "rule_avg_speed": 27.0,
            "stock_rule_collision_pct": 0.0, "stock_rule_per_100km": 0.0,
            "stock_rule_avg_speed": 22.0}  # fmt: skip
    rows = []
    for trial, per100, speed in ((1, [1.0, 1.0], [26.0, 26.0]), (2, [0.0, 0.5], [24.0, 24.0])):
        for seed in (0, 1):
            rows.append({"trial": trial, "seed": seed, "per_100km": per100[seed],
                         "avg_speed": speed[seed], "collision_pct": 2.0, "crashes": 2,
                         "episodes": 100, "km": 160.0, "stock_collision_pct": 0.5,
                         "stock_per_100km": 0.3, "stock_avg_speed": 21.5, "stock_crashes": 0,
                         "stock_episodes": 100, "stock_km": 130.0, **rule})  # fmt: skip
    summary = choose_by_rule(cfg, pd.DataFrame(rows))
    # trial 2 is safer but at 24 < 0.95 x 27 m/s: trial 1 (-0.5: 1.0 per 100 km under 2.0,
    # 0.5% under its allowance) ranks first
    assert list(summary.trial) == [1, 2] and summary.objective[0] == pytest.approx(-0.5)
    first = summary.iloc[0]
    assert first.per_100km_lo < first.per_100km < first.per_100km_hi  # seeds agree: widened
    assert first.stock_collision_pct_lo == 0.0 < first.stock_collision_pct_hi


@pytest.mark.slow
def test_a_tiny_recipe_by_the_rule_trains_and_scores_both_policies(tmp_path):
    from bgap.experiments.recipe import recipe

    cfg = _cfg(
        "mode=rule", "agent=qrdqn", "sweep=learner_qrdqn", "profile=tiny", "trials=2",
        "candidates=1", "check_seeds=[0,1]", "check_episodes=10", "sweep_eval_episodes=4",
        "env=sparse", "backend=vector", f"root={tmp_path}",
        "levers=['agent.extractor=flatten','agent.extractor=attention']",
    )  # fmt: skip
    paths = recipe(cfg, progress=False)
    table = pd.read_csv(paths["candidates"])
    assert len(table) == 2 and (table.rule_avg_speed > 20).all()
    # one of the two levers is the chosen trial's own extractor: only the other is trained
    levers = pd.read_csv(tmp_path / "recipe" / "levers.csv")
    assert len(levers) == 2 and levers.trial.nunique() == 1
    assert levers.run_dir.str.contains("-lever").all()
    text = paths["levers"].read_text()
    assert "Left out (the recipe already has them)" in text and text.count("\n| ") == 3
    assert (table.stock_rule_avg_speed > 20).all() and table.stock_avg_speed.between(5, 40).all()
    assert "rule-based ego" in paths["table"].read_text()
    agent = validate(
        compose("train", ["agent=user_recipe", f"hydra.searchpath=[file://{tmp_path}/presets]"])
    ).agent
    assert agent.algo == "qrdqn"


@pytest.mark.slow
def test_the_check_in_processes_gives_the_rows_it_gives_in_one(tmp_path, monkeypatch):
    """The candidates' check with ``workers=2`` (two (trial, seed) checks at a time, each in
    a spawned process) and ``workers=1``: the same rows, in the same order."""
    import bgap.experiments.recipe as recipe_module
    from bgap.experiments.sweep import sweep

    monkeypatch.setattr(recipe_module, "SIDE_BY_SIDE_STEPS", 0)  # tiny trainings too
    base = ["mode=rule", "profile=tiny", "trials=1", "check_seeds=[0,1]", "check_episodes=10",
            "sweep_eval_episodes=4", "env=sparse", "backend=vector",
            f"root={tmp_path}"]  # fmt: skip
    study = sweep(_cfg(*base), progress=False)
    tables = {}
    for workers in (1, 2):
        cfg = _cfg(*base, f"workers={workers}")
        variants = [recipe_module.variant(t) for t in study.trials]
        rows = recipe_module.check_all(cfg, variants, tmp_path / f"w{workers}", False)
        tables[workers] = pd.DataFrame(rows).drop(columns="run_dir")
    assert list(tables[1].seed) == [0, 1]
    pd.testing.assert_frame_equal(tables[1], tables[2])


def test_the_check_resumes_from_the_study_on_a_machine_without_its_run_folders(
    tmp_path, monkeypatch
):
    """Finished check rows are kept in the study's attributes with their validation curves:
    after the study's trial log is restored into a new database (a new machine), the same
    check trains nothing and returns the same rows, the learning curves come from the study,
    and a check of other validation episodes is trained again."""
    import optuna

    import bgap.experiments.recipe as recipe_module
    from bgap.experiments import trial_log

    trained = []

    def fake_check_seed(cfg, v, seed, root, progress):  # one training's row and its curve
        run_dir = root / f"{v.folder}-s{seed}"
        run_dir.mkdir(parents=True)
        curve = {"gradient_updates": [100, 200], "collision_pct": [9.0, seed],
                 "avg_speed": [20.0, 25.0], "idle_collision_pct": [3.0, 3.0],
                 "idle_avg_speed": [25.0, 25.0], "rule_collision_pct": [1.0, 1.0],
                 "rule_avg_speed": [27.0, 27.0]}  # fmt: skip
        pd.DataFrame(curve).to_csv(run_dir / "evaluations.csv", index=False)
        trained.append((v.label, seed))
        return {"trial": v.label, "seed": seed, "run_dir": str(run_dir), "per_100km": seed / 3}

    monkeypatch.setattr(recipe_module, "check_seed", fake_check_seed)
    cfg = _cfg("mode=rule", "check_seeds=[0,1,2]", "workers=1")
    overrides = ["env=dense", "agent.gamma=0.9"]
    variants = [recipe_module.Variant(5, "trial-0005", overrides),
                recipe_module.Variant("agent.gamma=0.8", "trial-0005-lever1",
                                      ["env=dense", "agent.gamma=0.8"])]  # fmt: skip
    db = f"sqlite:///{tmp_path / 'first.db'}"
    study = optuna.create_study(study_name="s", storage=db)
    first = recipe_module.check_all(cfg, variants, tmp_path / "a", False, study)
    assert len(trained) == 6 and [r["seed"] for r in first] == [0, 1, 2, 0, 1, 2]

    trial_log.save(db, "s", tmp_path / "log.json")
    again = f"sqlite:///{tmp_path / 'again.db'}"  # the new machine: a new root too
    trial_log.restore(again, tmp_path / "log.json")
    restored = optuna.load_study(study_name="s", storage=again)
    rows = recipe_module.check_all(cfg, variants, tmp_path / "b", False, restored)
    assert len(trained) == 6  # nothing trained again
    assert [r | {"run_dir": ""} for r in rows] == [r | {"run_dir": ""} for r in first]
    assert rows[4]["run_dir"] == str(tmp_path / "b" / "trial-0005-lever1-s1")
    found = recipe_module.curves([r["run_dir"] for r in rows[:3]], restored)
    assert list(found) == ["trial-0005-s0", "trial-0005-s1", "trial-0005-s2"]
    assert found["trial-0005-s2"].collision_pct.tolist() == [9.0, 2.0]
    assert recipe_module.curves([r["run_dir"] for r in rows[:3]]) == {}  # folders gone

    other = _cfg("mode=rule", "check_seeds=[0,1,2]", "workers=1", "check_episodes=50")
    recipe_module.check_all(other, variants[:1], tmp_path / "c", False, restored)
    assert len(trained) == 9  # other validation episodes: other rows

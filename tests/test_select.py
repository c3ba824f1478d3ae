"""Training seeds chosen on validation (``bgap.select``): the score, the groups, a tiny run."""

from __future__ import annotations

from dataclasses import replace

import pandas as pd
import pytest
import yaml

from bgap.analysis.episodes import arm_algo, arm_name, learner_arm
from bgap.analysis.stats import policy_score as score
from bgap.analysis.stats import rule_objective
from bgap.common.config import validate
from bgap.common.errors import ConfigError
from bgap.experiments.config import compose
from bgap.experiments.evaluate_policies import policy_specs
from bgap.experiments.select import groups, select
from bgap.experiments.train import train
from bgap.experiments.validation import validation_figures


def _f(pct: float, per100: float, speed: float) -> dict[str, float]:
    return {"collision_pct": pct, "per_100km": per100, "avg_speed": speed}


def test_each_policys_score_is_its_half_of_the_recipe_objective():
    rule = _f(2.0, 1.5, 20.0)
    # by hand: 19 m/s is exactly 0.95 x 20, so no shortfall
    assert score("behavior_rich", _f(9.0, 1.0, 19.0), rule) == pytest.approx(1.0 - 1.5)
    assert score("default", _f(2.5, 9.0, 19.0), rule) == pytest.approx(2.5 - 2.0 - 1.0)
    # 18.05 m/s is 5% below the floor of 19
    assert score("default", _f(0.0, 0.0, 18.05), rule) == pytest.approx(1005.0)
    # two policies that keep the pace: the recipe's objective is the worse of their scores
    rich, stock = _f(5.0, 3.0, 27.0), _f(1.5, 2.0, 21.0)
    rich_rule, stock_rule = _f(4.0, 2.2, 27.0), _f(0.0, 0.0, 22.0)
    assert rule_objective(rich, rich_rule, stock, stock_rule) == pytest.approx(
        max(score("behavior_rich", rich, rich_rule), score("default", stock, stock_rule))
    )


def test_runs_fall_into_consecutive_groups_per_density_and_family():
    table = pd.DataFrame(  # fmt: skip
        [
            (d, p, s)
            for d in ("dense", "sparse")
            for p in ("behavior_rich", "default")
            for s in range(8, 14)
        ],
        columns=["density", "policy", "seed"],
    )
    g = groups(table, 3)
    assert (g[table.seed < 11] == 0).all() and (g[table.seed >= 11] == 1).all()
    with pytest.raises(ConfigError, match="group=4 does not divide the 6 behavior_rich runs"):
        groups(table, 4)


def test_a_selection_arm_is_named_by_its_algorithm_and_its_k():
    assert arm_algo("learner-qrdqn-k3") == arm_algo("learner-qrdqn") == "QR-DQN"
    assert "best of 3 training seeds" in arm_name("learner-qrdqn-k3")
    assert arm_name("learner-qrdqn").startswith("QR-DQN learner") and "best" not in arm_name(
        "learner-qrdqn"
    )
    assert learner_arm("learner-dqn-k12") == ("dqn", 12)
    assert learner_arm("learner-ppo") == ("ppo", None)
    assert learner_arm("main") is None and arm_algo("main") == "DQN"


def test_a_tiny_selection_keeps_each_groups_best_run_for_evaluation(tmp_path):
    runs = tmp_path / "runs" / "sparse"
    base = ["profile=tiny", "env=sparse", "env.duration=10", f"root={tmp_path}"]
    cfgs = []
    for seed in (0, 1):
        cfg = validate(compose("train", [*base, f"seed={seed}"]))
        cfg = replace(cfg, run_dir=str(runs / f"sparse-behavior_rich-s{seed}"))
        train(cfg, progress=False)
        cfgs.append(cfg)
    out, tables = tmp_path / "kept", tmp_path / "tables"
    table = select(tmp_path / "runs", out, tables, k=2, episodes=4)

    # each run's figures as the sweep's validation measures them, independently
    for cfg, row in zip(cfgs, table.sort_values("seed").itertuples(), strict=True):
        mine = validation_figures(cfg.run_dir, cfg, 4)
        assert row.per_100km == pytest.approx(mine["per_100km"])
        assert row.avg_speed == pytest.approx(mine["avg_speed"])
    kept = table[table.kept]
    assert len(kept) == 1 and kept.score.iloc[0] == table.score.min()
    copy = out / "sparse" / kept.run.iloc[0].name
    assert (copy / "model.zip").exists() and not (copy / "checkpoints").exists()
    specs = policy_specs(replace(cfgs[0], models=[str(out)], baselines=[]))
    assert list(specs) == [f"kept/sparse/{copy.name}"]
    assert pd.read_csv(tables / "selection.csv").kept.sum() == 1
    # both folders record the settings the selection used
    used = {"runs": str(tmp_path / "runs"), "group": 2, "episodes": 4, "out": str(out),
            "table": str(tables)}  # fmt: skip
    for folder in (out, tables):
        assert yaml.safe_load((folder / "config.yaml").read_text()) == used
    with pytest.raises(ConfigError, match="holds an earlier selection"):
        select(tmp_path / "runs", out, tables, k=2, episodes=4)

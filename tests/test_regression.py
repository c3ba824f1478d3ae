"""Outputs unchanged on fixed seeds: numbers the code produced before the simulator seam
(commit d1375c6, stored in ``tests/data/regression.json``), recomputed through today's code.

Each backend used to have its own loop in evaluation, dataset generation and calibration;
these cases pin that the one rollout loop plays exactly the same episodes.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bgap.common.config import validate
from tests.configs import compose

EXPECTED = json.loads((Path(__file__).parent / "data" / "regression.json").read_text())
KEYS = [
    "policy",
    "mix",
    "density",
    "seed",
    "crashed",
    "avg_speed",
    "lane_changes",
    "steps",
    "return",
]


def _same_rows(expected: list[dict], rows: list[dict]) -> None:
    assert len(rows) == len(expected)
    for want, got in zip(expected, rows, strict=True):
        for key, value in want.items():
            if isinstance(value, float):
                assert got[key] == pytest.approx(value, rel=1e-12, abs=1e-12), (key, want, got)
            else:
                assert got[key] == value, (key, want, got)


def _summary(table) -> dict:
    return {
        "rows": len(table),
        "x_sum": float(table.x.sum()),
        "y_sum": float(table.y.sum()),
        "speed_mean": float(table.speed.mean()),
        "lane_sum": int(table.lane.astype(int).sum()),
        "crashed": int(table.crashed.sum()),
        "aggressive_rows": int((table.label == "aggressive").sum()),
        "frames": int(table.frame.max()),
    }


PAPER = ["reward=highway", "agent=dqn"]
"""The settings the expected values were recorded with (before the recipe became the default)."""


def _same_summary(expected: dict, got: dict) -> None:
    for key, value in expected.items():
        assert got[key] == pytest.approx(value, rel=1e-12), key


def test_evaluation_grid_on_the_vector_backend_is_unchanged():
    from bgap.experiments.evaluate import Cell, evaluate

    cfg = validate(compose("train", [*PAPER, "env=sparse", "workers=1", "backend=vector",
                                     "eval_seed=500"]))  # fmt: skip
    cells = [Cell(m, d, 180.0) for d in ("sparse", "dense") for m in (0.0, 0.6)]
    policies = {"idle": "idle", "random": "random", "left": "left"}
    episodes = evaluate(cfg, policies, cells, episodes=6, progress=False)
    _same_rows(EXPECTED["evaluate_vector"], episodes[KEYS].to_dict(orient="records"))


def test_evaluation_on_highway_env_is_unchanged():
    from bgap.experiments.evaluate import Cell, evaluate

    overrides = [*PAPER, "env=sparse", "env.duration=15", "workers=1", "backend=highway",
                 "eval_seed=500"]  # fmt: skip
    cfg = validate(compose("train", overrides))
    episodes = evaluate(
        cfg, {"idle": "idle", "random": "random"}, [Cell(0.6, "sparse", 90.0)], 3, False
    )
    _same_rows(EXPECTED["evaluate_highway"], episodes[KEYS].to_dict(orient="records"))


@pytest.mark.parametrize(
    "case,overrides,episodes",
    [
        ("simulate_vector", ["policy=random", "backend=vector", "env.duration=20"], 3),
        ("simulate_highway_idle", ["policy=idle", "backend=highway", "env.duration=10"], 2),
    ],
)
def test_simulated_datasets_are_unchanged(case, overrides, episodes):
    from bgap.datasets.simulate import simulate

    cfg = validate(compose("simulate", ["env=sparse", "mix=0.6", "seed=7", *overrides]))
    _same_summary(EXPECTED[case], _summary(simulate(cfg, episodes=episodes, progress=False)))


def test_a_calibration_trial_scores_the_same():
    from bgap.calibration import calibrate as cal

    cfg = validate(compose("calibrate", ["calibrate.episodes=2", "calibrate.duration=20"]))
    stats = cal.scene_scores(cfg, cfg.behavior)
    want = EXPECTED["calibration_trial"]
    for key in ("auc", "crashed", "mean_conservative", "mean_aggressive"):
        assert stats[key] == pytest.approx(want[key], rel=1e-9), key
    for key in ("speed_conservative", "speed_aggressive"):
        assert stats[key] == pytest.approx(want[key], rel=1e-12), key
    # the objective (since the calibration's search and check agree) sums both classes'
    # misses; the stored value was the aggressive class's alone (no penalty applied here)
    value = cal.objective_value(cfg, "aggressive", stats)
    assert want["objective_aggressive"] == pytest.approx(abs(want["mean_aggressive"] - 0.77))
    both = want["objective_aggressive"] + abs(want["mean_conservative"] - 0.31)
    assert value == pytest.approx(both, rel=1e-6)


def test_a_tiny_training_learns_the_same_parameters(tmp_path):
    from bgap.agents.dqn import DQN
    from bgap.experiments.evaluate import Cell, evaluate
    from bgap.experiments.train import train

    overrides = [*PAPER, "env=sparse", "profile=tiny", "backend=vector", f"root={tmp_path}",
                 "workers=1"]  # fmt: skip
    cfg = validate(compose("train", [*overrides, "mix_sampling=paper", "seed=3"]))
    run = train(cfg, progress=False)
    model = DQN.load(run / "model.zip", device="cpu")
    params = np.concatenate([p.detach().numpy().ravel() for p in model.policy.parameters()])
    want = EXPECTED["train_tiny_vector"]
    assert model.num_timesteps == want["timesteps"] and model._n_updates == want["n_updates"]
    assert float(params.sum()) == pytest.approx(want["param_sum"], rel=1e-6)
    assert float(np.abs(params).sum()) == pytest.approx(want["param_abs_sum"], rel=1e-6)
    episodes = evaluate(cfg, {"m": str(run)}, [Cell(0.5, "sparse", 180.0)], 5, progress=False)
    cols = ["seed", "crashed", "avg_speed", "lane_changes", "steps", "return"]
    _same_rows(want["eval"], episodes[cols].to_dict(orient="records"))

"""Evaluation metrics on scripted policies, training runs, resumption, reproducibility."""

from __future__ import annotations

from dataclasses import replace

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
from highway_env.vehicle.kinematics import Vehicle

from bgap.envs import make_env
from bgap.evaluate import Cell, evaluate, load_policy, run_episode, summarize
from tests.conftest import make_cfg


def exp_cfg(*overrides: str):
    from bgap.config import compose, validate

    return validate(compose("train", list(overrides)))


def test_idle_policy_never_changes_lane():
    env = make_env(make_cfg("env=sparse", "env.duration=15"))
    idle, _ = load_policy("idle")
    for seed in range(3):
        assert run_episode(env, idle, seed)["lane_changes"] == 0


def test_always_left_counts_each_real_lane_change_once():
    # empty road: from lane L the ego can go left exactly L times, then the action is a no-op
    env = make_env(make_cfg("env=sparse", "env.vehicles_count=0", "env.duration=12"))
    left, _ = load_policy("left")
    lanes = set()
    for seed in range(8):
        env.reset(seed=seed)
        start_lane = env.unwrapped.vehicle.lane_index[2]
        lanes.add(start_lane)
        result = run_episode(env, left, seed)
        assert result["lane_changes"] == start_lane
        assert not result["crashed"]
    assert len(lanes) > 1  # the check covered several starting lanes


class Roadblock(gym.Wrapper):
    """After reset, a stopped car 30 m ahead of the ego in its lane: idle must crash."""

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        u = self.env.unwrapped
        lane = u.road.network.get_lane(u.vehicle.lane_index)
        s, _ = lane.local_coordinates(u.vehicle.position)
        block = Vehicle(u.road, lane.position(s + 30.0, 0), lane.heading_at(s + 30.0), 0.0)
        block.bgap_label, block.bgap_id = "conservative", 99
        u.road.vehicles.append(block)
        return obs, info


def test_forced_crash_counts_one_collision():
    env = Roadblock(make_env(make_cfg("env=sparse", "env.vehicles_count=0", "env.duration=20")))
    idle, _ = load_policy("idle")
    crash = run_episode(env, idle, 0)
    assert crash["crashed"] and crash["steps"] < 20
    clean = run_episode(
        make_env(make_cfg("env=sparse", "env.vehicles_count=0", "env.duration=20")), idle, 0
    )
    assert not clean["crashed"]
    rows = [
        dict(policy="idle", mix=0.0, density="sparse", radius=180.0, seed=k, **r)
        for k, r in enumerate([crash, clean, clean, clean])
    ]
    summary = summarize(pd.DataFrame(rows)).iloc[0]
    assert summary.collision_pct == 25.0
    assert summary.collision_lo < 25.0 < summary.collision_hi


def test_policies_play_identical_seeded_episodes():
    cfg = exp_cfg("env=sparse", "env.duration=5", "workers=1")
    episodes = evaluate(
        cfg,
        {"idle": "idle", "idle2": "idle", "random": "random"},
        [Cell(0.5, "sparse", 180.0)],
        episodes=3,
        progress=False,
    )
    a = episodes[episodes.policy == "idle"].drop(columns="policy").reset_index(drop=True)
    b = episodes[episodes.policy == "idle2"].drop(columns="policy").reset_index(drop=True)
    pd.testing.assert_frame_equal(a, b)
    assert list(episodes[episodes.policy == "random"].seed) == list(a.seed)


def test_paper_grid_has_the_papers_cells():
    from bgap.evaluate import grid_cells

    cells = grid_cells(exp_cfg("grid=paper"))
    assert len(cells) == 7 * 2 * 3
    assert {c.density for c in cells} == {"sparse", "dense"}


def _short(tmp_path, *extra):
    return exp_cfg(
        "env=sparse",
        "env.duration=10",
        "profile.train_steps=240",
        "profile.n_envs=1",
        "profile.checkpoint_every=60",
        "agent.learning_starts=50",
        f"root={tmp_path}",
        *extra,
    )


@pytest.mark.parametrize("backend", ["vector", "highway"])
def test_resume_continues_from_the_checkpoint(tmp_path, monkeypatch, backend):
    import json

    from bgap import train as train_mod

    cfg = replace(_short(tmp_path, f"backend={backend}"), run_dir=str(tmp_path / "run"))
    original = train_mod.Progress._on_step

    def interrupt(self):
        if self.num_timesteps >= 130:
            raise KeyboardInterrupt
        return original(self)

    monkeypatch.setattr(train_mod.Progress, "_on_step", interrupt)
    with pytest.raises(KeyboardInterrupt):
        train_mod.train(cfg, progress=False)
    state = json.loads((tmp_path / "run/checkpoints/state.json").read_text())
    assert state["steps"] == 130 and not (tmp_path / "run/model.zip").exists()
    monkeypatch.setattr(train_mod.Progress, "_on_step", original)

    started = []
    learn = train_mod.DQN.learn

    def spy(self, *args, **kwargs):
        started.append((self.num_timesteps, kwargs["total_timesteps"]))
        return learn(self, *args, **kwargs)

    monkeypatch.setattr(train_mod.DQN, "learn", spy)
    train_mod.train(replace(cfg, resume=True), progress=False)
    assert started == [(130, 240 - 130)]
    from bgap.agents.dqn import DQN

    model = DQN.load(tmp_path / "run/model.zip")
    assert model.num_timesteps == 240
    final = json.loads((tmp_path / "run/checkpoints/state.json").read_text())
    assert final["episodes"] > state["episodes"]


@pytest.mark.parametrize("backend", ["vector", "highway"])
def test_same_seed_reproduces_training_and_evaluation(tmp_path, backend):
    from bgap.train import train

    cfg = _short(tmp_path, f"backend={backend}", "workers=1")
    a = train(replace(cfg, run_dir=str(tmp_path / "a")), progress=False)
    b = train(replace(cfg, run_dir=str(tmp_path / "b")), progress=False)
    cell = [Cell(0.5, "sparse", 180.0)]
    ea = evaluate(cfg, {"m": str(a)}, cell, episodes=3, progress=False)
    eb = evaluate(cfg, {"m": str(b)}, cell, episodes=3, progress=False)
    pd.testing.assert_frame_equal(ea, eb)
    assert (tmp_path / "a/config.yaml").exists() and (tmp_path / "a/command.txt").exists()
    assert any((tmp_path / "a/tb").rglob("events.out.tfevents*"))


@pytest.mark.slow
def test_short_training_beats_random_on_collisions(tmp_path):
    from bgap.train import train

    cfg = exp_cfg("env=sparse", "mix=0.5", "profile.train_steps=3000", f"root={tmp_path}", "seed=3")
    run = train(cfg, progress=False)
    episodes = evaluate(
        cfg,
        {"dqn": str(run), "random": "random"},
        [Cell(0.5, "sparse", 180.0)],
        episodes=50,
        progress=False,
    )
    rate = episodes.groupby("policy").crashed.mean()
    assert rate["dqn"] < rate["random"], rate.to_dict()
    assert np.isfinite(episodes.avg_speed).all()


@pytest.mark.slow
def test_training_on_the_vector_backend_transfers_to_highway_env(tmp_path):
    """Equal steps of training on either backend, both evaluated on highway-env on the same
    seeds: the collision rates' 95% intervals overlap and both beat a random policy."""
    from bgap.evaluate import summarize
    from bgap.train import train

    runs = {}
    for backend in ("vector", "highway"):
        cfg = exp_cfg(
            "env=sparse",
            "mix=0.5",
            "profile.train_steps=3000",
            f"root={tmp_path}",
            "seed=3",
            f"backend={backend}",
        )
        runs[backend] = str(train(cfg, progress=False))
    cfg = exp_cfg("env=sparse", "mix=0.5", "backend=highway", f"root={tmp_path}")
    episodes = evaluate(
        cfg,
        {**runs, "random": "random"},
        [Cell(0.5, "sparse", 180.0)],
        episodes=100,
        progress=False,
    )
    s = summarize(episodes).set_index("policy")
    assert s.loc["vector", "collision_lo"] <= s.loc["highway", "collision_hi"]
    assert s.loc["highway", "collision_lo"] <= s.loc["vector", "collision_hi"]
    for backend in runs:
        assert s.loc[backend, "collision_pct"] < s.loc["random", "collision_pct"], s
